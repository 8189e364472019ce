"""The same estimator across several logs (issue 14, "Comparison everywhere"): series named per estimator, log and
run, each log from its own start; the RMS table of one estimator per log against a baseline log; the Compare logs
page headless with two bundled logs and a stored synthetic run on each."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from streamlit.testing.v1 import AppTest

from app import adapters, comparison, figures, runs, samples, session, tables
from app.workspace import Workspace
from tests.test_app_run_comparison import ENTRYPOINT, TIMEOUT_S, _store_run

LOGS = (samples.SAMPLE_DIR / "failed_cell.ulg", samples.SAMPLE_DIR / "paper.ulg")


def _frame(start_s: float, n: int = 200) -> pd.DataFrame:
    time_s = start_s + np.arange(n) * 0.1
    return pd.DataFrame({"time_s": time_s, "roll_deg": np.sin(time_s), "pitch_deg": 0.0, "yaw_deg": 170.0})


def test_every_log_is_drawn_from_its_own_start_in_its_own_colour():
    unix = figures.LogRun("events.ulg", "default", figures.TimeBase(start_s=1.7e9),
                          {"three_stage": _frame(1.7e9), "truth": _frame(1.7e9), "full_state_direct": _frame(1.7e9)})
    short = figures.LogRun("short.ulg", "tuned", figures.TimeBase(start_s=12.0),
                           {"three_stage": _frame(12.0), "onboard": _frame(12.0)})
    frames, bases, styles = figures.overlay_log_sources([unix, short], "three_stage")
    assert list(frames) == ["three_stage · events.ulg · default", "truth · events.ulg",
                            "three_stage · short.ulg · tuned", "onboard · short.ulg"]  # other estimators left out
    assert bases["truth · events.ulg"] == unix.time_base and bases["onboard · short.ulg"] == short.time_base
    assert styles["three_stage · events.ulg · default"] == (figures.AXIS_COLORS[0], "solid")
    assert styles["truth · events.ulg"] == (figures.AXIS_COLORS[0], figures.REFERENCE_DASH["truth"])
    assert styles["three_stage · short.ulg · tuned"][0] == figures.AXIS_COLORS[1]

    fig = figures.overlay_logs_figure([unix, short], "three_stage", comparison.STATE_PANELS["Attitude"],
                                      title="Attitude", window=(0.0, 10.0))
    roll = {trace.name: trace for trace in fig.data if trace.yaxis == "y"}
    for name in ("three_stage · events.ulg · default", "three_stage · short.ulg · tuned"):
        assert roll[name].x[0] == pytest.approx(0.0)  # seconds since that log's start
        assert max(roll[name].x) <= 10.1 + 1e-9  # the shared window, one sample beyond
    assert "log clock 1700000000.000" in roll["three_stage · events.ulg · default"].customdata[0]
    assert roll["three_stage · short.ulg · tuned"].line.color == figures.AXIS_COLORS[1]
    assert fig.layout.xaxis3.title.text == figures.TIME_TITLE


def test_the_rms_of_one_estimator_per_log_against_the_baseline_log():
    columns = ["Height (m)", "Wind (m/s)"]
    first = pd.DataFrame([[2.0, 1.0], [9.0, 9.0]], index=["three_stage", "full_state_direct"], columns=columns)
    second = pd.DataFrame([[3.0, 0.5]], index=["three_stage"], columns=columns)
    no_run = pd.DataFrame([[1.0, 1.0]], index=["full_state_direct"], columns=columns)
    table = comparison.log_rms_comparison({"a · r1": first, "b · r2": second, "c · r3": no_run}, "three_stage",
                                          "a · r1", dict.fromkeys(["a · r1", "b · r2", "c · r3"], "truth"))
    assert set(table["estimator"]) == {"three_stage"} and list(table["run"].unique()) == ["a · r1", "b · r2"]
    height = table.set_index(["run", "quantity"])
    assert height.loc[("b · r2", "Height (m)"), "delta"] == pytest.approx(1.0)
    assert height.loc[("b · r2", "Wind (m/s)"), "delta [%]"] == pytest.approx(-50.0)
    assert height.loc[("b · r2", "Wind (m/s)"), "change"] == comparison.IMPROVED
    wide = tables.rms_delta_table(table, "a · r1")
    assert wide.loc[("b · r2", "three_stage"), "Height (m)"] == "3.00 (+1.00, +50.0 %) ▲"


def test_logs_against_another_reference_than_the_baseline_get_no_verdict():
    """Issue 34: an octocopter against its onboard estimate is not "regressed" against a simulated mission against
    its truth; only like references compare, and a sentence says why the others are not."""
    columns = ["Position (m)"]
    truth = pd.DataFrame([[3.0]], index=["three_stage"], columns=columns)
    onboard = pd.DataFrame([[50.0]], index=["three_stage"], columns=columns)
    other_truth = pd.DataFrame([[6.0]], index=["three_stage"], columns=columns)
    references = {"paper · r1": "truth", "octo · r2": "onboard", "sim · r3": "truth"}
    table = comparison.log_rms_comparison({"paper · r1": truth, "octo · r2": onboard, "sim · r3": other_truth},
                                          "three_stage", "paper · r1", references).set_index("run")
    assert table.at["octo · r2", "change"] == comparison.OTHER_REFERENCE
    assert np.isnan(table.at["octo · r2", "delta"]) and np.isnan(table.at["octo · r2", "delta [%]"])
    assert table.at["sim · r3", "change"] == comparison.REGRESSED  # truth with truth still compares
    wide = tables.rms_delta_table(table.reset_index(), "paper · r1")
    assert wide.loc[("octo · r2", "three_stage"), "Position (m)"] == "50.00 (other reference)"
    styled = tables.rms_delta_style(table.reset_index(), "paper · r1").to_html()
    assert styled.count("background-color") == 1  # only the like-for-like row is coloured
    text = comparison.other_reference_text(references, "paper · r1")
    assert "octo · r2 against the onboard estimate" in text and "sim · r3" not in text
    assert "baseline, which is against the ground truth" in text
    assert comparison.other_reference_text(references, "sim · r3").startswith("Not compared")
    assert comparison.other_reference_text({"a": "truth", "b": "truth"}, "a") is None
    assert comparison.like_for_like("onboard", "onboard") and not comparison.like_for_like(None, None)


def test_every_reference_has_its_plain_sentence():
    assert comparison.reference_sentence("truth") == "Errors against the ground truth."
    assert "not necessarily better" in comparison.reference_sentence("onboard")
    assert "no errors" in comparison.reference_sentence(None)


def test_runs_with_an_estimator():
    stored = pd.DataFrame({"run_id": ["r1", "r2"], "settings_json": [
        json.dumps({"estimators": ["three_stage", "full_state_direct"]}), json.dumps({"estimators": ["three_stage"]})]})
    assert comparison.runs_with(stored, "three_stage") == ["r1", "r2"]
    assert comparison.runs_with(stored, "full_state_direct") == ["r1"]
    assert comparison.runs_with(stored, "full_state_indirect") == []


def test_compare_logs_page_overlays_one_estimator_of_two_logs(tmp_path: Path, monkeypatch):
    monkeypatch.setenv(session.WORKSPACE_ENV, str(tmp_path))
    at = AppTest.from_file(str(ENTRYPOINT), default_timeout=TIMEOUT_S)
    at.run()  # adds the bundled samples
    at.switch_page("views/compare_logs.py").run()
    assert not at.exception
    assert any("Fewer than two logs" in info.value for info in at.info)

    workspace = Workspace(tmp_path)
    shas = [hashlib.sha256(path.read_bytes()).hexdigest() for path in LOGS]
    run_ids = [_store_run(workspace, sha256, adapters.stored_log(str(tmp_path.resolve()), sha256), offset,
                          runs.DEFAULT_NOISE) for sha256, offset in zip(shas, (2.0, 4.0), strict=True)]
    at.selectbox(key="cmp_estimator").set_value("three_stage").run()
    assert not at.exception and not at.error
    assert sorted(at.multiselect(key="cmp_logs").value) == sorted(shas)
    at.multiselect(key="cmp_logs").set_value(shas).run()
    at.selectbox(key="cmp_baseline").set_value(shas[0]).run()
    assert not at.exception
    names = {sha256: workspace.list_runs(sha256)["name"].iloc[0] for sha256 in shas}
    labels = [f"{path.name} · {names[sha256]}" for path, sha256 in zip(LOGS, shas, strict=True)]
    [wide] = [table.value for table in at.table if "Height (m)" in table.value.columns]
    assert list(wide.index) == [(labels[0], "three_stage"), (labels[1], "three_stage")]
    assert wide.loc[(labels[0], "three_stage"), "Height (m)"] == "2.00 (baseline)"
    assert wide.loc[(labels[1], "three_stage"), "Height (m)"] == "4.00 (+2.00, +100.0 %) ▲"

    [chart] = [json.loads(chart.proto.spec) for chart in at.get("plotly_chart")]
    series = {trace["name"] for trace in chart["data"]}
    assert {f"three_stage · {label}" for label in labels} <= series
    assert {f"truth · {path.name}" for path in LOGS} <= series
    assert not any(name.startswith("full_state_indirect") for name in series)
    assert chart["layout"]["dragmode"] == "select"  # a box on it zooms the page's range
    at.segmented_control(key="cmp_panel").set_value("Errors").run()
    assert not at.exception
    [chart] = [json.loads(chart.proto.spec) for chart in at.get("plotly_chart")]
    assert chart["layout"]["title"]["text"] == "Errors: three_stage across logs"
    assert at.selectbox(key=f"cmp_run_{shas[1]}").value == run_ids[1]


def _parameter_view(root: Path, monkeypatch, first: str, second: str) -> AppTest:
    """The Compare logs page's parameter view of two stored logs."""
    monkeypatch.setenv(session.WORKSPACE_ENV, str(root))
    monkeypatch.setattr(samples, "find_samples", lambda *args: [])
    at = AppTest.from_file(str(ENTRYPOINT), default_timeout=TIMEOUT_S)
    at.run()
    at.switch_page("views/compare_logs.py").run()
    at.segmented_control(key="cmp_view").set_value("Parameters between two logs").run()
    at.selectbox(key="cmp_params_a").set_value(first).run()
    at.selectbox(key="cmp_params_b").set_value(second).run()
    assert not at.exception and not at.error
    return at


