"""NIS verdicts (pass / warn / fail against the chi-square band), the automatic-tau warnings, the display units of
the calibration page, and the calibration page showing them (issue 14, 'Verdicts' and 'Labels and units')."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from streamlit.testing.v1 import AppTest

from app import comparison, figures, samples, session, tables
from calib.allan import allan_deviation, allan_figures
from calib.tau import TAU_GRID_POINTS, TauSelection
from estimators.consistency import MIN_UPDATES, NIS_WARNING_RANGE, channel_consistency
from ingest.log_formats import load_flight_log
from tests.conftest import REPO_DIR
from workflows.calibration import choose_tau_by_replay, measure_noise

BAND = (0.98, 1.02)


# ---------------------------------------------------------------------------------------------------- verdicts
@pytest.mark.parametrize(("mean_nis", "level"), [
    (1.0, "pass"), (BAND[0], "pass"), (BAND[1], "pass"),                       # the band is inclusive
    (0.979, "warn"), (1.021, "warn"), (NIS_WARNING_RANGE[0], "warn"), (NIS_WARNING_RANGE[1], "warn"),
    (NIS_WARNING_RANGE[0] - 1e-3, "fail"), (NIS_WARNING_RANGE[1] + 1e-3, "fail"), (0.07, "fail"), (40.0, "fail"),
])
def test_nis_verdict_levels_at_the_boundaries(mean_nis, level):
    verdict = tables.nis_verdict("baro", mean_nis, BAND, 5000)
    assert verdict.level == level
    assert verdict.color == tables.VERDICT_COLORS[level]
    assert verdict.sentence.startswith(f"baro: mean NIS {mean_nis:.3g}")


def test_nis_verdict_sentences_say_which_way_r_is_wrong():
    low = tables.nis_verdict("baro", 0.07, BAND, 5000).sentence
    assert low == ("baro: mean NIS 0.07, far below its 95 % band 0.98-1.02 (outside 0.2..3): R is too pessimistic "
                   "(the filter trusts this sensor less than it could)")
    high = tables.nis_verdict("gps_vel", 7.5, BAND, 5000).sentence
    assert "far above its 95 % band 0.98-1.02" in high and "R is too optimistic or the model is wrong" in high
    slightly = tables.nis_verdict("mag", 1.4, BAND, 5000).sentence
    assert "above its 95 % band 0.98-1.02 but within 0.2..3" in slightly and "far" not in slightly
    assert "R is slightly too optimistic or the model is slightly off" in slightly
    assert "inside its 95 % band" in tables.nis_verdict("mag", 1.0, BAND, 5000).sentence


def test_nis_verdict_does_not_judge_few_or_no_updates():
    few = tables.nis_verdict("sun", 40.0, (0.4, 1.8), MIN_UPDATES - 1)
    assert few.level == "not judged" and f"only {MIN_UPDATES - 1} updates" in few.sentence
    assert tables.nis_verdict("sun", 40.0, (0.4, 1.8), MIN_UPDATES).level == "fail"
    assert tables.nis_verdict("sun", math.nan, (0.4, 1.8), 100).level == "not judged"


def _diagnostics(scale_by_sensor: dict[str, float], n: int = 2000) -> pd.DataFrame:
    """Diagnostics rows of one estimator: white innovations whose NIS is chi-square(1) times the sensor's scale."""
    rng = np.random.default_rng(7)
    parts = []
    for sensor, scale in scale_by_sensor.items():
        nu = rng.normal(size=n) * math.sqrt(scale)
        parts.append(pd.DataFrame({"estimator": "three_stage", "sensor": sensor, "component": "x",
                                   "time_s": np.arange(n) * 0.1, "innovation": nu, "innovation_var": 1.0,
                                   "nis": nu**2, "accepted": True}))
    return pd.concat(parts, ignore_index=True)


def test_verdicts_of_channel_consistency_and_of_the_nis_summary():
    diagnostics = _diagnostics({"baro": 1.0, "gps_vel": 1.6, "mag": 0.05})
    by_channel = {c.channel: tables.channel_verdict(c).level for c in channel_consistency(diagnostics)}
    assert by_channel == {"baro.x": "pass", "gps_vel.x": "warn", "mag.x": "fail"}

    summary = tables.with_nis_verdicts(comparison.nis_summary(diagnostics))
    assert list(summary["verdict"]) == ["pass", "warn", "fail"]
    assert summary["why"].iloc[2].startswith("three_stage mag: mean NIS")
    low, high = comparison.nis_band(2000)
    assert summary["95 % band [-]"].iloc[0] == f"{low:.3g} .. {high:.3g}"
    html = tables.verdict_style(summary).to_html()
    assert tables.VERDICT_COLORS["fail"] in html and tables.VERDICT_COLORS["pass"] in html


