"""Simulated sensors match their configured grades (noise within 5 %, biases, Gauss-Markov GPS error, wind
triangle, photocell faults)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from estimators.environment import geodetic_to_ned, isa_altitude_m, isa_pressure_pa, sun_direction_ned
from ingest.frames import quat_to_matrix
from ingest.sun_device import SunDevice
from sim.kinematics import Site, fly
from sim.mission import ChangeAltitude, Cruise, HandLaunch, Mission, Still, Turn
from sim.photocells import SunCellGrade, simulate_sun_device
from sim.processes import gauss_markov
from sim.sensors import (
    RHO_SEA_LEVEL_KG_M3,
    AirspeedGrade,
    BaroGrade,
    GpsGrade,
    ImuGrade,
    MagGrade,
    panel_current_a,
    simulate_airspeed,
    simulate_baro,
    simulate_gps,
    simulate_imu,
    simulate_mag,
)
from sim.wind import WindConfig

IMU_HZ = 250.0
SITE = Site()
MISSION = Mission(legs=(Still(40.0), HandLaunch(), ChangeAltitude(60.0, 3.0), Cruise(60.0),
                        Turn(360.0, radius_m=100.0)), initial_heading_deg=300.0)
#: Relative tolerance of every noise standard deviation.
STD_RTOL = 0.05


@pytest.fixture(scope="module")
def truth():
    return fly(MISSION, SITE, WindConfig(), np.random.default_rng(5), rate_hz=IMU_HZ)


def _state_at(truth, frame):
    """The truth at a stream's sample times."""
    return truth.at(np.round(frame["sample_time_s"].to_numpy() * 1e6).astype(np.int64))


def _rel_std_error(residual, sigma):
    return np.abs(np.std(residual, axis=0) / sigma - 1.0)


def test_imu_noise_bias_and_misalignment(truth):
    grade = dataclasses.replace(ImuGrade(), gyro_bias_walk_rad_s_sqrt_s=0.0)
    frame, errors = simulate_imu(truth, grade, np.random.default_rng(1))
    gyro = frame[["gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"]].to_numpy()
    accel = frame[["accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"]].to_numpy()
    gyro_residual = gyro - truth.rates_rad_s @ errors["gyro_matrix"].T
    accel_residual = accel - truth.specific_force_m_s2 @ errors["accel_matrix"].T
    still, flying = truth.segment_mask("still"), truth.airborne == 1.0
    # white noise at rest; noise plus motor vibration in flight
    assert _rel_std_error(gyro_residual[still], grade.gyro_noise_rad_s).max() < STD_RTOL
    assert _rel_std_error(accel_residual[still], grade.accel_noise_m_s2).max() < STD_RTOL
    flight_gyro_sigma = np.hypot(grade.gyro_noise_rad_s, grade.gyro_vibration_rad_s)
    flight_accel_sigma = np.hypot(grade.accel_noise_m_s2, grade.accel_vibration_m_s2)
    assert _rel_std_error(gyro_residual[flying], flight_gyro_sigma).max() < STD_RTOL
    assert _rel_std_error(accel_residual[flying], flight_accel_sigma).max() < STD_RTOL
    # the mean residual is the recorded bias (within 4 standard errors of the mean)
    for residual, bias, sigma in ((gyro_residual[still], errors["gyro_bias_start_rad_s"], grade.gyro_noise_rad_s),
                                  (accel_residual[still], errors["accel_bias_m_s2"], grade.accel_noise_m_s2)):
        np.testing.assert_allclose(residual.mean(axis=0), bias, atol=4 * sigma / np.sqrt(len(residual)))
    # Table 1 bounds: biases, scale and cross-axis errors
    assert np.all(np.abs(errors["accel_bias_m_s2"]) <= grade.accel_bias_limit_m_s2)
    assert np.all(np.abs(errors["gyro_bias_start_rad_s"]) <= grade.gyro_bias_limit_rad_s)
    for matrix, scale, cross in ((errors["gyro_matrix"], grade.gyro_scale_limit, grade.gyro_cross_axis_limit),
                                 (errors["accel_matrix"], grade.accel_scale_limit, grade.accel_cross_axis_limit)):
        assert np.all(np.abs(np.diag(matrix) - 1.0) <= scale)
        assert np.all(np.abs(matrix - np.diag(np.diag(matrix))) <= cross)
        assert np.abs(matrix - np.eye(3)).max() > 0.3 * cross  # the errors are really injected
    np.testing.assert_array_equal(frame.index.to_numpy(), truth.time_s)
    np.testing.assert_array_equal(frame["dt_s"].to_numpy(), 1.0 / IMU_HZ)


