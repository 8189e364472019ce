"""Home: the selected log at a glance, upload of new logs, and the workspace's past uploads and runs."""

import hashlib

import streamlit as st

from app import adapters, session, tables
from app.workspace import sanitize_name

#: Session-state key of the reader warnings of the upload just stored, shown after the rerun that opens it.
UPLOAD_WARNINGS_KEY = "_upload_warnings"

st.title("solarnav")
st.write("Upload a PX4 ULog (and optionally the sun-device log), check its streams, calibrate the sensors' noise "
         "from the flight itself, then re-run three EKFs and compare them with the autopilot and the truth.")

workspace = session.workspace()
sha256 = session.selected_sha256()
if sha256 is not None:
    entry = workspace.get_log(sha256)
    st.subheader(f"Open log: {entry.display_name if entry else sha256[:12]}")
    with session.input_errors(stop=False):  # an unreadable log must not hide the upload form
        log = adapters.stored_log(session.root(), sha256)
        columns = st.columns(4)
        columns[0].metric("Duration", tables.duration_text(log.meta.duration_s))
        columns[1].metric("Vehicle", tables.vehicle_name(log.meta.vehicle_type).split(" (")[0])
        columns[2].metric("Streams", len(log.meta.streams))
        columns[3].metric("Estimator runs", len(workspace.list_runs(sha256)))
        links = st.columns(4)
        links[0].page_link("views/overview.py", label="Overview: streams and track", icon=":material/flight:")
        links[1].page_link("views/calibration.py", label="Calibrate the sensors", icon=":material/tune:")
        links[2].page_link("views/estimators.py", label="Compare the estimators", icon=":material/compare_arrows:")
        links[3].page_link("views/sun.py", label="Sun vector", icon=":material/wb_sunny:")

st.subheader("Upload a flight")
# warnings of the upload just stored: kept across the rerun that opens it (as `solarnav info` prints them)
for warning in st.session_state.pop(UPLOAD_WARNINGS_KEY, ()):
    st.warning(warning)
limit_mb = st.get_option("server.maxUploadSize")
with st.form("upload", clear_on_submit=True):
    ulog_file = st.file_uploader(f"PX4 ULog or ArduPilot DataFlash log (.ulg, .bin, up to {limit_mb} MB)",
                                 type=["ulg", "bin"], key="upload_ulog")
    sun_file = st.file_uploader("Sun-device log (.csv, optional)", type=["csv"], key="upload_sun")
    device_file = st.file_uploader("Sun-device geometry (.json, optional)", type=["json"], key="upload_device")
    submitted = st.form_submit_button("Add to the workspace", type="primary")
if submitted:
    if ulog_file is None:
        st.warning("Choose a .ulg or .bin file first.")
    else:
        content = ulog_file.getvalue()
        sun_csv = sun_file.getvalue() if sun_file else None
        device_json = device_file.getvalue() if device_file else None
        name = sanitize_name(ulog_file.name)
        with session.input_errors(stop=False):  # nothing is stored unless every file is usable
            uploaded = adapters.validate_upload(content, name, sun_csv, device_json)
            known = workspace.get_log(hashlib.sha256(content).hexdigest())
            entry = workspace.add_log(content, name, sun_csv=sun_csv, device_json=device_json)
            st.session_state[UPLOAD_WARNINGS_KEY] = [f"{entry.display_name}: {warning}"
                                                     for warning in uploaded.meta.warnings]
            if known is not None:
                st.toast(f"{name} is already in the workspace (added {known.added_utc} as {known.display_name}).")
            session.open_log(entry.sha256)

st.subheader("Workspace")
st.caption("Every upload is stored under its content hash; calibrations and estimator runs are stored beside it "
           "and survive a restart. Select a row to open that log.")
st.page_link("views/workspace.py", label="Rename or delete logs, calibrations and runs",
             icon=":material/inventory_2:")
logs = tables.logs_table(workspace.list_logs(), workspace.list_runs())
st.dataframe(logs, hide_index=True, on_select=session.open_selected_row, selection_mode="single-row",
             key=session.LOGS_TABLE_KEY, column_config={"sha256": None})
stored_runs = workspace.list_runs()
runs = tables.runs_table(stored_runs, workspace.list_logs())
if len(runs):
    runs.insert(0, "name", stored_runs["name"].to_numpy(dtype=object))
    st.write("Estimator runs")
    st.dataframe(runs, hide_index=True)
else:
    st.caption("No estimator runs yet: run them on the Estimators page.")