# ---------------------------------------------------------------------------------------------------- auto tau
def _selection(log10_tau: float, nis: float, band=(0.98, 1.02), lag1: float = 0.0) -> TauSelection:
    grid = tuple(np.linspace(-1.0, 2.0, 13))
    return TauSelection(tau=10.0**log10_tau, method="likelihood", log10_tau_grid=grid, neg_log_likelihood=grid,
                        mean_nis=grid, n_innovations=20000, nis_at_tau=nis, nis_band=band, lag1_autocorrelation=lag1)


def test_tau_warnings_outside_the_band_and_at_a_grid_bound():
    assert tables.tau_warnings(_selection(0.3, 1.0)) == []
    assert tables.tau_warnings(TauSelection(tau=1.0, method="default")) == []
    [outside] = tables.tau_warnings(_selection(0.3, 0.95))
    assert "outside its own 95 % NIS band" in outside and "mean NIS 0.95" in outside and "0.98-1.02" in outside
    assert "coloured" in tables.tau_warnings(_selection(0.3, 0.95, lag1=0.8))[0]
    [upper] = tables.tau_warnings(_selection(2.0 - 0.005, 1.0))
    assert "upper bound" in upper and "tau = 100" in upper
    [lower] = tables.tau_warnings(_selection(-1.0, 1.0))
    assert "lower bound" in lower
    assert tables.tau_warnings(_selection(2.0 - 0.1, 1.0)) == []  # not at the bound: 0.4 grid steps inside
    assert len(tables.tau_warnings(_selection(2.0, 3.5))) == 2


# ---------------------------------------------------------------------------------------------------- units
@pytest.mark.parametrize(("unit", "variance"), [("m/s^2", "(m/s²)²"), ("rad/s", "(rad/s)²"), ("deg/s", "(deg/s)²"),
                                                ("m/s", "(m/s)²"), ("m", "m²"), ("gauss", "gauss²"), ("", "-")])
def test_variance_units(unit, variance):
    assert tables.variance_unit(unit) == variance


def test_gyro_is_displayed_in_deg_per_s():
    matrix = pd.DataFrame(np.diag([1e-6, 2e-6, 3e-6]), index=list("xyz"), columns=list("xyz"))
    shown, heading = tables.display_r_matrix(matrix, "rad/s")
    assert heading == "(deg/s)²" and shown.loc["y", "y"] == pytest.approx(2e-6 * math.degrees(1.0) ** 2)
    shown, heading = tables.display_r_matrix(matrix, "m/s^2")
    assert heading == "(m/s²)²" and shown.loc["y", "y"] == 2e-6

    noise = pd.DataFrame({"sensor": ["accelerometer", "gyroscope"], "axis": "x", "unit": ["m/s^2", "rad/s"],
                          "eta": 0.01, "beta": 0.0, "sigma": 0.01, "sigma_robust": 0.01, "mean": 0.1,
                          "physical_bias": 0.002, "segment_end_s": 10.0})
    shown = tables.display_noise_table(noise)
    assert list(shown["unit"]) == ["m/s²", "deg/s"]
    assert shown.loc[0, "sigma"] == 0.01 and shown.loc[1, "sigma"] == pytest.approx(0.01 * math.degrees(1.0))
    assert shown.loc[1, "physical_bias"] == pytest.approx(0.002 * math.degrees(1.0))

    white = np.random.default_rng(3).normal(0.0, 0.01, (20_000, 2))
    curves = [allan_deviation(white[:, k], 250.0) for k in range(2)]
    frames = [pd.DataFrame({"tau_s": c.taus_s, "adev": c.adev, "adev_err": c.adev_err}) for c in curves]
    readoffs = [allan_figures(c) for c in curves]
    scaled, figs, unit = tables.display_allan(frames, readoffs, "rad/s")
    assert unit == "deg/s" and scaled[0]["adev"].iloc[0] == pytest.approx(frames[0]["adev"].iloc[0] * 57.29578)
    assert figs[1].sigma_per_sample == pytest.approx(readoffs[1].sigma_per_sample * math.degrees(1.0))
    assert tables.display_allan(frames, readoffs, "m/s^2")[2] == "m/s^2"


def test_allan_titles_name_the_sensor():
    white = np.random.default_rng(4).normal(0.0, 0.01, 20_000)
    curve = allan_deviation(white, 250.0)
    frame = pd.DataFrame({"tau_s": curve.taus_s, "adev": curve.adev, "adev_err": curve.adev_err})
    titles = {sensor: figures.allan_figure([frame], [allan_figures(curve)], ("x",), "deg/s", sensor=sensor)
              .layout.title.text for sensor in ("gyroscope", "accelerometer")}
    assert titles["gyroscope"].startswith("Allan deviation of the gyroscope")
    assert titles["accelerometer"].startswith("Allan deviation of the accelerometer")


