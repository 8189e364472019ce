"""Compare logs: the same estimator across several logs of the workspace, each with one of its stored runs:
attitude, errors and wind overlaid over the time since each log's start, and the RMS table of every log with its
difference to a baseline log, like for like only: a log against another reference than the baseline's (onboard
estimate vs ground truth) gets no improved / regressed verdict, and a sentence says why (issue 34). Its other view:
the autopilot parameters that differ between two logs, grouped by prefix, and each flight's onboard noise
parameters next to solarnav's (as ``solarnav params``; docs/workflows.md, 'Parameter diff')."""

import streamlit as st

from app import adapters, comparison, figures, session, tables
from calib.export import read_calibration
from estimators.api import ESTIMATORS
from ingest.errors import InputError
from workflows.params import ADDED, CHANGED, REMOVED, autopilot_of, diff_parameters, noise_parameter_table

#: Most logs overlaid at once (the parsed logs and comparisons of that many stay cached: app.adapters).
MAX_LOGS = 4
ESTIMATOR_KEY, LOGS_KEY, BASELINE_KEY, PANEL_KEY, RANGE_KEY = (
    "cmp_estimator", "cmp_logs", "cmp_baseline", "cmp_panel", "cmp_time_range")
CHARTS = {"Attitude": comparison.STATE_PANELS["Attitude"], "Errors": comparison.ERROR_ROWS,
          "Wind": comparison.STATE_PANELS["Wind"]}
#: Why a chart's row may have no value in any log.
MISSING_WHY = {"Attitude": "", "Errors": comparison.MISSING_ERRORS_WHY, "Wind": comparison.MISSING_WIND_WHY}
ESTIMATES_VIEW, PARAMETERS_VIEW = "Estimates across logs", "Parameters between two logs"

root = session.root()
workspace = session.workspace()
st.title("Compare logs")


def solarnav_noise(sha256: str) -> tuple[object, str]:
    """(calibration, where it comes from) of a log for its noise table: its newest saved calibration (which may hold
    identified noise), else the automatic calibration; (None, why) when the log cannot be calibrated."""
    saved = workspace.list_calibrations(sha256)
    if len(saved):
        newest = saved.iloc[0]
        return read_calibration(workspace.calibration_path(newest["calib_id"])), f"saved calibration {newest['name']}"
    try:
        return adapters.calibration(root, sha256, None, (), "sigma"), "automatic calibration (Calibration page)"
    except InputError as exc:
        return None, f"not calibrated: {exc}"


