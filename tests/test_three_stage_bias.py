"""The three-stage filter has no bias states: without a calibration it removes the error-state filter's in-flight
accelerometer bias from its specific force (docs/three_stage.md, 'Pre-processing'). An accelerometer bias b
tilts its roll and pitch by about b / g (0.4 m/s^2, inside the Table-1 zero-g offset of 50 mg, is 2.3 deg)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from calib.figures import MAX_ACCEL_BIAS_STD_M_S2, SOURCE_INFLIGHT_BIAS
from estimators.api import run_estimators
from estimators.config import EstimatorConfig
from estimators.evaluation import evaluate
from ingest.flightlog import FlightLog
from sim.scenarios import SCENARIOS
from sim.simulate import simulate

SEED = 11


@pytest.fixture(scope="module")
def calm():
    """A calm simulated flight of 300 s (60 s at rest, launch, about 4 minutes circling) with its sensor errors."""
    return simulate(SCENARIOS["calm"], np.random.default_rng(SEED), duration_s=300.0)


@pytest.fixture(scope="module")
def default_replay(calm):
    return run_estimators(calm.log, estimators=("three_stage", "full_state_indirect"), rate_hz=5.0)


def test_the_removed_bias_is_the_error_state_filters_estimate_of_the_simulated_bias(calm, default_replay):
    details = default_replay.reports["three_stage"].details
    final = default_replay.reports["full_state_indirect"].details["final_state"]
    removed = np.asarray(details["accel_bias_removed_m_s2"])
    np.testing.assert_array_equal(removed, [final[f"ba{axis}"] for axis in "xyz"])
    # Horizontal axes: what tilts roll and pitch; observable in turns through the GPS velocity. What the filters
    # see in near-level flight is the additive bias plus the axes' misalignment and scale acting on gravity.
    imu = calm.errors["imu"]
    gravity = np.array([0.0, 0.0, -9.81])
    effective = np.asarray(imu["accel_bias_m_s2"]) + (np.asarray(imu["accel_matrix"]) - np.eye(3)) @ gravity
    assert np.abs(removed[:2] - effective[:2]).max() < 0.1, (removed, effective)
    uses = {item["figure"]: (item["source"], item["use"]) for item in details["calibration"]}
    assert uses["accel_bias"][0] == SOURCE_INFLIGHT_BIAS and "error-state" in uses["accel_bias"][1]


def test_the_three_stage_result_does_not_depend_on_the_selection(calm, default_replay):
    alone = run_estimators(calm.log, estimators="three_stage", rate_hz=5.0)
    together = default_replay.states[default_replay.states["estimator"] == "three_stage"].reset_index(drop=True)
    np.testing.assert_array_equal(alone.states["roll_deg"].to_numpy(), together["roll_deg"].to_numpy())
    one_thread = run_estimators(calm.log, estimators=("three_stage", "full_state_indirect"), rate_hz=5.0, threads=1)
    np.testing.assert_array_equal(one_thread.states["roll_deg"].to_numpy(),
                                  default_replay.states["roll_deg"].to_numpy())


def test_removing_the_bias_levels_roll_and_pitch(calm, default_replay):
    # a bias of zero given (as a calibration would give it): nothing removed, the filter as before this rule
    zero = run_estimators(calm.log, estimators="three_stage", rate_hz=5.0,
                          config=_with_accel_bias(EstimatorConfig(), 0.0))
    rms_before = evaluate(zero.states, calm.log).rms().loc["three_stage"]
    rms_after = evaluate(default_replay.states, calm.log).rms().loc["three_stage"]
    assert math.hypot(rms_before["roll_deg"], rms_before["pitch_deg"]) > 0.8, "a draw that tilts the filter visibly"
    assert math.hypot(rms_after["roll_deg"], rms_after["pitch_deg"]) < 0.6 * math.hypot(rms_before["roll_deg"],
                                                                                        rms_before["pitch_deg"])


def test_an_axis_that_has_not_converged_is_left_at_zero_and_the_others_still_level(calm, default_replay):
    # a z bias random walk (a fixed-wing's cross-axis coupling, evaluation.SIM_ACCEL_BIAS_RW_Z) keeps the z bias
    # sigma above the convergence limit; the horizontal axes, which tilt the levelling, are still removed
    noise = dataclasses.replace(EstimatorConfig().noise, accel_bias_rw_z_m_s3_sqrt_hz=0.05)
    replay = run_estimators(calm.log, estimators=("three_stage", "full_state_indirect"), rate_hz=5.0,
                            config=EstimatorConfig(noise=noise))
    final = replay.reports["full_state_indirect"].details["final_state_std"]
    assert final["dbaz"] > MAX_ACCEL_BIAS_STD_M_S2 >= max(final["dbax"], final["dbay"]), final
    details = replay.reports["three_stage"].details
    removed = details["accel_bias_removed_m_s2"]
    estimated = replay.reports["full_state_indirect"].details["final_state"]
    assert removed == [estimated["bax"], estimated["bay"], 0.0] or tuple(removed) == (estimated["bax"],
                                                                                       estimated["bay"], 0.0)
    uses = {item["figure"]: item["use"] for item in details["calibration"]}
    assert "not converged, left at zero: z (sigma" in uses["accel_bias"]
    rms = evaluate(replay.states, calm.log).rms().loc["three_stage"]
    rms_default = evaluate(default_replay.states, calm.log).rms().loc["three_stage"]
    assert math.hypot(rms["roll_deg"], rms["pitch_deg"]) < 1.2 * math.hypot(rms_default["roll_deg"],
                                                                            rms_default["pitch_deg"])


def test_no_gps_no_bias_removed(calm):
    streams = {name: frame for name, frame in calm.log.streams.items() if name != "gps"}
    without_gps = FlightLog(streams=streams, meta=calm.log.meta)
    details = run_estimators(without_gps, estimators="three_stage", rate_hz=5.0,
                             allow_untrusted=True).reports["three_stage"].details
    assert details["accel_bias_removed_m_s2"] is None
    assert all(item["figure"] != "accel_bias" for item in details["calibration"])


def _with_accel_bias(config: EstimatorConfig, value: float) -> EstimatorConfig:
    return dataclasses.replace(config, calibrated=dataclasses.replace(config.calibrated,
                                                                      accel_bias_m_s2=(value, value, value)))


def test_a_failing_error_state_run_fails_the_waiting_three_stage_run_instead_of_hanging(calm, monkeypatch):
    import threading

    import estimators.api as api

    def broken(flight_log, inputs, config):
        raise RuntimeError("error-state kernel failed")

    monkeypatch.setitem(api.ESTIMATORS, "full_state_indirect", broken)
    outcome = []

    def replay():
        try:
            run_estimators(calm.log, estimators=("three_stage", "full_state_indirect"), rate_hz=5.0)
        except RuntimeError as exc:
            outcome.append(str(exc))

    worker = threading.Thread(target=replay, daemon=True)
    worker.start()
    worker.join(timeout=120.0)
    assert not worker.is_alive(), "the three-stage run waits forever for the failed error-state run"
    assert outcome == ["error-state kernel failed"]
