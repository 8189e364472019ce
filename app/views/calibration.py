"""Calibration: pick the segment, set the FIR filters, and read the noise figures (paper Table 4, eq 50), the R
matrices (eq 51) with tau (eq 52), the Allan deviations, and download CALIB.json / the PX4 .params file."""

import hashlib
import threading
import time
from collections.abc import Callable

import numpy as np
import pandas as pd
import streamlit as st
from streamlit.runtime.scriptrunner import add_script_run_ctx, get_script_run_ctx

from app import adapters, figures, session, tables, time_range
from calib.calibration import SENSORS
from calib.figures import MEANING_LOWER_BOUND, MEANING_UPPER_BOUND
from calib.fir import frequency_response
from calib.tables import noise_meaning, noise_table, r_tables, table4
from calib.tau import TAU_GRID_POINTS, TAU_METHODS
from workflows.exports import calibration_text

TAU_CHOICES = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0)
TAU_MODE_LABELS = {"manual": "by hand", "likelihood": "auto: likelihood", "nis": "auto: mean NIS = 1"}
WINDOW_KEY = "calib_window"
#: Session key of the wish to identify the noise (outlives the toggle's own state, which a page switch drops).
TUNE_WANTED_KEY = "calib_tune_wanted"
#: Step of the window slider [s].
WINDOW_STEP_S = 0.1



@st.fragment(run_every=2.0)
def wait_for(job: adapters.IdentificationJob) -> None:
    """The identification's progress, redrawn every 2 s (only this fragment meanwhile); the page reruns when it is
    done."""
    if job.future.done():
        st.rerun()
    fraction, text = job.progress()
    st.progress(fraction, text=f"{text} (running for {time.monotonic() - job.started_s:.0f} s)")


def tau_progress(slot) -> Callable[[int], None]:
    """Draws the automatic tau's replays in ``slot`` (from the replays' threads): the grid's share, then the search."""
    script_context = get_script_run_ctx()

    def show(replays: int) -> None:
        add_script_run_ctx(threading.current_thread(), script_context)
        grid = min(replays, TAU_GRID_POINTS)
        slot.progress(grid / TAU_GRID_POINTS, text=f"Choosing tau: replay {replays} of the three-stage estimator "
                      f"({grid}/{TAU_GRID_POINTS} grid points" + (", then the search)" if replays > grid else ")"))

    return show


log = session.require_log()
root, sha256 = session.root(), session.selected_sha256()
clock = figures.time_base(log)
st.title(f"Calibration: {log.meta.source}")

# ------------------------------------------------------------------ segment
st.subheader("Segment")
candidates = adapters.candidate_segments(root, sha256)
automatic = st.radio("Segment", ["automatic", "window"], horizontal=True, key="calib_mode",
                     format_func={"automatic": "automatic (longest stationary, else steady, per sensor)",
                                  "window": "pick a window"}.get, label_visibility="collapsed") == "automatic"
if automatic and candidates.empty:
    st.warning("No stationary or steady segment was found automatically: pick a window.")
    automatic = False
span = figures.time_span(log)  # [s since start]


def take_box_selection() -> None:
    """Chart callback: a box dragged on the segment chart (seconds since start) becomes the window."""
    chosen = time_range.selected_window(st.session_state["calib_segment_chart"], span, step_s=WINDOW_STEP_S)
    if chosen is not None:
        st.session_state[WINDOW_KEY] = chosen
        st.session_state["calib_mode"] = "window"


# the page shows seconds since the log start; the calibration gets and stores the window on the log clock
window, empty_window = None, False
if WINDOW_KEY in st.session_state:  # a window of another log, kept in the session, brought inside this one
    kept = tuple(st.session_state[WINDOW_KEY])
    empty_here = kept[0] == kept[1] and span[0] <= kept[0] <= span[1]  # said so below, not widened silently
    if figures.clamp_window(kept, span) != kept and not empty_here:
        st.session_state[WINDOW_KEY] = figures.clamp_window(kept, span)
