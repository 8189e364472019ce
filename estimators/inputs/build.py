"""Orchestration shared by the three filters: a :class:`~ingest.flightlog.FlightLog` -> the flat, time-sorted
arrays the numba kernels loop over (docs/estimators.md, 'Inputs'; docs/estimators.md, 'Scheduling rule';
docs/estimators.md, 'Initial alignment'; docs/estimators.md, 'Sensor plan').

What this module decides, once, for every estimator:

* **IMU rows** ``(time_s, gyro, accel)``: each ``sensor_combined`` row is a zero-order-hold rate over the interval
  ending at its time stamp, so row ``k`` drives the propagation from ``time_s[k-1]`` to ``time_s[k]``.
  Non-finite rows and rows whose time does not advance (duplicates) are dropped; intervals longer than
  ``timing.max_imu_gap_factor`` median periods are reported as gaps (the filter propagates across them with the
  held rate and the process noise of the whole gap).
* **Measurement events** ``(time_s, kind, imu_index, values[6], variances[6])``, one row per sensor sample at the
  sensor's own sample time (``sample_time_s`` when logged, else the row time), sorted by time; ``imu_index`` is
  the IMU row whose interval contains the event, so the kernels propagate to the event time exactly (split dt),
  update, and continue. Repeated samples (the sample time did not advance) are dropped. GPS rows are fused at
  their measurement time, publication time minus the receiver latency ``EKF2_GPS_DELAY`` [ms] as PX4 EKF2 does;
  without that parameter the logged ``sample_time_s``, else the PX4 default delay
  (:func:`gps_measurement_time_s`). Output epochs
  (``OUTPUT``) are events too, on the grid ``k / rate_hz`` of the log clock.
* **Sensor plan**: which sensors are usable, which are skipped and why, and the degradations of
  docs/estimators.md, 'Sensor plan' (no airspeed -> no wind states and no airspeed; multicopter -> no fixed-wing
  pseudo-measurements; no GPS -> attitude and height only, with a zero-velocity pseudo-measurement keeping the
  tilt observable; no magnetometer -> yaw dead-reckoned).
* **Origin** (first good GPS fix, docs/estimators.md, 'Frames and attitude identities'), the earth magnetic
  field there (World Magnetic Model at the log's date), the barometer offset to GPS height and the **initial
  alignment** from the first still seconds (docs/estimators.md, 'Initial alignment').

Event values and variances per kind: :mod:`estimators.inputs.records`.
"""


from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import pandas as pd

from estimators import environment
from estimators.config import PX4_DEFAULT_GPS_DELAY_MS, EstimatorConfig
from estimators.inputs.alignment import initial_alignment
from estimators.inputs.records import (
    AIRSPEED,
    AUTO_HEADING,
    BARO,
    GPS_POS,
    GPS_VEL,
    HEADING_SOURCES,
    MAG,
    N_EVENT_VALUES,
    OUTPUT,
    SENSOR_NAMES,
    SIDESLIP,
    ZERO_VELOCITY,
    GpsRows,
    ImuSamples,
    MeasurementEvents,
    Origin,
    ReplayInputs,
    SensorPlan,
    resolve_heading,
)
from estimators.inputs.sun_events import sun_heading_events
from ingest.errors import InputError
from ingest.flightlog import FlightLog

#: Sensor-plan notes that state what the vehicle or the log is, not a problem (the dashboard shows them apart,
#: app.notes): a sensor the log does not have, a multicopter's unused fixed-wing aids.
NOT_IN_LOG = "not in the log"
NOT_FIXED_WING = "not a fixed-wing vehicle (MAV_TYPE)"
NO_AIRSPEED = "no airspeed: no wind states, no airspeed update"
MULTICOPTER = "multicopter: no fixed-wing pseudo-measurements"
#: GPS rows with a worse horizontal accuracy [m] are not used (docs/estimators.md, 'Sensor plan': eph < 10 m); the
#: origin needs < 5 m.
GPS_MAX_EPH_M = 10.0
GPS_ORIGIN_MAX_EPH_M = 5.0
#: Magnetometer stream accepted when its median field strength lies in this range [gauss] (docs/estimators.md, 'Sensor
#: plan').
MAG_STRENGTH_RANGE_GAUSS = (0.15, 1.0)
#: Spread of the measured field strength (1st to 99th percentile, relative to the median) above which the automatic
#: rule fuses the magnetometer as a heading: 12 %, a disturbance of +-6 % of the field, which in a three-axis update
#: tilts the reference by up to 3.4 deg (docs/estimators.md, 'Magnetometer heading fusion').
MAG_HEADING_SPREAD = 0.12
#: Horizontal accuracy assumed when a receiver reports none [m] (Table 1: NEO-M8N 2.5 m).
GPS_DEFAULT_EPH_M = 2.5
#: Seconds of GPS used to estimate the barometer offset (docs/three_stage.md, 'Pre-processing').
BARO_OFFSET_WINDOW_S = 10.0
#: Decimal year used for the magnetic model when a log carries no UTC time.
FALLBACK_DECIMAL_YEAR = 2020.0
#: Output/pseudo epochs allowed per IMU sample, plus a fixed allowance: more means the log's time axis is far
#: longer than its data (corrupt timestamps, docs/robustness.md, 'Time base checks'), and np.arange would
#: allocate without bound.
MAX_EPOCHS_PER_IMU_SAMPLE = 10
MAX_EPOCHS_FIXED = 1_000_000


