"""End to end in a real browser: ``solarnav dashboard`` on a free port with a temporary workspace, driven by
headless Chromium (Debian's ``chromium``) through Playwright: upload a sample log with its sun-device files, look
at every page, run the estimators, and find the comparison chart and the RMS table; open a batch output directory
on the Fleet page. Screenshots of every page go to ``test-artifacts/`` (git-ignored) for a human to look at.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from app.batch.figures import FLAG_TRACE
from app.report import SECTIONS as REPORT_SECTIONS
from app.samples import SAMPLE_DIR
from tests.batch_logs import DOUBLED_FROM, N_FLIGHTS, OUTDIR_ESTIMATORS, VEHICLE, flight_name, write_batch_outdir
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
#: Every plotly chart of the page: its title, trace names, sizes and types, first x axis range and smallest
#: finite x.
#: JavaScript: ``values(x)``, a trace's data as a plain array (plotly may send base64 ``{dtype, bdata}``).
VALUES_JS = """
    const DTYPES = {f8: Float64Array, f4: Float32Array, i4: Int32Array, u4: Uint32Array, i2: Int16Array,
                    u2: Uint16Array, i1: Int8Array, u1: Uint8Array};
    const values = x => {  // a plain or typed array, or plotly's base64 {dtype, bdata}
        if (!x) return [];
        if (x.bdata !== undefined && DTYPES[x.dtype]) {
            const bytes = Uint8Array.from(atob(x.bdata), c => c.charCodeAt(0));
            return Array.from(new DTYPES[x.dtype](bytes.buffer));
        }
        return Array.from(x);
    };"""
PLOTS_JS = """() => {""" + VALUES_JS + """
    return [...document.querySelectorAll('.js-plotly-plot')].map(gd => {
        const data = gd.data || [], layout = gd.layout || {};
        let xmin = Infinity;
        for (const trace of data) {
            for (const x of values(trace.x)) {
                const v = Number(x);
                if (x !== null && Number.isFinite(v) && v < xmin) xmin = v;
            }
        }
        const title = layout.title ? (typeof layout.title === 'string' ? layout.title : layout.title.text || '') : '';
        const range = layout.xaxis && layout.xaxis.range ? Array.from(layout.xaxis.range).map(Number) : null;
        return {title: title.replace(/<[^>]*>/g, ''), names: data.map(t => t.name || ''),
                sizes: data.map(t => values(t.x).length),
                types: data.map(t => t.type || 'scatter'), xrange: range, xmin: Number.isFinite(xmin) ? xmin : null,
                x0: data.length ? String(JSON.stringify(data[0].x)).slice(0, 80) : null};
    });
}"""
#: The rows of a Streamlit dataframe's accessible table (the grid draws on a canvas): header, then one list of cell
#: texts per row drawn.
GRID_JS = """grid => [...grid.querySelectorAll('[role=row]')].map(
    row => [...row.querySelectorAll('[role=columnheader], [role=gridcell]')].map(cell => cell.textContent))"""
#: An RMS difference cell: "4.00 (+2.00, +100.0 %)" (and a change mark).
RMS_DELTA_CELL = re.compile(r"\d+\.\d{2} \([+-]\d+\.\d{2}, (?:[+-]\d+\.\d|–) %\)")
ESTIMATORS = ("three_stage", "full_state_direct", "full_state_indirect")


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


def _screenshot(page, name: str | Path) -> None:
    """Full-height screenshot of the main area, ``name``.png under ``test-artifacts/`` (a relative path)."""
    path = ARTIFACTS_DIR / f"{name}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    height = page.evaluate("() => document.querySelector('[data-testid=\"stMain\"]').scrollHeight")
    page.set_viewport_size({"width": 1400, "height": min(max(height, 1000), 9000)})
    time.sleep(1.0)  # let plotly redraw at the new size
    page.screenshot(path=str(path))
    page.set_viewport_size({"width": 1400, "height": 1000})


def _plots(page) -> list[dict]:
    return page.evaluate(PLOTS_JS)


def _plot(page, title: str, check=lambda plot: bool(plot["names"])) -> dict:
    """The first chart whose title starts with ``title`` and for which ``check`` holds, once drawn so."""
    deadline = time.monotonic() + SLOW_MS / 1000
    while True:
        found = [plot for plot in _plots(page) if plot["title"].startswith(title) and check(plot)]
        if found:
            return found[0]
        if time.monotonic() > deadline:
            charts = [(plot["title"], plot["xrange"], plot["xmin"], plot["x0"]) for plot in _plots(page)]
            raise AssertionError(f"no chart {title!r} passing the check; charts: {charts}")
        time.sleep(0.5)


def _same_window(plot: dict, window: tuple[float, float], tolerance: float = 0.011) -> bool:
    """The chart's first x axis shows ``window`` [s] (to ``tolerance``)."""
    return plot["xrange"] is not None and all(abs(a - b) < tolerance
                                              for a, b in zip(plot["xrange"], window, strict=True))


