"""Headless page tests (``streamlit.testing.v1.AppTest``): every page renders with a sample log loaded, shows
its tables and metrics, and reacts to a widget change; uploads are validated and stored."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from streamlit.testing.v1 import AppTest

from app import samples, session
from app.workspace import Workspace
from tests.conftest import REAL_LOGS_DIR, REPO_DIR

ENTRYPOINT = REPO_DIR / "app" / "dashboard.py"
#: Used when no bundled sample exists yet (the simulator writes them): a SITL log with GPS and ground truth.
FALLBACK_LOG = REAL_LOGS_DIR / "sample_logging_tagged_and_default_params.ulg"
TIMEOUT_S = 180


@pytest.fixture(scope="module")
def workspace_dir(tmp_path_factory) -> Path:
    """A workspace holding the bundled samples (added by the app on first start) or the fallback log."""
    root = tmp_path_factory.mktemp("workspace")
    if not samples.find_samples():
        Workspace(root).add_log(FALLBACK_LOG.read_bytes(), FALLBACK_LOG.name)
    return root


@pytest.fixture
def open_page(workspace_dir, monkeypatch):
    """Run the dashboard on ``workspace_dir`` and switch to a page; returns the AppTest."""
    monkeypatch.setenv(session.WORKSPACE_ENV, str(workspace_dir))

    def run(page: str | None = None) -> AppTest:
        at = AppTest.from_file(str(ENTRYPOINT), default_timeout=TIMEOUT_S)
        at.run()
        assert not at.exception
        if page is not None:
            at.switch_page(page)
            at.run()
            assert not at.exception
        return at

    return run


def _chart_traces(at: AppTest, index: int) -> list[dict]:
    return json.loads(at.get("plotly_chart")[index].proto.spec)["data"]


def test_home_opens_on_a_stored_log_and_lists_the_workspace(open_page):
    at = open_page()
    assert at.sidebar.selectbox[0].value is not None
    labels = [metric.label for metric in at.metric]
    assert labels == ["Duration", "Vehicle", "Streams", "Estimator runs"]
    table = at.dataframe[0].value
    assert {"name", "size [MB]", "added (UTC)", "sun log", "runs"} <= set(table.columns)
    assert len(table) >= 1


def test_home_upload_rejects_a_bad_file_and_stores_a_good_one(open_page, workspace_dir):
    at = open_page()
    at.file_uploader(key="upload_ulog").set_value(("../../notes.ulg", b"not a ulog at all", "application/octet"))
    at.button[0].click()  # the form's submit button
    at.run()
    assert not at.exception
    assert any("cannot be used" in error.value for error in at.error)
    assert all(entry.display_name != "notes.ulg" for entry in Workspace(workspace_dir).list_logs())

    small = REAL_LOGS_DIR / "sample_log_small.ulg"
    at.file_uploader(key="upload_ulog").set_value(("../evil/<small>.ulg", small.read_bytes(), "application/octet"))
    at.button[0].click()
    at.run()
    assert not at.exception and not at.error
    entries = Workspace(workspace_dir).list_logs()
    uploaded = next(entry for entry in entries if entry.display_name == "_small_.ulg")
    assert at.sidebar.selectbox[0].value == uploaded.sha256


def test_overview_shows_metadata_streams_and_reacts_to_options(open_page):
    at = open_page("views/overview.py")
    assert [metric.label for metric in at.metric] == ["Data duration", "Streams", "Missing sensors",
                                                "Reader warnings"]
    streams = at.dataframe[0].value
    assert "imu" in set(streams["stream"]) and {"topic", "rate_hz", "gaps"} <= set(streams.columns)
    assert at.info or at.warning  # missing streams are explained
    with_phases = len(_chart_traces(at, 1))
    at.toggle(key="overview_phases").set_value(False).run()
    assert not at.exception
    assert len(_chart_traces(at, 1)) < with_phases


def _frames(at: AppTest, predicate) -> list:
    """Values of the page's data frames that satisfy ``predicate`` (data frames carry no key in AppTest)."""
    return [frame.value for frame in at.dataframe if predicate(frame.value)]


def test_calibration_tables_tau_and_window(open_page):
    at = open_page("views/calibration.py")
    [table4] = _frames(at, lambda v: "Noise (eq 50 eta)" in v.index)
    assert any("Gyroscope (deg/s)" in column for column in table4.columns)
    [noise] = _frames(at, lambda v: "segment_end_s" in v.columns)
    assert {"accelerometer", "gyroscope"} <= set(noise["sensor"])
    is_r = lambda v: list(v.index) == ["x", "y", "z"] and list(v.columns) == ["x", "y", "z"]  # noqa: E731
    r_before = _frames(at, is_r)[0].to_numpy(dtype=float)  # accelerometer first
    at.select_slider(key="calib_tau").set_value(10.0).run()
    assert not at.exception
    r_after = _frames(at, is_r)[0].to_numpy(dtype=float)
    assert r_after[1, 1] == pytest.approx(10.0 * r_before[1, 1]) and r_after[0, 0] == pytest.approx(r_before[0, 0])

    at.radio(key="calib_mode").set_value("window").run()
    low, high = at.slider(key="calib_window").value
    at.slider(key="calib_window").set_value((low, low + 0.6 * (high - low))).run()
    assert not at.exception
    [noise] = _frames(at, lambda v: "segment_end_s" in v.columns)
    assert noise["segment_end_s"].max() == pytest.approx(low + 0.6 * (high - low), abs=0.05)
