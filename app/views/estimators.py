"""Estimators: run the three EKFs (choice of estimators, heading aid, noise) with progress, and compare them with
the onboard estimate and the ground truth: states, errors, the RMS table (paper Table 2), innovations and NIS."""

import json
import threading

import pandas as pd
import streamlit as st
from streamlit.runtime.scriptrunner import add_script_run_ctx, get_script_run_ctx

from app import adapters, comparison, figures, runs, session, tables, time_range
from app.notes import PROBLEM, note_text, run_notes
from estimators.api import DEFAULT_ESTIMATORS, ESTIMATORS, UNTRUSTED_PREFIX
from estimators.inputs.records import AUTO_HEADING, resolve_heading
from ingest.errors import InputError

#: The run shown (the baseline of several): the Map page opens on it.
RUN_KEY = "est_run"
#: The runs shown, overlaid (issue 14), and the one the others are compared with.
RUNS_KEY = "est_runs"
BASELINE_KEY = "est_baseline"
#: Most runs overlaid at once (the comparisons of that many stay cached: adapters.run_comparison).
MAX_RUNS = 4
RANGE_KEY = "est_time_range"
#: (run id, measured stages) of the last run made on this page.
TIMINGS_KEY = "est_last_run_timings"
HEADING_LABELS = {"mag": "magnetometer", "sun": "sun vector", "mag+sun": "both (default with sun data)"}

log = session.require_log()
root, sha256 = session.root(), session.selected_sha256()
workspace = session.workspace()
clock = figures.time_base(log)
st.title(f"Estimators: {log.meta.source}")

# ------------------------------------------------------------------ input quality (docs/estimators.md, 'Inputs the
# estimators refuse'): refused inputs stop a run unless the form's override is ticked
findings = adapters.input_quality(root, sha256)
refused = [finding for finding in findings if finding["severity"] == "refuse"]
for finding in refused:
    st.error(f"**Refused input**: {finding['message']}. The estimators do not run on this log unless "
             "*Run despite refused inputs* is ticked; every report then carries the warning.")
for finding in findings:
    if finding["severity"] != "refuse":
        st.warning(f"**Flagged input**: {finding['message']}")

# ------------------------------------------------------------------ run form
saved_calibrations = workspace.list_calibrations(sha256)
saved = list(saved_calibrations["calib_id"])
# the automatic calibration needs a stationary or steady segment (calib.segments.auto_segments): offered only then
automatic = not adapters.candidate_segments(root, sha256).empty
noise_labels = {runs.DEFAULT_NOISE: "default R (datasheet noise)",
                **({runs.AUTO_CALIBRATION: "calibrated R (automatic calibration of this log)"} if automatic else {}),
                **{calib_id: f"saved: {name}" for calib_id, name in zip(saved_calibrations["calib_id"],
                                                                    saved_calibrations["name"], strict=True)}}
# the default first: both with sun-device data (resolve_heading), else the magnetometer alone
headings = (resolve_heading(AUTO_HEADING, True), "mag", "sun") if log.has("sun") else ("mag",)
with st.form("run_form"):
    chosen = st.multiselect("Estimators", list(ESTIMATORS), default=list(DEFAULT_ESTIMATORS), key="est_names")
    left, right = st.columns(2)
    heading = left.radio("Heading aid", headings, format_func=HEADING_LABELS.get, horizontal=True,
                         key="est_heading", help=None if log.has("sun") else "the log has no sun-device data")
    noise = right.radio("Measurement noise", list(noise_labels), format_func=noise_labels.get, key="est_noise",
                        help=None if automatic else "No automatic calibration: the log has no stationary or steady "
                        "segment. Pick a window on the Calibration page and save it to calibrate R.")
    force = st.checkbox("Run despite refused inputs", value=False, key="est_force", disabled=not refused,
                        help="replay a log whose inputs the estimators refuse (solarnav replay --force)")
    submitted = st.form_submit_button("Run estimators", type="primary")