#: Viewport rectangle of the main plot area of the chart whose title starts with the argument (scrolled into view).
PLOT_AREA_JS = """title => {
    const gd = [...document.querySelectorAll('.js-plotly-plot')].find(gd => {
        const t = gd.layout && gd.layout.title;
        return String(t ? (typeof t === 'string' ? t : t.text || '') : '').replace(/<[^>]*>/g, '').startsWith(title);
    });
    const area = gd && gd.querySelector('.nsewdrag');
    if (!area) return null;
    area.scrollIntoView({block: 'center'});
    const box = area.getBoundingClientRect();
    return {x: box.x, y: box.y, width: box.width, height: box.height};
}"""


def _drag_box(page, title: str, start: float, end: float) -> None:
    """Drag a horizontal box across the chart titled ``title``, from ``start`` to ``end`` (shares of the plot
    width), as a user selecting a time range does; then let the page settle."""
    area = page.evaluate(PLOT_AREA_JS, title)
    assert area is not None, f"no chart {title!r}"
    y = area["y"] + 0.5 * area["height"]
    page.mouse.move(area["x"] + start * area["width"], y)
    page.mouse.down()
    page.mouse.move(area["x"] + end * area["width"], y, steps=12)
    page.mouse.up()
    _settle(page)


def _open(page, title: str) -> None:
    page.locator("[data-testid='stSidebarNav'] a", has_text=title).first.click()
    page.locator("[data-testid='stMain'] h1", has_text=title).wait_for()
    _settle(page)


def _add_log(page, log: Path) -> None:
    """Upload ``log`` on the Home page and add it to the workspace (a stored log is recognised); it is then the
    log open in the sidebar."""
    page.locator("[data-testid='stSidebarNav'] a", has_text="Home").first.click()
    uploader = page.locator("[data-testid='stFileUploader']").filter(has_text="PX4 ULog")
    uploader.wait_for()
    _settle(page)
    uploader.locator("input[type='file']").set_input_files(str(log))
    uploader.locator("[data-testid='stFileChipDeleteBtn']").wait_for()
    page.get_by_role("button", name="Add to the workspace").click()
    page.wait_for_function("() => document.querySelector('input[aria-label=\"Flight log\"]')"
                           f".value.startsWith('{log.name}')", timeout=SLOW_MS)
    _settle(page)


