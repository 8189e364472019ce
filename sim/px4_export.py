"""Write a simulation as the files a user uploads: a PX4-style ULog, the sun-device CSV and device JSON, and a JSON
side file with the scenario and the injected sensor errors.

Topics and fields are those of PX4 >= 1.14 (``ver_data_format`` 2: float64 GPS degrees and metres):
``sensor_combined``, ``vehicle_magnetometer``, ``vehicle_air_data``, ``airspeed``, ``vehicle_gps_position``, the
SITL ground truth ``vehicle_attitude_groundtruth``, ``vehicle_local_position_groundtruth``,
``vehicle_global_position_groundtruth``, and the true wind (which PX4 does not log) in
``solarnav_wind_groundtruth`` (``timestamp``, ``windspeed_north``, ``windspeed_east``; float32 m/s).
Every file is written atomically (:func:`ingest.files.atomic_write_bytes`) and is a pure function of the simulation,
so a rerun with the same seed reproduces it byte for byte.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
from pathlib import Path

import numpy as np
import pandas as pd

from estimators.environment import air_density_kg_m3
from ingest.files import atomic_write_bytes
from ingest.flightlog import FlightLog
from sim.simulate import HARDWARE, STREAM_TOPICS, SimResult
from sim.ulog_writer import ulog_bytes

#: Decimals of the sun-device CSV: time [s] (1 ms) and currents [mA] (0.1 uA).
CSV_TIME_DECIMALS = 3
CSV_CURRENT_DECIMALS = 4

_F4, _F8, _U8 = np.float32, np.float64, np.uint64


def _table(time_s, columns: list[tuple[str, type, np.ndarray]]) -> np.ndarray:
    """Structured rows: ``timestamp`` [us] from ``time_s`` [s], then ``(field, type, values)``; 2-D values make
    an array field."""
    time_s = np.asarray(time_s, dtype=float)
    fields = [("timestamp", _U8)] + [(name, kind, np.shape(values)[1:]) for name, kind, values in columns]
    table = np.empty(len(time_s), dtype=fields)
    table["timestamp"] = np.round(time_s * 1e6).astype(np.int64)
    for name, _, values in columns:
        table[name] = values
    return table


def _us(seconds) -> np.ndarray:
    return np.round(np.asarray(seconds, dtype=float) * 1e6).astype(np.int64)


def px4_topics(log: FlightLog, *, origin: tuple[float, float, float],
               airspeed_air_temp_c: np.ndarray | None = None) -> list[tuple[str, np.ndarray]]:
    """The PX4 topics of a canonical flight log (streams it lacks are left out; ``sun`` is not a PX4 topic).

    Parameters
    ----------
    log : FlightLog
        Streams in the canonical layout; ``gps``, ``mag``, ``baro``, ``airspeed`` may carry ``sample_time_s``.
    origin : tuple of 3 float
        Reference (lat [deg], lon [deg], alt [m]) of ``truth_local_position`` (PX4 ``ref_lat/ref_lon/ref_alt``).
    airspeed_air_temp_c : numpy.ndarray, optional
        Outside-air temperature per ``airspeed`` row [degC]; NaN when omitted.

    Returns
    -------
    list of (topic name, structured array)
    """
    s = log.streams
    topics = []

    def sample_us(frame):
        return _us(frame.get("sample_time_s", frame.index))

    if log.has("imu"):
        f = s["imu"]
        dt_us = _us(f["dt_s"]) if "dt_s" in f else np.zeros(len(f), dtype=np.int64)
        topics.append((STREAM_TOPICS["imu"], _table(f.index, [
            ("gyro_rad", _F4, f[["gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"]].to_numpy()),
            ("gyro_integral_dt", np.uint32, dt_us),
            ("accelerometer_timestamp_relative", np.int32, np.zeros(len(f))),
            ("accelerometer_m_s2", _F4, f[["accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"]].to_numpy()),
            ("accelerometer_integral_dt", np.uint32, dt_us)])))
    if log.has("mag"):
        f = s["mag"]
        topics.append((STREAM_TOPICS["mag"], _table(f.index, [
            ("timestamp_sample", _U8, sample_us(f)),
            ("magnetometer_ga", _F4, f[["mag_x_gauss", "mag_y_gauss", "mag_z_gauss"]].to_numpy())])))
    if log.has("baro"):
        f = s["baro"]
        topics.append((STREAM_TOPICS["baro"], _table(f.index, [
            ("timestamp_sample", _U8, sample_us(f)), ("baro_alt_meter", _F4, f["alt_m"]),
            ("baro_temp_celcius", _F4, f["temp_c"]), ("baro_pressure_pa", _F4, f["pressure_pa"]),
            ("rho", _F4, air_density_kg_m3(f["pressure_pa"], f["temp_c"]))])))
    if log.has("airspeed"):
        f = s["airspeed"]
        air_temp = np.full(len(f), np.nan) if airspeed_air_temp_c is None else airspeed_air_temp_c
        topics.append((STREAM_TOPICS["airspeed"], _table(f.index, [
            ("timestamp_sample", _U8, sample_us(f)), ("indicated_airspeed_m_s", _F4, f["ias_m_s"]),
            ("true_airspeed_m_s", _F4, f["tas_m_s"]), ("air_temperature_celsius", _F4, air_temp),
            ("confidence", _F4, np.ones(len(f)))])))
    if log.has("gps"):
        f = s["gps"]
        vn, ve = f["vn_m_s"].to_numpy(), f["ve_m_s"].to_numpy()
        utc_us = np.where(np.isfinite(f["time_utc_s"]), _us(f["time_utc_s"].fillna(0.0)), 0)
        topics.append((STREAM_TOPICS["gps"], _table(f.index, [
            ("timestamp_sample", _U8, sample_us(f)), ("latitude_deg", _F8, f["lat_deg"]),
            ("longitude_deg", _F8, f["lon_deg"]), ("altitude_msl_m", _F8, f["alt_m"]),
            ("time_utc_usec", _U8, utc_us), ("eph", _F4, f["eph_m"]), ("epv", _F4, f["epv_m"]),
            ("s_variance_m_s", _F4, f.get("speed_accuracy_m_s", pd.Series(np.nan, index=f.index))),
            ("vel_m_s", _F4, np.hypot(vn, ve)), ("vel_n_m_s", _F4, vn), ("vel_e_m_s", _F4, ve),
            ("vel_d_m_s", _F4, f["vd_m_s"]), ("cog_rad", _F4, np.arctan2(ve, vn)),
            ("fix_type", np.uint8, f["fix_type"]), ("vel_ned_valid", np.bool_, np.ones(len(f), dtype=bool)),
            ("satellites_used", np.uint8, f.get("satellites_used", pd.Series(0, index=f.index)))])))
    if log.has("truth_attitude"):
        f = s["truth_attitude"]
        topics.append((STREAM_TOPICS["truth_attitude"], _table(f.index, [
            ("q", _F4, f[["qw", "qx", "qy", "qz"]].to_numpy())])))
    if log.has("truth_local_position"):
        f = s["truth_local_position"]
        n = len(f)
        topics.append((STREAM_TOPICS["truth_local_position"], _table(f.index, [
            ("ref_lat", _F8, np.full(n, origin[0])), ("ref_lon", _F8, np.full(n, origin[1])),
            *((name, _F4, f[f"{name}_m"]) for name in ("x", "y", "z")),
            *((name, _F4, f[f"{name}_m_s"]) for name in ("vx", "vy", "vz")),
            ("ref_alt", _F4, np.full(n, origin[2]))])))
    if log.has("truth_global_position"):
        f = s["truth_global_position"]
        topics.append((STREAM_TOPICS["truth_global_position"], _table(f.index, [
            ("lat", _F8, f["lat_deg"]), ("lon", _F8, f["lon_deg"]), ("alt", _F4, f["alt_m"])])))
    if log.has("truth_wind"):
        f = s["truth_wind"]
        topics.append((STREAM_TOPICS["truth_wind"], _table(f.index, [
            ("windspeed_north", _F4, f["wind_n_m_s"]), ("windspeed_east", _F4, f["wind_e_m_s"])])))
    return topics


def sun_csv_text(sun: pd.DataFrame, utc_offset_s: float) -> str:
    """The sun-device CSV: ``unix_time_s`` (UTC) and ``i1_mA`` .. ``i7_mA``, fixed decimals."""
    values = np.column_stack([sun.index.to_numpy() + utc_offset_s, sun.to_numpy() * 1e3])
    buffer = io.StringIO()
    header = ",".join(["unix_time_s", *(f"i{cell}_mA" for cell in range(1, sun.shape[1] + 1))])
    np.savetxt(buffer, values, delimiter=",", header=header, comments="",
               fmt=[f"%.{CSV_TIME_DECIMALS}f"] + [f"%.{CSV_CURRENT_DECIMALS}f"] * sun.shape[1])
    return buffer.getvalue()


def _jsonable(value):
    if isinstance(value, dict):
        return {str(key): _jsonable(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(item) for item in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def side_file(result: SimResult) -> dict:
    """JSON-ready record of the run: scenario (mission, site, wind with its turbulence and discrete gusts when
    configured, sensor grades), seed, mission segments [s of log clock], the UTC offset and the injected sensor
    errors."""
    start = result.log.meta.start_time_s
    scenario = dataclasses.asdict(result.scenario)
    if scenario["wind"]["turbulence"] is None:  # keeps the record of a scenario without turbulence as it was
        del scenario["wind"]["turbulence"]
    return _jsonable({
        "scenario": scenario | {"mission": {
            "legs": [{"leg": type(leg).__name__, **dataclasses.asdict(leg)} for leg in result.scenario.mission.legs],
            "initial_heading_deg": result.scenario.mission.initial_heading_deg,
            "manoeuvre": dataclasses.asdict(result.scenario.mission.manoeuvre)}},
        "seed": result.seed,
        "segments_log_time_s": [{"leg": name, "start_s": start + t0, "end_s": start + t1}
                                for name, t0, t1 in result.truth.segments],
        "utc_offset_s": result.truth.utc_offset_s,
        "origin": {"lat_deg": result.truth.origin[0], "lon_deg": result.truth.origin[1],
                   "alt_m": result.truth.origin[2]},
        "sensor_errors": result.errors,
    })


def output_paths(directory: str | os.PathLike, name: str) -> dict[str, Path]:
    """Files of a simulation named ``name`` in ``directory``: ``ulog``, ``sun_csv``, ``device_json``, ``side_json``."""
    directory = Path(directory)
    return {"ulog": directory / f"{name}.ulg", "sun_csv": directory / f"{name}_sun.csv",
            "device_json": directory / f"{name}_device.json", "side_json": directory / f"{name}_sim.json"}


def write_outputs(result: SimResult, directory: str | os.PathLike) -> dict[str, Path]:
    """Write the ULog, sun CSV, device JSON and side JSON of ``result`` into ``directory`` (created if needed).

    Returns
    -------
    dict of str -> pathlib.Path
        As :func:`output_paths`.
    """
    paths = output_paths(directory, result.scenario.name)
    paths["ulog"].parent.mkdir(parents=True, exist_ok=True)
    log = result.log
    topics = px4_topics(log, origin=result.truth.origin, airspeed_air_temp_c=result.airspeed_air_temp_c)
    info = {"sys_name": HARDWARE, "ver_hw": HARDWARE, "ver_data_format": 2}
    atomic_write_bytes(paths["ulog"], ulog_bytes(topics, info=info, parameters=log.meta.parameters))
    atomic_write_bytes(paths["sun_csv"], sun_csv_text(log.streams["sun"], log.meta.utc_offset_s).encode())
    device = dataclasses.asdict(result.scenario.sensors.device)
    for path, content in ((paths["device_json"], device), (paths["side_json"], side_file(result))):
        atomic_write_bytes(path, (json.dumps(_jsonable(content), indent=2, sort_keys=True) + "\n").encode())
    return paths
