"""Fleet: the summary of a ``solarnav batch`` output directory (docs/batch.md, 'Fleet page'): the logs with
filters, per-vehicle noise trends with their change flags, estimator RMS distributions across the fleet,
parameter differences between logs, and a log opened on the other pages."""

from pathlib import Path

import streamlit as st

from app import session
from app.batch.figures import parameter_differences, rms_distribution_figure, trend_figure
from app.batch.summary import BATCHES_DIR, FLEET_FILE, read_summary
from app.batch.task import OK, TAU_COLUMN, noise_column
from app.comparison import QUANTITIES
from calib.calibration import SENSORS
from estimators.evaluation import REFERENCE_STREAMS

#: Widget keys.
DIR_KEY, VEHICLES_KEY, STATUS_KEY, FIGURE_KEY, RMS_KEY, COMPARE_KEY, OPEN_KEY = (
    "fleet_dir", "fleet_vehicles", "fleet_status", "fleet_figure", "fleet_rms", "fleet_compare", "fleet_open")
#: Columns of the log table, when present.
TABLE_COLUMNS = ("name", "vehicle", "utc_start", "duration_s", "firmware", "estimator", "status", "message",
                 "noise_flags", "tau", "wall_s")

st.title("Fleet")
st.caption("Many logs processed by `solarnav batch`: open its output directory.")
found = sorted(str(path.parent) for path in (Path(session.root()) / BATCHES_DIR).glob(f"*/{FLEET_FILE}"))
if DIR_KEY not in st.session_state and found:
    st.session_state[DIR_KEY] = found[-1]
outdir = st.text_input("Batch output directory", key=DIR_KEY,
                       help=f"OUTDIR of `solarnav batch ... -o OUTDIR`; the workspace's batches: {', '.join(found)}"
                       if found else f"OUTDIR of `solarnav batch ... -o OUTDIR` (e.g. the workspace's "
                       f"{BATCHES_DIR}/NAME)")
if not outdir:
    st.info("No batch opened: run `solarnav batch LOGS... --calibrate --replay -o OUTDIR` and enter OUTDIR.")
    st.stop()
with session.input_errors():
    fleet, history = read_summary(outdir)

vehicles = sorted(v for v in fleet["vehicle"].dropna().unique() if v)
chosen = st.multiselect("Vehicles", vehicles, default=vehicles, key=VEHICLES_KEY)
statuses = st.multiselect("Status", sorted(fleet["status"].unique()), default=sorted(fleet["status"].unique()),
                          key=STATUS_KEY)
shown = fleet[(fleet["vehicle"].isin(chosen) | (fleet["vehicle"] == "")) & fleet["status"].isin(statuses)]
logs = shown.drop_duplicates("file")
failed = int((logs["status"] != OK).sum())
st.metric("Logs", len(logs), help=f"{failed} failed" if failed else None)
st.dataframe(shown[[c for c in TABLE_COLUMNS if c in shown]], hide_index=True, key="fleet_table")

st.subheader("Noise per vehicle")
flagged = history[history["flagged"].astype(bool) & history["vehicle"].isin(chosen)]
for row in flagged.itertuples():
    st.warning(f"{session.markdown_text(row.vehicle)}: {session.markdown_text(row.name)}: {row.figure} noise "
               f"{row.ratio:.2f} x the median of the vehicle's earlier logs")
units = {sensor: SENSORS[sensor].unit for sensor in SENSORS if noise_column(sensor) in fleet}
figures = [*units, TAU_COLUMN] if TAU_COLUMN in fleet else list(units)
if figures:
    figure = st.selectbox("Figure", figures, index=figures.index("gyroscope") if "gyroscope" in figures else 0,
                          key=FIGURE_KEY)
    st.plotly_chart(trend_figure(history[history["vehicle"].isin(chosen)], figure, units.get(figure, "-")),
                    key="fleet_trend")
else:
    st.caption("The batch did not calibrate (`--calibrate`): no noise history.")

st.subheader("Estimators across the fleet")
rms_columns = {f"rms_{source}_{q}": f"RMS {label} against {source}" for source in REFERENCE_STREAMS
               for q, (label, _) in QUANTITIES.items() if f"rms_{source}_{q}" in fleet}
if rms_columns:
    column = st.selectbox("RMS", list(rms_columns), format_func=rms_columns.get, key=RMS_KEY)
    st.plotly_chart(rms_distribution_figure(shown, column, rms_columns[column]), key="fleet_rms_chart")
else:
    st.caption("The batch did not replay the estimators (`--replay`), or no log has a reference.")

good = logs[logs["status"] == OK]
labels = {row.sha256: f"{row.name} ({row.sha256[:8]})" for row in good.itertuples()}
st.subheader("Parameter differences")
pair = st.multiselect("Logs to compare", list(labels), format_func=labels.get, max_selections=4, key=COMPARE_KEY)
if len(pair) >= 2:
    differences = parameter_differences(outdir, good[good["sha256"].isin(pair)])
    if len(differences):
        st.dataframe(differences, key="fleet_params")
    else:
        st.caption("The logs have the same parameters.")

st.subheader("Open a log")
target = st.selectbox("Log", list(labels), format_func=labels.get, index=None, key=OPEN_KEY)
if target is not None and st.button("Open on the other pages"):
    row = good[good["sha256"] == target].iloc[0]
    companions = {key: Path(row[key]).read_bytes() if isinstance(row.get(key), str) else None
                  for key in ("sun_csv", "device_json")}
    entry = session.workspace().add_log(Path(row["file"]).read_bytes(), row["name"], **companions)
    st.session_state[session.PENDING_LOG_KEY] = entry.sha256
    st.switch_page("views/overview.py")