def test_gyro_bias_random_walk(truth):
    grade = ImuGrade()
    _, errors = simulate_imu(truth, grade, np.random.default_rng(2))
    drift = errors["gyro_bias_end_rad_s"] - errors["gyro_bias_start_rad_s"]
    expected_sigma = grade.gyro_bias_walk_rad_s_sqrt_s * np.sqrt(truth.tau_s[-1])
    assert np.all(np.abs(drift) < 4 * expected_sigma) and np.abs(drift).max() > 0


def test_magnetometer_model(truth):
    grade = dataclasses.replace(MagGrade(), solar_gauss_per_a=0.0)
    frame, errors = simulate_mag(truth, SITE, grade, np.random.default_rng(3))
    mag = frame[["mag_x_gauss", "mag_y_gauss", "mag_z_gauss"]].to_numpy()
    field_body = np.einsum("nji,j->ni", quat_to_matrix(_state_at(truth, frame).q_nb), errors["earth_field_ned_gauss"])
    residual = mag - field_body @ errors["mag_matrix"].T
    assert _rel_std_error(residual, grade.noise_gauss).max() < STD_RTOL
    np.testing.assert_allclose(residual.mean(axis=0), errors["hard_iron_gauss"],
                               atol=4 * grade.noise_gauss / np.sqrt(len(residual)))
    assert np.all(np.abs(errors["hard_iron_gauss"]) <= grade.hard_iron_limit_gauss)
    # WMM at the paper's site: about 0.53 gauss, inclination about 54 deg, declination about -4 deg
    north, east, down = errors["earth_field_ned_gauss"]
    assert np.degrees(np.arctan2(down, np.hypot(north, east))) == pytest.approx(54.3, abs=1.0)
    assert np.degrees(np.arctan2(east, north)) == pytest.approx(-4.3, abs=1.0)
    assert len(frame) == pytest.approx(truth.tau_s[-1] * grade.rate_hz, abs=1)


def test_solar_panel_current_disturbs_the_magnetometer(truth):
    clean_grade = dataclasses.replace(MagGrade(), solar_gauss_per_a=0.0)
    disturbed, errors = simulate_mag(truth, SITE, MagGrade(), np.random.default_rng(3))
    clean, _ = simulate_mag(truth, SITE, clean_grade, np.random.default_rng(3))
    difference = np.linalg.norm((disturbed - clean).to_numpy()[:, :3], axis=1)
    state = _state_at(truth, disturbed)
    current = panel_current_a(truth, SITE, state.time_us, MagGrade().panel_current_max_a)
    # disturbance = gain x panel current (through the 1 % soft-iron matrix); it varies as the wing turns to the sun
    np.testing.assert_allclose(difference, MagGrade().solar_gauss_per_a * current, rtol=0.02)
    assert errors["solar_disturbance_max_gauss"] == pytest.approx(difference.max(), rel=0.02)
    turning = state.segment_mask("turn")
    assert np.ptp(current[turning]) > 0.2  # [A]


def test_barometer_offset_drift_noise(truth):
    grade = BaroGrade()
    frame, errors = simulate_baro(truth, SITE, grade, np.random.default_rng(4))
    state = _state_at(truth, frame)
    true_pressure = isa_pressure_pa(state.alt_m, SITE.sea_level_pressure_pa)
    residual = frame["pressure_pa"].to_numpy() - true_pressure
    elapsed = state.tau_s
    model = errors["offset_pa"] + errors["drift_pa_s"] * elapsed
    assert _rel_std_error(residual - model, grade.noise_pa) < STD_RTOL
    slope, intercept = np.polyfit(elapsed, residual, 1)
    assert intercept == pytest.approx(errors["offset_pa"], abs=0.2)
    assert slope == pytest.approx(errors["drift_pa_s"], abs=0.005)
    assert abs(errors["offset_pa"]) <= grade.offset_limit_pa
    np.testing.assert_allclose(frame["alt_m"], isa_altitude_m(frame["pressure_pa"], grade.qnh_setting_pa))
    # the offset shows up as a baro altitude bias of about 8.4 m per hPa near the ground
    still = state.segment_mask("still")
    bias_m = np.mean(frame["alt_m"].to_numpy()[still] - state.alt_m[still])
    assert bias_m == pytest.approx(-errors["offset_pa"] / 100 * 8.4, abs=0.3 + 0.05 * abs(errors["offset_pa"]))


