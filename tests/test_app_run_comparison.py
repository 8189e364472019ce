"""Several estimator runs of one log side by side (issue 14, "Comparison everywhere"): the styles of overlaid
series, the long RMS table with baseline deltas, the NIS tables of several runs, the overlay figures, and the
Estimators page headless with two stored synthetic runs."""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from streamlit.testing.v1 import AppTest

from app import adapters, comparison, figures, runs, samples, session, tables
from app.workspace import Workspace
from estimators import evaluation
from estimators.core.results import DIAGNOSTIC_COLUMNS, STATE_COLUMNS
from ingest.flightlog import FlightLog
from tests.app_logs import truth_only_log
from tests.conftest import REPO_DIR

ENTRYPOINT = REPO_DIR / "app" / "dashboard.py"
SHORT_SAMPLE = samples.SAMPLE_DIR / "failed_cell.ulg"
TIMEOUT_S = 300
POSITION = "Position (m)"
ESTIMATORS = ("three_stage", "full_state_indirect")


def _states(log: FlightLog, offsets: dict[str, tuple[float, float]], step: int = 2) -> pd.DataFrame:
    """Estimators following the truth with a height offset [m] and a yaw offset [deg] each."""
    truth = log["truth_global_position"].iloc[::step]
    time_s = truth.index.to_numpy(float)
    reference = evaluation.reference_states(log, "truth", time_s)
    parts = [reference.assign(estimator=name, alt_m=reference["alt_m"] + d_alt, yaw_deg=reference["yaw_deg"] + d_yaw)
             for name, (d_alt, d_yaw) in offsets.items()]
    return pd.concat(parts, ignore_index=True)[list(STATE_COLUMNS)]


# ------------------------------------------------------------------------------------------------ pure functions
def test_run_style_colour_per_estimator_dash_per_run():
    for estimator in ("three_stage", "full_state_direct", "full_state_indirect"):
        colours = {figures.run_style(estimator, k)[0] for k in range(8)}
        assert colours == {figures.SOURCE_COLORS[estimator]}
    dashes = [figures.run_style("three_stage", k)[1] for k in range(len(figures.RUN_DASHES) + 1)]
    assert dashes[:-1] == list(figures.RUN_DASHES) and dashes[0] == "solid" and len(set(dashes[:-1])) == len(dashes) - 1
    assert dashes[-1] == dashes[0]  # cycles
    assert figures.run_style("three_stage", 1)[1] == figures.run_style("full_state_direct", 1)[1]
    assert figures.run_style("my_filter", 0) == figures.run_style("my_filter", 0)  # unknown: stable colour
    assert figures.run_style("my_filter", 0)[0] in figures.AXIS_COLORS
    assert figures.run_series_name("three_stage", "calibrated") == "three_stage · calibrated"


def test_overlay_sources_names_each_estimator_per_run_and_keeps_references_once():
    frame = pd.DataFrame({"time_s": [0.0, 1.0], "alt_m": [1.0, 2.0]})
    frames, styles = figures.overlay_sources({
        "default": {"three_stage": frame, "truth": frame, "onboard": frame},
        "tuned": {"three_stage": frame + 1, "full_state_direct": frame, "truth": frame + 5}})
    assert list(frames) == ["three_stage · default", "three_stage · tuned", "full_state_direct · tuned", "truth",
                            "onboard"]
    assert frames["truth"] is frame  # from the first run
    assert styles["three_stage · default"] == (figures.SOURCE_COLORS["three_stage"], "solid")
    assert styles["three_stage · tuned"] == (figures.SOURCE_COLORS["three_stage"], "dash")
    assert styles["full_state_direct · tuned"] == (figures.SOURCE_COLORS["full_state_direct"], "dash")
    assert styles["truth"] == (figures.SOURCE_COLORS["truth"], figures.REFERENCE_DASH["truth"])


