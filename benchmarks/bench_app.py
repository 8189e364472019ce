"""Dashboard responsiveness on a long log: how fast every page renders once the log is processed.

Simulates the paper mission extended to ``--minutes`` (default one hour; 250 Hz IMU, 50 Hz magnetometer and
barometer, 10 Hz GPS and sun device) into a temporary workspace, processes it (parse, default estimator run of the
three filters, stored like the dashboard does), then renders every page:

* headless (``streamlit.testing.v1.AppTest``, in this process): the script time of the first visit (derived data
  computed and cached) and of a re-visit, and the size of the plotly figures sent to the browser;
* in headless Chromium (when ``/usr/bin/chromium`` exists): ``solarnav dashboard`` on the same workspace, time
  from the click on the page's link until its last element is shown and every chart is drawn (the server parses
  the log when it is opened, which is reported as processing).

Target (issue 7): every page in a few seconds after processing.

Run: ``STREAMLIT_LOGGER_LEVEL=error .venv/bin/python benchmarks/bench_app.py [--minutes 60] [--no-browser]`` (not
part of the test suite; a few minutes in all).
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

from app import runs, session
from app.loading import load_stored_log
from app.workspace import Workspace
from sim.px4_export import write_outputs
from sim.scenarios import SCENARIOS
from sim.simulate import simulate

REPO_DIR = Path(__file__).resolve().parents[1]
ENTRYPOINT = REPO_DIR / "app" / "dashboard.py"
PAGES = {"Home": "views/home.py", "Overview": "views/overview.py", "Calibration": "views/calibration.py",
         "Estimators": "views/estimators.py", "Sun vector": "views/sun.py"}
LONG_LOG_NAME = "long_paper_mission.ulg"
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
#: What each page draws last: the browser timing waits for it (then for every plotly chart to be drawn).
PAGE_DONE = {"Home": "h3:has-text('Workspace')", "Overview": "h3:has-text('Flight phases')",
             "Calibration": "button:has-text('Download PX4 .params')", "Estimators": "h3:has-text('Download')",
             "Sun vector": "[data-testid='stMetric']:has-text('RMS')"}
CHARTS_DRAWN_JS = ("() => [...document.querySelectorAll('[data-testid=\"stPlotlyChart\"]')]"
                   ".every(chart => chart.querySelector('.js-plotly-plot .main-svg'))")
SETTLED_JS = ("() => !document.querySelector('[data-testid=\"stStatusWidget\"]')"
              " && !document.querySelector('[data-testid=\"stSpinner\"]')"
              " && !document.querySelector('[data-testid=\"stSkeleton\"]')")


def _timed(function):
    start = time.perf_counter()
    value = function()
    return time.perf_counter() - start, value


def prepare(directory: Path, minutes: float) -> tuple[Workspace, str]:
    """Simulate the long flight and store it in a workspace under ``directory``; returns it and the log's hash."""
    sim_s, _ = _timed(lambda: write_outputs(simulate(SCENARIOS["paper"], np.random.default_rng(0),
                                                     duration_s=60.0 * minutes), directory / "sim"))
    ulog = directory / "sim" / "paper.ulg"
    print(f"simulated {minutes:g} min in {sim_s:.1f} s: {ulog.stat().st_size / 1e6:.0f} MB ULog")
    workspace = Workspace(directory / "workspace")
    entry = workspace.add_log(ulog.read_bytes(), LONG_LOG_NAME,
                              sun_csv=(directory / "sim" / "paper_sun.csv").read_bytes(),
                              device_json=(directory / "sim" / "paper_device.json").read_bytes())
    return workspace, entry.sha256


def process(workspace: Workspace, sha256: str) -> None:
    """Parse the log and store the default run of the three estimators (what the dashboard's first start does)."""
    parse_s, log = _timed(lambda: load_stored_log(workspace, sha256))
    imu_rows = len(log["imu"])
    print(f"processing: parse {parse_s:.1f} s ({imu_rows} IMU rows, {log.meta.duration_s / 60:.1f} min)")
    run_s, _ = _timed(lambda: runs.replay_and_store(workspace, sha256, log, runs.RunSettings()))
    print(f"processing: estimator run (three filters, stored) {run_s:.1f} s")