def build_replay_inputs(flight_log: FlightLog, config: EstimatorConfig | None = None, *, rate_hz: float = 50.0,
                        heading: str = AUTO_HEADING, sun_observations: pd.DataFrame | None = None) -> ReplayInputs:
    """Prepare the kernel inputs of one log (validated once, here).

    Parameters
    ----------
    flight_log : FlightLog
        The canonical log; needs an ``imu`` stream.
    config : EstimatorConfig, optional
        Settings (defaults when None).
    rate_hz : float
        Output rate [Hz]; output epochs are ``k / rate_hz`` on the log clock.
    heading : {"auto", "mag", "sun", "mag+sun"}
        Absolute heading source(s); ``"auto"`` (default): ``"mag+sun"`` with sun-device data or
        ``sun_observations``, else ``"mag"`` (:func:`estimators.inputs.records.resolve_heading`).
    sun_observations : pandas.DataFrame, optional
        Sun-vector observations indexed by ``time_s`` [s] with columns ``sun_x, sun_y, sun_z`` (unit vector in
        body FRD), ``sun_n, sun_e, sun_d`` (unit vector towards the sun in NED) and ``sigma_rad`` (direction
        noise per tangent axis [rad]); produced by the sun-vector solver. Required for ``heading`` with sun.

    Returns
    -------
    ReplayInputs

    Raises
    ------
    InputError
        No usable IMU data, bad rate or heading choice, sun heading without sun observations.
    """
    config = EstimatorConfig() if config is None else config
    source = flight_log.meta.source
    if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and 0 < rate_hz <= 1000):
        raise InputError(f"output rate must be in (0, 1000] Hz, got {rate_hz!r}", field="rate_hz")
    if heading not in HEADING_SOURCES:
        raise InputError(f"heading must be one of {', '.join(HEADING_SOURCES)}, got {heading!r}", field="heading")
    chosen = heading != AUTO_HEADING
    heading = resolve_heading(heading, sun_observations is not None or flight_log.has("sun"))
    notes = _Notes()
    imu = _imu_samples(flight_log, config, notes.warnings)
    t_start, t_end = float(imu.time_s[0]), float(imu.time_s[-1])
    _check_epoch_count(t_start, t_end, max(rate_hz, config.timing.pseudo_rate_hz), len(imu.time_s), source)
    fixed_wing = bool(flight_log.meta.is_fixed_wing)
    if flight_log.meta.vehicle_type is None:
        notes.warnings.append("MAV_TYPE missing: multicopter assumptions (no fixed-wing pseudo-measurements)")

    gps_delay_s, delay_source = _gps_delay_s(flight_log, config)
    gps = _gps_rows(flight_log, gps_delay_s, delay_source, notes.skipped)
    origin = _origin(flight_log, gps)
    gravity = float(environment.local_gravity_m_s2(origin.lat_deg if origin.source == "gps" else 45.0,
                                                   origin.alt_m))
    if gps is not None:
        notes.parts += _gps_events(gps, origin, config)
    else:
        notes.degradations.append("no GPS: attitude and height only; zero-velocity pseudo-measurement keeps the "
                                  "tilt observable; no position or velocity output")
    baro, baro_offset_m = _baro_events(flight_log, gps, origin, config, notes)
    mag = _mag_events(flight_log, heading, origin, imu, config, notes)
    sun_part = sun_heading_events(flight_log, heading, sun_observations, origin, source, notes.warnings,
                                  chosen=chosen)
    if sun_part is not None:
        notes.parts.append(sun_part)
    airspeed = _airspeed_events(flight_log, gps, fixed_wing, config, notes)
    _pseudo_events(t_start, t_end, fixed_wing, airspeed, gps, config, notes)

    alignment, mag_rejection = initial_alignment(flight_log, imu, gps, mag.rows, mag.field_ned, mag.strength_gauss,
                                                 sun_part, origin, baro, baro_offset_m, gravity, config,
                                                 notes.warnings)
    mag_rows = mag.rows
    if mag_rejection is not None:
        notes.skipped["mag"] = mag_rejection
        notes.parts = [part for part in notes.parts if part[1] != MAG]
        mag_rows = None
    if mag_rows is None and sun_part is None:
        notes.degradations.append("no absolute heading (magnetometer/sun): yaw dead-reckoned from the gyro"
                                  + (" from the autopilot's initial yaw"
                                     if alignment.yaw_source == "onboard_attitude" else ""))
    output_time_s = np.arange(math.ceil(t_start * rate_hz - 1e-9), math.floor(t_end * rate_hz + 1e-9) + 1) / rate_hz
    notes.parts.append((output_time_s, OUTPUT, np.zeros((len(output_time_s), 0)),
                        np.zeros((len(output_time_s), 0))))
    events = _merge_events(notes.parts, imu.time_s)
    used = tuple(SENSOR_NAMES[k] for k in range(OUTPUT) if events.count(k) > 0)
    plan = SensorPlan(fixed_wing=fixed_wing, has_gps=gps is not None, has_baro=baro is not None,
                      has_mag=mag_rows is not None, has_airspeed=airspeed is not None, has_sun=sun_part is not None,
                      used=used, skipped=notes.skipped, degradations=tuple(notes.degradations),
                      mag_fusion=mag.fusion)
    return ReplayInputs(imu=imu, events=events, origin=origin, plan=plan, alignment=alignment,
                        mag_field_ned=mag.field_ned, mag_strength_gauss=mag.strength_gauss,
                        mag_field_source=mag.field_source, gravity_m_s2=gravity, gps_delay_s=gps_delay_s,
                        gps_time_rule=gps.time_rule if gps is not None else "", baro_offset_m=baro_offset_m,
                        output_time_s=output_time_s, source=source, warnings=tuple(notes.warnings))


