"""Estimators: run the three EKFs (choice of estimators, heading aid, noise) with progress, and compare them with
the onboard estimate and the ground truth: states, errors, the RMS table (paper Table 2), innovations and NIS."""

import pandas as pd
import streamlit as st

from app import adapters, comparison, figures, runs, session, tables
from estimators.api import DEFAULT_ESTIMATORS, ESTIMATORS, UNTRUSTED_PREFIX
from estimators.inputs.records import HEADING_SOURCES

RUN_KEY = "est_run"
RANGE_KEY = "est_time_range"
HEADING_LABELS = {"mag": "magnetometer", "sun": "sun vector", "mag+sun": "both"}

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
saved = list(workspace.list_calibrations(sha256)["calib_id"])
noise_labels = {runs.DEFAULT_NOISE: "default R (datasheet noise)",
                runs.AUTO_CALIBRATION: "calibrated R (automatic calibration of this log)",
                **{calib_id: f"saved calibration {calib_id}" for calib_id in saved}}
headings = HEADING_SOURCES if log.has("sun") else ("mag",)
with st.form("run_form"):
    chosen = st.multiselect("Estimators", list(ESTIMATORS), default=list(DEFAULT_ESTIMATORS), key="est_names")
    left, right = st.columns(2)
    heading = left.radio("Heading aid", headings, format_func=HEADING_LABELS.get, horizontal=True,
                         key="est_heading", help=None if log.has("sun") else "the log has no sun-device data")
    noise = right.radio("Measurement noise", list(noise_labels), format_func=noise_labels.get, key="est_noise")
    force = st.checkbox("Run despite refused inputs", value=False, key="est_force", disabled=not refused,
                        help="replay a log whose inputs the estimators refuse (solarnav replay --force)")
    submitted = st.form_submit_button("Run estimators", type="primary")
if submitted:
    settings = runs.RunSettings(estimators=tuple(chosen), heading=heading, noise=noise,
                                allow_untrusted=bool(force and refused))
    run_id = runs.find_run(workspace, sha256, settings)
    if run_id is None:
        bar = st.progress(0.0, text="Preparing ...")
        with session.input_errors():
            calibration = adapters.run_calibration(root, sha256, noise)
            run_id = runs.replay_and_store(workspace, sha256, log, settings, calibration,
                                           progress=lambda fraction, text: bar.progress(fraction, text=text))
        bar.empty()
        st.toast(f"Run {run_id} stored in the workspace.")
    else:
        st.info("A run with these settings is stored already: showing it.")
    st.session_state[RUN_KEY] = run_id

stored = workspace.list_runs(sha256)
if stored.empty:
    st.info("No estimator run for this log yet: choose the settings above and press **Run estimators**.")
    st.stop()
labels = dict(zip(stored["run_id"], tables.runs_table(stored, workspace.list_logs()).apply(
    lambda row: f"{row['created (UTC)']} · {row['estimators']} · heading {row['heading aid']} · {row['R']}",
    axis=1), strict=True))
if st.session_state.get(RUN_KEY) not in labels:
    st.session_state[RUN_KEY] = next(iter(labels))
run_id = st.selectbox("Run", list(labels), format_func=labels.get, key=RUN_KEY)
report = adapters.run_report(root, run_id)
result = adapters.run_comparison(root, sha256, run_id)

untrusted = dict.fromkeys(w for facts in report.values() for w in facts["warnings"] if w.startswith(UNTRUSTED_PREFIX))
for warning in untrusted:  # a forced run's refused inputs, once for all estimators, never collapsed
    st.error(warning)
for name, facts in report.items():
    # inconsistent channels of a calibrated run are never hidden in the collapsed details
    for warning in facts["warnings"]:
        if "inconsistent" in warning:
            st.warning(warning)
    with st.expander(f"{name}: used {', '.join(facts['used']) or 'nothing'}; "
                     f"{facts['timings_s'].get('total', float('nan')):.1f} s"):
        for reason in (*[f"skipped {k}: {v}" for k, v in facts["skipped"].items()], *facts["degradations"],
                       *facts["warnings"]):
            st.warning(reason)
        if facts["details"].get("calibration"):
            st.caption("Calibrated figures: source and what this estimator did with each")
            st.dataframe(pd.DataFrame(facts["details"]["calibration"]), hide_index=True, key=f"calibration_{name}")
        st.json(facts["details"], expanded=False)

st.subheader("RMS errors (paper Table 2 layout)")
if result.reference is None:
    st.warning("The log has neither ground truth nor an onboard estimate: errors cannot be computed.")
else:
    st.caption(f"Against the {'ground truth' if result.reference == 'truth' else 'onboard estimate (no truth)'};"
               " position = horizontal distance, wind = horizontal vector difference, course where ground speed "
               f">= {comparison.MIN_COURSE_SPEED_M_S:g} m/s.")
    st.table(adapters.rms_table(root, sha256, run_id).style.format("{:.2f}", na_rep="–"))

