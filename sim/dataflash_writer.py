"""Write a simulation as an ArduPilot DataFlash ``.bin`` (the format :mod:`ingest.dataflash_reader` reads).

The file holds what an ArduPlane log holds for the canonical streams, in the layouts of ArduPilot 4.0
(``libraries/AP_Logger/LogStructure.h``; only the fields the reader uses): ``IMU``, ``MAG`` (mGauss), ``BARO``
(Alt relative to the first sample, Press, Temp), ``GPS`` + ``GPA`` (GPS week and milliseconds, speed, course and
climb rate, accuracies, the fix's sample time in ms), ``ARSP``; SITL's ground truth ``SIM`` (attitude quaternion,
Lat/Lng/Alt) and ``SIM2`` (NED position and velocity), and the true wind, which ArduPilot does not log, in
solarnav's own ``SWND`` (``TimeUS``, ``WN``, ``WE``; float32 m/s). ``PARM`` and the firmware / board ``MSG`` lines
come first, then every data record merged by time (stable: ties keep the message order, then the row order).
Records are laid out with numpy structured arrays; the file is a pure function of the simulation and is written
atomically (:func:`ingest.files.atomic_write_bytes`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ingest import dataflash_format as df
from ingest.atmosphere import ISA_SEA_LEVEL_DENSITY_KG_M3
from ingest.dataflash_reader import GPS_EPOCH_UNIX_S, MGAUSS_TO_GAUSS, WEEK_S, leap_seconds
from ingest.files import atomic_write_bytes
from ingest.flightlog import FlightLog
from sim.simulate import HARDWARE, SimResult

#: Firmware line of the simulated log (the reader takes the vehicle type, fixed wing, from it).
FIRMWARE = f"ArduPlane V4.0.8 ({HARDWARE})"
#: Type id of the first message written after ``FMT`` (ArduPilot's ids are its own; the reader uses names).
FIRST_TYPE_ID = 129


@dataclass(frozen=True)
class Message:
    """Rows of one message type: ``codes`` (DataFlash format, ``TimeUS`` first as ``Q``), ``columns`` and the
    values of every column after ``TimeUS`` in DataFlash's meaning (degrees, metres; the writer applies the x100
    / x1e7 storage of c/C/e/E/L)."""

    name: str
    codes: str
    columns: tuple[str, ...]
    time_s: np.ndarray
    values: tuple[np.ndarray, ...]


def _stored(values: np.ndarray, code: str) -> np.ndarray:
    """Values as stored for format ``code``: divided by its scale and rounded for integer codes."""
    kind, scale = df.FORMAT_CODES[code]
    if code in "nNZ":
        return np.asarray(values, dtype=kind)
    stored = np.asarray(values, dtype=float) / scale
    return stored if np.dtype(kind).kind == "f" else np.round(stored).astype(np.int64)


def dataflash_bytes(messages: Sequence[Message], *, parameters: Mapping[str, float], texts: Sequence[str],
                    start_time_s: float) -> bytes:
    """The file: ``FMT`` records, ``PARM`` and ``MSG`` (``texts``) records at ``start_time_s``, then the data
    records of ``messages`` merged by time."""
    start = np.array([start_time_s])
    header = [Message("PARM", "QNf", ("TimeUS", "Name", "Value"), np.repeat(start, len(parameters)),
                      (np.array([name.encode() for name in parameters], dtype="S16"),
                       np.array(list(parameters.values()), dtype=float))),
              Message("MSG", "QZ", ("TimeUS", "Message"), np.repeat(start, len(texts)),
                      (np.array([text.encode() for text in texts], dtype="S64"),))]
    everything = [*header, *messages]
    definitions = [(df.FMT_TYPE, df.FMT_LENGTH, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")]
    tables = []
    for k, message in enumerate(everything):
        type_id = FIRST_TYPE_ID + k
        dtype = df.record_dtype(message.codes, message.columns)
        definitions.append((type_id, dtype.itemsize, message.name, message.codes, ",".join(message.columns)))
        table = np.zeros(len(message.time_s), dtype=dtype)
        table["_head"] = np.void(bytes((df.HEAD_1, df.HEAD_2, type_id)))
        table["TimeUS"] = np.round(np.asarray(message.time_s, dtype=float) * 1e6).astype(np.uint64)
        for column, code, values in zip(message.columns[1:], message.codes[1:], message.values, strict=True):
            table[column] = _stored(values, code)
        tables.append(table)
    fmt = np.zeros(len(definitions), dtype=df.FMT_DTYPE)
    fmt["head"] = np.void(bytes((df.HEAD_1, df.HEAD_2, df.FMT_TYPE)))
    for field, values in zip(("type", "length", "name", "format", "columns"), zip(*definitions, strict=True),
                             strict=True):
        fmt[field] = [value.encode() if isinstance(value, str) else value for value in values]
    # Header records first (they are timed at the start anyway), then a stable merge of the data by time.
    time_us = np.concatenate([np.where(k < len(header), 0, t["TimeUS"].astype(np.int64))
                              for k, t in enumerate(tables)])
    kind = np.concatenate([np.full(len(t), k) for k, t in enumerate(tables)])
    row = np.concatenate([np.arange(len(t)) for t in tables])
    order = np.lexsort((row, kind, time_us))
    lengths = np.array([t.dtype.itemsize for t in tables])[kind[order]]
    offsets = np.empty(len(order), dtype=np.int64)
    offsets[order] = np.cumsum(lengths) - lengths
    body = np.zeros(int(lengths.sum()), dtype=np.uint8)
    for k, table in enumerate(tables):
        size = table.dtype.itemsize
        body[offsets[kind == k][:, None] + np.arange(size)] = table.view(np.uint8).reshape(len(table), size)
    return fmt.tobytes() + body.tobytes()


def dataflash_messages(log: FlightLog) -> list[Message]:
    """The DataFlash messages of a canonical (simulated) flight log; streams it lacks are left out."""
    s = log.streams
    messages = []
    if log.has("imu"):
        f = s["imu"]
        messages.append(Message("IMU", "Qffffff", ("TimeUS", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"),
                                f.index.to_numpy(), tuple(f[c].to_numpy() for c in (
                                    "gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s",
                                    "accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"))))
    if log.has("mag"):
        f = s["mag"]
        messages.append(Message("MAG", "Qhhh", ("TimeUS", "MagX", "MagY", "MagZ"), f.index.to_numpy(),
                                tuple(f[f"mag_{a}_gauss"].to_numpy() / MGAUSS_TO_GAUSS for a in "xyz")))
    if log.has("baro"):
        f = s["baro"]
        alt_m = f["alt_m"].to_numpy()
        messages.append(Message("BARO", "Qffc", ("TimeUS", "Alt", "Press", "Temp"), f.index.to_numpy(),
                                (alt_m - alt_m[0], f["pressure_pa"].to_numpy(), f["temp_c"].to_numpy())))
    if log.has("gps"):
        messages += _gps_messages(s["gps"])
    if log.has("airspeed"):
        f = s["airspeed"]
        ias = f["ias_m_s"].to_numpy()
        messages.append(Message("ARSP", "Qff", ("TimeUS", "Airspeed", "DiffPress"), f.index.to_numpy(),
                                (ias, np.sign(ias) * 0.5 * ISA_SEA_LEVEL_DENSITY_KG_M3 * ias**2)))
    if log.has("truth_attitude") and log.has("truth_global_position"):
        att, pos = s["truth_attitude"], s["truth_global_position"]
        time_s = att.index.to_numpy()
        position = [np.interp(time_s, pos.index.to_numpy(), pos[c].to_numpy()) for c in ("alt_m", "lat_deg",
                                                                                          "lon_deg")]
        messages.append(Message("SIM", "QccCfLLffff", ("TimeUS", "Roll", "Pitch", "Yaw", "Alt", "Lat", "Lng", "Q1",
                                                       "Q2", "Q3", "Q4"), time_s,
                                (att["roll_deg"].to_numpy(), att["pitch_deg"].to_numpy(),
                                 att["yaw_deg"].to_numpy() % 360.0, *position,
                                 *(att[c].to_numpy() for c in ("qw", "qx", "qy", "qz")))))
    if log.has("truth_local_position"):
        f = s["truth_local_position"]
        messages.append(Message("SIM2", "Qffffff", ("TimeUS", "PN", "PE", "PD", "VN", "VE", "VD"), f.index.to_numpy(),
                                tuple(f[c].to_numpy() for c in ("x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s"))))
    if log.has("truth_wind"):
        f = s["truth_wind"]
        messages.append(Message("SWND", "Qff", ("TimeUS", "WN", "WE"), f.index.to_numpy(),
                                (f["wind_n_m_s"].to_numpy(), f["wind_e_m_s"].to_numpy())))
    return messages


def _gps_messages(f) -> list[Message]:
    """``GPS`` and ``GPA`` at the row times: GPS week / ms from the UTC time, speed and course from the NED
    velocity, the sample time as GPA SMS [ms]."""
    utc_s = f["time_utc_s"].to_numpy()
    has_time = np.isfinite(utc_s)
    gps_s = np.where(has_time, utc_s, GPS_EPOCH_UNIX_S) - GPS_EPOCH_UNIX_S + np.where(has_time, leap_seconds(utc_s), 0)
    week = np.floor(gps_s / WEEK_S)
    week_ms = np.round((gps_s - week * WEEK_S) * 1e3)
    vn, ve = f["vn_m_s"].to_numpy(), f["ve_m_s"].to_numpy()
    time_s = f.index.to_numpy()
    sample_s = f["sample_time_s"].to_numpy() if "sample_time_s" in f else time_s
    n = len(f)
    speed_accuracy = f["speed_accuracy_m_s"].to_numpy() if "speed_accuracy_m_s" in f else np.zeros(n)
    satellites = f["satellites_used"].to_numpy() if "satellites_used" in f else np.zeros(n)
    return [
        Message("GPS", "QBIHBCLLefff", ("TimeUS", "Status", "GMS", "GWk", "NSats", "HDop", "Lat", "Lng", "Alt", "Spd",
                                        "GCrs", "VZ"), time_s,
                (f["fix_type"].to_numpy(), week_ms, week, satellites, np.ones(n), f["lat_deg"].to_numpy(),
                 f["lon_deg"].to_numpy(), f["alt_m"].to_numpy(), np.hypot(vn, ve),
                 np.degrees(np.arctan2(ve, vn)) % 360.0, f["vd_m_s"].to_numpy())),
        Message("GPA", "QCCCCI", ("TimeUS", "VDop", "HAcc", "VAcc", "SAcc", "SMS"), time_s,
                (np.ones(n), f["eph_m"].to_numpy(), f["epv_m"].to_numpy(), speed_accuracy, sample_s * 1e3)),
    ]


def write_dataflash(result: SimResult, path: str | os.PathLike) -> Path:
    """Write ``result`` as a DataFlash ``.bin`` at ``path`` (atomically); returns ``path``.

    Parameters: ``SCHED_LOOP_RATE`` (the IMU rate, as a 50-400 Hz ArduPilot loop logs its IMU),
    ``GPS_DELAY_MS`` (the receiver latency), ``ARSPD_TYPE`` 1 (an airspeed sensor fitted) and
    ``AHRS_EKF_TYPE`` 3.
    """
    log = result.log
    sensors = result.scenario.sensors
    parameters = {"SCHED_LOOP_RATE": float(sensors.imu.rate_hz), "GPS_DELAY_MS": float(sensors.gps.latency_s * 1e3),
                  "ARSPD_TYPE": 1.0, "AHRS_EKF_TYPE": 3.0}
    texts = [FIRMWARE, f"{HARDWARE} 00000000 00000000 00000000"]
    content = dataflash_bytes(dataflash_messages(log), parameters=parameters, texts=texts,
                              start_time_s=log.meta.start_time_s)
    return atomic_write_bytes(path, content)
