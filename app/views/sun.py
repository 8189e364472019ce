"""Sun vector: photocell currents, which cells are lit or faulty over time, the solved sun direction against the
one predicted from the ephemeris and the attitude, and their angle."""

from contextlib import nullcontext

import numpy as np
import pandas as pd
import streamlit as st

from app import adapters, figures, session, sun_compare
from estimators.evaluation import position_origin
from estimators.warmup import COMPILE_MESSAGE, SUN_SOLVER, cache_state
from ingest.sun_device import SunDevice

log = session.require_log()
root, sha256 = session.root(), session.selected_sha256()
clock = figures.time_base(log)
RANGE_KEY = "sun_time_range"
#: Set once the solver's kernel is known to be compiled in this session (the check reads the sources: 0.1 s).
SOLVER_READY_KEY = "sun_solver_ready"
st.title(f"Sun vector: {log.meta.source}")
if not log.has("sun"):
    st.info("This log has no sun-device data. Upload the photocell CSV (and its device JSON) together with the "
            ".ulg on the Home page to use the sun vector.")
    st.stop()

device = log.meta.sun_device
if device is None:
    st.info("No device geometry was given: the default device (45 deg side faces, aligned with the body) is used.")
    device = SunDevice()
azimuths = ", ".join(f"{a:g}" for a in device.azimuths_deg)
mounting = ", ".join(f"{a:g}" for a in device.mount_rpy_deg)
st.caption(f"Device: side faces tilted {device.tilt_deg:g} deg at azimuths {azimuths} deg; mounted at roll, pitch, "
           f"yaw {mounting} deg.")

ready = st.session_state.get(SOLVER_READY_KEY) or cache_state((SUN_SOLVER,)).warm
with session.input_errors(), nullcontext() if ready else st.spinner(f"{COMPILE_MESSAGE.capitalize()}: the "
                                                                   "sun-vector solver ..."):
    solution = adapters.sun_table(root, sha256)
st.session_state[SOLVER_READY_KEY] = True
st.caption(f"The solver's sky-light model used the up vector of the {solution.attrs.get('up_reference', 'level')} "
           "attitude ('level': none available).")
states = sun_compare.cell_states(solution, device)
solved = solution["status"] == "ok"
columns = st.columns(4)
columns[0].metric("Samples", f"{len(solution):,}")
columns[1].metric("Solved", f"{100 * solved.mean():.1f} %")
columns[2].metric("With a faulty cell", f"{100 * (states == sun_compare.CELL_FAULTY).any(axis=1).mean():.1f} %")
faulty_share = (states == sun_compare.CELL_FAULTY).mean(axis=0)
columns[3].metric("Most often faulty", f"cell {int(np.argmax(faulty_share)) + 1}" if faulty_share.any() else "none")

span = figures.time_span(log)
window = session.time_range_slider(RANGE_KEY, span, "Every time chart of the page shows this range, with the "
                                   "samples in it at full resolution and the y axes fitted to them.")


def time_chart(fig, key: str) -> None:
    """A time chart of the page: a box dragged across it sets the page's range (every chart follows)."""
    session.time_chart(fig, key, RANGE_KEY, span)


currents_ma = {f"cell {k + 1}": log["sun"][column] * 1e3 for k, column in enumerate(log["sun"].columns)}
time_chart(figures.time_series_figure(currents_ma, "current [mA]", title="Photocell currents", time_base=clock,
                                      window=window), "currents")
time_chart(figures.cell_state_figure(solution["time_s"].to_numpy(), states, sun_compare.CELL_STATE_NAMES,
                                     time_base=clock, window=window), "cells")
st.dataframe(pd.DataFrame({"cell": [f"cell {k + 1}" for k in range(states.shape[1])],
                           "lit [%]": 100 * (states == sun_compare.CELL_LIT).mean(axis=0),
                           "faulty [%]": 100 * faulty_share}).set_index("cell").T.round(1), key="cell_shares")
if not solved.all():
    st.warning("Epochs without a solution: " + ", ".join(f"{name} {count}" for name, count
                                                          in solution.loc[~solved, "status"].value_counts().items()))

st.subheader("Solved vs predicted")
sources = [source for source in ("truth", "onboard") if log.has(f"{source}_attitude")]
if position_origin(log) is None or log.meta.utc_offset_s is None:
    st.info("The prediction needs a GPS position and GPS time (for the ephemeris); this log lacks them.")
elif not sources:
    st.info("The prediction needs an attitude (ground truth or the autopilot's estimate); this log has neither.")
else:
    source = st.radio("Attitude for the prediction", sources, horizontal=True, key="sun_attitude",
                      format_func={"truth": "ground truth", "onboard": "onboard estimate"}.get)
    time_s = solution["time_s"].to_numpy(float)
    frames = {}
    for label, prefix in (("sun device", "sun"), (source, f"pred_{source}")):
        azimuth, elevation = sun_compare.body_angles_deg(solution[[f"{prefix}_{a}" for a in "xyz"]].to_numpy(float))
        frames[label] = pd.DataFrame({"time_s": time_s, "azimuth_deg": azimuth, "elevation_deg": elevation})
    time_chart(figures.quantity_figure(
        frames, [("azimuth_deg", "azimuth [deg]"), ("elevation_deg", "elevation [deg]")],
        title=f"Body-frame sun direction: photocells vs ephemeris + {source} attitude", time_base=clock,
        window=window), "sun_angles")
    error = solution.set_index("time_s")[f"angle_{source}_deg"].dropna()
    columns = st.columns(3)
    columns[0].metric("Median angle error", f"{error.median():.2f} deg")
    columns[1].metric("95th percentile", f"{error.quantile(0.95):.2f} deg")
    columns[2].metric("RMS", f"{np.sqrt((error**2).mean()):.2f} deg")
    time_chart(figures.time_series_figure({"sun device": error}, "angle to the prediction [deg]",
                                          title="Angular error", time_base=clock, window=window), "sun_error")