def _points(trace: dict) -> int:
    """Number of x values of a plotly trace as serialised for the browser (plain list or base64 typed array)."""
    x = trace.get("x")
    if isinstance(x, dict):
        return len(base64.b64decode(x["bdata"])) // np.dtype(x["dtype"]).itemsize
    return len(x) if isinstance(x, list) else 0


def headless_pages(workspace: Workspace, sha256: str) -> None:
    """Script time of every page (first visit and re-visit) and the size of its figures, via AppTest."""
    from streamlit.testing.v1 import AppTest

    os.environ[session.WORKSPACE_ENV] = str(workspace.root)
    at = AppTest.from_file(str(ENTRYPOINT), default_timeout=1800)
    at.run()
    parse_s, _ = _timed(lambda: at.sidebar.selectbox[0].set_value(sha256).run())
    print(f"headless: open the long log on Home (parses it into the app's cache) {parse_s:.1f} s")
    print(f"{'page':<12} {'first visit [s]':>16} {'re-visit [s]':>13} {'figures':>8} {'figure data [kB]':>17} "
          f"{'points per trace':>18}")
    for name, page in PAGES.items():
        at.switch_page(page)
        first_s, _ = _timed(at.run)
        again_s, _ = _timed(at.run)
        if at.exception:
            raise RuntimeError(f"{name}: {at.exception[0].value}")
        specs = [chart.proto.spec for chart in at.get("plotly_chart")]
        points = max((_points(trace) for spec in specs for trace in json.loads(spec)["data"]), default=0)
        print(f"{name:<12} {first_s:>16.2f} {again_s:>13.2f} {len(specs):>8} {sum(map(len, specs)) / 1e3:>17.0f} "
              f"{points:>18}")


def browser_pages(workspace: Workspace) -> None:
    """Time from the click on each page's link until the page is settled, in headless Chromium."""
    from playwright.sync_api import sync_playwright

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = subprocess.Popen([sys.executable, "-m", "app.cli", "dashboard", "--workspace", str(workspace.root),
                               "--port", str(port), "--skip-sample-runs"], cwd=REPO_DIR, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        url = f"http://127.0.0.1:{port}"
        for _ in range(240):
            try:
                urllib.request.urlopen(f"{url}/_stcore/health", timeout=2).close()
                break
            except OSError:
                time.sleep(0.5)
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            tab = browser.new_page(viewport={"width": 1400, "height": 1000})
            tab.set_default_timeout(600_000)

            def settle() -> None:
                time.sleep(0.3)
                tab.wait_for_function(SETTLED_JS, polling=100)

            tab.goto(url)
            tab.get_by_role("combobox", name="Flight log").click()
            settle()

            def open_long_log() -> None:
                tab.get_by_role("option").filter(has_text=LONG_LOG_NAME).first.click()
                tab.locator("[data-testid='stMetric']", has_text="Estimator runs").filter(has_text="1").wait_for()
                settle()

            parse_s, _ = _timed(open_long_log)
            print(f"browser: open the long log on Home (the server parses it) {parse_s:.1f} s")
            for name in PAGES:
                visits = []
                for _ in range(2):
                    start = time.perf_counter()
                    tab.locator("[data-testid='stSidebarNav'] a", has_text=name).first.click()
                    tab.locator("[data-testid='stMain'] h1", has_text=name if name != "Home" else "solarnav").wait_for()
                    tab.locator(f"[data-testid='stMain'] {PAGE_DONE[name]}").first.wait_for()
                    tab.wait_for_function(CHARTS_DRAWN_JS, polling=100)
                    visits.append(time.perf_counter() - start)
                    settle()
                print(f"browser: {name:<12} first visit {visits[0]:.2f} s, re-visit {visits[1]:.2f} s")
            browser.close()
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0, help="length of the simulated flight [min]")
    parser.add_argument("--no-browser", action="store_true", help="skip the headless Chromium timings")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as directory:
        workspace, sha256 = prepare(Path(directory), args.minutes)
        process(workspace, sha256)
        headless_pages(workspace, sha256)
        if not args.no_browser and CHROMIUM.exists():
            browser_pages(workspace)


if __name__ == "__main__":
    main()