PANELS = {
    "Attitude": [("roll_deg", "roll [deg]"), ("pitch_deg", "pitch [deg]"), ("yaw_deg", "yaw [deg]")],
    "Altitude and speeds": [("alt_m", "altitude [m]"), ("ground_speed_m_s", "ground speed [m/s]"),
                            ("course_deg", "course [deg]"), ("airspeed_m_s", "airspeed [m/s]")],
    "Wind": [("wind_n_m_s", "wind north [m/s]"), ("wind_e_m_s", "wind east [m/s]")],
}
INNOVATIONS = "Innovations and NIS"
ERROR_ROWS = [(column, f"{label.split(' (')[0].lower()} error [{unit}]")
              for column, (label, unit) in comparison.QUANTITIES.items()]


@st.fragment
def comparison_plots() -> None:
    """One view at a time: states of every source, their errors against the reference, or the innovations and NIS
    (only the view shown is computed; reruns alone on a change)."""
    panel = st.segmented_control("Show", [*PANELS, "Track", "Errors", INNOVATIONS], default="Attitude",
                                 key="est_panel")
    span = figures.time_span(log)
    st.session_state[RANGE_KEY] = figures.clamp_window(st.session_state.get(RANGE_KEY), span)
    window = st.slider("Time range [s since log start]", *span, step=0.01, format="%.2f", key=RANGE_KEY,
                       help="Every time chart below shows this range, with the samples in it at full resolution "
                            "and the y axes fitted to them (the track: the part flown in it).")
    if panel == INNOVATIONS:
        innovation_plots(window)
    elif panel == "Track":
        tracks = {name: frame for name, frame in result.quantities.items() if frame["north_m"].notna().any()}
        if tracks:
            st.plotly_chart(figures.track_figure(tracks, time_base=clock, window=window), key="est_track")
        else:
            st.info("No position to draw: the log has no GPS fix (the local NED origin).")
    elif panel == "Errors":
        if not result.errors:
            st.info("No reference to compute errors against.")
        else:
            st.plotly_chart(figures.quantity_figure(result.errors, ERROR_ROWS,
                                                    title=f"Errors against the {result.reference}",
                                                    time_base=clock, window=window), key="est_errors")
    elif panel is not None:
        st.plotly_chart(figures.quantity_figure(result.quantities, PANELS[panel], title=panel, time_base=clock,
                                                window=window), key="est_states")


def innovation_plots(window: tuple[float, float]) -> None:
    """Consistency summary, then the innovations and NIS of one estimator's sensor."""
    summary = adapters.nis_summary(root, run_id)
    st.dataframe(tables.verdict_style(tables.with_nis_verdicts(summary)), hide_index=True, key="nis_summary",
                 column_config={"why": st.column_config.TextColumn("why", width="large")})
    left, middle, right = st.columns(3)
    estimator = left.selectbox("Estimator", list(report), key="est_diag_estimator")
    sensor = middle.selectbox("Sensor", list(summary.loc[summary["estimator"] == estimator, "sensor"]),
                              key="est_diag_sensor")
    nis_window = right.select_slider("NIS window [updates]", [10, 20, 50, 100, 200, 500], value=50,
                                     key="est_window")
    if sensor is None:
        st.info(f"{estimator} fused no measurement.")
        return
    rows = adapters.sensor_diagnostics(root, run_id, estimator, sensor)
    units = {str(c): comparison.innovation_unit(sensor, str(c)) for c in rows["component"].unique()}
    st.plotly_chart(figures.innovation_figure(rows, units, title=f"{estimator}: {sensor} innovations",
                                              time_base=clock, window=window), key="est_innovations")
    st.plotly_chart(figures.nis_figure(adapters.moving_nis(root, run_id, estimator, sensor, nis_window),
                                       nis_window, comparison.nis_band(nis_window),
                                       title=f"{estimator}: {sensor} NIS", time_base=clock, time_window=window),
                    key="est_nis")


st.subheader("Comparison")
comparison_plots()

st.subheader("Download")
st.caption("Each table keeps the log-clock `time_s` and adds `time_since_start_s` (seconds since the log start).")
columns = st.columns(4)
for k, (table, suffix) in enumerate([(t, s) for t in ("states", "diagnostics") for s in ("parquet", "csv")]):
    columns[k].download_button(
        f"{table} (.{suffix})", lambda table=table, suffix=suffix: comparison.table_download(
            adapters.run_table(root, run_id, table), clock, suffix),
        file_name=f"{sha256[:8]}_{run_id}_{table}.{suffix}", key=f"download_{table}_{suffix}")
