"""Acceptance on the bundled simulated paper mission: calibration recovers the injected noise and biases.

``sample_logs/paper.ulg`` is written by ``solarnav simulate`` together with ``paper_sim.json``, the record of every
injected sensor error. Expected values below come from that record and the sensor models it names:

* IMU: white noise ``*_noise`` on the ground, ``sqrt(noise^2 + vibration^2)`` per axis in flight;
* barometer: pressure noise [Pa] times |dh/dp| of the ISA altitude the log reports (QNH 101325 Pa);
* airspeed: differential-pressure noise [Pa] / (rho V) (dV = dq / (rho V) for q = rho V^2 / 2), rho from the
  logged static pressure and the site's air temperature model (ground temperature, ISA lapse rate);
* magnetometer and GPS velocity: their white noise.

GPS position is not checked: its simulated error is a first-order Gauss-Markov process (tau = 1100 s) without a
white component, so there is no per-sample white noise to recover.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calib.bias import GravityReference
from calib.calibration import calibrate
from calib.segments import find_steady_segments, user_segment
from estimators.api import run_estimators
from estimators.config import EstimatorConfig, config_from_figures
from estimators.environment import ISA_LAPSE_K_M, air_density_kg_m3, isa_altitude_m, local_gravity_m_s2
from estimators.tuning import tune_estimator
from ingest.frames import quat_to_matrix
from ingest.log_formats import load_flight_log

SAMPLE_LOGS = Path(__file__).resolve().parents[1] / "sample_logs"
IMU_RATE_HZ = 250.0


@pytest.fixture(scope="module")
def record():
    return json.loads((SAMPLE_LOGS / "paper_sim.json").read_text())


@pytest.fixture(scope="module")
def log():
    return load_flight_log(SAMPLE_LOGS / "paper.ulg")


@pytest.fixture(scope="module")
def gravity(record):
    origin = record["origin"]
    return GravityReference(float(local_gravity_m_s2(origin["lat_deg"], origin["alt_m"])), "site")


@pytest.fixture(scope="module")
def ground_cal(log, gravity):
    return calibrate(log, gravity=gravity)


def _legs(record, name):
    return [(leg["start_s"], leg["end_s"]) for leg in record["segments_log_time_s"] if leg["leg"] == name]


def _baro_sigma_m(noise_pa, pressure_pa, qnh_pa):
    """Altitude noise [m] of pressure noise ``noise_pa`` at ``pressure_pa``: |dh/dp| by central difference."""
    return noise_pa * abs(isa_altitude_m(pressure_pa + 1.0, qnh_pa) - isa_altitude_m(pressure_pa - 1.0, qnh_pa)) / 2


def test_ground_segment_is_the_still_leg(record, ground_cal):
    (start_s, end_s), = _legs(record, "still")[:1]
    segment = ground_cal.sensors["gyroscope"].segment
    assert segment.kind == "stationary"
    # The log starts inside the still leg. The 0.2 s moving average lets the first fraction of a second of the
    # launch's acceleration ramp pass; the 1 s trim must keep the launch out: end within (end - 1.5, end).
    assert segment.start_s == pytest.approx(start_s, abs=0.05)
    assert end_s - 1.5 < segment.end_s < end_s


def test_ground_noise_within_10_percent(record, log, ground_cal):
    imu = record["sensor_errors"]["imu"]
    sensors = ground_cal.sensors
    np.testing.assert_allclose(sensors["gyroscope"].sigma, imu["gyro_noise_rad_s"], rtol=0.10)
    np.testing.assert_allclose(sensors["accelerometer"].sigma, imu["accel_noise_m_s2"], rtol=0.10)
    np.testing.assert_allclose(sensors["magnetometer"].sigma, record["sensor_errors"]["mag"]["noise_gauss"],
                               rtol=0.10)
    np.testing.assert_allclose(sensors["gps_velocity"].sigma, record["sensor_errors"]["gps"]["velocity_noise_m_s"],
                               rtol=0.10)
    baro = record["sensor_errors"]["baro"]
    pressure = sensors["barometer"].segment.select(log["baro"])["pressure_pa"].mean()
    assert sensors["barometer"].sigma[0] == pytest.approx(
        _baro_sigma_m(baro["noise_pa"], pressure, baro["qnh_setting_pa"]), rel=0.10)


def test_allan_white_noise_density_within_15_percent(record, ground_cal):
    imu = record["sensor_errors"]["imu"]
    for sensor, sigma in (("gyroscope", imu["gyro_noise_rad_s"]), ("accelerometer", imu["accel_noise_m_s2"])):
        densities = [f.white_density for f in ground_cal.allan[sensor]]
        np.testing.assert_allclose(densities, sigma / np.sqrt(IMU_RATE_HZ), rtol=0.15, err_msg=sensor)


def test_stationary_biases_within_20_percent(record, log, ground_cal):
    imu = record["sensor_errors"]["imu"]
    bias = ground_cal.stationary_bias
    # The gyro bias walks (2e-5 rad/s/sqrt(s)): compare with its value at the start of the flight.
    np.testing.assert_allclose(bias.gyro_bias_rad_s, imu["gyro_bias_start_rad_s"], rtol=0.20)
    # Along gravity the accelerometer reads |(I + M) g up + b| = g + g up^T M up + b . up to first order.
    truth = bias.segment.select(log["truth_attitude"])[["qw", "qx", "qy", "qz"]].to_numpy()
    up = -quat_to_matrix(truth)[:, 2, :].mean(axis=0)
    up /= np.linalg.norm(up)
    scale = np.array(imu["accel_matrix"]) - np.eye(3)
    expected = np.dot(imu["accel_bias_m_s2"], up) + bias.gravity.value_m_s2 * up @ scale @ up
    assert bias.accel_bias_parallel_m_s2 == pytest.approx(expected, rel=0.20)


def test_cruise_noise_within_10_percent(record, log, gravity):
    imu = record["sensor_errors"]["imu"]
    site = record["scenario"]["site"]
    for start_s, end_s in _legs(record, "cruise"):
        # Leave the pitch/roll transitions of the neighbouring legs out (roll-in 4 s, pitch transition 6 s).
        cal = calibrate(log, segment=user_segment(log, start_s + 8.0, end_s - 8.0), gravity=gravity)
        sensors = cal.sensors
        gyro = np.hypot(imu["gyro_noise_rad_s"], imu["gyro_vibration_rad_s"])
        accel = np.hypot(imu["accel_noise_m_s2"], imu["accel_vibration_m_s2"])
        np.testing.assert_allclose(sensors["gyroscope"].sigma, gyro, rtol=0.10)
        np.testing.assert_allclose(sensors["accelerometer"].sigma, accel, rtol=0.10)
        np.testing.assert_allclose(sensors["magnetometer"].sigma, record["sensor_errors"]["mag"]["noise_gauss"],
                                   rtol=0.10)
        np.testing.assert_allclose(sensors["gps_velocity"].sigma,
                                   record["sensor_errors"]["gps"]["velocity_noise_m_s"], rtol=0.10)
        baro = sensors["barometer"].segment.select(log["baro"])
        pressure = baro["pressure_pa"].mean()
        errors = record["sensor_errors"]
        assert sensors["barometer"].sigma[0] == pytest.approx(
            _baro_sigma_m(errors["baro"]["noise_pa"], pressure, errors["baro"]["qnh_setting_pa"]), rel=0.10)
        temp_c = site["ground_temp_c"] - ISA_LAPSE_K_M * (baro["alt_m"].mean() - site["ground_alt_m"])
        rho = float(air_density_kg_m3(pressure, temp_c))
        speed = sensors["airspeed"].mean[0]
        assert sensors["airspeed"].sigma[0] == pytest.approx(errors["airspeed"]["noise_pa"] / (rho * speed),
                                                             rel=0.10)


def test_cruise_legs_are_found_as_steady_segments(record, log):
    steady = find_steady_segments(log)
    # Every cruise leg, without its transitions, lies inside one steady segment ...
    for start_s, end_s in _legs(record, "cruise"):
        assert any(s.start_s <= start_s + 8.0 and s.end_s >= end_s - 8.0 for s in steady)
    # ... and no steady segment reaches more than 2 s (window blur) into a climb, descent, launch or landing.
    for name in ("changealtitude", "handlaunch", "land", "still"):
        for start_s, end_s in _legs(record, name):
            for s in steady:
                assert min(s.end_s, end_s) - max(s.start_s, start_s) < 2.0, (name, s)


def test_tuned_noise_brings_the_replay_nis_closer_to_one(log, ground_cal):
    """Full-state direct replay of the whole mission, default noise vs the noise identified from the flight's
    innovations (``estimators.tuning.tune_estimator`` from the ground calibration, a small budget: the start and
    the covariance-matching steps). On the channels whose noise is identified (barometer, airspeed,
    magnetometer) the mean NIS moves towards its expected value 1. (The calibrated R alone no longer does: a
    measured figure is root-sum-squared with the default's model error, so it never sets the noise below it.)"""
    told = []  # the progress: one call per replay, counting up to the replays made
    result = tune_estimator(log, ground_cal, "full_state_direct", budget=4,
                            progress=lambda *replays: told.append(replays))
    assert told == [("full_state_direct", k, 4) for k in range(1, result.n_replays + 1)] and result.n_replays >= 2
    assert result.log_likelihood_trace[-1] > result.log_likelihood_trace[0]
    channels = [("baro", "alt"), ("airspeed", "tas"), ("mag", "x"), ("mag", "y"), ("mag", "z")]
    nis = {}
    for name, config in (("default", EstimatorConfig()), ("tuned", config_from_figures(result.figures))):
        diagnostics = run_estimators(log, estimators="full_state_direct", config=config, rate_hz=1.0).diagnostics
        nis[name] = diagnostics.groupby(["sensor", "component"], observed=True)["nis"].mean()
    for channel in channels:
        assert abs(nis["tuned"][channel] - 1.0) < abs(nis["default"][channel] - 1.0), channel
        assert 0.5 <= nis["tuned"][channel] <= 2.0, channel