def test_upload_run_and_compare_in_a_browser(page):
    page.locator("[data-testid='stMain'] h1", has_text="solarnav").wait_for()
    _settle(page)
    for label, name in (("PX4 ULog", f"{SAMPLE}.ulg"), ("Sun-device log", f"{SAMPLE}_sun.csv"),
                        ("Sun-device geometry", f"{SAMPLE}_device.json")):
        uploader = page.locator("[data-testid='stFileUploader']").filter(has_text=label)
        uploader.locator("input[type='file']").set_input_files(str(SAMPLE_DIR / name))
        uploader.locator("[data-testid='stFileChipDeleteBtn']").wait_for()  # the upload has finished
    page.get_by_role("button", name="Add to the workspace").click()
    page.wait_for_function("() => document.querySelector('input[aria-label=\"Flight log\"]')"
                           f".value.startsWith('{SAMPLE}.ulg')", timeout=SLOW_MS)
    _settle(page)
    _screenshot(page, "home")

    # time axes in seconds since the log start (issue 14; on the real sample_px4_events.ulg, whose log clock is
    # Unix time: test_the_unix_clock_log_starts_near_zero_in_a_browser)
    _open(page, "Overview")
    assert page.locator("[data-testid='stMetric']").filter(has_text="Data duration").count() == 1
    altitude = _plot(page, "Altitude and flight phases", lambda plot: plot["xmin"] is not None)
    assert 0 <= altitude["xmin"] < 5, altitude["xmin"]
    _screenshot(page, "overview")
    _open(page, "Calibration")
    page.get_by_role("heading", name="Results").wait_for()
    segment = _plot(page, "Calibration segment", lambda plot: plot["xmin"] is not None)
    assert 0 <= segment["xmin"] < 5, segment["xmin"]  # seconds since the log start, as on the other pages
    _screenshot(page, "calibration")

    # one run: default settings (all estimators, magnetometer heading, default R)
    _open(page, "Estimators")
    page.get_by_role("button", name="Run estimators").click()
    page.get_by_role("heading", name="RMS errors (paper Table 2 layout)").wait_for(timeout=RUN_MS)
    _settle(page)
    rms_table = page.locator("[data-testid='stTable']").filter(has_text="Roll Angle (deg)")
    for estimator in ESTIMATORS:
        assert rms_table.get_by_text(estimator, exact=True).is_visible()
    page.locator(".js-plotly-plot .legendtext").first.wait_for()
    legend = page.eval_on_selector_all(".js-plotly-plot .legendtext", "texts => texts.map(t => t.textContent)")
    assert {*ESTIMATORS, "truth"} <= set(legend)
    _screenshot(page, "estimators_one_run")

    # a second run with the sun-vector heading: added to the runs shown, overlaid, compared in the RMS table
    page.locator("[data-testid='stRadio']").filter(has_text="Heading aid").get_by_text(
        "sun vector", exact=True).click()
    page.get_by_role("button", name="Run estimators").click()
    page.get_by_text("Every run against the baseline").wait_for(timeout=RUN_MS)
    _settle(page)
    runs_select = page.locator("[data-testid='stMultiSelect']").filter(has_text="Runs")
    assert runs_select.locator("[data-testid='stMultiSelectTagsContainer'] [data-tag]").count() == 2
    attitude = _plot(page, "Attitude", lambda plot: sum(" · " in name for name in plot["names"]) >= 6)
    run_names = {name.split(" · ", 1)[1] for name in attitude["names"] if " · " in name}
    assert len(run_names) == 2, attitude["names"]
    for estimator in ESTIMATORS:
        for run_name in run_names:
            assert f"{estimator} · {run_name}" in attitude["names"], attitude["names"]
    rms_table = page.locator("[data-testid='stTable']").filter(has_text="(baseline)")
    rms_table.wait_for()
    cells = rms_table.locator("td").all_inner_texts()
    assert any(RMS_DELTA_CELL.search(cell) for cell in cells), cells
    assert sum("(baseline)" in cell for cell in cells) >= len(ESTIMATORS)
    _screenshot(page, "estimators_two_runs")

    # zoom: the page's one time range, moved on the keyboard, is the x range of every time chart
    full = tuple(attitude["xrange"])
    slider = page.locator("[data-testid='stSlider']").filter(has_text="Time range [s since log start]")
    thumbs = slider.get_by_role("slider")
    assert thumbs.count() == 2
    span = full[1] - full[0]
    expected = (full[0] + 0.2 * span, full[1] - 0.3 * span)  # PageUp / PageDown: a tenth of the span each
    for thumb, key, presses in ((0, "PageUp", 2), (1, "PageDown", 3)):
        for _ in range(presses):  # each press reruns the page, which may take the focus: focus again every time
            thumbs.nth(thumb).focus()
            page.keyboard.press(key)
            _settle(page)
    attitude = _plot(page, "Attitude", lambda plot: _same_window(plot, expected, 0.01 * span))
    zoomed = tuple(attitude["xrange"])
    _screenshot(page, "estimators_zoomed_attitude")
    page.locator("[data-testid='stButtonGroup']").filter(has_text="Attitude").get_by_text(
        "Innovations and NIS", exact=True).click()
    _settle(page)
    innovations = _plot(page, "three_stage: ", lambda plot: plot["title"].endswith("innovations"))
    nis = _plot(page, "three_stage: ", lambda plot: plot["title"].endswith("NIS"))
    for plot in (innovations, nis):
        assert _same_window(plot, zoomed), (plot["title"], plot["xrange"], zoomed)
    _screenshot(page, "estimators_zoomed_innovations")

    # zoom one, all follow: a box dragged across the innovations chart is the range of the NIS chart too
    width = zoomed[1] - zoomed[0]
    expected = (zoomed[0] + 0.3 * width, zoomed[0] + 0.6 * width)
    _drag_box(page, innovations["title"], 0.3, 0.6)
    nis = _plot(page, nis["title"], lambda plot: _same_window(plot, expected, 0.05 * width))
    innovations = _plot(page, innovations["title"], lambda plot: _same_window(plot, tuple(nis["xrange"])))
    assert nis["xrange"][1] - nis["xrange"][0] < 0.5 * width, (nis["xrange"], zoomed)
    low, high = (float(thumbs.nth(k).get_attribute("aria-valuetext")) for k in (0, 1))  # the page's range moved
    assert (low, high) == pytest.approx(tuple(nis["xrange"]), abs=0.011), ((low, high), nis["xrange"])
    _screenshot(page, "estimators_box_zoom_followed")
    page.get_by_role("button", name="Full span").click()
    _settle(page)
    _plot(page, nis["title"], lambda plot: _same_window(plot, full, 0.01 * span))
    _screenshot(page, "estimators_full_span_again")

    # the map: GPS and the estimators of the baseline run on a plotly map
    _open(page, "Map")
    page.get_by_role("heading", name="Local NED").wait_for()
    drawn = _plot(page, "", lambda plot: "scattermap" in plot["types"])
    drawn = {name for name, kind in zip(drawn["names"], drawn["types"], strict=True) if kind == "scattermap"}
    assert page.locator(".js-plotly-plot .maplibregl-canvas").count() == 1  # MapLibre drew it
    assert "GPS" in drawn and drawn & set(ESTIMATORS), drawn
    _screenshot(page, "map")

    _open(page, "Compare logs")  # one log with runs only: the page says what it needs
    page.get_by_text("Fewer than two logs").wait_for()
    _screenshot(page, "compare_logs")

    _open(page, "Sun vector")
    assert page.locator("[data-testid='stMetric']").filter(has_text="Most often faulty").count() == 1
    _screenshot(page, "sun_vector")

    _open(page, "Workspace")
    page.get_by_role("heading", name="Rename or delete").wait_for()
    _screenshot(page, "workspace")