if submitted:
    settings = runs.RunSettings(estimators=tuple(chosen), heading=heading, noise=noise,
                                allow_untrusted=bool(force and refused))
    run_id = runs.find_run(workspace, sha256, settings)
    if run_id is None:
        bar = st.progress(0.0, text="Preparing ...")
        script_context = get_script_run_ctx()

        def show(fraction: float, text: str) -> None:  # also from the estimators' threads: they draw for this page
            add_script_run_ctx(threading.current_thread(), script_context)
            bar.progress(fraction, text=text)

        stage_clock = runs.StageClock(show, runs.run_steps(len(settings.estimators),
                                                           calibrate=noise != runs.DEFAULT_NOISE))
        if noise != runs.DEFAULT_NOISE:
            stage_clock.start("calibrating", "Calibrating the sensors for R ...")
        try:
            calibration = adapters.run_calibration(root, sha256, noise)
        except InputError as exc:  # the log is fine; it has no segment the automatic calibration can use
            bar.empty()
            st.error(f"No automatic calibration of this log ({exc}). Pick a window on the **Calibration** page, save "
                     "it there, and choose it under *Measurement noise*.")
            st.stop()
        with session.input_errors():
            run_id = runs.replay_and_store(workspace, sha256, log, settings, calibration, clock=stage_clock)
        bar.empty()
        st.session_state[TIMINGS_KEY] = (run_id, stage_clock.summary())
        st.toast(f"Run {run_id} stored in the workspace.")
    else:
        st.info("A run with these settings is stored already: showing it.")
    selection = [r for r in st.session_state.get(RUNS_KEY, []) if r in set(workspace.list_runs(sha256)["run_id"])]
    st.session_state[RUNS_KEY] = (selection if run_id in selection else [*selection, run_id])[-MAX_RUNS:]

stored = workspace.list_runs(sha256)
timed_run, timings = st.session_state.get(TIMINGS_KEY, (None, ""))
if timed_run in set(stored["run_id"]):  # where the last run's time went, measured
    st.caption(f"Run {comparison.run_names(stored)[timed_run]} took {timings}.")
if stored.empty:
    st.info("No estimator run for this log yet: choose the settings above and press **Run estimators**.")
    st.stop()

# ------------------------------------------------------------------ the runs shown (issue 14: several overlaid)
names = comparison.run_names(stored)
details = tables.run_details(stored, workspace.list_logs(), names)
kept = [run_id for run_id in st.session_state.get(RUNS_KEY, []) if run_id in names][:MAX_RUNS]
if not kept:  # the default: the run shown before (the Map page reads it), else the newest
    previous = st.session_state.get(RUN_KEY)
    kept = [previous if previous in names else next(iter(names))]
st.session_state[RUNS_KEY] = kept
selected = st.multiselect("Runs", list(names), format_func=names.get, key=RUNS_KEY, max_selections=MAX_RUNS,
                          help="Pick several runs of this log (default vs calibrated R, magnetometer vs sun "
                               "heading, ...): every chart overlays them, one colour per estimator and one dash "
                               "style per run, and the tables compare them with the baseline. A run is named by "
                               "its log, noise source and time; the settings are under *Run details*.")
with st.expander("Run details: estimators, heading aid, noise (R), created"):
    st.dataframe(details.loc[selected], hide_index=True, key="est_run_details")
if not selected:
    st.info("Select at least one run above.")
    st.stop()
multi = len(selected) > 1
if multi:
    if st.session_state.get(BASELINE_KEY) not in selected:
        st.session_state[BASELINE_KEY] = selected[0]
    baseline = st.selectbox("Baseline run", selected, format_func=names.get, key=BASELINE_KEY,
                            help="The RMS table gives every run's difference to this run.")
    st.caption("Line styles: " + ", ".join(f"{names[run_id]} {figures.RUN_DASHES[k % len(figures.RUN_DASHES)]}"
                                          for k, run_id in enumerate(selected)) + ".")
else:
    baseline = selected[0]
st.session_state[RUN_KEY] = baseline
run_id = baseline
shown = {names[run_id]: run_id for run_id in selected}  # run name -> run id, in overlay order
reports = {name: adapters.run_report(root, rid) for name, rid in shown.items()}
results = {name: adapters.run_comparison(root, sha256, rid) for name, rid in shown.items()}
report, result = reports[names[baseline]], results[names[baseline]]