@dataclass
class _Notes:
    """What :func:`build_replay_inputs` collects while it reads the streams: the event parts
    ``(time_s, kind, values, variances)`` and the sensor plan's notes."""

    parts: list[tuple[np.ndarray, int, np.ndarray, np.ndarray]] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    degradations: list[str] = field(default_factory=list)


class _Magnetometer(NamedTuple):
    """The magnetometer as the replay uses it: rows ``(time_s, field [gauss])`` (None: not used), the unit earth
    field NED, the median measured strength [gauss], the field's source and the fusion form."""

    rows: tuple[np.ndarray, np.ndarray] | None
    field_ned: np.ndarray
    strength_gauss: float
    field_source: str
    fusion: str


def _baro_events(flight_log: FlightLog, gps: GpsRows | None, origin: Origin, config: EstimatorConfig,
                 notes: _Notes):
    """Barometer height events above the origin (offset to the GPS height); returns the rows and the offset [m]."""
    baro_offset_m = 0.0
    baro = _sensor_rows(flight_log, "baro", ("alt_m",), notes.skipped)
    if baro is None:
        notes.degradations.append("no barometer: height from GPS only")
        return None, baro_offset_m
    baro_t, baro_alt = baro[0], baro[1][:, 0]
    if gps is not None:
        baro_offset_m = _baro_offset_m(baro_t, baro_alt, gps)
    z = baro_alt - baro_offset_m - origin.alt_m
    notes.parts.append((baro_t, BARO, z[:, None], np.full((len(z), 1), config.noise.baro_sigma_m ** 2)))
    return baro, baro_offset_m