@pytest.fixture(scope="module")
def batch_outdir(tmp_path_factory) -> Path:
    """A ``solarnav batch`` OUTDIR of the simulated fleet (one vehicle, its gyro noise doubled in the later logs)."""
    outdir = tmp_path_factory.mktemp("batch") / "out"
    write_batch_outdir(outdir, tmp_path_factory.mktemp("fleet") / "logs")
    return outdir


def test_the_unix_clock_log_starts_near_zero_in_a_browser(page, real_logs_dir):
    """PX4's sample_px4_events.ulg (SITL) has a log clock in Unix time (1.7e9 s): its time axes still start near 0
    (issue 14)."""
    log = real_logs_dir / "sample_px4_events.ulg"
    _add_log(page, log)
    _open(page, "Overview")
    altitude = _plot(page, "Altitude and flight phases", lambda plot: plot["xmin"] is not None)
    assert -1 < altitude["xmin"] < 5, altitude["xmin"]  # (time 0 is the first IMU sample: a barometer may lead)
    _screenshot(page, "overview_sample_px4_events")
    _open(page, "Calibration")
    page.get_by_role("heading", name="Results").wait_for()
    segment = _plot(page, "Calibration segment", lambda plot: plot["xmin"] is not None)
    assert -1 < segment["xmin"] < 5, segment["xmin"]
    _screenshot(page, "calibration_sample_px4_events")


def test_a_batch_output_directory_on_the_fleet_page_in_a_browser(page, batch_outdir):
    _open(page, "Fleet")
    page.get_by_text("No batch opened").wait_for()  # the server's workspace has no batch: the user enters OUTDIR
    field = page.get_by_label("Batch output directory", exact=True)
    field.fill(str(batch_outdir))
    field.press("Enter")
    page.get_by_role("heading", name="Noise per vehicle").wait_for()
    _settle(page)
    count = page.locator("[data-testid='stMetric']").filter(has_text="Logs")
    assert count.locator("[data-testid='stMetricValue']").inner_text() == str(N_FLIGHTS + 2)  # with 2 bad files
    grid = page.locator("[data-testid='stDataFrame'] table[role='grid']").first  # the grid's accessible table
    header, *rows = grid.evaluate(GRID_JS)
    logs = [dict(zip(header, row, strict=True)) for row in rows]
    assert int(grid.get_attribute("aria-rowcount")) == 1 + len(logs) == 3 + N_FLIGHTS * len(OUTDIR_ESTIMATORS)
    names = {f"{flight_name(k)}.ulg" for k in range(N_FLIGHTS)}
    assert {log["name"] for log in logs} == {*names, "empty.ulg", "corrupt.ulg"}  # every row drawn
    assert all((log["status"] == "ok") == (log["name"] in names) for log in logs), logs
    good = [log for log in logs if log["name"] in names]
    assert {log["vehicle"] for log in good} == {VEHICLE}
    flagged = [f"{flight_name(k)}.ulg" for k in range(DOUBLED_FROM, N_FLIGHTS)]
    warnings = page.locator("[data-testid='stAlertContentWarning']").all_inner_texts()
    assert len(warnings) == len(flagged), warnings
    for name, text in zip(flagged, warnings, strict=True):
        assert f"{VEHICLE}: {name}: gyroscope noise" in text, text
    assert all((log["noise_flags"] == "gyroscope") == (log["name"] in flagged) for log in good), good
    trend = _plot(page, "gyroscope per vehicle", lambda plot: FLAG_TRACE in plot["names"])
    sizes = dict(zip(trend["names"], trend["sizes"], strict=True))
    assert sizes == {VEHICLE: N_FLIGHTS, FLAG_TRACE: len(flagged)}, trend
    _screenshot(page, "fleet")