def show_verdict(label: str, verdict: dict | None) -> None:
    """One element per estimator and run: its consistency verdict (green consistent, blue conservative, red
    inconsistent); the channels behind it are in the estimator's details."""
    if verdict is not None:  # (None: a run stored before verdicts existed)
        box = {"consistent": st.success, "conservative": st.info}.get(verdict["status"], st.error)
        box(f"**{label}** innovations: {verdict['summary']}")


def widget_key(base: str, index: int) -> str:
    """A widget key unique per shown run (the single-run page keeps its historical keys)."""
    return f"{base}_{index}" if multi else base


for run_name, run_report in reports.items():  # a forced run's refused inputs, once per run, never collapsed
    for warning in dict.fromkeys(w for facts in run_report.values() for w in facts["warnings"]
                                 if w.startswith(UNTRUSTED_PREFIX)):
        st.error(f"{run_name}: {warning}" if multi else warning)

st.subheader("RMS errors (paper Table 2 layout)")
if result.reference is None:
    st.warning(comparison.reference_sentence(None))
else:
    st.markdown(f"**{comparison.reference_sentence(result.reference)}**")
    st.caption("Position = horizontal distance, wind = horizontal vector difference; airspeed, course and wind in "
               f"flight only (reference ground speed > {comparison.MIN_COURSE_SPEED_M_S:g} m/s). "
               f"{comparison.window_caption(result, clock.start_s)} (docs/evaluation.md).")
    if not multi:
        st.table(adapters.rms_table(root, sha256, run_id).style.format("{:.2f}", na_rep="–"))
    else:
        deltas = comparison.rms_comparison({name: adapters.rms_table(root, sha256, rid) for name, rid in shown.items()},
                                           names[baseline])
        st.caption(f"Every run against the baseline **{names[baseline]}**: RMS (difference, in the quantity's "
                   f"unit, and in % of the baseline's RMS); ▼ green improved, ▲ red regressed, ≈ within "
                   f"{comparison.RMS_CHANGE_TOLERANCE_PCT:g} %.")
        st.table(tables.rms_delta_style(deltas, names[baseline]))
        with st.expander("The comparison as a long table"):
            st.dataframe(deltas, hide_index=True, key="rms_comparison",
                         column_config={c: st.column_config.NumberColumn(c, format="%.3f")
                                        for c in ("RMS", "baseline RMS", "delta", "delta [%]")})

st.subheader("Consistency")
st.caption("One verdict per estimator and run (docs/calibration.md, 'Consistency checks'); the channels behind it "
           "are in the estimator's details below it.")
for index, (run_name, run_report) in enumerate(reports.items()):
    prefix = f"{run_name}: " if multi else ""
    for name, facts in sorted(run_report.items(),  # the inconsistent estimators first
                              key=lambda item: item[1]["details"].get("verdict", {}).get("status") != "inconsistent"):
        show_verdict(f"{prefix}{name}", facts["details"].get("verdict"))
    run_estimators = tuple(run_report)
    notes = run_notes(run_report, fixed_wing=log.meta.is_fixed_wing)
    for note in notes:  # each once, the problems first
        if note.severity == PROBLEM:
            st.warning(prefix + note_text(note, run_estimators))
    expected = [note_text(note, run_estimators) for note in notes if note.severity != PROBLEM]
    if expected:
        st.info(f"{prefix}Expected for this log, nothing wrong:\n" + "\n".join(f"- {text}" for text in expected))
    for name, facts in run_report.items():
        with st.expander(f"{prefix}{name}: used {', '.join(facts['used']) or 'nothing'}; "
                         f"{facts['timings_s'].get('total', float('nan')):.1f} s"):
            if facts["details"].get("verdict"):
                st.caption("Consistency of each measurement channel (docs/calibration.md, 'Consistency checks')")
                st.dataframe(tables.verdict_channels(facts["details"]["verdict"]), hide_index=True,
                             key=widget_key(f"verdict_{name}", index))
            if facts["details"].get("calibration"):
                st.caption("Calibrated figures: source and what this estimator did with each")
                st.dataframe(pd.DataFrame(facts["details"]["calibration"]), hide_index=True,
                             key=widget_key(f"calibration_{name}", index))
            st.json(facts["details"], expanded=False)