def test_airspeed_from_differential_pressure_and_wind_triangle(truth):
    grade = AirspeedGrade()
    frame, errors, air_temp = simulate_airspeed(truth, SITE, grade, np.random.default_rng(6))
    state = _state_at(truth, frame)
    ias = frame["ias_m_s"].to_numpy()
    diff_pressure = np.sign(ias) * 0.5 * RHO_SEA_LEVEL_KG_M3 * ias**2
    temperature_k = SITE.ground_temp_c + 273.15 - 0.0065 * (state.alt_m - SITE.ground_alt_m)
    rho = isa_pressure_pa(state.alt_m, SITE.sea_level_pressure_pa) / (287.0531 * temperature_k)
    residual = diff_pressure - 0.5 * rho * state.airspeed_m_s**2 - errors["offset_pa"]
    assert _rel_std_error(residual, grade.noise_pa) < STD_RTOL
    assert abs(errors["offset_pa"]) <= grade.offset_limit_pa
    assert _rel_std_error(air_temp - (temperature_k - 273.15), grade.air_temp_noise_c) < STD_RTOL
    # wind triangle with the measured airspeed: |GPS-like ground velocity - wind| = TAS up to the sensor errors
    cruise = state.segment_mask("cruise")
    air_velocity = state.vel_ned_m_s - state.wind_ned_m_s
    tas_error = frame["tas_m_s"].to_numpy()[cruise] - np.linalg.norm(air_velocity[cruise], axis=1)
    offset_effect = errors["offset_pa"] / (rho[cruise].mean() * 12.5)  # d(V)/d(dp) = 1 / (rho V)
    assert np.mean(tas_error) == pytest.approx(offset_effect, abs=0.02)
    assert np.std(tas_error) < 0.1


def test_gauss_markov_statistics():
    tau_s, dt_s, sigma = 2.0, 0.1, 1.5
    samples = gauss_markov(400_000, dt_s, tau_s, sigma, np.random.default_rng(9))[:, 0]
    assert np.std(samples) == pytest.approx(sigma, rel=0.03)
    for lag in (1, 10, 30):
        autocorrelation = np.mean(samples[:-lag] * samples[lag:]) / np.var(samples)
        assert autocorrelation == pytest.approx(np.exp(-lag * dt_s / tau_s), abs=0.01)
    starts = gauss_markov(1, dt_s, tau_s, (1.0, 2.0), np.random.default_rng(0), stationary_start=False)
    np.testing.assert_array_equal(starts, 0.0)


