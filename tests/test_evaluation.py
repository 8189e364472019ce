"""The one evaluator (issue 30): explicit window and origin, in-flight quantities, and the same numbers in the
dashboard's table, the library's table and the batch summary for one run (docs/evaluation.md)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from app import adapters, comparison, runs, samples
from app.batch.task import reference_rms
from app.workspace import Workspace
from estimators import evaluation
from estimators.evaluation import QUANTITIES, evaluate, rms_errors, rms_window
from ingest.flightlog import FlightLog
from tests.app_logs import truth_only_log
from tests.conftest import REPO_DIR


def _estimate(log, yaw_error_deg) -> pd.DataFrame:
    """The truth of ``log`` as an estimator's states, its yaw off by ``yaw_error_deg(time_s)``."""
    time_s = log["truth_attitude"].index.to_numpy(float)
    states = evaluation.reference_states(log, "truth", time_s)
    return states.assign(estimator="e", yaw_deg=states["yaw_deg"] + yaw_error_deg(time_s - time_s[0]))


def test_the_window_skips_the_convergence_and_keeps_the_last_third():
    assert rms_window(np.array([0.0, 100.0, 200.0])) == (60.0, 200.0)
    assert rms_window(np.array([0.0, 100.0, 200.0]), convergence_s=0.0) == (0.0, 200.0)
    assert rms_window(np.array([10.0, 40.0])) == (30.0, 40.0)  # 60 s would leave nothing of a 30-s run
    assert all(np.isnan(rms_window(np.array([]))))


def test_rms_covers_the_window_only_and_follows_the_convergence_parameter():
    log = truth_only_log(n=2000, rate_hz=10.0)  # 200 s
    states = _estimate(log, lambda t: np.where(t < 60.0, 10.0, 1.0))
    assert evaluate(states, log).rms().at["e", "yaw_deg"] == pytest.approx(1.0)
    everything = evaluate(states, log, convergence_s=0.0)
    assert everything.window_s[0] == pytest.approx(10.0)
    assert everything.rms().at["e", "yaw_deg"] == pytest.approx(np.sqrt((600 * 100.0 + 1400 * 1.0) / 2000), rel=1e-3)


def test_the_origin_is_the_first_fix_or_explicit_and_position_errors_do_not_depend_on_it():
    log = truth_only_log()
    states = _estimate(log, lambda t: 0.0 * t)
    states["lat_deg"] += 5.0 / 111_000.0  # 5 m north
    default = evaluate(states, log)
    assert default.origin == tuple(float(v) for v in log["gps"].iloc[0])
    elsewhere = evaluate(states, log, origin=(35.1, 108.1, 0.0))
    assert elsewhere.origin == (35.1, 108.1, 0.0)
    for result in (default, elsewhere):
        assert result.rms().at["e", "position_m"] == pytest.approx(5.0, rel=2e-3)


def test_airspeed_course_and_wind_count_in_flight_only():
    log = truth_only_log(n=2000, rate_hz=10.0)
    slow = log["truth_local_position"].index.to_numpy(float) < 110.0  # the first 100 s on the ground
    log["truth_local_position"].loc[slow, "vx_m_s"] = 0.0
    states = _estimate(log, lambda t: 0.0 * t)
    states.loc[states["time_s"] < 110.0, "wind_n_m_s"] += 4.0  # a wind held on the ground: not an error
    result = evaluate(states, log, convergence_s=0.0)
    assert np.isnan(result.errors["e"].loc[states["time_s"] < 110.0, "wind_m_s"]).all()
    assert result.rms().at["e", "wind_m_s"] == pytest.approx(0.0, abs=1e-9)


def test_an_unknown_reference_is_refused_and_a_missing_one_gives_no_errors():
    log = truth_only_log()
    states = _estimate(log, lambda t: 0.0 * t)
    with pytest.raises(ValueError, match="reference"):
        evaluate(states, log, reference="gps")
    onboard = evaluate(states, log, reference="onboard")
    assert onboard.reference is None and onboard.errors == {} and onboard.rms().empty
    without_truth = FlightLog(streams={"gps": log["gps"]}, meta=log.meta)
    with pytest.raises(ValueError, match="no ground truth"):
        rms_errors(states, without_truth)


def test_dashboard_library_and_batch_show_the_same_numbers_for_one_run(tmp_path):
    """A default run of the bundled mission, made and shown as the dashboard does (stored run, cached adapters),
    against the library's table and the batch summary's columns of the same states."""
    workspace = Workspace(tmp_path / "workspace")
    paper = next(sample for sample in samples.find_samples(REPO_DIR / "sample_logs") if sample.ulog.stem == "paper")
    entry = samples.add_samples(workspace, [paper])[0]
    root = str(workspace.root)
    log = adapters.stored_log(root, entry.sha256)
    run_id = runs.replay_and_store(workspace, entry.sha256, log, runs.RunSettings(heading="mag"))
    dashboard = adapters.rms_table(root, entry.sha256, run_id)
    states = adapters.run_table(root, run_id, "states")
    library = rms_errors(states, log)
    batch = reference_rms(states, log)
    assert list(dashboard.columns) == [label for label, _ in comparison.QUANTITIES.values()]
    assert list(dashboard.index) == list(library.index) == list(batch)
    for name in library.index:
        for quantity, label in zip(QUANTITIES, dashboard.columns, strict=True):
            assert dashboard.at[name, label] == library.at[name, quantity], (name, quantity)
            assert batch[name][f"rms_truth_{quantity}"] == library.at[name, quantity], (name, quantity)
    assert np.isfinite(library.to_numpy()).all()
