"""The Fleet page (``streamlit.testing.v1.AppTest``) on a batch OUTDIR of the simulated fleet: the log table, the
gyro trend with the change flags on the logs whose simulated gyro noise was doubled, the RMS distributions, and a
log opened on the other pages."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from streamlit.testing.v1 import AppTest

from app import session
from app.batch.figures import FLAG_TRACE
from app.batch.summary import BATCHES_DIR, read_summary
from app.workspace import Workspace
from tests.batch_logs import DOUBLED_FROM, N_FLIGHTS, OUTDIR_ESTIMATORS, VEHICLE, flight_name, write_batch_outdir
from tests.conftest import REPO_DIR

ENTRYPOINT = REPO_DIR / "app" / "dashboard.py"
#: Widget keys of app/views/fleet.py (a page module cannot be imported: it runs the page).
DIR_KEY, FIGURE_KEY, OPEN_KEY = "fleet_dir", "fleet_figure", "fleet_open"
TIMEOUT_S = 300


@pytest.fixture(scope="module")
def workspace_dir(tmp_path_factory) -> Path:
    """A workspace whose ``batches/sim_fleet`` holds the batch outputs of the simulated fleet."""
    root = tmp_path_factory.mktemp("workspace")
    write_batch_outdir(root / BATCHES_DIR / "sim_fleet", tmp_path_factory.mktemp("fleet") / "logs")
    return root


@pytest.fixture
def fleet_page(workspace_dir, monkeypatch) -> AppTest:
    monkeypatch.setenv(session.WORKSPACE_ENV, str(workspace_dir))
    at = AppTest.from_file(str(ENTRYPOINT), default_timeout=TIMEOUT_S)
    at.run()
    at.switch_page("views/fleet.py")
    at.run()
    assert not at.exception
    return at


def test_the_page_opens_the_workspace_batch_and_flags_the_doubled_gyro(fleet_page, workspace_dir):
    at = fleet_page
    assert at.text_input(key=DIR_KEY).value == str(workspace_dir / BATCHES_DIR / "sim_fleet")
    assert at.metric[0].label == "Logs" and at.metric[0].value == str(N_FLIGHTS + 2)
    table = at.dataframe[0].value
    assert set(table["status"]) == {"ok", "error"}
    assert set(table.loc[table["status"] == "ok", "vehicle"]) == {VEHICLE}
    flagged = [f"{flight_name(k)}.ulg" for k in range(DOUBLED_FROM, N_FLIGHTS)]
    warnings = [w.value for w in at.warning]
    assert len(warnings) == len(flagged)
    for name, text in zip(flagged, warnings, strict=True):
        assert session.markdown_text(name) in text and "gyroscope noise" in text
    assert at.selectbox(key=FIGURE_KEY).value == "gyroscope"
    traces = json.loads(at.get("plotly_chart")[0].proto.spec)["data"]
    flag = next(trace for trace in traces if trace["name"] == FLAG_TRACE)
    assert len(flag["text"]) == len(flagged) and all("x the median" in text for text in flag["text"])
    assert {trace["name"] for trace in traces} == {VEHICLE, FLAG_TRACE}
    boxes = json.loads(at.get("plotly_chart")[1].proto.spec)["data"]
    assert [box["name"] for box in boxes] == list(OUTDIR_ESTIMATORS)


def test_a_log_of_the_batch_opens_on_the_other_pages(fleet_page, workspace_dir):
    at = fleet_page
    fleet, _ = read_summary(workspace_dir / BATCHES_DIR / "sim_fleet")
    sha256 = fleet.loc[fleet["name"] == f"{flight_name(0)}.ulg", "sha256"].iloc[0]
    at.selectbox(key=OPEN_KEY).set_value(sha256).run()
    next(button for button in at.button if button.label == "Open on the other pages").click().run()
    assert not at.exception
    assert at.session_state[session.LOG_KEY] == sha256
    assert sha256 in {entry.sha256 for entry in Workspace(workspace_dir).list_logs()}