def test_gps_error_process_latency_and_time(truth):
    grade = GpsGrade()
    frame, errors = simulate_gps(truth, grade, np.random.default_rng(8))
    sample_time = frame["sample_time_s"].to_numpy()
    state = _state_at(truth, frame)
    np.testing.assert_allclose(frame.index.to_numpy() - sample_time, grade.latency_s, atol=1e-9)
    np.testing.assert_allclose(frame["time_utc_s"].to_numpy() - sample_time, truth.utc_offset_s, atol=1e-6)
    assert sample_time[0] - truth.time_s[0] == pytest.approx(grade.time_to_first_fix_s)
    measured = geodetic_to_ned(frame["lat_deg"], frame["lon_deg"], frame["alt_m"], *truth.origin)
    true = geodetic_to_ned(state.lat_deg, state.lon_deg, state.alt_m, *truth.origin)
    error = np.column_stack(measured) - np.column_stack(true)
    np.testing.assert_allclose(np.sqrt(np.mean(error**2, axis=0)), errors["position_error_rms_ned_m"], atol=1e-3)
    # Gauss-Markov: the innovation e[k+1] - a e[k] with a = exp(-T/tau) is white with the configured std
    decay = np.exp(-1.0 / grade.rate_hz / grade.position_tau_s)
    innovation = error[1:] - decay * error[:-1]
    expected = np.asarray(grade.position_sigma_m) * np.sqrt(1.0 - decay**2)
    assert _rel_std_error(innovation, expected).max() < STD_RTOL
    lag1 = np.sum(innovation[1:] * innovation[:-1], axis=0) / np.sum(innovation**2, axis=0)
    assert np.abs(lag1).max() < 0.1
    velocity_error = frame[["vn_m_s", "ve_m_s", "vd_m_s"]].to_numpy() - state.vel_ned_m_s
    assert _rel_std_error(velocity_error.ravel(), grade.velocity_noise_m_s) < STD_RTOL
    # ground speed and course (eqs 8-9) from the GPS velocity: course noise ~ sigma_V / V_g
    flying = state.airborne == 1.0
    true_course = np.arctan2(state.vel_ned_m_s[:, 1], state.vel_ned_m_s[:, 0])
    course_error = np.angle(np.exp(1j * (np.arctan2(frame["ve_m_s"], frame["vn_m_s"]).to_numpy() - true_course)))
    ground_speed = np.hypot(state.vel_ned_m_s[:, 0], state.vel_ned_m_s[:, 1])
    expected_course_sigma = grade.velocity_noise_m_s / ground_speed[flying]
    assert np.std(course_error[flying] / expected_course_sigma) == pytest.approx(1.0, rel=0.1)


def test_photocell_currents_faults_and_clouds(truth):
    device = SunDevice()
    grade = SunCellGrade(failed_cell=3, failed_window_s=(50.0, 80.0), cloud_window_s=(100.0, 140.0),
                         cloud_edge_s=5.0)
    clean = dataclasses.replace(grade, noise_a=0.0, failed_cell=None, cloud_window_s=None)
    frame, errors = simulate_sun_device(truth, SITE, grade, device, np.random.default_rng(10))
    noiseless, _ = simulate_sun_device(truth, SITE, clean, device, np.random.default_rng(10))
    tau = frame.index.to_numpy() - truth.time_s[0]
    failed = (tau >= 50.0) & (tau < 80.0)
    cloud = (tau > 105.0) & (tau < 135.0)
    assert np.all(frame["i3_a"].to_numpy()[failed] == 0.0)
    healthy = ~failed & ~((tau > 95.0) & (tau < 145.0))
    residual = (frame - noiseless).to_numpy()[healthy]
    assert _rel_std_error(residual.ravel(), grade.noise_a) < STD_RTOL
    # at rest: top cell = k sin(sun elevation seen from the pitched body) + the full sky current
    still = tau < 40.0
    attitude = quat_to_matrix(truth.at(np.round(frame.index.to_numpy() * 1e6).astype(np.int64)).q_nb)[still]
    times = pd.to_datetime(frame.index.to_numpy()[still] + truth.utc_offset_s, unit="s", utc=True)
    s_ned, elevation = sun_direction_ned(times, SITE.lat_deg, SITE.lon_deg, SITE.ground_alt_m)
    assert 25.0 < elevation.mean() < 32.0  # autumn morning at the paper's site
    s_body = np.einsum("nji,nj->ni", attitude, s_ned)
    up_body = -attitude[:, 2, :]
    expected_top = grade.k_a * np.maximum(0.0, -s_body[:, 2]) + grade.sky_a * 0.5 * (1.0 - up_body[:, 2])
    np.testing.assert_allclose(noiseless["i1_a"].to_numpy()[still], expected_top, atol=2e-6)
    # under the cloud the direct-sun part drops to the transmittance
    sky_only = grade.sky_a * 0.5 * (1.0 - up_body[:, 2]).mean()
    ratio = (frame["i1_a"].to_numpy()[cloud] - sky_only) / (noiseless["i1_a"].to_numpy()[cloud] - sky_only)
    assert np.median(ratio) == pytest.approx(grade.cloud_transmittance, abs=0.03)
    assert errors["failed_cell"] == 3