def test_the_parameter_view_of_two_bundled_logs(tmp_path: Path, monkeypatch):
    """Issue 33 (1): equal parameters say so (no empty table); each flight's onboard EKF2 noise sits next to the
    automatic calibration's values."""
    workspace = Workspace(tmp_path)
    shas = [workspace.add_log(path.read_bytes(), path.name).sha256 for path in LOGS]
    at = _parameter_view(tmp_path, monkeypatch, *shas)
    assert any("0 changed, 0 added (only in B), 0 removed (only in A)" in text.value for text in at.markdown)
    assert not [frame for frame in at.dataframe if "change" in frame.value.columns]
    noise = [frame.value for frame in at.dataframe if "onboard" in frame.value.columns]
    assert len(noise) == 2
    for table in noise:  # the calibrated sensor noises have solarnav's value (the process noises need identification)
        assert table["name"].str.startswith("EKF2_").all(), table
        assert {"EKF2_GYR_NOISE", "EKF2_ACC_NOISE", "EKF2_MAG_NOISE", "EKF2_BARO_NOISE"} <= set(
            table.loc[table["solarnav"].notna(), "name"]), table
    assert sum("automatic calibration" in text.value for text in at.markdown) == 2
    at.selectbox(key="cmp_params_a").set_value(shas[1]).run()  # A takes B's log: B moves to the other one
    assert not at.exception and at.selectbox(key="cmp_params_b").value == shas[0]


