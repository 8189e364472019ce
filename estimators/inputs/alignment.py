"""Initial alignment from the first still seconds of the log (docs/estimators.md, 'Initial alignment'): still
window, tilt from the mean specific force, yaw from the magnetometer (or the onboard estimate), gyro bias.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from estimators import environment
from estimators.config import EstimatorConfig
from estimators.inputs.records import Alignment, GpsRows, ImuSamples, Origin
from ingest.flightlog import FlightLog
from ingest.frames import quat_to_euler

#: The sun gives an initial yaw only when its horizontal component (cos of the elevation) exceeds this.
MIN_SUN_HORIZONTAL = 0.2
#: A still window's specific-force norm may differ this much from gravity (accelerometer offset) [m/s^2].
STILL_GRAVITY_TOLERANCE_M_S2 = 1.0
#: A magnetometer whose inclination at the start differs more than this from the reference field is not used [deg].
MAG_DIP_TOLERANCE_DEG = 15.0


# ----------------------------------------------------------------------------------------------------------------
# initial alignment (docs/estimators.md, 'Initial alignment')


def still_window(imu: ImuSamples, gravity_m_s2: float, config: EstimatorConfig) -> tuple[int, int] | None:
    """Row range ``[i0, i1)`` of the first still window starting at the log start, or None.

    Still means a 0.2 s moving average of the gyro below ``timing.still_gyro_rad_s`` and a specific-force norm
    within ``timing.still_accel_m_s2`` of its median over the first second (not of g: a MEMS accelerometer's
    zero-g offset, up to 80 mg in Table 1, would hide every still window), that median itself within
    :data:`STILL_GRAVITY_TOLERANCE_M_S2` of gravity. The window must start within the first second and last at
    least ``timing.still_window_s``.
    """
    timing = config.timing
    t = imu.time_s
    n_avg = min(max(1, round(0.2 / imu.median_dt_s)), len(t))
    first_second = int(np.searchsorted(t, t[0] + 1.0, side="right"))
    # The test runs on growing prefixes of the log: the window ends at the first moving row, usually seconds after
    # the start. A prefix's last n_avg rows are left to the next, longer prefix (their averages need later rows).
    rows = min(len(t), first_second + 2 * n_avg)
    while True:
        gyro_norm = np.linalg.norm(_moving_average(imu.gyro_rad_s[:rows], n_avg), axis=1)
        accel_norm = np.linalg.norm(_moving_average(imu.accel_m_s2[:rows], n_avg), axis=1)
        reference = float(np.median(accel_norm[:first_second]))
        if abs(reference - gravity_m_s2) > STILL_GRAVITY_TOLERANCE_M_S2:
            return None
        still = (gyro_norm < timing.still_gyro_rad_s) & (np.abs(accel_norm - reference) < timing.still_accel_m_s2)
        if rows < len(t):
            still = still[:rows - n_avg]
        start_candidates = np.flatnonzero(still[:first_second])
        if len(start_candidates) == 0:
            return None
        i0 = int(start_candidates[0])
        moving = np.flatnonzero(~still[i0:])
        if len(moving) or rows == len(t):
            break
        rows = min(len(t), 2 * rows)
    i1 = i0 + int(moving[0]) if len(moving) else len(t)
    if t[i1 - 1] - t[i0] < timing.still_window_s:
        return None
    return i0, i1


def _moving_average(values: np.ndarray, n_avg: int) -> np.ndarray:
    """Centred moving average of the rows of ``values`` (n, k) over ``n_avg`` <= n rows: row i averages rows
    ``i - n_avg // 2`` to ``i - n_avg // 2 + n_avg - 1``; rows whose window would leave the array hold the nearest
    full-window average."""
    n, half = len(values), n_avg // 2
    cumulative = np.zeros((n + 1, values.shape[1]))
    np.cumsum(values, axis=0, out=cumulative[1:])
    full_windows = (cumulative[n_avg:] - cumulative[:-n_avg]) / n_avg  # row j: mean of rows j .. j + n_avg - 1
    return full_windows[np.clip(np.arange(n) - half, 0, n - n_avg)]


def tilt_from_specific_force(f_b: np.ndarray) -> tuple[float, float]:
    """Roll and pitch [rad] of a vehicle at rest from its mean specific force (FRD, about (0, 0, -g) level)."""
    roll = math.atan2(-f_b[1], -f_b[2])
    pitch = math.atan2(f_b[0], math.hypot(f_b[1], f_b[2]))
    return roll, pitch


def yaw_from_magnetometer(m_b: np.ndarray, roll_rad: float, pitch_rad: float, field_ned: np.ndarray) -> float:
    """Yaw [rad] from a body-frame vector whose NED direction ``field_ned`` is known (magnetic field or sun),
    tilt-compensated (docs/three_stage.md, 'Stage 2: heading'): the level-frame vector ``Ry(theta) Rx(phi) m_b`` has
    heading ``D - psi``
    with D the heading of the reference vector (the declination for the magnetic field)."""
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    # Rx(phi) m, then Ry(theta)
    y1 = cr * m_b[1] - sr * m_b[2]
    z1 = sr * m_b[1] + cr * m_b[2]
    x2 = cp * m_b[0] + sp * z1
    yaw = math.atan2(field_ned[1], field_ned[0]) - math.atan2(y1, x2)
    return math.atan2(math.sin(yaw), math.cos(yaw))


def initial_alignment(flight_log: FlightLog, imu: ImuSamples, gps: GpsRows | None, mag, mag_field: np.ndarray,
               mag_strength: float, sun, origin: Origin, baro, baro_offset_m: float, gravity: float,
               config: EstimatorConfig, warnings: list[str]) -> tuple[Alignment, str | None]:
    """Initial state, and why the magnetometer must not be used (None when it is consistent)."""
    t0 = float(imu.time_s[0])
    window = still_window(imu, gravity, config)
    velocity = np.zeros(3)
    position = np.zeros(3)
    if gps is not None:
        i = int(np.argmin(np.abs(gps.time_s - t0)))
        north, east, down = environment.geodetic_to_ned(gps.lat_deg[i], gps.lon_deg[i], gps.alt_m[i],
                                                        origin.lat_deg, origin.lon_deg, origin.alt_m)
        position = np.array([float(north), float(east), float(down)])
    elif baro is not None:
        position[2] = -(float(np.median(baro[1][:20, 0])) - baro_offset_m - origin.alt_m)
    gyro_bias = np.zeros(3)
    still_s = None
    onboard = flight_log.streams.get("onboard_attitude")
    if window is not None:
        i0, i1 = window
        roll, pitch = tilt_from_specific_force(imu.accel_m_s2[i0:i1].mean(axis=0))
        gyro_bias = imu.gyro_rad_s[i0:i1].mean(axis=0)
        still_s = (float(imu.time_s[i0]), float(imu.time_s[i1 - 1]))
        tilt_source = "still_window"
    elif onboard is not None and len(onboard) and {"qw", "qx", "qy", "qz"} <= set(onboard.columns):
        roll, pitch, _ = _onboard_euler_at(onboard, t0)
        tilt_source = "onboard_attitude"
        warnings.append("no still window at the start: initial roll/pitch from the autopilot's attitude")
    else:
        n = max(1, round(0.5 / imu.median_dt_s))
        roll, pitch = tilt_from_specific_force(imu.accel_m_s2[:n].mean(axis=0))
        tilt_source = "accelerometer"
        warnings.append("no still window at the start: initial roll/pitch from the accelerometer (in air)")
    if window is None and gps is not None:
        i = int(np.argmin(np.abs(gps.time_s - t0)))
        velocity = gps.vel_ned[i].copy()
    yaw, yaw_source = 0.0, "none"
    mag_rejection = None
    if mag is not None:
        t_end = still_s[1] if still_s is not None else mag[0][0] + 0.5
        sel = mag[0] <= max(t_end, mag[0][0])
        m_b = mag[1][sel].mean(axis=0) / mag_strength
        # the measured inclination must match the reference field (a wrongly calibrated or rotated
        # magnetometer would otherwise give a confidently wrong yaw)
        down_b = np.array([-math.sin(pitch), math.sin(roll) * math.cos(pitch), math.cos(roll) * math.cos(pitch)])
        dip_measured = math.degrees(math.asin(float(np.clip(np.dot(m_b, down_b) / np.linalg.norm(m_b), -1, 1))))
        dip_expected = math.degrees(math.asin(float(np.clip(mag_field[2], -1, 1))))
        if abs(dip_measured - dip_expected) > MAG_DIP_TOLERANCE_DEG:
            mag_rejection = (f"inclination {dip_measured:.1f} deg at the start does not match the earth field's "
                             f"{dip_expected:.1f} deg (miscalibrated or rotated magnetometer)")
        else:
            yaw, yaw_source = yaw_from_magnetometer(m_b, roll, pitch, mag_field), "mag"
    if yaw_source == "none" and sun is not None and len(sun[0]):
        # gravity + sun (docs/estimators.md, 'Initial alignment' "TRIAD"): the sun's horizontal direction,
        # tilt-compensated like the field
        t_end = still_s[1] if still_s is not None else sun[0][0] + 0.5
        sel = sun[0] <= max(t_end, sun[0][0])
        s_b, s_n = sun[2][sel, 0:3].mean(axis=0), sun[2][sel, 3:6].mean(axis=0)
        if math.hypot(s_n[0], s_n[1]) > MIN_SUN_HORIZONTAL:
            yaw, yaw_source = yaw_from_magnetometer(s_b, roll, pitch, s_n), "sun"
    has_onboard = onboard is not None and len(onboard) and {"qw", "qx", "qy", "qz"} <= set(onboard.columns)
    if yaw_source == "none" and has_onboard:
        yaw, yaw_source = _onboard_euler_at(onboard, t0)[2], "onboard_attitude"
        warnings.append("initial yaw borrowed from the autopilot's attitude (no usable magnetometer)")
    elif (yaw_source == "none" and gps is not None
          and np.hypot(velocity[0], velocity[1]) > config.timing.min_ground_speed_m_s):
        yaw, yaw_source = math.atan2(velocity[1], velocity[0]), "gps_course"
    alignment = Alignment(roll_rad=roll, pitch_rad=pitch, yaw_rad=yaw, gyro_bias_rad_s=gyro_bias,
                          velocity_ned_m_s=velocity, position_ned_m=position, still_window_s=still_s,
                          yaw_source=yaw_source, tilt_source=tilt_source)
    return alignment, mag_rejection


def _onboard_euler_at(onboard: pd.DataFrame, time_s: float) -> tuple[float, float, float]:
    i = int(np.clip(np.searchsorted(onboard.index.to_numpy(dtype=float), time_s), 0, len(onboard) - 1))
    q = onboard.iloc[i][["qw", "qx", "qy", "qz"]].to_numpy(dtype=float)
    roll, pitch, yaw = quat_to_euler(q)
    return float(roll), float(pitch), float(yaw)