# ---------------------------------------------------------------------------------------------------- issue 34
#: Screenshots of the issue-34 checks (under test-artifacts/), for a human to look at.
SHOTS_DIR = Path("issue34")
OCTOCOPTER = "px4_1.14_octo_flight_61.ulg"
GROUND_WALK = "arduplane_4.0.8_ground_walk.bin"
MISSION = "paper.ulg"
#: One chart (title starting with the argument) in detail: axis titles and ranges, annotations, and per trace its
#: name, y axis, points, breaks (null / NaN y) and finite y extremes.
CHART_JS = """title => {""" + VALUES_JS + """
    const gd = [...document.querySelectorAll('.js-plotly-plot')].find(gd => {
        const t = gd.layout && gd.layout.title;
        return String(t ? (typeof t === 'string' ? t : t.text || '') : '').replace(/<[^>]*>/g, '').startsWith(title);
    });
    if (!gd) return null;
    const axes = {};
    for (const [key, axis] of Object.entries(gd.layout)) {
        if (/^[xy]axis\\d*$/.test(key)) {
            axes[key] = {title: axis.title ? (axis.title.text || '') : '',
                         range: axis.range ? Array.from(axis.range) : null};
        }
    }
    const traces = gd.data.map(t => {
        const y = values(t.y).map(v => (v === null ? NaN : Number(v)));
        const finite = y.filter(Number.isFinite);
        return {name: t.name || '', yaxis: t.yaxis || 'y', n: y.length, breaks: y.length - finite.length,
                ymin: finite.length ? Math.min(...finite) : null, ymax: finite.length ? Math.max(...finite) : null};
    });
    return {axes, traces, annotations: (gd.layout.annotations || []).map(a => a.text || '')};
}"""


def _chart(page, title: str, check=lambda chart: True) -> dict:
    """:data:`CHART_JS` of the chart titled ``title`` once it passes ``check``."""
    deadline = time.monotonic() + SLOW_MS / 1000
    while True:
        chart = page.evaluate(CHART_JS, title)
        if chart is not None and chart["traces"] and check(chart):
            return chart
        if time.monotonic() > deadline:
            raise AssertionError(f"no chart {title!r} passing the check: {chart}")
        time.sleep(0.5)


def _pick_log(page, name: str) -> None:
    """Open the stored log ``name`` in the sidebar's log picker."""
    page.locator("[data-testid='stSidebar'] [data-testid='stSelectbox']").filter(has_text="Flight log").click()
    page.get_by_role("option", name=re.compile(re.escape(name))).first.click()
    page.wait_for_function("() => document.querySelector('input[aria-label=\"Flight log\"]')"
                           f".value.startsWith('{name}')", timeout=SLOW_MS)
    _settle(page)


def _range_thumbs(page):
    """The two thumbs of the page's time-range slider."""
    slider = page.locator("[data-testid='stSlider']").filter(has_text="Time range [s since log start]")
    return slider.get_by_role("slider")


def _ensure_run(page, name: str) -> None:
    """Open ``name`` on the Estimators page with a stored default run (run now when it has none)."""
    _pick_log(page, name)
    _open(page, "Estimators")
    if page.get_by_text("No estimator run for this log yet").count():
        page.get_by_role("button", name="Run estimators").click()
        page.get_by_role("heading", name="RMS errors (paper Table 2 layout)").wait_for(timeout=RUN_MS)
        _settle(page)