if not automatic:
    default = tuple(clock.since_start(candidates[["start_s", "end_s"]].iloc[0])) if len(candidates) else span
    shown_window = st.slider("Window [s since log start]", span[0], span[1], value=default, step=WINDOW_STEP_S,
                             key=WINDOW_KEY, format="%.1f", help="drag a box across the chart below to pick it")
    empty_window = shown_window[1] <= shown_window[0]
    if empty_window:
        st.error(f"The chosen window ({shown_window[0]:.1f} .. {shown_window[1]:.1f} s since the log start) is "
                 "empty: it has zero length. Choose a longer one: move the slider's ends apart or drag a box "
                 "across the chart below.")
    window = (clock.start_s + shown_window[0], clock.start_s + shown_window[1])
shaded = candidates if window is None else pd.DataFrame([("user", *window, "window")], columns=candidates.columns)
st.plotly_chart(figures.segment_figure(adapters.imu_norms(root, sha256), shaded, time_base=clock),
                key="calib_segment_chart", on_select=take_box_selection, selection_mode="box")
if automatic:
    st.dataframe(clock.shift(candidates, ["start_s", "end_s"]), hide_index=True, width="stretch", column_config={
        "start_s": st.column_config.NumberColumn("start [s since start]", format="%.1f"),
        "end_s": st.column_config.NumberColumn("end [s since start]", format="%.1f")})

if empty_window:  # nothing to calibrate on: the chart above stays to pick a window on
    st.stop()

# ------------------------------------------------------------------ filter settings and calibration
st.subheader("Filters and noise")
available = [name for name, channels in SENSORS.items() if log.has(channels.stream)]
requests = st.data_editor(
    tables.fir_editor_table(available, [log.meta.streams[SENSORS[name].stream].rate_hz for name in available],
                            log.meta.is_fixed_wing),
    hide_index=True, key="calib_fir", disabled=["sensor", "default"], placeholder="default", width="stretch",
    column_config={
        "default": st.column_config.TextColumn("default cutoff"),
        "cutoff_hz": st.column_config.NumberColumn("cutoff [Hz] (empty: default)", min_value=0.01),
        "numtaps": st.column_config.NumberColumn("taps (empty: default, odd)", min_value=1, step=2)})
fir_rows = tables.fir_rows(requests)
left, right = st.columns(2)
noise = left.radio("R from", ["sigma", "eta"], horizontal=True, key="calib_noise",
                   format_func={"sigma": "sigma (residual std, default)", "eta": "eta (eq 50, as the paper)"}.get)
tau_mode = right.radio("tau (eq 52: multiplies the accelerometer's body-y variance)", ["manual", *TAU_METHODS],
                       horizontal=True, key="calib_tau_mode", format_func=TAU_MODE_LABELS.get)
# the hand-set tau survives a detour through the automatic modes (their control is a different widget)
st.session_state["calib_tau"] = st.session_state.get("calib_tau", 1.0)
with session.input_errors():
    base = adapters.calibration(root, sha256, window, fir_rows, noise)
    selection = None
    if tau_mode != "manual":
        slot = st.empty()
        selection = adapters.auto_tau(root, sha256, window, fir_rows, noise, tau_mode, tau_progress(slot))
        slot.empty()
if selection is None:
    tau = right.select_slider("tau", TAU_CHOICES, key="calib_tau")
else:  # greyed, showing the tau actually in use
    tau = right.number_input("tau (in use, chosen automatically)", value=float(selection.tau), format="%.3g",
                             disabled=True)
current = adapters.with_tau_value(base, selection or tau) if selection or tau != base.tau.tau else base
meanings = {name: noise_meaning(base, name) for name in base.sensors}
upper = [name for name, meaning in meanings.items() if meaning == MEANING_UPPER_BOUND]
if upper:  # the figures that mislead most come first
    st.warning(f"The noise figures of {', '.join(upper)} are **upper bounds**: the segment is neither at rest nor in "
               "steady flight, so its motion and vibration count as noise. Pick a stationary or steady window for "
               "the sensor noise itself.")