def _mag_events(flight_log: FlightLog, heading: str, origin: Origin, imu: ImuSamples, config: EstimatorConfig,
                notes: _Notes) -> _Magnetometer:
    """Magnetometer events (field over its median strength) when the stream is plausible and a heading source."""
    mag = _sensor_rows(flight_log, "mag", ("mag_x_gauss", "mag_y_gauss", "mag_z_gauss"), notes.skipped)
    if mag is not None:
        strength = float(np.median(np.linalg.norm(mag[1], axis=1)))
        if not MAG_STRENGTH_RANGE_GAUSS[0] <= strength <= MAG_STRENGTH_RANGE_GAUSS[1]:
            notes.skipped["mag"] = (f"median field strength {strength:.3f} gauss outside "
                                    f"{MAG_STRENGTH_RANGE_GAUSS[0]}-{MAG_STRENGTH_RANGE_GAUSS[1]} gauss")
            mag = None
        elif heading not in ("mag", "mag+sun"):
            notes.skipped["mag"] = f"heading source is {heading!r}"
            mag = None
    if mag is None:
        return _Magnetometer(None, np.zeros(3), 1.0, "none", "none")
    field_ned, field_source = _earth_field_unit(flight_log, origin, mag, imu, config, notes.warnings)
    fusion = _mag_fusion(mag[1], strength, config, notes.degradations)
    values = mag[1] / strength
    mag_sigma = config.noise.mag_sigma_axes or (config.noise.mag_sigma,) * 3
    notes.parts.append((mag[0], MAG, values, np.broadcast_to(np.square(mag_sigma), values.shape).copy()))
    return _Magnetometer(mag, field_ned, strength, field_source, fusion)


def _airspeed_events(flight_log: FlightLog, gps: GpsRows | None, fixed_wing: bool, config: EstimatorConfig,
                     notes: _Notes):
    """True-airspeed events while flying; returns the rows (None: no airspeed, no wind states)."""
    airspeed = _sensor_rows(flight_log, "airspeed", ("tas_m_s",), notes.skipped)
    if airspeed is not None:
        tas_t, tas = airspeed[0], airspeed[1][:, 0]
        if np.nanstd(tas) < 0.1:
            notes.skipped["airspeed"] = "true airspeed constant"
            airspeed = None
        else:
            # a fixed-wing pitot on the ground reads the wind, not flight through the air
            flying = (_airborne(tas_t, airspeed, gps, config) if fixed_wing
                      else tas > config.timing.min_airspeed_m_s)
            if not flying.any():
                notes.skipped["airspeed"] = (f"never above {config.timing.min_airspeed_m_s} m/s"
                                             + (f" with a ground speed above {config.timing.min_ground_speed_m_s} "
                                                "m/s" if fixed_wing else ""))
                airspeed = None
            else:
                notes.parts.append((tas_t[flying], AIRSPEED, tas[flying, None],
                                    np.full((int(flying.sum()), 1), config.noise.airspeed_sigma_m_s ** 2)))
    if airspeed is None:
        notes.degradations.append(NO_AIRSPEED)
    return airspeed


def _pseudo_events(t_start: float, t_end: float, fixed_wing: bool, airspeed, gps: GpsRows | None,
                   config: EstimatorConfig, notes: _Notes) -> None:
    """Pseudo-measurements at ``timing.pseudo_rate_hz``: zero sideslip while a fixed wing flies, zero velocity
    without GPS (docs/estimators.md, 'Sensor plan')."""
    if fixed_wing:
        pseudo_t = _pseudo_times(t_start, t_end, config.timing.pseudo_rate_hz)
        airborne = _airborne(pseudo_t, airspeed, gps, config)
        sigma = config.noise.sideslip_sigma_m_s if airspeed is not None else config.noise.sideslip_no_wind_sigma_m_s
        times = pseudo_t[airborne]
        notes.parts.append((times, SIDESLIP, np.zeros((len(times), 1)), np.full((len(times), 1), sigma ** 2)))
    else:
        notes.skipped["sideslip"] = NOT_FIXED_WING
        notes.degradations.append(MULTICOPTER)
    if gps is None:
        times = _pseudo_times(t_start, t_end, config.timing.pseudo_rate_hz)
        notes.parts.append((times, ZERO_VELOCITY, np.zeros((len(times), 3)),
                            np.full((len(times), 3), config.noise.zero_velocity_sigma_m_s ** 2)))


# ----------------------------------------------------------------------------------------------------------------
# streams