def test_a_log_switch_shows_the_whole_flight_in_a_browser(page, real_logs_dir):
    """Issue 34 (a): after the 78.7-s octocopter the bundled 14-min mission is shown whole, not its first 78.7 s;
    a partial range is named on the charts; the ArduPlane log after it is whole again."""
    _add_log(page, real_logs_dir / OCTOCOPTER)
    _open(page, "Overview")
    octocopter = _plot(page, "Altitude and flight phases", lambda plot: plot["xrange"] is not None)
    assert octocopter["xrange"][1] == pytest.approx(78.7, abs=0.1), octocopter["xrange"]
    _pick_log(page, MISSION)
    mission = _plot(page, "Altitude and flight phases", lambda plot: plot["xrange"][1] > 100.0)
    assert mission["xrange"] == pytest.approx([0.0, 864.0], abs=1.0), mission["xrange"]
    thumbs = _range_thumbs(page)
    assert float(thumbs.nth(1).get_attribute("aria-valuetext")) == pytest.approx(mission["xrange"][1], abs=0.011)
    altitude = _chart(page, "Altitude and flight phases")
    assert altitude["axes"]["xaxis"]["title"] == "time since log start [s]"  # the whole log: no note
    _screenshot(page, SHOTS_DIR / "a_overview_mission_after_octocopter")
    thumbs.nth(0).focus()
    page.keyboard.press("PageUp")  # a tenth of the span: the chart now shows part of the flight and says so
    _settle(page)
    altitude = _chart(page, "Altitude and flight phases", lambda chart: "showing" in chart["axes"]["xaxis"]["title"])
    assert re.search(r"showing 86\.\d-864\.0 s of 0-864 s", altitude["axes"]["xaxis"]["title"]), altitude["axes"]
    _screenshot(page, SHOTS_DIR / "a_overview_mission_part_named")
    _add_log(page, real_logs_dir / GROUND_WALK)  # the 85-s ArduPlane log after the mission's range: whole too
    _open(page, "Overview")
    walk = _plot(page, "Altitude and flight phases", lambda plot: plot["xrange"][1] < 100.0)
    assert walk["xrange"] == pytest.approx([0.0, 85.14], abs=0.02), walk["xrange"]
    _screenshot(page, SHOTS_DIR / "a_overview_ground_walk_after_mission")


def test_the_octocopter_yaw_is_readable_in_a_browser(page, real_logs_dir):
    """Issue 34 (b): the octocopter heads about south (yaw near +-180 deg): drawn on 0-360 in one piece."""
    _add_log(page, real_logs_dir / OCTOCOPTER)
    _ensure_run(page, OCTOCOPTER)
    attitude = _chart(page, "Attitude", lambda chart: any(t["yaxis"] == "y3" for t in chart["traces"]))
    assert attitude["axes"]["yaxis3"]["title"] == "yaw [deg] on 0-360", attitude["axes"]
    yaw = [trace for trace in attitude["traces"] if trace["yaxis"] == "y3"]
    assert {trace["name"] for trace in yaw} >= {"onboard", *ESTIMATORS}
    for trace in yaw:  # one piece each (the onboard yaw wraps 10 times on -180..180), about south
        assert trace["breaks"] <= 1 and trace["ymin"] > 90.0 and trace["ymax"] < 270.0, trace
    _screenshot(page, SHOTS_DIR / "b_octocopter_attitude")
    page.locator("[data-testid='stButtonGroup']").filter(has_text="Attitude").get_by_text(
        "Altitude and speeds", exact=True).click()
    _settle(page)
    speeds = _chart(page, "Altitude and speeds")
    assert "airspeed" not in " ".join(axis["title"] for axis in speeds["axes"].values())  # no sensor
    page.get_by_text("Not drawn, no value in any source: airspeed.").wait_for()
    _screenshot(page, SHOTS_DIR / "b_octocopter_speeds_without_airspeed")


def test_the_in_flight_innovations_of_the_mission_are_visible_in_a_browser(page):
    """Issue 34 (c): the accelerometer innovations of the bundled mission, not flattened by the landing spike."""
    _ensure_run(page, MISSION)
    page.locator("[data-testid='stButtonGroup']").filter(has_text="Attitude").get_by_text(
        "Innovations and NIS", exact=True).click()
    _settle(page)
    sensor = page.locator("input[aria-label='Sensor']")
    sensor.click(timeout=30_000)
    sensor.fill("accel", timeout=30_000)
    page.keyboard.press("Enter")
    _settle(page)
    chart = _chart(page, "three_stage: accel innovations",
                   lambda chart: any(t["name"] == "innovation" for t in chart["traces"]))
    inside = [t for t in chart["traces"] if t["name"] == "innovation"]
    off_scale = [t for t in chart["traces"] if t["name"] == "off-scale"]
    assert off_scale and chart["annotations"] and "beyond the axis" in chart["annotations"][0], chart
    spiky = 0
    for trace in inside:  # every row's axis fits its innovations; a spike beyond it is marked, not scaled to
        axis = chart["axes"][trace["yaxis"].replace("y", "yaxis")]
        low, high = axis["range"]
        drawn = max(abs(trace["ymin"]), abs(trace["ymax"]))
        assert high == pytest.approx(-low) and high < 1.5 * drawn, (axis, trace)
        spiky += high < 0.1 * drawn
    assert spiky, inside  # the landing: over ten times the in-flight scale
    _screenshot(page, SHOTS_DIR / "c_mission_innovations")