def test_overlay_figures_style_every_series_and_keep_the_window():
    log = truth_only_log()
    results = comparison.compare_runs({"default": _states(log, {"three_stage": (5.0, 0.0)}),
                                       "tuned": _states(log, {"three_stage": (1.0, 0.0)})}, log)
    per_run = {name: result.quantities for name, result in results.items()}
    window = (10.0, 40.0)
    fig = figures.overlay_quantity_figure(per_run, [("alt_m", "altitude [m]"), ("yaw_deg", "yaw [deg]")],
                                          title="Altitude", time_base=figures.TimeBase(start_s=10.0), window=window)
    legend = [trace.name for trace in fig.data if trace.showlegend is not False]
    assert legend == ["three_stage · default", "three_stage · tuned", "truth"]
    for trace in fig.data:
        expected = {"three_stage · default": "solid", "three_stage · tuned": "dash",
                    "truth": figures.REFERENCE_DASH["truth"]}[trace.name]
        assert trace.line.dash == expected
        assert trace.line.color == figures.SOURCE_COLORS[trace.name.split(" · ")[0]]
        assert np.nanmax(trace.x) <= window[1] + 0.1 and np.nanmin(trace.x) >= window[0] - 0.1
    assert list(fig.layout.xaxis2.range) == list(window)

    track = figures.overlay_track_figure(per_run, time_base=figures.TimeBase(start_s=10.0), window=window)
    lines = {trace.name: trace for trace in track.data if trace.mode == "lines"}
    assert set(lines) == {"three_stage · default", "three_stage · tuned", "truth"}
    assert lines["three_stage · tuned"].line.dash == "dash"
    starts = [trace for trace in track.data if trace.mode == "markers"]
    assert all(trace.marker.color == figures.SOURCE_COLORS[trace.name.split(" · ")[0].removesuffix(" start")]
               for trace in starts)

    diagnostics = {run: pd.DataFrame({"time_s": 10.0 + np.arange(100.0), "component": "h", "innovation": scale,
                                      "innovation_var": 1.0, "nis": scale**2, "accepted": True})
                   for run, scale in (("default", 1.0), ("tuned", 0.5))}
    innovations = figures.overlay_innovation_figure(diagnostics, "three_stage", {"h": "m"}, title="baro",
                                                    time_base=figures.TimeBase(start_s=10.0), window=window)
    named = [trace for trace in innovations.data if " · " in trace.name and "sqrt" not in trace.name]
    assert [(t.name, t.line.dash) for t in named] == [("three_stage · default", "solid"),
                                                      ("three_stage · tuned", "dash")]
    assert innovations.layout.yaxis.title.text == "h [m]"
    moving = {run: comparison.moving_nis(frame, 10) for run, frame in diagnostics.items()}
    nis = figures.overlay_nis_figure(moving, "three_stage", 10, comparison.nis_band(10), title="NIS",
                                     time_base=figures.TimeBase(start_s=10.0), time_window=window)
    assert [(t.name, t.line.dash) for t in nis.data] == [("h: three_stage · default", "solid"),
                                                         ("h: three_stage · tuned", "dash")]
    assert nis.data[0].line.color == nis.data[1].line.color  # colour per component, dash per run