def _imu_samples(flight_log: FlightLog, config: EstimatorConfig, warnings: list[str]) -> ImuSamples:
    source = flight_log.meta.source
    if not flight_log.has("imu"):
        raise InputError("no IMU data (sensor_combined): nothing to propagate", source=source, field="imu")
    frame = flight_log["imu"]
    gyro_columns = ("gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s")
    accel_columns = ("accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2")
    missing = [c for c in (*gyro_columns, *accel_columns) if c not in frame.columns]
    if missing:
        raise InputError(f"missing columns {missing}", source=source, field="imu")
    # writable copies (the kernels' compiled signatures take writable arrays), each made once
    time_s = frame.index.to_numpy(dtype=float, copy=True)
    columns = [frame[c].to_numpy(dtype=float) for c in (*gyro_columns, *accel_columns)]
    gyro, accel = np.column_stack(columns[:3]), np.column_stack(columns[3:])
    keep = np.logical_and.reduce([np.isfinite(time_s), *(np.isfinite(column) for column in columns)])
    # of the finite rows, keep strictly increasing times (a duplicate or a step back repeats a sample)
    keep[keep] = _new_samples(time_s[keep])
    n_dropped = int(np.count_nonzero(~keep))
    if n_dropped:
        time_s, gyro, accel = time_s[keep], gyro[keep], accel[keep]
    if len(time_s) < 10:
        raise InputError(f"only {len(time_s)} usable IMU rows", source=source, field="imu")
    dt = np.diff(time_s)
    median_dt = float(np.median(dt))
    is_gap = dt > config.timing.max_imu_gap_factor * median_dt
    gaps = tuple((float(time_s[i]), float(dt[i])) for i in np.flatnonzero(is_gap))
    if n_dropped:
        warnings.append(f"IMU: dropped {n_dropped} non-finite or repeated rows")
    if gaps:
        warnings.append(f"IMU: {len(gaps)} gaps (longest {max(g[1] for g in gaps):.3f} s), propagated with the "
                        "held rate")
    return ImuSamples(time_s=time_s, gyro_rad_s=gyro, accel_m_s2=accel, median_dt_s=median_dt, gaps=gaps,
                      n_dropped=n_dropped)


def _sample_time_s(frame: pd.DataFrame) -> np.ndarray:
    """The sensor's own sample time: ``sample_time_s`` when logged and plausible (at most 1 s before the row time,
    never after it), else the row time."""
    row_time = frame.index.to_numpy(dtype=float)
    if "sample_time_s" not in frame.columns:
        return row_time
    sample = frame["sample_time_s"].to_numpy(dtype=float)
    plausible = np.isfinite(sample) & (sample <= row_time) & (sample >= row_time - 1.0)
    return np.where(plausible, sample, row_time)


def _new_samples(time_s: np.ndarray) -> np.ndarray:
    """Mask of rows whose sample time advanced (a republished sample repeats its sample time)."""
    mask = np.ones(len(time_s), dtype=bool)
    if len(time_s) > 1:
        mask[1:] = time_s[1:] > np.maximum.accumulate(time_s)[:-1]
    return mask


def _sensor_rows(flight_log: FlightLog, stream: str, columns: tuple[str, ...], skipped: dict[str, str]):
    """``(sample_time_s, values)`` of the finite, new samples of a stream, or None (reason in ``skipped``)."""
    name = {"baro": "baro", "mag": "mag", "airspeed": "airspeed"}[stream]
    if not flight_log.has(stream):
        skipped[name] = NOT_IN_LOG
        return None
    frame = flight_log[stream]
    if any(c not in frame.columns for c in columns):
        skipped[name] = f"missing columns {[c for c in columns if c not in frame.columns]}"
        return None
    time_s = _sample_time_s(frame)
    values = frame.loc[:, list(columns)].to_numpy(dtype=float)
    keep = np.isfinite(time_s) & np.isfinite(values).all(axis=1)
    time_s, values = time_s[keep], values[keep]
    order = np.argsort(time_s, kind="stable")
    time_s, values = time_s[order], values[order]
    new = _new_samples(time_s)
    time_s, values = time_s[new], values[new]
    if len(time_s) < 2:
        skipped[name] = "fewer than two valid samples"
        return None
    return time_s, values


def _gps_delay_s(flight_log: FlightLog, config: EstimatorConfig) -> tuple[float, str]:
    """GPS latency [s] and where it comes from: ``"config"``, ``"parameter"`` (EKF2_GPS_DELAY) or ``"default"``."""
    if config.timing.gps_delay_s is not None:
        return float(config.timing.gps_delay_s), "config"
    value = flight_log.meta.parameters.get("EKF2_GPS_DELAY")
    if value is not None and math.isfinite(float(value)) and 0 <= float(value) < 1000:
        return float(value) / 1000.0, "parameter"
    return PX4_DEFAULT_GPS_DELAY_MS / 1000.0, "default"