def parameter_view(entries: dict) -> None:
    """The parameter diff of two workspace logs (changed, added, removed; grouped by prefix) and, per log, the
    onboard estimator's noise parameters next to solarnav's values for that flight in the same units."""
    if len(entries) < 2:
        st.info("Add a second log to the workspace (Home page) to compare its parameters.")
        return
    names = {sha256: f"{entry.display_name} ({sha256[:8]})" for sha256, entry in entries.items()}
    left, right = st.columns(2)
    first = left.selectbox("Log A", list(names), format_func=names.get, key="cmp_params_a")
    second = right.selectbox("Log B", [sha256 for sha256 in names if sha256 != first], format_func=names.get,
                             key="cmp_params_b")
    logs = {sha256: adapters.stored_log(root, sha256) for sha256 in (first, second)}
    table = diff_parameters(logs[first].meta.parameters, logs[second].meta.parameters)
    counts = table["change"].value_counts()
    st.markdown(f"**{counts.get(CHANGED, 0)} changed, {counts.get(ADDED, 0)} added (only in B), "
                f"{counts.get(REMOVED, 0)} removed (only in A)** of {len(logs[first].meta.parameters)} / "
                f"{len(logs[second].meta.parameters)} parameters (compared at float32 precision).")
    if len(table):
        groups = list(dict.fromkeys(table["group"]))
        shown = st.multiselect("Groups", groups, default=groups, key=f"cmp_params_groups_{first}_{second}",
                               help="Parameter prefixes (EKF2_, EK3_, SENS_, CAL_, ...).")
        st.dataframe(table[table["group"].isin(shown)].rename(columns={"value_a": "A", "value_b": "B"}),
                     hide_index=True, key="cmp_params_diff", width="stretch")
        st.download_button("Parameter diff (.csv)", table.to_csv(index=False), file_name="parameter_diff.csv",
                           mime="text/csv", key="cmp_params_download")
    st.subheader("Onboard noise parameters vs solarnav's")
    st.caption("Per flight, its autopilot's estimator noise parameters (EKF2 for PX4, EKF3 for ArduPilot) next to the "
               "values solarnav calibrated or identified for the same flight, in the autopilot's units; ratio = "
               "solarnav / onboard. Identify the noise on the Calibration page and save it to use identified values.")
    for sha256, log in logs.items():
        cal, how = solarnav_noise(sha256)
        autopilot = "EKF3" if autopilot_of(log) == "ardupilot" else "EKF2"
        st.markdown(f"**{session.markdown_text(entries[sha256].display_name)}**: onboard {autopilot}; solarnav "
                    f"from the {session.markdown_text(how)}")
        st.dataframe(noise_parameter_table(log, cal), hide_index=True, key=f"cmp_params_noise_{sha256}",
                     width="stretch", column_config={"ratio": st.column_config.NumberColumn(format="%.2g")})


view = st.segmented_control("View", [ESTIMATES_VIEW, PARAMETERS_VIEW], default=ESTIMATES_VIEW, key="cmp_view")
if view == PARAMETERS_VIEW:
    parameter_view({entry.sha256: entry for entry in workspace.list_logs()})
    st.stop()
st.caption("One estimator across several logs, each with one of its stored runs: every chart starts each log at its "
           "own first IMU sample (time since log start), and the RMS table compares each log with a baseline log.")

estimator = st.selectbox("Estimator", list(ESTIMATORS), key=ESTIMATOR_KEY)
entries = {entry.sha256: entry for entry in workspace.list_logs()}
stored = {sha256: workspace.list_runs(sha256) for sha256 in entries}
with_runs = {sha256: comparison.runs_with(runs, estimator) for sha256, runs in stored.items()}
candidates = [sha256 for sha256, run_ids in with_runs.items() if run_ids]
if len(candidates) < 2:
    st.info(f"Fewer than two logs of the workspace have a stored run of {estimator}: run it on more logs on the "
            "**Estimators** page (or `solarnav replay`) to compare them.")
    st.stop()
log_names = {sha256: f"{entries[sha256].display_name} ({sha256[:8]})" for sha256 in candidates}
kept = [sha256 for sha256 in st.session_state.get(LOGS_KEY, []) if sha256 in log_names]
if not kept:  # the default: the log open in the sidebar and the next one with a run
    current = session.selected_sha256()
    kept = list(dict.fromkeys([current, *candidates] if current in log_names else candidates))[:2]
st.session_state[LOGS_KEY] = kept[:MAX_LOGS]
chosen = st.multiselect("Logs", list(log_names), format_func=log_names.get, key=LOGS_KEY, max_selections=MAX_LOGS,
                        help=f"Logs with a stored run of {estimator}; every chart overlays them, one colour per log.")
if len(chosen) < 2:
    st.info("Select at least two logs above.")
    st.stop()

# ------------------------------------------------------------------ one run per log
run_names = {sha256: comparison.run_names(stored[sha256]) for sha256 in chosen}
columns = st.columns(len(chosen))
picked = {}
for column, sha256 in zip(columns, chosen, strict=True):
    if st.session_state.get(f"cmp_run_{sha256}") not in with_runs[sha256]:  # a deleted run: the newest instead
        st.session_state[f"cmp_run_{sha256}"] = with_runs[sha256][0]
    picked[sha256] = column.selectbox(f"Run of {entries[sha256].display_name}", with_runs[sha256],
                                      format_func=run_names[sha256].get, key=f"cmp_run_{sha256}")