PANELS = comparison.STATE_PANELS
ERROR_ROWS = comparison.ERROR_ROWS
INNOVATIONS = "Innovations and NIS"
span = figures.time_span(log)


def time_chart(fig, key: str) -> None:
    """A time chart of the page: a box dragged across it sets the page's range (every chart follows)."""
    session.time_chart(fig, key, RANGE_KEY, span)


@st.fragment
def comparison_plots() -> None:
    """One view at a time: states of every source, their errors against the reference, or the innovations and NIS
    (only the view shown is computed; reruns alone on a change). Several selected runs are overlaid."""
    panel = st.segmented_control("Show", [*PANELS, "Track", "Errors", INNOVATIONS], default="Attitude",
                                 key="est_panel")
    window = session.time_range_slider(RANGE_KEY, span, "Every time chart below shows this range, with the "
                                       "samples in it at full resolution and the y axes fitted to them (the track: "
                                       "the part flown in it).", owner=(sha256, *selected))
    note = time_range.partial_text(window, span)
    if panel == INNOVATIONS:
        (innovation_overlays if multi else innovation_plots)(window)
    elif panel == "Track":
        tracks = {name: {source: frame for source, frame in run.quantities.items() if frame["north_m"].notna().any()}
                  for name, run in results.items()}
        if not any(tracks.values()):
            st.info("No position to draw: the log has no GPS fix (the local NED origin).")
        elif multi:
            st.plotly_chart(figures.note_partial(figures.overlay_track_figure(tracks, time_base=clock, window=window),
                                                 note), key="est_track")
        else:
            st.plotly_chart(figures.note_partial(figures.track_figure(tracks[names[run_id]], time_base=clock,
                                                                      window=window), note), key="est_track")
    elif panel == "Errors":
        if not result.errors:
            st.info(comparison.reference_sentence(None))
        else:
            st.caption(comparison.reference_sentence(result.reference))
            rows_chart(ERROR_ROWS, {name: run.errors for name, run in results.items()},
                       f"Errors against {comparison.REFERENCE_NAMES[result.reference]}", "est_errors",
                       comparison.MISSING_ERRORS_WHY, window)
    elif panel is not None:
        rows_chart(PANELS[panel], {name: run.quantities for name, run in results.items()}, panel, "est_states",
                   comparison.MISSING_STATES_WHY if panel != "Wind" else comparison.MISSING_WIND_WHY, window)


def rows_chart(rows, frames_by_run: dict, title: str, key: str, why: str, window: tuple[float, float]) -> None:
    """A chart of ``rows`` of every shown run's frames (overlaid for several runs), without the airspeed of a log
    that has none and without rows no source has (a sentence says which and why; no chart when none is left)."""
    frames_by_run = {name: comparison.without_absent_airspeed(frames, log) for name, frames in frames_by_run.items()}
    frames, _ = figures.overlay_sources(frames_by_run)
    missing = comparison.missing_rows_text(frames, rows, why)
    if not figures.rows_with_data(frames, rows):
        st.info(missing)
        return
    if multi:
        time_chart(figures.overlay_quantity_figure(frames_by_run, rows, title=title, time_base=clock, window=window),
                   key)
    else:
        time_chart(figures.quantity_figure(next(iter(frames_by_run.values())), rows, title=title, time_base=clock,
                                           window=window), key)
    if missing:
        st.caption(missing)


def nis_table_and_choice(table: pd.DataFrame, estimators: list[str]) -> tuple[str, str | None, int]:
    """The NIS table with its verdicts, then the estimator, sensor and NIS window [updates] to plot."""
    st.dataframe(tables.verdict_style(tables.with_nis_verdicts(table)), hide_index=True, key="nis_summary",
                 column_config={"why": st.column_config.TextColumn("why", width="large")})
    left, middle, right = st.columns(3)
    estimator = left.selectbox("Estimator", estimators, key="est_diag_estimator")
    sensor = middle.selectbox("Sensor", list(dict.fromkeys(table.loc[table["estimator"] == estimator, "sensor"])),
                              key="est_diag_sensor")
    nis_window = right.select_slider("NIS window [updates]", [10, 20, 50, 100, 200, 500], value=50,
                                     key="est_window")
    return estimator, sensor, nis_window


