"""End to end in a real browser: ``solarnav dashboard`` on a free port with a temporary workspace, driven by
headless Chromium (Debian's ``chromium``) through Playwright: upload a sample log with its sun-device files, look
at every page, run the estimators, and find the comparison chart and the RMS table. Screenshots of every page go
to ``test-artifacts/`` (git-ignored) for a human to look at.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from app.samples import SAMPLE_DIR
from tests.conftest import REPO_DIR

pytestmark = pytest.mark.browser

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
ARTIFACTS_DIR = REPO_DIR / "test-artifacts"
SAMPLE = "failed_cell"
#: Generous: a shared CI machine may need to parse a log and compile the filters (numba) on first use.
SLOW_MS = 300_000
RUN_MS = 900_000
#: Nothing is running or loading on the page any more.
SETTLED_JS = ("() => !document.querySelector('[data-testid=\"stStatusWidget\"]')"
              " && !document.querySelector('[data-testid=\"stSpinner\"]')"
              " && !document.querySelector('[data-testid=\"stSkeleton\"]')")


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """``solarnav dashboard`` serving a temporary workspace; yields its URL and stops it afterwards."""
    if not CHROMIUM.exists():
        pytest.fail(f"{CHROMIUM} is missing: install Debian's chromium (scripts/test.sh does)")
    port = _free_port()
    log_path = tmp_path_factory.mktemp("server") / "server.log"
    command = [sys.executable, "-m", "app.cli", "dashboard", "--workspace", str(tmp_path_factory.mktemp("ws")),
               "--port", str(port), "--skip-sample-runs"]
    with open(log_path, "w") as log:
        process = subprocess.Popen(command, cwd=REPO_DIR, stdout=log, stderr=subprocess.STDOUT,
                                   env={**os.environ, "STREAMLIT_SERVER_HEADLESS": "true"}, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                with urllib.request.urlopen(f"{url}/_stcore/health", timeout=2) as response:
                    if response.status == 200:
                        break
            except OSError:
                pass
            if process.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"the dashboard did not start:\n{log_path.read_text()}")
            time.sleep(0.5)
        yield url
    finally:
        os.killpg(process.pid, signal.SIGTERM)
        process.wait(timeout=30)


@pytest.fixture(scope="module")
def page(server):
    """A Chromium page (1400 px wide) on the dashboard; its last state is saved as ``last_state.png``."""
    from playwright.sync_api import sync_playwright

    ARTIFACTS_DIR.mkdir(exist_ok=True)
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        tab = browser.new_page(viewport={"width": 1400, "height": 1000})
        tab.set_default_timeout(SLOW_MS)
        tab.goto(server)
        yield tab
        if tab.locator("h1").count():  # whatever the outcome, keep the last state for a human to look at
            tab.screenshot(path=str(ARTIFACTS_DIR / "last_state.png"), full_page=True)
        browser.close()


def _settle(page) -> None:
    """Wait until the script run is over and nothing is loading, and fail on any exception box."""
    time.sleep(1.0)
    page.wait_for_function(SETTLED_JS, timeout=SLOW_MS)
    time.sleep(1.0)
    exceptions = page.locator("[data-testid='stException']")
    assert exceptions.count() == 0, exceptions.first.inner_text()


def _screenshot(page, name: str) -> None:
    """Full-height screenshot of the main area under ``test-artifacts/``."""
    height = page.evaluate("() => document.querySelector('[data-testid=\"stMain\"]').scrollHeight")
    page.set_viewport_size({"width": 1400, "height": min(max(height, 1000), 9000)})
    time.sleep(1.0)  # let plotly redraw at the new size
    page.screenshot(path=str(ARTIFACTS_DIR / f"{name}.png"))
    page.set_viewport_size({"width": 1400, "height": 1000})


def _open(page, title: str) -> None:
    page.locator("[data-testid='stSidebarNav'] a", has_text=title).first.click()
    page.locator("[data-testid='stMain'] h1", has_text=title).wait_for()
    _settle(page)


def test_upload_run_and_compare_in_a_browser(page):
    page.locator("[data-testid='stMain'] h1", has_text="solarnav").wait_for()
    _settle(page)
    uploaders = page.locator("[data-testid='stFileUploader']")
    for k, name in enumerate((f"{SAMPLE}.ulg", f"{SAMPLE}_sun.csv", f"{SAMPLE}_device.json")):
        uploaders.nth(k).locator("input[type='file']").set_input_files(str(SAMPLE_DIR / name))
        uploaders.nth(k).locator("[data-testid='stFileChipDeleteBtn']").wait_for()  # the upload has finished
    page.get_by_role("button", name="Add to the workspace").click()
    page.wait_for_function("() => document.querySelector('input[aria-label=\"Flight log\"]')"
                           f".value.startsWith('{SAMPLE}.ulg')", timeout=SLOW_MS)
    _settle(page)
    _screenshot(page, "1_home")

    _open(page, "Overview")
    assert page.locator("[data-testid='stMetric']").filter(has_text="Data duration").count() == 1
    _screenshot(page, "2_overview")
    _open(page, "Calibration")
    page.get_by_role("heading", name="Results").wait_for()
    _screenshot(page, "3_calibration")

    _open(page, "Estimators")
    page.get_by_role("button", name="Run estimators").click()
    page.get_by_role("heading", name="RMS errors (paper Table 2 layout)").wait_for(timeout=RUN_MS)
    _settle(page)
    rms_table = page.locator("[data-testid='stTable']").filter(has_text="Roll Angle (deg)")
    for estimator in ("three_stage", "full_state_direct", "full_state_indirect"):
        assert rms_table.get_by_text(estimator, exact=True).is_visible()
    page.locator(".js-plotly-plot .legendtext").first.wait_for()
    legend = page.eval_on_selector_all(".js-plotly-plot .legendtext", "texts => texts.map(t => t.textContent)")
    assert {"three_stage", "full_state_direct", "full_state_indirect", "truth"} <= set(legend)
    _screenshot(page, "4_estimators")

    _open(page, "Sun vector")
    assert page.locator("[data-testid='stMetric']").filter(has_text="Most often faulty").count() == 1
    _screenshot(page, "5_sun_vector")
