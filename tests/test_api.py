"""The replay contract: ``estimators.api.run_estimators`` tables and reports, the estimator registry, the
calibration -> noise mapping, and ``solarnav replay``."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from app.cli import main
from estimators.api import ESTIMATORS, parse_estimator_names, run_estimators
from estimators.config import EstimatorConfig, config_from_calibration
from estimators.core.results import (
    DIAGNOSTIC_COLUMNS,
    DIAGNOSTIC_SENSOR_NAMES,
    STATE_COLUMNS,
    STD_COLUMNS,
    states_frame,
)
from estimators.inputs.records import Origin
from ingest.errors import InputError
from tests.estimators_synthetic import synthetic_flight


@pytest.fixture(scope="module")
def flight():
    return synthetic_flight(8.0, seed=11)


def test_tables_follow_the_contract(flight):
    result = run_estimators(flight, estimators="full_state_direct", rate_hz=25.0)
    states = result.states
    assert tuple(states.columns[:len(STATE_COLUMNS)]) == STATE_COLUMNS
    assert set(states.columns[len(STATE_COLUMNS):]) <= set(STD_COLUMNS)
    assert (states["estimator"] == "full_state_direct").all()
    np.testing.assert_allclose(np.diff(states["time_s"]), 0.04, atol=1e-9)
    np.testing.assert_allclose(states["time_s"] * 25.0, np.round(states["time_s"] * 25.0), atol=1e-6)
    assert ((states["yaw_deg"] >= -180) & (states["yaw_deg"] < 180)).all()
    assert states[list(STATE_COLUMNS[2:])].notna().all().all()  # fixed-wing with every sensor: nothing missing
    # altitude above MSL: the synthetic flight is level at the origin's 630 m
    assert states["alt_m"].iloc[-1] == pytest.approx(630.0, abs=1.0)
    assert tuple(result.diagnostics.columns) == DIAGNOSTIC_COLUMNS
    assert result.diagnostics["accepted"].dtype == bool
    report = result.reports["full_state_direct"]
    assert {"prepare", "kernel", "total"} <= set(report.timings_s)
    assert report.used == ("baro", "airspeed", "sideslip", "gps_pos", "gps_vel", "mag")


def test_diagnostics_share_one_vocabulary(flight):
    """Every estimator names its sensors and components from one table (the three-stage's stage-1 ``accel`` and
    wind-triangle ``wind`` included), so the diagnostics of a multi-estimator run stay categorical."""
    result = run_estimators(flight)
    diagnostics = result.diagnostics
    for column in ("sensor", "component"):
        assert isinstance(diagnostics[column].dtype, pd.CategoricalDtype), column
    assert tuple(diagnostics["sensor"].cat.categories) == DIAGNOSTIC_SENSOR_NAMES
    three_stage = diagnostics[diagnostics["estimator"] == "three_stage"]
    assert {"accel", "wind"} <= set(three_stage["sensor"].astype(str))
    accel = three_stage[three_stage["sensor"] == "accel"]
    assert set(accel["component"].astype(str)) == {"x", "y", "z"}
    assert diagnostics["component"].notna().all()


def test_state_columns_share_no_memory():
    """states_frame wraps its columns without copying them, so no two columns may be one array (setting a value in
    one NaN column must not change another)."""
    k = 5
    position_velocity = np.zeros((k, 3))
    states = states_frame(np.arange(k) * 0.02, np.zeros(k), np.zeros(k), np.zeros(k), position_velocity,
                          position_velocity, None, Origin(math.nan, math.nan, 100.0, "baro"),
                          std={"vn_m_s_std": np.ones(k), "wind_n_m_s_std": np.ones(k)}, navigation=False, wind=False)
    columns = [states[column].to_numpy() for column in states.columns]
    assert not any(np.shares_memory(a, b) for i, a in enumerate(columns) for b in columns[i + 1:])
    states.loc[0, "vn_m_s"] = 1.0
    blank = ["lat_deg", "lon_deg", "ve_m_s", "vd_m_s", "wind_n_m_s", "wind_e_m_s", "vn_m_s_std", "wind_n_m_s_std"]
    assert states.loc[0, blank].isna().all()


def test_registry_and_selection(flight):
    assert set(ESTIMATORS) == {"three_stage", "full_state_direct", "full_state_indirect"}
    assert parse_estimator_names(" full_state_direct, three_stage,full_state_direct ") == (
        "full_state_direct", "three_stage")
    with pytest.raises(InputError, match=r"unknown estimator.*kalman.*available"):
        run_estimators(flight, estimators=["kalman"])
    with pytest.raises(InputError, match="no estimator"):
        parse_estimator_names(",")
    with pytest.raises(InputError, match="heading"):
        run_estimators(flight, estimators=["full_state_direct"], heading="gps")


def test_config_from_calibration_maps_noise():
    """docs/calibration.md, 'From calibration to filter settings': a measured figure is root-sum-squared with the
    default (never below it), the magnetometer is normalised by the field strength per axis, tuned figures of the
    selected estimator are used as they are, and every figure's source and use is recorded."""
    from types import SimpleNamespace

    from calib.figures import SOURCE_ALLAN, SOURCE_INFLIGHT, SOURCE_STILL, SOURCE_TUNED, Figure

    default = EstimatorConfig().noise
    gyro_axes, accel_axes = (5e-5, 6e-5, 7e-5), (0.02, 0.03, 0.04)
    figures = {
        "gyro_noise_density": Figure("gyro_noise_density", float(np.sqrt(np.mean(np.square(gyro_axes)))),
                                     SOURCE_ALLAN, axes=gyro_axes),
        "accel_noise_density": Figure("accel_noise_density", 0.05, SOURCE_STILL, axes=accel_axes),
        "baro_noise": Figure("baro_noise", 0.3, SOURCE_STILL),
        "airspeed_noise": Figure("airspeed_noise", 1.2, SOURCE_INFLIGHT),
        "mag_noise": Figure("mag_noise", 0.01, SOURCE_STILL, axes=(0.005, 0.01, 0.02)),
        "mag_field_strength": Figure("mag_field_strength", 0.5, SOURCE_STILL),
    }
    tuned = {**figures, "baro_noise": Figure("baro_noise", 0.1, SOURCE_TUNED)}
    calibration = SimpleNamespace(figures=figures,
                                  tuning={"full_state_direct": SimpleNamespace(figures=tuned)})
    config = config_from_calibration(calibration)
    noise = config.noise
    # IMU densities: sqrt(default^2 + measured^2), never below the default
    assert noise.gyro_noise_rad_s_sqrt_hz == pytest.approx(math.hypot(default.gyro_noise_rad_s_sqrt_hz,
                                                                      figures["gyro_noise_density"].value))
    assert noise.accel_noise_m_s2_sqrt_hz == pytest.approx(math.hypot(default.accel_noise_m_s2_sqrt_hz, 0.05))
    assert noise.gyro_noise_rad_s_sqrt_hz >= default.gyro_noise_rad_s_sqrt_hz
    # measurements: the setting is the default's model error plus the measured noise
    assert noise.baro_sigma_m == pytest.approx(math.hypot(default.baro_sigma_m, 0.3))
    assert noise.baro_sigma_m > default.baro_sigma_m
    assert noise.airspeed_sigma_m_s == pytest.approx(math.hypot(default.airspeed_sigma_m_s, 1.2))
    # magnetometer per axis in field units (/ 0.5 gauss), each root-sum-squared with the default
    np.testing.assert_allclose(noise.mag_sigma_axes, np.hypot(default.mag_sigma, np.array([0.01, 0.02, 0.04])))
    assert noise.gps_vel_sigma_floor_m_s == default.gps_vel_sigma_floor_m_s
    provenance = {figure: (source, use) for figure, source, use in config.calibrated.provenance}
    assert set(provenance) == set(figures)
    assert provenance["baro_noise"][0] == SOURCE_STILL and "sqrt(default" in provenance["baro_noise"][1]
    assert provenance["gyro_noise_density"][0] == SOURCE_ALLAN
    assert "noise.mag_sigma_axes" in provenance["mag_noise"][1]
    # the estimator's tuned figures are taken as they are; another estimator gets the calibration's figures
    direct = config_from_calibration(calibration, estimator="full_state_direct")
    assert direct.noise.baro_sigma_m == 0.1
    assert {f: s for f, s, _ in direct.calibrated.provenance}["baro_noise"] == SOURCE_TUNED
    assert config_from_calibration(calibration, estimator="three_stage").noise == noise
    with pytest.raises(InputError, match=r"noise\.baro_sigma_m"):
        EstimatorConfig().with_noise(baro_sigma_m=-1.0)