def innovation_plots(window: tuple[float, float]) -> None:
    """Consistency summary, then the innovations and NIS of one estimator's sensor."""
    summary = adapters.nis_summary(root, run_id)
    estimator, sensor, nis_window = nis_table_and_choice(summary, list(report))
    if sensor is None:
        st.info(f"{estimator} fused no measurement.")
        return
    rows = adapters.sensor_diagnostics(root, run_id, estimator, sensor)
    units = {str(c): comparison.innovation_unit(sensor, str(c)) for c in rows["component"].unique()}
    time_chart(figures.innovation_figure(rows, units, title=f"{estimator}: {sensor} innovations",
                                         time_base=clock, window=window), "est_innovations")
    time_chart(figures.nis_figure(adapters.moving_nis(root, run_id, estimator, sensor, nis_window),
                                  nis_window, comparison.nis_band(nis_window),
                                  title=f"{estimator}: {sensor} NIS", time_base=clock, time_window=window), "est_nis")


def innovation_overlays(window: tuple[float, float]) -> None:
    """The consistency summaries of the selected runs side by side (a ``run`` column, the runs of each
    estimator and sensor adjacent), then one estimator's sensor in every run overlaid."""
    summaries = {name: adapters.nis_summary(root, rid) for name, rid in shown.items()}
    table = comparison.nis_comparison(summaries)
    estimators = list(dict.fromkeys([*(e for r in reports.values() for e in r), *table["estimator"]]))
    estimator, sensor, nis_window = nis_table_and_choice(table, estimators)
    if sensor is None:
        st.info(f"{estimator} fused no measurement in the selected runs.")
        return
    rows = {name: adapters.sensor_diagnostics(root, rid, estimator, sensor) for name, rid in shown.items()}
    rows = {name: frame for name, frame in rows.items() if len(frame)}
    units = {str(c): comparison.innovation_unit(sensor, str(c)) for frame in rows.values()
             for c in frame["component"].unique()}
    time_chart(figures.overlay_innovation_figure(rows, estimator, units, title=f"{estimator}: {sensor} innovations",
                                                 time_base=clock, window=window), "est_innovations")
    moving = {name: adapters.moving_nis(root, shown[name], estimator, sensor, nis_window) for name in rows}
    time_chart(figures.overlay_nis_figure(moving, estimator, nis_window, comparison.nis_band(nis_window),
                                          title=f"{estimator}: {sensor} NIS", time_base=clock, time_window=window),
               "est_nis")


st.subheader("Comparison")
comparison_plots()

st.subheader("Download")
st.caption("Each table keeps the log-clock `time_s` and adds `time_since_start_s` (seconds since the log start).")
for index, (run_name, shown_id) in enumerate(shown.items()):
    if multi:
        st.caption(f"Run **{run_name}**")
    columns = st.columns(5)
    for k, (table, suffix) in enumerate([(t, s) for t in ("states", "diagnostics") for s in ("parquet", "csv")]):
        columns[k].download_button(
            f"{table} (.{suffix})", lambda table=table, suffix=suffix, shown_id=shown_id: comparison.table_download(
                adapters.run_table(root, shown_id, table), clock, suffix),
            file_name=f"{sha256[:8]}_{shown_id}_{table}.{suffix}", key=widget_key(f"download_{table}_{suffix}", index))
    run_settings = json.loads(stored.set_index("run_id").at[shown_id, "settings_json"])
    columns[4].download_button(
        "Flight report (.html)", lambda run_settings=run_settings: adapters.flight_report_html(root, sha256,
                                                                                              run_settings),
        file_name=f"{sha256[:8]}_{shown_id}_report.html", mime="text/html", key=widget_key("download_report", index),
        help="One self-contained HTML file (works offline), as `solarnav report`: the flight, its streams, the "
             "calibration, each estimator's verdict, the comparison, the track and the autopilot parameters; the "
             "log is replayed with this run's settings when you click (a few seconds).")