def gps_measurement_time_s(frame: pd.DataFrame, delay_s: float, delay_source: str) -> tuple[np.ndarray, str]:
    """Time at which each GPS row was measured, and the rule used.

    PX4 EKF2 takes the GNSS publication time (``timestamp``, our row time) minus ``EKF2_GPS_DELAY`` (EKF2.cpp
    ``UpdateGpsSample`` and ``EstimatorInterface::setGpsData``); a logged ``timestamp_sample`` is not used by it.
    So: with an explicit delay (configuration or the log's parameter), ``row time - delay``; without one, the
    logged ``sample_time_s`` when present (the sensor's own measurement time), else ``row time -`` the PX4
    default. For solarnav's simulator (``timestamp = timestamp_sample + latency`` and ``EKF2_GPS_DELAY =
    latency``) the rules agree.
    """
    row_time = frame.index.to_numpy(dtype=float)
    if delay_source == "default" and "sample_time_s" in frame.columns:
        return _sample_time_s(frame), "sample_time_s"
    return row_time - delay_s, f"row time - {delay_s * 1000:.0f} ms ({delay_source})"


def _gps_rows(flight_log: FlightLog, delay_s: float, delay_source: str, skipped: dict[str, str]) -> GpsRows | None:
    if not flight_log.has("gps"):
        skipped["gps_pos"] = skipped["gps_vel"] = NOT_IN_LOG
        return None
    frame = flight_log["gps"]
    time_s, time_rule = gps_measurement_time_s(frame, delay_s, delay_source)
    get = lambda c: frame[c].to_numpy(dtype=float) if c in frame.columns else np.full(len(frame), np.nan)  # noqa: E731
    lat, lon, alt = get("lat_deg"), get("lon_deg"), get("alt_m")
    vel = np.column_stack([get("vn_m_s"), get("ve_m_s"), get("vd_m_s")])
    eph, epv, fix = get("eph_m"), get("epv_m"), get("fix_type")
    eph = np.where(np.isfinite(eph), eph, GPS_DEFAULT_EPH_M)
    epv = np.where(np.isfinite(epv), epv, 2.0 * eph)
    good = (np.isfinite(time_s) & np.isfinite(lat) & np.isfinite(lon) & np.isfinite(alt) & np.isfinite(vel).all(1)
            & (fix >= 3) & (eph < GPS_MAX_EPH_M)
            & ((np.abs(lat) + np.abs(lon)) > 0))  # (0, 0) is a receiver's "no position"
    if not good.any():
        skipped["gps_pos"] = skipped["gps_vel"] = f"no 3D fix with eph < {GPS_MAX_EPH_M} m"
        return None
    idx = np.flatnonzero(good)
    idx = idx[np.argsort(time_s[idx], kind="stable")]
    idx = idx[_new_samples(time_s[idx])]
    speed = get("speed_accuracy_m_s")[idx]
    return GpsRows(time_s=time_s[idx], lat_deg=lat[idx], lon_deg=lon[idx], alt_m=alt[idx], vel_ned=vel[idx],
                    eph_m=eph[idx], epv_m=epv[idx], speed_sigma_m_s=np.where(speed > 0, speed, np.nan),
                    time_rule=time_rule)


def _origin(flight_log: FlightLog, gps: GpsRows | None) -> Origin:
    if gps is not None:
        good = np.flatnonzero(gps.eph_m < GPS_ORIGIN_MAX_EPH_M)
        i = int(good[0]) if len(good) else 0
        return Origin(float(gps.lat_deg[i]), float(gps.lon_deg[i]), float(gps.alt_m[i]), "gps")
    if flight_log.has("baro"):
        alt = flight_log["baro"]["alt_m"].to_numpy(dtype=float)
        alt = alt[np.isfinite(alt)]
        if len(alt):
            return Origin(math.nan, math.nan, float(np.median(alt[:20])), "baro")
    return Origin(math.nan, math.nan, 0.0, "none")


def _gps_events(gps: GpsRows, origin: Origin, config: EstimatorConfig):
    noise = config.noise
    north, east, down = environment.geodetic_to_ned(gps.lat_deg, gps.lon_deg, gps.alt_m, origin.lat_deg,
                                                    origin.lon_deg, origin.alt_m)
    pos = np.column_stack([north, east, down])
    sigma_h = np.maximum(noise.gps_pos_eph_scale * gps.eph_m, noise.gps_pos_sigma_floor_m)
    sigma_v = np.maximum(noise.gps_hgt_epv_scale * gps.epv_m, noise.gps_hgt_sigma_floor_m)
    pos_var = np.column_stack([sigma_h ** 2, sigma_h ** 2, sigma_v ** 2])
    speed_sigma = np.where(np.isfinite(gps.speed_sigma_m_s), gps.speed_sigma_m_s, noise.gps_vel_sigma_default_m_s)
    speed_sigma = np.maximum(speed_sigma, noise.gps_vel_sigma_floor_m_s) * noise.gps_vel_accuracy_scale
    vel_var = np.repeat((speed_sigma ** 2)[:, None], 3, axis=1)
    return [(gps.time_s, GPS_POS, pos, pos_var), (gps.time_s, GPS_VEL, gps.vel_ned, vel_var)]