def test_replay_command(real_logs_dir, tmp_path, capsys):
    log = real_logs_dir / "sample_px4_events.ulg"
    out, diag = tmp_path / "states.csv", tmp_path / "diag.parquet"
    status = main(["replay", str(log), "--estimators", "full_state_direct", "--rate-hz", "10", "-o", str(out),
                   "--diagnostics", str(diag)])
    assert status == 0
    states, diagnostics = pd.read_csv(out), pd.read_parquet(diag)
    assert tuple(states.columns[:len(STATE_COLUMNS)]) == STATE_COLUMNS
    assert tuple(diagnostics.columns) == DIAGNOSTIC_COLUMNS and len(diagnostics) > 100
    assert "full_state_direct:" in capsys.readouterr().out
    assert not list(tmp_path.glob(".*.tmp"))  # atomic write leaves no temporary file
    # bad input: one line on stderr, exit status 2, nothing written
    assert main(["replay", str(log), "-o", str(tmp_path / "states.txt")]) == 2
    assert "must end in .parquet or .csv" in capsys.readouterr().err
    assert main(["replay", str(log), "--estimators", "nope", "-o", str(tmp_path / "x.csv")]) == 2
    assert "unknown estimator" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_estimators_in_threads_equal_one_after_the_other(flight):
    """The estimators share one set of replay inputs across threads: nothing they read may be changed by another
    (a run in place on a shared array would show here as a difference)."""
    events = []
    threaded = run_estimators(flight, threads=3, progress=lambda stage, name: events.append((stage, name)))
    serial = run_estimators(flight, threads=1)
    pd.testing.assert_frame_equal(threaded.states, serial.states)
    pd.testing.assert_frame_equal(threaded.diagnostics, serial.diagnostics)
    for name in ESTIMATORS:
        stages = [stage for stage, estimator in events if estimator == name]
        assert stages == ["prepare", "run", "done"], (name, stages)