lower = [name for name, meaning in meanings.items() if meaning == MEANING_LOWER_BOUND]
if lower:
    st.info(f"The noise figures of {', '.join(lower)} come from the vehicle at rest: **lower bounds** of the in-flight "
            "noise (no vibration).")
for warning in base.warnings:
    st.warning(warning)
for warning in tables.tau_warnings(selection) if selection is not None else ():
    st.warning(f"Automatic tau: {warning}")

SECTIONS = ("Noise and bias (Table 4)", "Filter and overlays", "R matrices and tau", "Allan deviation")


@st.fragment
def results() -> None:
    """One result section at a time (only the one shown is computed; reruns alone on a change)."""
    section = st.segmented_control("Show", SECTIONS, default=SECTIONS[0], key="calib_section")
    if section == SECTIONS[0]:
        st.dataframe(tables.flat_columns(table4(base)), key="calib_table4", width="stretch")
        st.caption("Paper Table 4 layout: eq 50 noise eta and bias beta, the residual sigma (per sample at the "
                   "stream's rate), its robust variant, and the physically referenced bias on a stationary segment. "
                   "Gyroscope figures are shown in deg/s on this page, as in the paper (CALIB.json and the .params "
                   "file are in SI: rad/s).")
        st.dataframe(clock.shift(tables.display_noise_table(noise_table(base).reset_index()),
                                 ["segment_start_s", "segment_end_s"]), hide_index=True,
                     key="calib_all_sensors", width="stretch", column_config={
                         "rate_hz": st.column_config.NumberColumn("rate [Hz]", format="%.1f"),
                         "cutoff_hz": st.column_config.NumberColumn("cutoff [Hz]", format="%.3g"),
                         "segment_start_s": st.column_config.NumberColumn("segment start [s since start]",
                                                                          format="%.1f"),
                         "segment_end_s": st.column_config.NumberColumn("segment end [s since start]",
                                                                        format="%.1f")})
    elif section == SECTIONS[1]:
        sensor = st.selectbox("Sensor", list(base.sensors), key="calib_sensor")
        cal = base.sensors[sensor]
        response = frequency_response(cal.fir)
        st.plotly_chart(figures.frequency_response_figure(response.freq_hz, response.gain_single,
                                                          response.gain_zero_phase, cal.fir.cutoff_hz))
        time_s, raw, filtered = adapters.raw_and_filtered(root, sha256, sensor, (cal.segment.start_s,
                                                                                 cal.segment.end_s),
                                                          cal.fir.fs_hz, cal.fir.cutoff_hz, cal.fir.numtaps)
        st.plotly_chart(figures.raw_filtered_figure(time_s, raw, filtered, cal.axes, cal.unit, time_base=clock))
        for warning in cal.warnings:
            st.info(f"{sensor}: {warning}")
    elif section == SECTIONS[2]:
        if selection is not None:
            st.plotly_chart(figures.tau_curve_figure(selection.log10_tau_grid, selection.neg_log_likelihood,
                                                     selection.mean_nis, selection.tau, selection.nis_band),
                            key="calib_tau_curve")
            st.caption(f"tau = {selection.tau:.3g}: mean NIS {selection.nis_at_tau:.3g} over "
                       f"{selection.n_innovations} innovations (95 % band {selection.nis_band[0]:.3g} .. "
                       f"{selection.nis_band[1]:.3g}), lag-1 autocorrelation {selection.lag1_autocorrelation:.2f}. "
                       f"{selection.note}")
        columns = st.columns(3)
        for k, (name, matrix) in enumerate(r_tables(current).items()):
            unit = current.sensors[name].unit if name in current.sensors else SENSORS[name].unit if name in SENSORS \
                else "-"
            shown, heading = tables.display_r_matrix(matrix, unit)
            columns[k % 3].write(f"**{name}** [{heading}]")
            columns[k % 3].dataframe(shown.style.format("{:.3e}"), key=f"calib_r_{name}", width="stretch")
        st.caption("Variances of eq 51; the gyroscope's in (deg/s)² as everywhere on this page (the exports are in "
                   "SI).")
    elif section == SECTIONS[3]:
        if not base.allan:
            st.info("No stationary segment: the Allan deviation needs the vehicle at rest (pick a stationary "
                    "window).")
        for name, curves in adapters.allan(root, sha256, window, fir_rows, noise).items():
            axes = base.sensors[name].axes
            curves, readoffs, unit = tables.display_allan(curves, list(base.allan[name]), base.sensors[name].unit)
            st.plotly_chart(figures.allan_figure(curves, readoffs, axes, tables.pretty_unit(unit), sensor=name),
                            key=f"allan_{name}")
            st.dataframe(tables.allan_table(readoffs, axes, tables.pretty_unit(unit)), hide_index=True,
                         key=f"allan_table_{name}", width="stretch")


