"""A synthetic FlightLog with known injected white noise and biases, shared by the calib tests.

The vehicle stands still (tilted by ``ATTITUDE_DEG``) except inside ``motion`` windows, where it rocks about
its x axis. Every sensor adds seeded white noise of the standard deviations in ``NOISE`` to its true value; the
gyro and accelerometer add the constant biases ``GYRO_BIAS_RAD_S`` / ``ACCEL_BIAS_M_S2``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pymap3d
import pytest

from ingest.flightlog import STREAM_COLUMNS, FlightLog, LogMetadata, stream_info
from ingest.frames import euler_to_matrix, euler_to_quat

RATES_HZ = {"imu": 250.0, "mag": 50.0, "baro": 20.0, "gps": 10.0, "airspeed": 20.0, "onboard_attitude": 50.0}
#: Injected per-sample white-noise standard deviations, per sensor and axis (units of the calibrated channel).
NOISE = {
    "accelerometer": (0.05, 0.03, 0.08),          # m/s^2
    "gyroscope": (0.004, 0.006, 0.005),          # rad/s
    "magnetometer": (0.004, 0.005, 0.006),       # gauss
    "barometer": (0.3,),                         # m
    "airspeed": (0.2,),                          # m/s
    "gps_position": (0.4, 0.5, 0.8),             # m (north, east, down)
    "gps_velocity": (0.05, 0.06, 0.08),          # m/s
}
GYRO_BIAS_RAD_S = np.array([0.01, -0.02, 0.005])
ACCEL_BIAS_M_S2 = np.array([0.2, -0.1, 0.15])
ATTITUDE_DEG = (10.0, -5.0, 30.0)  # roll, pitch, yaw
GRAVITY_M_S2 = 9.80665
EARTH_FIELD_NED_GAUSS = np.array([0.21, 0.01, 0.43])
ORIGIN = (47.4, 8.5, 488.0)  # lat [deg], lon [deg], alt [m]
MOTION_RATE_RAD_S = 0.8  # rocking amplitude about x inside motion windows


def synthetic_log(duration_s: float = 60.0, *, seed: int = 0, motion: tuple[tuple[float, float], ...] = (),
                  airspeed_m_s: float = 0.0, vehicle_type: int = 1) -> FlightLog:
    """The log described in the module docstring; time starts at 100 s on the log clock."""
    rng = np.random.default_rng(seed)
    t0 = 100.0

    def times(stream):
        return t0 + np.arange(int(duration_s * RATES_HZ[stream])) / RATES_HZ[stream]

    def noise(sensor, n):
        return rng.normal(0.0, NOISE[sensor], size=(n, len(NOISE[sensor])))

    roll, pitch, yaw = np.radians(ATTITUDE_DEG)
    r_nb = euler_to_matrix(roll, pitch, yaw)
    streams = {}

    t = times("imu")
    moving = np.zeros(len(t), dtype=bool)
    for a, b in motion:
        moving |= (t >= a) & (t <= b)
    true_rate = np.zeros((len(t), 3))
    true_rate[moving, 0] = MOTION_RATE_RAD_S * np.sin(2 * np.pi * 0.5 * t[moving])
    specific_force = np.tile(r_nb.T @ np.array([0.0, 0.0, -GRAVITY_M_S2]), (len(t), 1))
    specific_force[moving, 1] += 2.0 * np.sin(2 * np.pi * 0.5 * t[moving])
    gyro = true_rate + GYRO_BIAS_RAD_S + noise("gyroscope", len(t))
    accel = specific_force + ACCEL_BIAS_M_S2 + noise("accelerometer", len(t))
    streams["imu"] = _frame(t, np.hstack([gyro, accel]), STREAM_COLUMNS["imu"])

    t = times("mag")
    streams["mag"] = _frame(t, r_nb.T @ EARTH_FIELD_NED_GAUSS + noise("magnetometer", len(t)),
                            STREAM_COLUMNS["mag"])

    t = times("baro")
    alt = ORIGIN[2] + noise("barometer", len(t))[:, 0]
    streams["baro"] = _frame(t, np.column_stack([alt, np.full(len(t), 95600.0), np.full(len(t), 15.0)]),
                             STREAM_COLUMNS["baro"])

    t = times("gps")
    ned = noise("gps_position", len(t))
    lat, lon, alt = pymap3d.ned2geodetic(ned[:, 0], ned[:, 1], ned[:, 2], *ORIGIN)
    vel = noise("gps_velocity", len(t))
    n = len(t)
    streams["gps"] = _frame(t, np.column_stack([lat, lon, ORIGIN[2] - ned[:, 2], vel, np.full(n, 1.2),
                                                np.full(n, 1.8), np.full(n, 3.0), 1.7e9 + t]),
                            STREAM_COLUMNS["gps"])

    t = times("airspeed")
    tas = airspeed_m_s + noise("airspeed", len(t))[:, 0]
    streams["airspeed"] = _frame(t, np.column_stack([tas, tas]), STREAM_COLUMNS["airspeed"])

    t = times("onboard_attitude")
    quat = np.tile(euler_to_quat(roll, pitch, yaw), (len(t), 1))
    euler = np.tile(np.array(ATTITUDE_DEG), (len(t), 1))
    streams["onboard_attitude"] = _frame(t, np.hstack([quat, euler]), STREAM_COLUMNS["onboard_attitude"])

    meta = LogMetadata(source="synthetic.ulg", sha256="0" * 64, vehicle_type=vehicle_type,
                       start_time_s=t0, end_time_s=float(streams["imu"].index[-1]), duration_s=duration_s,
                       streams={name: stream_info(name, frame.index.to_numpy()) for name, frame in streams.items()})
    return FlightLog(streams=streams, meta=meta)


def _frame(time_s: np.ndarray, values: np.ndarray, columns: tuple[str, ...]) -> pd.DataFrame:
    return pd.DataFrame(values, columns=list(columns), index=pd.Index(time_s, name="time_s"))


def test_synthetic_log_follows_the_contract():
    log = synthetic_log(10.0)
    for name, frame in log.streams.items():
        assert tuple(frame.columns) == STREAM_COLUMNS[name]
        assert frame.index.name == "time_s" and frame.index.is_monotonic_increasing
        assert log.meta.streams[name].rate_hz == pytest.approx(RATES_HZ[name])
    # At rest the specific force is -g along the body "down" of the tilted vehicle, plus the bias.
    mean_f = log["imu"][list(STREAM_COLUMNS["imu"][3:])].to_numpy().mean(axis=0)
    assert np.linalg.norm(mean_f - ACCEL_BIAS_M_S2) == pytest.approx(GRAVITY_M_S2, abs=0.01)
