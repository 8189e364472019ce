"""Calibration of the public PX4 logs: stationary segments found, MPU-class noise magnitudes.

Plausibility bands (orders of magnitude, not exact values): an MPU6000-class gyro has a noise density of
~0.005 deg/s/sqrt(Hz) = 8.7e-5 rad/s/sqrt(Hz), i.e. ~1.4e-3 rad/s per sample at 250 Hz before PX4's low-pass
and averaging lower it; its accelerometer ~400 ug/sqrt(Hz) = 3.9e-3 m/s^2/sqrt(Hz), ~0.06 m/s^2 per sample at
250 Hz. SITL adds noise of the same order. Bands: gyro 1e-4 .. 5e-2 rad/s, accelerometer 1e-3 .. 0.5 m/s^2.
"""

from __future__ import annotations

import numpy as np
import pytest

from calib.calibration import calibrate
from calib.export import calibration_from_dict, calibration_to_dict
from calib.parameter_export import export_figures, px4_parameters
from ingest.log_formats import load_flight_log

GYRO_BAND_RAD_S = (1e-4, 5e-2)
ACCEL_BAND_M_S2 = (1e-3, 0.5)


@pytest.fixture(scope="module", params=["sample.ulg", "sample_px4_events.ulg"])
def real_cal(request, real_logs_dir):
    log = load_flight_log(real_logs_dir / request.param)
    return request.param, log, calibrate(log)


def test_imu_noise_has_mpu_class_magnitude(real_cal):
    _, _, cal = real_cal
    gyro, accel = cal.sensors["gyroscope"], cal.sensors["accelerometer"]
    assert gyro.segment.kind == accel.segment.kind == "stationary"
    assert all(GYRO_BAND_RAD_S[0] < s < GYRO_BAND_RAD_S[1] for s in gyro.sigma)
    assert all(ACCEL_BAND_M_S2[0] < s < ACCEL_BAND_M_S2[1] for s in accel.sigma)
    # White-ish noise: the robust and plain sigma agree within 10 %.
    np.testing.assert_allclose(gyro.sigma_robust, gyro.sigma, rtol=0.1)
    # A stationary gyro bias of a calibrated MEMS gyro is below 0.05 rad/s (3 deg/s).
    assert np.all(np.abs(cal.stationary_bias.gyro_bias_rad_s) < 0.05)
    assert abs(cal.stationary_bias.accel_bias_parallel_m_s2) < 0.5
    assert set(cal.allan) == {"accelerometer", "gyroscope"}
    calibration_from_dict(calibration_to_dict(cal))  # exports validate
    names = {p.name for p in px4_parameters(export_figures(cal))}
    assert names >= {"EKF2_ACC_NOISE", "EKF2_GYR_NOISE", "EKF2_MAG_NOISE"}


def test_stationary_segments_where_the_logs_are_still(real_cal):
    name, log, cal = real_cal
    segment = cal.sensors["gyroscope"].segment
    # Motion edges read off 1-s windows of the raw IMU (gyro and accelerometer standard deviations per window);
    # the detected stretch is then trimmed by 1 s at an edge next to motion (StationaryCriteria.trim_s).
    if name == "sample.ulg":
        # Hand-moved on the bench until the window 118.2 .. 119.2 s (gyro std 0.33 rad/s before, 0.02 in it, 7e-4
        # after), then still to the end of the IMU data (181.49 s): start in [118.2, 119.7] + 1 s.
        assert 119.2 <= segment.start_s <= 120.7
        assert segment.end_s == pytest.approx(log["imu"].index[-1], abs=0.01)
    else:
        # SITL: on the ground from the first sample; take-off shows in the window 18.0 .. 19.0 s after it
        # (accelerometer z std 0.03 -> 0.29 m/s^2): duration in [18.0, 19.0] - 1 s.
        assert segment.start_s == pytest.approx(log["imu"].index[0], abs=0.01)
        assert 17.0 <= segment.duration_s <= 18.0
        assert {"barometer", "magnetometer", "gps_position"} <= set(cal.sensors)