def test_compare_logs_refuses_a_verdict_across_references_in_a_browser(page, real_logs_dir):
    """Issue 34 (d): the octocopter (against its onboard estimate) is not improved / regressed against the mission
    (against its truth)."""
    _add_log(page, real_logs_dir / OCTOCOPTER)
    _ensure_run(page, OCTOCOPTER)
    _ensure_run(page, MISSION)
    _open(page, "Compare logs")
    page.get_by_text("Not compared with the baseline").wait_for()
    page.get_by_text("Errors against the ground truth.").wait_for()
    page.get_by_text("lower means closer to the autopilot, not necessarily better").wait_for()
    table = page.locator("[data-testid='stTable']").filter(has_text="(baseline)")
    cells = table.locator("td").all_inner_texts()
    assert any("(other reference)" in cell for cell in cells), cells
    assert not any("▼" in cell or "▲" in cell for cell in cells), cells
    _screenshot(page, SHOTS_DIR / "d_compare_logs_across_references")



def test_the_octocopter_calibration_says_its_figures_are_upper_bounds_in_a_browser(page, real_logs_dir):
    """Issue 34 (e): the octocopter has no steady segment: its noise figures are named upper bounds on the page."""
    _add_log(page, real_logs_dir / OCTOCOPTER)
    _open(page, "Calibration")
    warning = page.locator("[data-testid='stAlert']").filter(has_text="are upper bounds")
    warning.wait_for()
    assert "motion and vibration count as noise" in warning.inner_text()
    _screenshot(page, SHOTS_DIR / "e_octocopter_calibration_upper_bounds")


def test_the_ardupilot_log_offers_the_ek3_parm_in_a_browser(page, real_logs_dir):
    """Issue 34 (f): an ArduPilot log's calibration downloads as an EKF3 .parm (as the CLI writes it) whose header
    names the flight and whose figures it holds (calibrated, or identified for which estimator)."""
    _add_log(page, real_logs_dir / GROUND_WALK)
    _open(page, "Calibration")
    button = page.locator("[data-testid='stDownloadButton']").filter(has_text="ArduPilot EKF3 .parm")
    button.wait_for()
    _screenshot(page, SHOTS_DIR / "f_ground_walk_calibration_exports")
    with page.expect_download() as download:
        button.get_by_role("button").click()
    text = Path(download.value.path()).read_text()
    assert download.value.suggested_filename == "solarnav_ek3.parm"
    assert f"calibrated by solarnav from {GROUND_WALK}" in text, text[:400]
    assert "the calibrated figures (no identification)" in text, text[:400]  # which figures: none identified
    assert re.search(r"^EK3_\w+[ ,]+[-+0-9.eE]+", text, re.MULTILINE), text[:400]


def test_noise_identification_survives_leaving_the_page_in_a_browser(page, real_logs_dir):
    """Issue 34 (g): identification started on the Calibration page goes on while another page is open, and the
    page found again shows it running or its result, with the toggle still on."""
    _add_log(page, real_logs_dir / OCTOCOPTER)
    _open(page, "Calibration")
    page.get_by_text("Identify noise", exact=False).first.click()
    page.get_by_text("Identifying the noise from the flight's innovations").wait_for()
    _screenshot(page, SHOTS_DIR / "g_identification_running")
    _open(page, "Overview")
    _open(page, "Calibration")
    toggle = page.locator("[data-testid='stCheckbox']").filter(has_text="Identify noise").locator("input")
    assert toggle.is_checked()
    running = page.get_by_text("Identifying the noise from the flight's innovations")
    done = page.locator("[data-testid='stDataFrame']").filter(has=page.locator("[role=columnheader]"))
    assert running.count() or done.count(), "neither running nor done after coming back"
    page.get_by_text("Verdict of the tuned mean NIS").wait_for(timeout=RUN_MS)  # and it finishes
    _settle(page)
    assert toggle.is_checked()
    _screenshot(page, SHOTS_DIR / "g_identification_found_done")