def test_rms_comparison_of_synthetic_runs_gives_baseline_deltas():
    log = truth_only_log()
    results = comparison.compare_runs({
        "default": _states(log, {"three_stage": (5.0, 2.0), "full_state_indirect": (2.0, 1.0)}),
        "calibrated": _states(log, {"three_stage": (5.0, 1.0), "full_state_indirect": (4.0, 1.0),
                                    "full_state_direct": (1.0, 0.0)})}, log)
    rms = {name: comparison.rms_table(result) for name, result in results.items()}
    table = comparison.rms_comparison(rms, "default")
    assert list(table.columns) == list(comparison.RMS_COMPARISON_COLUMNS)
    n_quantities = len(comparison.QUANTITIES)
    assert len(table) == (2 + 3) * n_quantities
    assert list(dict.fromkeys(zip(table["run"], table["estimator"], strict=True))) == [
        ("default", "three_stage"), ("default", "full_state_indirect"), ("calibrated", "three_stage"),
        ("calibrated", "full_state_indirect"), ("calibrated", "full_state_direct")]
    row = table.set_index(["run", "estimator", "quantity"])
    height = row.loc[("calibrated", "full_state_indirect", "Height (m)")]
    assert height["RMS"] == pytest.approx(4.0) and height["baseline RMS"] == pytest.approx(2.0)
    assert height["delta"] == pytest.approx(2.0) and height["delta [%]"] == pytest.approx(100.0)
    assert height["change"] == comparison.REGRESSED
    yaw = row.loc[("calibrated", "three_stage", "Yaw Angle (deg)")]
    assert yaw["delta"] == pytest.approx(-1.0) and yaw["delta [%]"] == pytest.approx(-50.0)
    assert yaw["change"] == comparison.IMPROVED
    assert row.loc[("calibrated", "three_stage", "Height (m)"), "change"] == comparison.UNCHANGED
    baseline_rows = table.loc[table["run"] == "default"]
    assert (baseline_rows["delta"].dropna() == 0.0).all()
    new = row.loc[("calibrated", "full_state_direct", "Height (m)")]  # not in the baseline: no delta
    assert new["RMS"] == pytest.approx(1.0) and np.isnan(new["delta"]) and new["change"] == ""
    with pytest.raises(KeyError):
        comparison.rms_comparison(rms, "tuned")

    assert comparison.change_verdict(0.5) == comparison.UNCHANGED
    assert comparison.change_verdict(-3.0) == comparison.IMPROVED
    assert comparison.change_verdict(np.nan) == ""

    wide = tables.rms_delta_table(comparison.rms_comparison(rms, "calibrated"), "calibrated")  # baseline first
    assert list(wide.index) == [("calibrated", "three_stage"), ("calibrated", "full_state_indirect"),
                                ("calibrated", "full_state_direct"), ("default", "three_stage"),
                                ("default", "full_state_indirect")]
    assert list(wide.columns) == [label for label, _ in comparison.QUANTITIES.values()]
    assert wide.loc[("calibrated", "full_state_indirect"), "Height (m)"] == "4.00 (baseline)"
    assert wide.loc[("default", "full_state_indirect"), "Height (m)"] == "2.00 (-2.00, -50.0 %) ▼"
    assert wide.loc[("default", "three_stage"), "Yaw Angle (deg)"] == "2.00 (+1.00, +100.0 %) ▲"
    html = tables.rms_delta_style(table, "default").to_html()
    assert tables.CHANGE_COLORS["improved"] in html and tables.CHANGE_COLORS["regressed"] in html


def test_nis_comparison_puts_the_runs_of_a_channel_side_by_side():
    def summary(mean: float) -> pd.DataFrame:
        return pd.DataFrame({"estimator": ["three_stage", "three_stage", "full_state_direct"],
                             "sensor": ["baro", "gps_vel", "baro"], "updates": [100, 100, 100],
                             "accepted [%]": 100.0, "mean NIS [-]": mean, "inside 95 % bound [%]": 95.0})

    table = comparison.nis_comparison({"default": summary(1.0), "tuned": summary(2.0)})
    assert list(table.columns)[:3] == ["run", "estimator", "sensor"]
    assert list(zip(table["run"], table["estimator"], table["sensor"], strict=True)) == [
        ("default", "three_stage", "baro"), ("tuned", "three_stage", "baro"),
        ("default", "three_stage", "gps_vel"), ("tuned", "three_stage", "gps_vel"),
        ("default", "full_state_direct", "baro"), ("tuned", "full_state_direct", "baro")]
    assert list(table["mean NIS [-]"]) == [1.0, 2.0] * 3
    assert "verdict" in tables.with_nis_verdicts(table)
    assert comparison.nis_comparison({}).empty