def test_the_parameter_view_of_the_two_real_octocopter_flights(tmp_path: Path, monkeypatch, real_logs_dir):
    """Issue 33 (1): the dashboard's diff is the library's (as ``solarnav params``), grouped by prefix."""
    from ingest.log_formats import load_flight_log
    from workflows.params import diff_parameters

    paths = [real_logs_dir / "px4_1.14_octo_flight_61.ulg", real_logs_dir / "px4_1.14_octo_flight_123.ulg"]
    workspace = Workspace(tmp_path)
    shas = [workspace.add_log(path.read_bytes(), path.name).sha256 for path in paths]
    at = _parameter_view(tmp_path, monkeypatch, *shas)
    expected = diff_parameters(*(load_flight_log(path).meta.parameters for path in paths))
    assert len(expected)  # two flights of one vehicle still differ in some parameters
    [shown] = [frame.value for frame in at.dataframe if "change" in frame.value.columns]
    assert list(shown["name"]) == list(expected["name"]) and list(shown["change"]) == list(expected["change"])
    assert list(at.multiselect(key=f"cmp_params_groups_{shas[0]}_{shas[1]}").value) == list(
        dict.fromkeys(expected["group"]))
    assert len([frame for frame in at.dataframe if "onboard" in frame.value.columns]) == 2