st.subheader("Results")
results()

# ------------------------------------------------------------------ noise identification
st.subheader("Noise identified from the flight")
st.caption("Per estimator, the noise figures that maximise the likelihood of its own innovations, starting from "
           "the calibrated ones (`solarnav calibrate --tune`; docs/calibration.md, 'Noise identification'). "
           "Saved calibrations carry them; runs with such a calibration use each estimator's own figures.")
# the toggle's own state is dropped when the page is left: its wish is kept apart, so the page comes back to it
if "calib_tune" not in st.session_state:
    st.session_state["calib_tune"] = st.session_state.get(TUNE_WANTED_KEY, False)
st.session_state[TUNE_WANTED_KEY] = st.toggle("Identify noise (about a minute for 15 minutes of flight; it keeps "
                                              "running when you leave the page)", key="calib_tune")
if st.session_state[TUNE_WANTED_KEY]:
    digest = hashlib.sha256(calibration_text(current).encode()).hexdigest()
    job = adapters.identification(root, sha256, current, digest)
    if not job.future.done():
        st.info("Identifying the noise from the flight's innovations: it goes on if you leave this page; come back "
                "for it.")
        wait_for(job)
    elif job.future.exception() is not None:
        with session.input_errors():
            job.future.result()
    else:
        current = job.future.result()
        st.dataframe(tables.tuning_table(current), hide_index=True, key="calib_tuning_table", width="stretch")
        st.dataframe(tables.verdict_style(tables.tuning_nis_table(current)), hide_index=True,
                     key="calib_tuning_nis", width="stretch",
                     column_config={"why": st.column_config.TextColumn("why", width="large")})
        low, high = tables.NIS_WARNING_RANGE
        st.caption("Verdict of the tuned mean NIS: pass inside its 95 % chi-square band, warn outside it but "
                   f"within {low:g} .. {high:g}, fail beyond (the band ignores correlated innovations, so long logs "
                   "rarely pass). A figure on its search bound is flagged in 'meaning'.")

# ------------------------------------------------------------------ export
st.subheader("Export")
files = adapters.calibration_files(root, sha256, current)
st.caption("The autopilot files hold " + ("the noise identified for full_state_indirect (EKF2 and EKF3 are "
           "error-state filters like it)" if "full_state_indirect" in current.tuning else
           "the calibrated figures (identify the noise above for the identified ones)")
           + "; each file's header names the flight and the estimator (how to replay with them: "
             "docs/calibration.md, 'Replaying with the autopilot replay tools').")
columns = st.columns(len(files) + 1)
for column, (name, text) in zip(columns, files.items(), strict=False):
    label, mime = adapters.CALIBRATION_FILES[name]
    column.download_button(label, text, file_name=name, mime=mime, key=f"calib_download_{name}")
if columns[-1].button("Save in the workspace", key="calib_save"):
    fir_json = [[name, None if np.isnan(cutoff) else cutoff, taps] for name, cutoff, taps in fir_rows]
    settings = {"window_s": window, "fir": fir_json, "noise": noise, "tau": current.tau.tau,
                "tau_method": current.tau.method}
    session.save_calibration(sha256, settings, files["CALIB.json"])