def test_run_names_use_the_catalog_name_else_the_run_id():
    stored = pd.DataFrame({"run_id": ["a" * 16, "b" * 16, "c" * 16]})
    assert comparison.run_names(stored) == {"a" * 16: "a" * 16, "b" * 16: "b" * 16, "c" * 16: "c" * 16}
    named = stored.assign(name=["calibrated", None, "calibrated"])
    assert comparison.run_names(named) == {"a" * 16: "calibrated (aaaaaaaa)", "b" * 16: "b" * 16,
                                           "c" * 16: "calibrated (cccccccc)"}


# ------------------------------------------------------------------------------------------------ the page
def _store_run(workspace: Workspace, sha256: str, log: FlightLog, alt_offset_m: float, noise: str) -> str:
    """A stored run (no replay: fast) whose estimators follow the truth ``alt_offset_m`` above it."""
    truth = log["truth_global_position"]
    time_s = truth.index.to_numpy(float)[::10]
    states = _states_on(log, time_s, alt_offset_m)
    diagnostics = pd.concat([pd.DataFrame({
        "estimator": name, "time_s": time_s, "sensor": "baro", "component": "h",
        "innovation": alt_offset_m * np.sin(time_s), "innovation_var": alt_offset_m**2, "nis": 0.5 * alt_offset_m,
        "accepted": True}) for name in ESTIMATORS], ignore_index=True)[list(DIAGNOSTIC_COLUMNS)]
    report = {name: {"used": ["baro"], "skipped": {}, "degradations": [], "warnings": [], "details": {},
                     "timings_s": {"total": 0.1}} for name in ESTIMATORS}
    settings = runs.RunSettings(estimators=ESTIMATORS, noise=noise).to_dict()
    return workspace.add_run(sha256, settings, states, diagnostics, report)


def _states_on(log: FlightLog, time_s: np.ndarray, alt_offset_m: float) -> pd.DataFrame:
    reference = evaluation.reference_states(log, "truth", time_s)
    parts = [reference.assign(estimator=name, alt_m=reference["alt_m"] + alt_offset_m * (k + 1))
             for k, name in enumerate(ESTIMATORS)]
    states = pd.concat(parts, ignore_index=True)[list(STATE_COLUMNS)]
    states["estimator"] = pd.Categorical(states["estimator"], categories=list(ESTIMATORS))
    return states


def _charts(at: AppTest) -> list[dict]:
    return [json.loads(chart.proto.spec) for chart in at.get("plotly_chart")]