ISSUE33_DIR = Path("issue33")
#: Top [px] of every element of the main area that the selector finds, in page order.
TOPS_JS = """selector => [...document.querySelectorAll('[data-testid="stMain"] ' + selector)]
    .map(element => element.getBoundingClientRect().top + window.scrollY)"""
#: Every alert box of the main area in page order: its top [px] and text.
ALERTS_JS = """() => [...document.querySelectorAll('[data-testid="stMain"] [data-testid="stAlert"]')]
    .map(element => ({top: element.getBoundingClientRect().top + window.scrollY, text: element.innerText}))"""


def test_two_runs_of_a_real_log_read_at_a_glance_in_a_browser(page, real_logs_dir):
    """Issue 33 (4): the octocopter's default run and a run with a calibration saved on the Calibration page (the
    flight has no steady segment for the automatic one): short run names, the RMS table first, then one verdict
    element per estimator per run (no box per channel), then the charts."""
    _add_log(page, real_logs_dir / OCTOCOPTER)
    _ensure_run(page, OCTOCOPTER)
    _open(page, "Calibration")
    page.get_by_role("button", name="Save in the workspace").click()
    _settle(page)
    _open(page, "Estimators")
    assert not page.get_by_text("calibrated R (automatic calibration of this log)").count()  # no steady segment
    page.get_by_text(re.compile(r"^saved: ")).first.click()
    page.get_by_role("button", name="Run estimators").click()
    page.get_by_text("Baseline run").wait_for(timeout=RUN_MS)  # the calibrated run is added to the shown runs
    page.get_by_role("heading", name="RMS errors (paper Table 2 layout)").wait_for(timeout=RUN_MS)
    _settle(page)
    _screenshot(page, ISSUE33_DIR / "after_estimators_two_runs")
    chosen = page.locator("[data-testid='stMultiSelect']").filter(has_text="Runs").locator(
        "[data-testid='stMultiSelectTagsContainer'] [data-tag]").all_inner_texts()
    assert len(chosen) == 2, chosen
    for name in chosen:  # log, noise source and time only: no estimator list, heading or time stamp
        assert re.fullmatch(r"px4 1\.14 octo flight 61 · (datasheet|calib [0-9a-f]{6}) · \d\d:\d\d", name), chosen
    table = page.evaluate(TOPS_JS, "[data-testid='stTable']")
    alerts = page.evaluate(ALERTS_JS)
    verdicts = [alert for alert in alerts if "innovations:" in alert["text"]]
    charts = page.evaluate(TOPS_JS, ".js-plotly-plot")
    assert table and charts, (table, charts)
    assert len(verdicts) == 2 * len(ESTIMATORS), [alert["text"] for alert in alerts]
    assert table[0] < verdicts[0]["top"] and verdicts[-1]["top"] < charts[0], (table, verdicts, charts)
    others = [alert["text"] for alert in alerts if table[0] < alert["top"] < charts[0] and alert not in verdicts]
    assert len(others) == len(set(others)), others  # no box per channel: each note once (issue 34)
    assert sum(text.startswith(tuple(f"{name}: Expected" for name in chosen)) for text in others) <= len(chosen)



def test_the_flight_report_downloads_and_opens_offline_in_a_browser(page, tmp_path):
    """Issue 33 (3): the bundled mission's report from the Estimators page opens in a browser without network: every
    section, its charts drawn by the embedded plotly."""
    _ensure_run(page, MISSION)
    button = page.locator("[data-testid='stDownloadButton']").filter(has_text="Flight report (.html)").first
    with page.expect_download(timeout=RUN_MS) as download:
        button.get_by_role("button").click()
    report = tmp_path / "report.html"
    download.value.save_as(report)
    assert report.stat().st_size > 1e6  # plotly itself is embedded
    context = page.context.browser.new_context(offline=True, viewport={"width": 1400, "height": 1000})
    try:
        offline = context.new_page()
        offline.goto(report.as_uri())
        offline.wait_for_function("() => document.querySelectorAll('.js-plotly-plot .main-svg').length >= 3")
        headings = offline.locator("h2").all_inner_texts()
        assert {label for _, label in REPORT_SECTIONS} <= set(headings), headings
        (ARTIFACTS_DIR / ISSUE33_DIR).mkdir(parents=True, exist_ok=True)
        offline.screenshot(path=str(ARTIFACTS_DIR / ISSUE33_DIR / "report_offline.png"), full_page=True)
    finally:
        context.close()