@pytest.mark.parametrize(("duration_s", "text"), [(864.0, "14 min 24.0 s"), (42.5, "42.5 s"),
                                                  (3725.0, "1 h 02 min 05.0 s"), (65.25, "1 min 05.2 s")])
def test_duration_text_carries_units(duration_s, text):
    assert tables.duration_text(duration_s) == text


def test_fir_editor_shows_the_defaults_and_reads_requests():
    editor = tables.fir_editor_table(["gyroscope", "gps_velocity"], [250.0, 5.0], fixed_wing=True)
    assert list(editor["default"]) == ["default (5 Hz)", "default (1 Hz)"]  # capped at 0.2 fs for slow streams
    rows = tables.fir_rows(editor)
    assert [row[0] for row in rows] == ["gyroscope", "gps_velocity"]
    assert all(math.isnan(cutoff) and taps == 0 for _, cutoff, taps in rows)
    editor.loc[0, ["cutoff_hz", "numtaps"]] = [8.0, 101.0]
    assert tables.fir_rows(editor)[0] == ("gyroscope", 8.0, 101)


# ---------------------------------------------------------------------------------------------------- the page
@pytest.fixture(scope="module")
def workspace_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("workspace")


def _calibration_page(workspace_dir: Path, monkeypatch, log: Path) -> AppTest:
    monkeypatch.setenv(session.WORKSPACE_ENV, str(workspace_dir))
    at = AppTest.from_file(str(REPO_DIR / "app" / "dashboard.py"), default_timeout=300)
    at.run()
    at.sidebar.selectbox[0].set_value(hashlib.sha256(log.read_bytes()).hexdigest()).run()
    at.switch_page("views/calibration.py")
    at.run()
    assert not at.exception
    return at


def _tau_warnings(at: AppTest) -> list[str]:
    return [warning.value for warning in at.warning if warning.value.startswith("Automatic tau:")]


@pytest.mark.parametrize(("log", "warned"), [("paper.ulg", True), ("failed_cell.ulg", False)])
def test_calibration_page_warns_on_an_inconsistent_auto_tau(workspace_dir, monkeypatch, log, warned):
    """paper.ulg: the likelihood tau (about 0.29) leaves the mean NIS (0.984) just below its band (0.987 .. 1.013)
    for 43 200 innovations; failed_cell.ulg's is inside its band."""
    at = _calibration_page(workspace_dir, monkeypatch, samples.SAMPLE_DIR / log)
    at.segmented_control(key="calib_section").set_value("R matrices and tau").run()
    headings = [m.value for m in at.markdown if m.value.startswith("**")]
    assert "**accelerometer** [(m/s²)²]" in headings and "**gyroscope** [(deg/s)²]" in headings
    assert not _tau_warnings(at) and len(at.number_input) == 0  # manual: the tau slider, no warning

    at.radio(key="calib_tau_mode").set_value("likelihood").run()
    assert not at.exception and not at.error
    [tau_in_use] = at.number_input
    assert tau_in_use.disabled and tau_in_use.value != 1.0
    [caption] = [c.value for c in at.caption if c.value.startswith("tau = ")]
    assert caption.startswith(f"tau = {tau_in_use.value:.3g}:")
    found = _tau_warnings(at)
    assert bool(found) is warned
    if warned:
        assert "outside its own 95 % NIS band" in found[0] and "below" in found[0]
    chart = json.loads(at.get("plotly_chart")[-1].proto.spec)
    assert chart["layout"]["title"]["text"].startswith("Automatic tau")


def test_table4_headings_render_powers():
    table = pd.DataFrame([[1.0, 2.0]], columns=pd.MultiIndex.from_tuples([("Accelerometer (m/s^2)", "x"),
                                                                          ("Gyroscope (deg/s)", "p")]))
    assert list(tables.flat_columns(table).columns) == ["Accelerometer (m/s²) x", "Gyroscope (deg/s) p"]


def test_auto_tau_tells_its_replays_and_the_page_clears_its_bar(workspace_dir, monkeypatch):
    """Issue 33 (5): the automatic tau's replays are counted one by one (the grid's, then the search's); the page's
    bar is gone once tau is chosen."""
    log = load_flight_log(samples.SAMPLE_DIR / "failed_cell.ulg")
    told = []
    choose_tau_by_replay(log, measure_noise(log), progress=told.append)
    assert sorted(told) == list(range(1, len(told) + 1)) and len(told) > TAU_GRID_POINTS
    at = _calibration_page(workspace_dir, monkeypatch, samples.SAMPLE_DIR / "failed_cell.ulg")
    at.segmented_control(key="calib_section").set_value("R matrices and tau").run()
    at.radio(key="calib_tau_mode").set_value("likelihood").run()
    assert not at.exception and at.number_input[0].disabled
    assert not at.get("progress")
