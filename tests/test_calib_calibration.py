"""calib.calibrate on the synthetic log with known injected noise and biases; tables; in-flight bias summary."""

from __future__ import annotations

import numpy as np
import pytest
from test_calib_synthetic import (
    ACCEL_BIAS_M_S2,
    ATTITUDE_DEG,
    GYRO_BIAS_RAD_S,
    NOISE,
    RATES_HZ,
    synthetic_log,
)

from calib.bias import GravityReference, summarize_bias_states
from calib.calibration import FirSettings, allan_curves, calibrate, with_tau
from calib.segments import user_segment
from calib.tables import noise_table, r_tables, table4
from calib.tau import user_tau
from ingest.errors import InputError
from ingest.frames import euler_to_matrix


@pytest.fixture(scope="module")
def still_log():
    return synthetic_log(60.0, seed=3)


@pytest.fixture(scope="module")
def still_cal(still_log):
    return calibrate(still_log)


def test_sigma_recovers_injected_noise_for_every_sensor_and_axis(still_cal):
    assert set(still_cal.sensors) == set(NOISE)
    for sensor, injected in NOISE.items():
        cal = still_cal.sensors[sensor]
        assert cal.segment.kind == "stationary"
        np.testing.assert_allclose(cal.sigma, injected, rtol=0.10, err_msg=sensor)
        np.testing.assert_allclose(cal.sigma_robust, injected, rtol=0.10, err_msg=sensor)
        assert cal.fir.fs_hz == pytest.approx(RATES_HZ["imu" if sensor in ("accelerometer", "gyroscope") else
                                                        {"magnetometer": "mag", "barometer": "baro",
                                                         "airspeed": "airspeed"}.get(sensor, "gps")])


def test_stationary_biases_match_the_injected_ones(still_cal):
    bias = still_cal.stationary_bias
    assert bias is not None and "onboard_attitude" in bias.attitude_source
    # Gyro: within 20 % of each injected bias (the standard error is 0.005 / sqrt(15000) ~ 4e-5 rad/s).
    np.testing.assert_allclose(bias.gyro_bias_rad_s, GYRO_BIAS_RAD_S, rtol=0.20)
    # Accelerometer: only the component along the (tilted) "up" direction is identifiable.
    up = -euler_to_matrix(*np.radians(ATTITUDE_DEG))[2]  # at rest f_b = R^T (0, 0, -g) = g * up
    np.testing.assert_allclose(bias.accel_up_body, up, atol=1e-9)
    parallel = ACCEL_BIAS_M_S2 @ up
    perpendicular = np.linalg.norm(ACCEL_BIAS_M_S2 - parallel * up)
    assert bias.accel_bias_parallel_m_s2 == pytest.approx(parallel, rel=0.20)
    assert bias.accel_horizontal_residual_m_s2 == pytest.approx(perpendicular, rel=0.20)
    np.testing.assert_allclose(bias.accel_bias_body_m_s2, bias.accel_bias_parallel_m_s2 * up, rtol=1e-12)


def test_local_gravity_shifts_the_parallel_bias(still_log, still_cal):
    local = GravityReference(9.80665 - 0.01, "test")
    shifted = calibrate(still_log, gravity=local).stationary_bias
    assert shifted.accel_bias_parallel_m_s2 - still_cal.stationary_bias.accel_bias_parallel_m_s2 == pytest.approx(
        0.01, abs=1e-12)
    assert shifted.gravity == local


def test_allan_white_noise_density_within_15_percent(still_cal):
    for sensor in ("accelerometer", "gyroscope"):
        figures = still_cal.allan[sensor]
        assert len(figures) == 3
        # White noise of per-sample std sigma at f_s has density N = sigma / sqrt(f_s).
        expected = np.array(NOISE[sensor]) / np.sqrt(RATES_HZ["imu"])
        np.testing.assert_allclose([f.white_density for f in figures], expected, rtol=0.15, err_msg=sensor)
        np.testing.assert_allclose([f.sigma_per_sample for f in figures], NOISE[sensor], rtol=0.15)
        assert all(np.isnan(f.rate_random_walk) for f in figures)  # no random walk injected


def test_allan_curves_for_display(still_log, still_cal):
    curves = allan_curves(still_log, still_cal)
    assert set(curves) == {"accelerometer", "gyroscope"}
    first = curves["gyroscope"][0]
    assert list(first.columns) == ["tau_s", "adev", "adev_err"]
    assert first["tau_s"].iloc[0] == pytest.approx(1 / RATES_HZ["imu"])
    assert first["adev"].iloc[0] == pytest.approx(NOISE["gyroscope"][0], rel=0.05)  # adev(tau0) = sigma


def test_r_matrices_eq51_and_tau_eq52(still_cal):
    sigma = np.array(still_cal.sensors["accelerometer"].sigma)
    np.testing.assert_allclose(still_cal.r_matrix("accelerometer"), np.diag(sigma**2))
    tripled = with_tau(still_cal, user_tau(3.0))
    np.testing.assert_allclose(tripled.r_matrix("accelerometer"), np.diag(sigma**2 * [1.0, 3.0, 1.0]))
    assert tripled.r["gyroscope"] == still_cal.r["gyroscope"] and tripled.tau.method == "user"
    np.testing.assert_allclose(still_cal.r_matrix("barometer"), [[still_cal.sensors["barometer"].sigma[0] ** 2]])