def _baro_offset_m(baro_t: np.ndarray, baro_alt: np.ndarray, gps: GpsRows) -> float:
    """Median of barometric minus GPS altitude over the first seconds with a fix
    (docs/three_stage.md, 'Pre-processing')."""
    window = gps.time_s <= gps.time_s[0] + BARO_OFFSET_WINDOW_S
    t = gps.time_s[window]
    inside = (t >= baro_t[0]) & (t <= baro_t[-1])
    if not inside.any():
        return 0.0
    baro_at_gps = np.interp(t[inside], baro_t, baro_alt)
    return float(np.median(baro_at_gps - gps.alt_m[window][inside]))


def _earth_field_unit(flight_log: FlightLog, origin: Origin, mag, imu: ImuSamples, config: EstimatorConfig,
                      warnings: list[str]) -> tuple[np.ndarray, str]:
    """Unit earth-field direction in NED: WMM at origin and date, else declination parameter + measured dip."""
    if origin.source == "gps":
        year = _decimal_year(flight_log)
        if year is None:
            year = FALLBACK_DECIMAL_YEAR
            warnings.append(f"no UTC time in the log: magnetic field of {FALLBACK_DECIMAL_YEAR:.1f} used")
        field_ned = environment.earth_field_ned_gauss(origin.lat_deg, origin.lon_deg, origin.alt_m, year)
        return field_ned / np.linalg.norm(field_ned), "wmm"
    params = flight_log.meta.parameters
    declination_deg = 0.0
    for name in ("EKF2_MAG_DECL", "ATT_MAG_DECL", "LPE_MAG_DECL"):
        if name in params and math.isfinite(float(params[name])):
            declination_deg = float(params[name])
            break
    # inclination from the first second: tilt-compensate the mean field with the mean specific force
    first = mag[0] <= mag[0][0] + 1.0
    m_b = mag[1][first].mean(axis=0)
    f_b = imu.accel_m_s2[imu.time_s <= imu.time_s[0] + 1.0].mean(axis=0)
    down_b = -f_b / np.linalg.norm(f_b)
    sin_dip = float(np.clip(np.dot(m_b, down_b) / np.linalg.norm(m_b), -1.0, 1.0))
    cos_dip = math.sqrt(1.0 - sin_dip ** 2)
    decl = math.radians(declination_deg)
    warnings.append(f"no position for the magnetic model: declination {declination_deg:.2f} deg from the log's "
                    f"parameters, inclination {math.degrees(math.asin(sin_dip)):.1f} deg measured")
    return np.array([cos_dip * math.cos(decl), cos_dip * math.sin(decl), sin_dip]), "declination_parameter"


def _decimal_year(flight_log: FlightLog) -> float | None:
    offset = flight_log.meta.utc_offset_s
    if offset is None and flight_log.has("gps") and "time_utc_s" in flight_log["gps"].columns:
        utc = flight_log["gps"]["time_utc_s"].to_numpy(dtype=float)
        utc = utc[np.isfinite(utc) & (utc > 1e9)]
        if len(utc):
            return environment.decimal_year(pd.Timestamp(float(np.median(utc)), unit="s"))
    if offset is None:
        return None
    t0 = float(flight_log["imu"].index[0])
    return environment.decimal_year(pd.Timestamp(t0 + offset, unit="s"))


def _check_epoch_count(t_start: float, t_end: float, rate_hz: float, n_imu: int, source: str) -> None:
    """Raise InputError when epochs at ``rate_hz`` [Hz] over [t_start, t_end] [s] would far outnumber the
    ``n_imu`` IMU samples (a defence: ingest drops corrupt timestamps, docs/robustness.md, 'Time base checks')."""
    n_epochs = (t_end - t_start) * rate_hz
    if not n_epochs <= MAX_EPOCHS_PER_IMU_SAMPLE * n_imu + MAX_EPOCHS_FIXED:
        raise InputError(f"the IMU time axis spans {t_end - t_start:.6g} s for only {n_imu} samples: {n_epochs:.3g} "
                         f"epochs at {rate_hz:g} Hz is implausible (corrupt timestamps)", source=source, field="imu")


