"""Dashboard responsiveness: page and action times, cold and warm, on the bundled log and on a 1-hour log.

The workspace holds the bundled sample logs (``sample_logs/``, each with the default run of the three filters, as
the dashboard's first start makes it), a batch output of them for the Fleet page, and, with ``--minutes M > 0``, the
paper mission simulated over M minutes (default one hour; 250 Hz IMU, 50 Hz magnetometer and barometer, 10 Hz GPS
and sun device) with its default run. Each log measured (``sample_logs/paper.ulg`` and the long one):

* actions, timed in the dashboard's own functions: parse, default run of the three filters (stored), automatic
  calibration, a run with the calibrated R;
* headless (``streamlit.testing.v1.AppTest``, in this process) every page: the script time of the first visit
  (cold: the log's derived data computed and cached) and of a re-visit (warm), the size of the plotly figures
  sent to the browser; then the page actions: two runs overlaid on Estimators, a zoom to one minute, automatic
  tau on Calibration;
* in headless Chromium (when ``/usr/bin/chromium`` exists): ``solarnav dashboard`` on the same workspace, time
  from the click on a page's link until its last element is shown and every chart is drawn, first visit and
  re-visit (the server parses the log when it is opened, which is reported as processing).

Targets: issue 14 (page and action times on both logs, cold and warm) and issue 15 (pages on a 1-hour log:
<= 3 s first visit, <= 1 s re-visit, script time).

Run: ``STREAMLIT_LOGGER_LEVEL=error .venv/bin/python benchmarks/bench_app.py [--minutes 60] [--no-browser]`` (not
part of the test suite; about ten minutes in all).
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

from app import adapters, runs, session
from app.batch.summary import BATCHES_DIR
from app.loading import load_stored_log
from app.samples import add_samples, find_samples
from app.workspace import Workspace
from sim.px4_export import write_outputs
from sim.scenarios import SCENARIOS
from sim.simulate import simulate

REPO_DIR = Path(__file__).resolve().parents[1]
ENTRYPOINT = REPO_DIR / "app" / "dashboard.py"
PAGES = {"Home": "views/home.py", "Overview": "views/overview.py", "Calibration": "views/calibration.py",
         "Estimators": "views/estimators.py", "Compare logs": "views/compare_logs.py", "Map": "views/map.py",
         "Sun vector": "views/sun.py", "Workspace": "views/workspace.py", "Fleet": "views/fleet.py"}
BUNDLED_LOG_NAME = "paper.ulg"
LONG_LOG_NAME = "long_paper_mission.ulg"
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
#: What each page draws last: the browser timing waits for it (then for every plotly chart to be drawn).
PAGE_DONE = {"Home": "h3:has-text('Workspace')", "Overview": "h3:has-text('Flight phases')",
             "Calibration": "button:has-text('Download PX4 .params')", "Estimators": "h3:has-text('Download')",
             "Compare logs": "h3:has-text('Comparison')", "Map": "h3:has-text('Local NED')",
             "Sun vector": "[data-testid='stMetric']:has-text('RMS')", "Workspace": "h3:has-text('Rename or delete')",
             "Fleet": "h3:has-text('Open a log')"}
CHARTS_DRAWN_JS = ("() => [...document.querySelectorAll('[data-testid=\"stPlotlyChart\"]')]"
                   ".every(chart => chart.querySelector('.js-plotly-plot .main-svg'))")
SETTLED_JS = ("() => !document.querySelector('[data-testid=\"stStatusWidget\"]')"
              " && !document.querySelector('[data-testid=\"stSpinner\"]')"
              " && !document.querySelector('[data-testid=\"stSkeleton\"]')")
#: Widget keys of the Estimators page (app/views/estimators.py: RUNS_KEY, RANGE_KEY; a page script is not importable).
ESTIMATOR_RUNS_KEY, ESTIMATOR_RANGE_KEY = "est_runs", "est_time_range"
#: Width of the zoom action's window [s].
ZOOM_WIDTH_S = 60.0


def _timed(function):
    start = time.perf_counter()
    value = function()
    return time.perf_counter() - start, value


def prepare(directory: Path, minutes: float) -> tuple[Workspace, dict[str, str]]:
    """The bench workspace under ``directory``: the bundled samples, their batch output, and the long flight when
    ``minutes`` > 0; returns it and the hash of each measured log (name -> sha256)."""
    workspace = Workspace(directory / "workspace")
    samples = find_samples()
    entries = add_samples(workspace, samples)
    targets = {BUNDLED_LOG_NAME: next(e.sha256 for e in entries if e.display_name == BUNDLED_LOG_NAME)}
    batch_s, batch = _timed(lambda: subprocess.run(
        [sys.executable, "-m", "app.cli", "batch", *(str(sample.ulog) for sample in samples), "--calibrate",
         "--replay", "--workers", "1", "-o", str(workspace.root / BATCHES_DIR / "bundled")],
        cwd=REPO_DIR, capture_output=True, text=True))
    if batch.returncode != 0:
        raise RuntimeError(f"solarnav batch failed: {batch.stderr[-2000:]}")
    print(f"batch of the {len(samples)} bundled logs for the Fleet page (1 worker): {batch_s:.1f} s")
    if minutes > 0:
        sim_s, _ = _timed(lambda: write_outputs(simulate(SCENARIOS["paper"], np.random.default_rng(0),
                                                         duration_s=60.0 * minutes), directory / "sim"))
        ulog = directory / "sim" / "paper.ulg"
        print(f"simulated {minutes:g} min in {sim_s:.1f} s: {ulog.stat().st_size / 1e6:.0f} MB ULog")
        targets[LONG_LOG_NAME] = workspace.add_log(
            ulog.read_bytes(), LONG_LOG_NAME, sun_csv=(directory / "sim" / "paper_sun.csv").read_bytes(),
            device_json=(directory / "sim" / "paper_device.json").read_bytes()).sha256
    return workspace, targets


def actions(workspace: Workspace, name: str, sha256: str) -> None:
    """Time the heavy actions of the dashboard on one log, in the functions its pages call: parse, default run
    (stored), automatic calibration, run with the calibrated R (stored)."""
    parse_s, log = _timed(lambda: load_stored_log(workspace, sha256))
    print(f"{name}: parse {parse_s:.2f} s ({len(log['imu'])} IMU rows, {log.meta.duration_s / 60:.1f} min)")
    for noise in (runs.DEFAULT_NOISE, runs.AUTO_CALIBRATION):
        settings = runs.RunSettings(noise=noise)
        if runs.find_run(workspace, sha256, settings) is not None:
            continue
        calib_s, calibration = _timed(lambda noise=noise: adapters.run_calibration(str(workspace.root), sha256, noise))
        if calibration is not None:
            print(f"{name}: automatic calibration {calib_s:.2f} s")
        clock = runs.StageClock(None, 1)
        runs.replay_and_store(workspace, sha256, log, settings, calibration, clock=clock)
        print(f"{name}: run of the three filters with {noise} R, stored: {clock.summary()}")


def _points(trace: dict) -> int:
    """Number of x values of a plotly trace as serialised for the browser (plain list or base64 typed array)."""
    x = trace.get("x")
    if isinstance(x, dict):
        return len(base64.b64decode(x["bdata"])) // np.dtype(x["dtype"]).itemsize
    return len(x) if isinstance(x, list) else 0


def _visit(at, name: str) -> tuple[float, float]:
    """Script time of a first visit of the page and of a re-visit [s]."""
    at.switch_page(PAGES[name])
    first_s, _ = _timed(at.run)
    again_s, _ = _timed(at.run)
    if at.exception:
        raise RuntimeError(f"{name}: {at.exception[0].value}")
    return first_s, again_s


def _figures(at) -> str:
    specs = [json.loads(chart.proto.spec) for chart in at.get("plotly_chart")]
    points = max((_points(trace) for spec in specs for trace in spec["data"]), default=0)
    size_kb = sum(len(chart.proto.spec) for chart in at.get("plotly_chart")) / 1e3
    return f"{len(specs):>8} {size_kb:>17.0f} {points:>18}"


def _rerun_timed(at, change) -> float:
    """Script time of the run after ``change(at)`` (a widget set or a button clicked) [s]."""
    change(at)
    seconds, _ = _timed(at.run)
    if at.exception:
        raise RuntimeError(str(at.exception[0].value))
    return seconds


def headless_pages(workspace: Workspace, name: str, sha256: str) -> None:
    """Every page and the page actions on one log, cold then warm, via AppTest (a fresh app session on emptied
    caches, as a fresh server)."""
    import streamlit as st
    from streamlit.testing.v1 import AppTest

    os.environ[session.WORKSPACE_ENV] = str(workspace.root)
    st.cache_data.clear()
    st.cache_resource.clear()
    at = AppTest.from_file(str(ENTRYPOINT), default_timeout=1800)
    at.run()
    parse_s, _ = _timed(lambda: at.sidebar.selectbox[0].set_value(sha256).run())
    print(f"\n{name}, headless: open the log on Home (parsed into the app's cache) {parse_s:.2f} s")
    print(f"{'page':<14} {'first visit [s]':>16} {'re-visit [s]':>13} {'figures':>8} {'figure data [kB]':>17} "
          f"{'points per trace':>18}")
    for page in PAGES:
        first_s, again_s = _visit(at, page)
        print(f"{page:<14} {first_s:>16.2f} {again_s:>13.2f} {_figures(at)}")
    # page actions, each timed cold (first time) and warm (same change again after a detour)
    at.switch_page(PAGES["Estimators"])
    at.run()
    run_ids = list(workspace.list_runs(sha256)["run_id"])[:2]

    def setting(widget: str, key: str, value):
        return lambda at: getattr(at, widget)(key=key).set_value(value)

    overlay = [_rerun_timed(at, setting("multiselect", ESTIMATOR_RUNS_KEY, ids))
               for ids in (run_ids, run_ids[:1], run_ids)]
    print(f"Estimators: overlay of {len(run_ids)} runs with the RMS difference table: {overlay[0]:.2f} s cold, "
          f"{overlay[2]:.2f} s warm; back to one run {overlay[1]:.2f} s")
    start_s, end_s = at.slider(key=ESTIMATOR_RANGE_KEY).value
    zoom = (start_s + 0.4 * (end_s - start_s), start_s + 0.4 * (end_s - start_s) + ZOOM_WIDTH_S)
    zooms = [_rerun_timed(at, setting("slider", ESTIMATOR_RANGE_KEY, window))
             for window in (zoom, (start_s, end_s), zoom)]
    print(f"Estimators: zoom every chart to {ZOOM_WIDTH_S:.0f} s: {zooms[0]:.2f} s cold, {zooms[2]:.2f} s warm; "
          f"back to the full span {zooms[1]:.2f} s")
    at.switch_page(PAGES["Calibration"])
    at.run()
    taus = [_rerun_timed(at, setting("radio", "calib_tau_mode", mode)) for mode in ("likelihood", "manual",
                                                                                    "likelihood")]
    print(f"Calibration: automatic tau (likelihood): {taus[0]:.2f} s cold, {taus[2]:.2f} s warm; "
          f"back to manual {taus[1]:.2f} s")


def browser_pages(workspace: Workspace, name: str) -> None:
    """Time from the click on each page's link until the page is settled, in headless Chromium, on the log
    ``name`` (a fresh server: the first visits are cold)."""
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
                tab.get_by_role("option").filter(has_text=name).first.click()
                tab.locator("[data-testid='stMetric']", has_text="Estimator runs").wait_for()
                settle()

            parse_s, _ = _timed(open_long_log)
            print(f"\n{name}, browser: open the log on Home (the server parses it) {parse_s:.2f} s")
            for page in PAGES:
                visits = []
                for _ in range(2):
                    start = time.perf_counter()
                    tab.locator("[data-testid='stSidebarNav'] a", has_text=page).first.click()
                    tab.locator("[data-testid='stMain'] h1", has_text=page if page != "Home" else "solarnav").wait_for()
                    tab.locator(f"[data-testid='stMain'] {PAGE_DONE[page]}").first.wait_for()
                    tab.wait_for_function(CHARTS_DRAWN_JS, polling=100)
                    visits.append(time.perf_counter() - start)
                    settle()
                print(f"browser: {page:<14} first visit {visits[0]:.2f} s, re-visit {visits[1]:.2f} s")
            browser.close()
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0,
                        help="length of the simulated long flight [min] (0: the bundled log only)")
    parser.add_argument("--no-browser", action="store_true", help="skip the headless Chromium timings")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as directory:
        workspace, targets = prepare(Path(directory), args.minutes)
        for entry in workspace.list_logs():
            actions(workspace, entry.display_name, entry.sha256)
        for name, sha256 in targets.items():
            headless_pages(workspace, name, sha256)
        if not args.no_browser and CHROMIUM.exists():
            for name in targets:
                browser_pages(workspace, name)


if __name__ == "__main__":
    main()