def test_estimators_page_compares_two_stored_runs(tmp_path: Path, monkeypatch):
    monkeypatch.setenv(session.WORKSPACE_ENV, str(tmp_path))
    at = AppTest.from_file(str(ENTRYPOINT), default_timeout=TIMEOUT_S)
    at.run()
    sha256 = hashlib.sha256(SHORT_SAMPLE.read_bytes()).hexdigest()
    at.sidebar.selectbox[0].set_value(sha256).run()
    assert not at.exception
    workspace = Workspace(tmp_path)
    log = adapters.stored_log(str(tmp_path.resolve()), sha256)
    default_run = _store_run(workspace, sha256, log, 2.0, runs.DEFAULT_NOISE)
    calibrated_run = _store_run(workspace, sha256, log, 4.0, runs.AUTO_CALIBRATION)
    names = comparison.run_names(workspace.list_runs(sha256))

    at.switch_page("views/estimators.py").run()
    assert not at.exception and not at.error
    assert at.multiselect(key="est_runs").value == [calibrated_run]  # the newest by default: one run as before
    [rms] = [table.value for table in at.table if "Roll Angle (deg)" in table.value.columns]
    assert list(rms.index) == list(ESTIMATORS)

    at.multiselect(key="est_runs").set_value([default_run, calibrated_run]).run()
    assert not at.exception and not at.error
    stem = SHORT_SAMPLE.stem.replace("_", " ")  # the log, the noise source, fewer estimators than 3, the time
    assert re.fullmatch(rf"{stem} · datasheet · 2 estimators · \d\d:\d\d", names[default_run]), names
    assert re.fullmatch(rf"{stem} · calibrated · 2 estimators · \d\d:\d\d", names[calibrated_run]), names
    assert at.multiselect(key="est_runs").options == [names[calibrated_run], names[default_run]]
    [details] = [frame.value for frame in at.dataframe if "heading aid" in frame.value.columns]
    assert list(details["name"]) == [names[default_run], names[calibrated_run]]  # the settings, in the expander
    assert list(details["R"]) == ["datasheet", "calibrated (automatic)"]
    assert set(details["estimators"]) == {", ".join(ESTIMATORS)}
    assert at.selectbox(key="est_baseline").value == default_run
    [wide] = [table.value for table in at.table if "Height (m)" in table.value.columns]
    assert len(wide) == 4  # two runs x two estimators
    assert wide.loc[(names[default_run], "three_stage"), "Height (m)"] == "2.00 (baseline)"
    assert wide.loc[(names[calibrated_run], "three_stage"), "Height (m)"] == "4.00 (+2.00, +100.0 %) ▲"
    assert wide.loc[(names[calibrated_run], "full_state_indirect"), "Height (m)"] == "8.00 (+4.00, +100.0 %) ▲"
    [long] = [frame.value for frame in at.dataframe if "delta [%]" in frame.value.columns]
    height = long.loc[long["quantity"] == "Height (m)"].set_index(["run", "estimator"])
    assert height.loc[(names[calibrated_run], "three_stage"), "delta"] == pytest.approx(2.0, abs=1e-6)
    assert height.loc[(names[calibrated_run], "full_state_indirect"), "delta [%]"] == pytest.approx(100.0)
    assert set(height.loc[names[calibrated_run], "change"]) == {comparison.REGRESSED}

    [states] = _charts(at)
    legend = {trace["name"]: trace["line"].get("dash") for trace in states["data"]
              if trace.get("showlegend") is not False}
    assert legend[f"three_stage · {names[default_run]}"] == "solid"
    assert legend[f"three_stage · {names[calibrated_run]}"] == "dash"
    assert legend[f"full_state_indirect · {names[calibrated_run]}"] == "dash"

    at.selectbox(key="est_baseline").set_value(calibrated_run).run()  # the other way round: improvements
    [long] = [frame.value for frame in at.dataframe if "delta [%]" in frame.value.columns]
    height = long.loc[long["quantity"] == "Height (m)"].set_index(["run", "estimator"])
    assert height.loc[(names[default_run], "three_stage"), "delta [%]"] == pytest.approx(-50.0)
    assert set(height.loc[names[default_run], "change"]) == {comparison.IMPROVED}

    at.segmented_control(key="est_panel").set_value("Errors").run()
    assert not at.exception
    [errors] = _charts(at)
    assert errors["layout"]["title"]["text"] == "Errors against the ground truth"
    assert {f"three_stage · {names[run]}" for run in (default_run, calibrated_run)} <= {
        trace["name"] for trace in errors["data"]}

    at.segmented_control(key="est_panel").set_value("Innovations and NIS").run()
    assert not at.exception
    [summary] = [frame.value for frame in at.dataframe if "mean NIS [-]" in frame.value.columns]
    assert list(summary["run"]) == [names[default_run], names[calibrated_run]] * 2
    innovations, nis = _charts(at)
    assert innovations["layout"]["title"]["text"] == "three_stage: baro innovations"
    assert {f"h: three_stage · {names[run]}" for run in (default_run, calibrated_run)} == {
        trace["name"] for trace in nis["data"]}
    downloads = [button.label for button in at.get("download_button")]
    assert len(downloads) == 10 and downloads.count("Flight report (.html)") == 2, downloads  # five per run