def _mag_fusion(field_gauss: np.ndarray, strength_gauss: float, config: EstimatorConfig,
                degradations: list[str]) -> str:
    """``"heading"`` or ``"vector"`` (docs/estimators.md, 'Magnetometer heading fusion'): ``config.mag_fusion``, or
    with ``"auto"`` the heading when the measured field strength spreads (1st to 99th percentile) by more than
    :data:`MAG_HEADING_SPREAD` of its median, a disturbance that would pull roll and pitch by more than 3 deg;
    a degradation line says why."""
    if config.mag_fusion != "auto":
        return config.mag_fusion
    low, high = np.percentile(np.linalg.norm(field_gauss, axis=1), (1.0, 99.0))
    spread = float((high - low) / strength_gauss)
    if spread <= MAG_HEADING_SPREAD:
        return "vector"
    degradations.append(f"magnetometer fused as its heading only: the field strength spreads by {spread:.0%} "
                        f"(1st-99th percentile) of its median, more than {MAG_HEADING_SPREAD:.0%}: a disturbed field "
                        "(currents, motors) would pull roll and pitch")
    return "heading"


def _pseudo_times(t_start: float, t_end: float, rate_hz: float) -> np.ndarray:
    return np.arange(math.ceil(t_start * rate_hz), math.floor(t_end * rate_hz) + 1) / rate_hz


def _airborne(times: np.ndarray, airspeed, gps: GpsRows | None, config: EstimatorConfig) -> np.ndarray:
    """Flying (fixed-wing models valid) at ``times``: the last airspeed above the minimum and the last GPS ground
    speed above V_min; either alone when the other sensor is missing (docs/estimators.md, 'Sensor plan'). The ground
    speed rule keeps a pitot on the ground, which reads the wind, from being taken for flight."""
    if airspeed is None and gps is None:
        return np.zeros(len(times), dtype=bool)
    result = np.ones(len(times), dtype=bool)
    if airspeed is not None:
        result &= _last_above(times, airspeed[0], airspeed[1][:, 0], config.timing.min_airspeed_m_s)
    if gps is not None:
        result &= _last_above(times, gps.time_s, np.hypot(gps.vel_ned[:, 0], gps.vel_ned[:, 1]),
                              config.timing.min_ground_speed_m_s)
    return result


def _last_above(times: np.ndarray, t: np.ndarray, value: np.ndarray, threshold: float) -> np.ndarray:
    """The last sample of ``value`` (at ``t``) at or before each of ``times`` exceeds ``threshold``."""
    i = np.searchsorted(t, times, side="right") - 1
    valid = i >= 0
    result = np.zeros(len(times), dtype=bool)
    result[valid] = value[i[valid]] > threshold
    return result


def _merge_events(parts, imu_time_s: np.ndarray) -> MeasurementEvents:
    """One time-sorted event table from ``(time_s, kind, values, variances)`` parts; equal times in kind order."""
    # parts in kind order, so a stable sort by time alone keeps equal times in kind order (each part's own order
    # after that), and the sort merges a few already sorted runs
    parts = sorted(parts, key=lambda part: part[1])
    time_s = np.concatenate([p[0] for p in parts])
    kind = np.concatenate([np.full(len(p[0]), p[1], dtype=np.int64) for p in parts])
    inside = np.flatnonzero((time_s >= imu_time_s[0]) & (time_s <= imu_time_s[-1]))
    order = inside[np.argsort(time_s[inside], kind="stable")]
    # each part's values go straight to their sorted rows (-1: outside the IMU span)
    sorted_row = np.full(len(time_s), -1)
    sorted_row[order] = np.arange(len(order))
    values = np.zeros((len(order), N_EVENT_VALUES))
    variances = np.zeros((len(order), N_EVENT_VALUES))
    start = 0
    for t, _, v, r in parts:
        rows = sorted_row[start:start + len(t)]
        kept = rows >= 0
        values[rows[kept], :v.shape[1]] = v[kept]
        variances[rows[kept], :r.shape[1]] = r[kept]
        start += len(t)
    time_s = time_s[order]
    imu_index = np.searchsorted(imu_time_s, time_s, side="left").astype(np.int64)
    return MeasurementEvents(time_s=time_s, kind=kind[order], imu_index=imu_index, values=values,
                             variances=variances)