def test_noise_choice_eta_builds_r_from_eq50(still_log):
    cal = calibrate(still_log, noise="eta")
    eta = np.array(cal.sensors["gyroscope"].eta)
    np.testing.assert_allclose(cal.r_matrix("gyroscope"), np.diag(eta**2))
    # eq 50's eta is half a range difference: the measured half-range is ~3.9 sigma for ~14000 white samples,
    # less the small half-range of the filtered noise, so eta is ~3 sigma, far above sigma (docs/calibration.md, 'Noise
    # and bias (eq 50)').
    assert np.all(eta > 2.5 * np.array(NOISE["gyroscope"]))
    with pytest.raises(InputError):
        calibrate(still_log, noise="std")


def test_user_window_with_motion_has_no_stationary_figures():
    log = synthetic_log(40.0, motion=((115.0, 120.0),))
    cal = calibrate(log, segment=user_segment(log, 105.0, 135.0))
    assert cal.sensors["gyroscope"].segment.kind == "user"
    assert cal.stationary_bias is None and cal.allan == {}
    assert any("no stationary segment" in w for w in cal.warnings)


def test_filter_settings_are_applied_and_checked(still_log):
    cal = calibrate(still_log, fir={"gyroscope": FirSettings(cutoff_hz=10.0, numtaps=101)})
    assert (cal.sensors["gyroscope"].fir.cutoff_hz, cal.sensors["gyroscope"].fir.numtaps) == (10.0, 101)
    assert cal.sensors["accelerometer"].fir.numtaps != 101  # other sensors keep their defaults
    with pytest.raises(InputError, match="Nyquist"):
        calibrate(still_log, fir={"barometer": FirSettings(cutoff_hz=15.0)})  # baro runs at 20 Hz
    with pytest.raises(InputError, match="unknown sensor"):
        calibrate(still_log, fir={"lidar": FirSettings()})


def test_short_segment_shortens_the_default_filter_only(still_log):
    segment = user_segment(still_log, 110.0, 116.0)  # baro: 121 samples, default 33 taps fit; gps: 61 < 99
    cal = calibrate(still_log, segment=segment)
    gps = cal.sensors["gps_velocity"]
    assert gps.fir.numtaps == 19 and any("shortened" in w for w in gps.warnings)  # 61 // 3 = 20 -> odd 19
    with pytest.raises(InputError, match="too few"):
        calibrate(still_log, segment=segment, fir={"gyroscope": FirSettings(numtaps=999)})


def test_missing_streams_are_skipped_and_no_imu_fails():
    log = synthetic_log(30.0)
    del log.streams["gps"], log.streams["airspeed"]
    cal = calibrate(log)
    assert set(cal.sensors) == {"accelerometer", "gyroscope", "magnetometer", "barometer"}
    del log.streams["imu"]
    with pytest.raises(InputError, match="no IMU"):
        calibrate(log)


def test_a_skipped_sensor_names_its_segment_since_the_log_start_and_on_the_log_clock():
    log = synthetic_log(30.0)
    log.streams["baro"]["alt_m"] = 480.0  # a stuck barometer: no noise to measure
    cal = calibrate(log)
    [warning] = [w for w in cal.warnings if w.startswith("barometer")]
    segment = cal.sensors["gyroscope"].segment  # the same automatic segment for every sensor
    start_s = log.meta.start_time_s
    assert start_s >= 100.0  # the two clocks differ
    assert (f"constant over the segment {segment.start_s - start_s:.1f} .. {segment.end_s - start_s:.1f} s since "
            f"log start (log clock {segment.start_s:.3f} .. {segment.end_s:.3f} s)") in warning


def test_tables(still_cal):
    table = noise_table(still_cal)
    assert table.loc[("gyroscope", "y"), "sigma"] == still_cal.sensors["gyroscope"].sigma[1]
    assert table.loc[("gyroscope", "z"), "physical_bias"] == still_cal.stationary_bias.gyro_bias_rad_s[2]
    assert np.isnan(table.loc[("barometer", "alt"), "physical_bias"])
    paper = table4(still_cal)
    assert list(paper.columns.get_level_values(1)) == ["x", "y", "z", "p", "q", "r"]
    assert paper.loc["Noise (sigma)", ("Gyroscope (deg/s)", "q")] == pytest.approx(
        np.degrees(still_cal.sensors["gyroscope"].sigma[1]))
    assert paper.loc["Bias (stationary)", ("Accelerometer (m/s^2)", "z")] == pytest.approx(
        still_cal.stationary_bias.accel_bias_body_m_s2[2])
    r = r_tables(still_cal)
    assert list(r["gps_velocity"].index) == ["north", "east", "down"]
    assert r["accelerometer"].loc["y", "y"] == pytest.approx(still_cal.sensors["accelerometer"].sigma[1] ** 2)


def test_summarize_bias_states_averages_after_convergence():
    time_s = np.linspace(0.0, 100.0, 1001)
    settled = np.array([0.01, -0.02, 0.005])
    gyro = np.where(time_s[:, None] < 20.0, 0.0, settled)  # converges at 20 s
    std = np.where(time_s[:, None] < 20.0, 0.1, 0.002) * np.ones((1, 3))
    bias = summarize_bias_states(time_s, gyro, std, source="full_state_indirect", settle_s=20.0)
    np.testing.assert_allclose(bias.gyro_bias_rad_s, settled)
    np.testing.assert_allclose(bias.gyro_bias_std_rad_s, 0.002)
    assert bias.window_s == (20.0, 100.0) and bias.accel_bias_m_s2 is None
    with pytest.raises(InputError):
        summarize_bias_states(time_s, gyro[:, :2], std, source="x", settle_s=0.0)
    with pytest.raises(InputError):
        summarize_bias_states(time_s, gyro, std, source="x", settle_s=500.0)