logs = {sha256: adapters.stored_log(root, sha256) for sha256 in chosen}
results = {sha256: adapters.run_comparison(root, sha256, run_id) for sha256, run_id in picked.items()}
log_runs = {sha256: figures.LogRun(entries[sha256].display_name, run_names[sha256][picked[sha256]],
                                   figures.time_base(logs[sha256]), {}) for sha256 in chosen}
labels = {sha256: log_run.label for sha256, log_run in log_runs.items()}

# ------------------------------------------------------------------ RMS per log against the baseline log
st.subheader(f"RMS errors of {estimator} (paper Table 2 layout)")
if st.session_state.get(BASELINE_KEY) not in chosen:
    st.session_state[BASELINE_KEY] = chosen[0]
baseline = st.selectbox("Baseline log", chosen, format_func=log_names.get, key=BASELINE_KEY,
                        help="The RMS table gives every log's difference to this log's run.")
without = [labels[sha256] for sha256, result in results.items() if result.reference is None]
if without:
    st.warning("No ground truth and no onboard estimate, so no errors, in: " + ", ".join(without) + ".")
references = {labels[sha256]: result.reference for sha256, result in results.items()}
deltas = comparison.log_rms_comparison({labels[sha256]: adapters.rms_table(root, sha256, run_id)
                                        for sha256, run_id in picked.items()}, estimator, labels[baseline],
                                       references)
for reference in dict.fromkeys(ref for ref in references.values() if ref is not None):  # what each RMS means
    named = ", ".join(label for label, ref in references.items() if ref == reference)
    st.markdown(f"**{session.markdown_text(named)}**: {comparison.reference_sentence(reference)}")
st.caption(f"RMS (difference to the baseline **{labels[baseline]}**, in the quantity's unit and in % of the "
           f"baseline's RMS, only between logs against the same reference); ▼ green improved, ▲ red regressed, ≈ "
           f"within {comparison.RMS_CHANGE_TOLERANCE_PCT:g} %.")
other_reference = comparison.other_reference_text(references, labels[baseline])
if other_reference:
    st.info(other_reference)
if len(deltas):
    st.table(tables.rms_delta_style(deltas, labels[baseline]))


# ------------------------------------------------------------------ overlaid charts
@st.fragment
def overlay_plots() -> None:
    """Attitude, errors or wind of the estimator in every chosen log, over the time since each log's start."""
    panel = st.segmented_control("Show", list(CHARTS), default="Attitude", key=PANEL_KEY) or "Attitude"
    span = (0.0, max(figures.time_span(log)[1] for log in logs.values()))
    window = session.time_range_slider(RANGE_KEY, span, "Every chart shows this range of time since each log's "
                                       "start, with the samples in it at full resolution.",
                                       owner=tuple(picked.items()))
    frames = {sha256: comparison.without_absent_airspeed(result.errors if panel == "Errors" else result.quantities,
                                                         logs[sha256]) for sha256, result in results.items()}
    overlaid = [figures.LogRun(log_run.log_name, log_run.run_name, log_run.time_base, frames[sha256])
                for sha256, log_run in log_runs.items()]
    drawn, _, _ = figures.overlay_log_sources(overlaid, estimator)
    missing = comparison.missing_rows_text(drawn, CHARTS[panel], MISSING_WHY[panel])
    if not figures.rows_with_data(drawn, CHARTS[panel]):
        st.info(missing)
        return
    title = f"{panel}: {estimator} across logs"
    session.time_chart(figures.overlay_logs_figure(overlaid, estimator, CHARTS[panel], title=title, window=window),
                       "cmp_chart", RANGE_KEY, span)
    if missing:
        st.caption(missing)


st.subheader("Comparison")
overlay_plots()
