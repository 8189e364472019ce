"""Streamlit entrypoint of the solarnav dashboard: page frame, workspace, log picker and navigation.

Run with ``solarnav dashboard [--workspace DIR] [--port N]`` or ``streamlit run app/dashboard.py [-- --workspace
DIR]`` from the repository root (where ``.streamlit/config.toml`` sets the upload limit).
"""

import streamlit as st

from app import adapters, session

st.set_page_config(page_title="solarnav", page_icon=":sunny:", layout="wide")

samples = adapters.bundled_logs(session.root())
main_sample = max(samples, key=lambda entry: entry.size_bytes, default=None)  # the full mission opens first
st.sidebar.title("solarnav")
session.log_picker(session.workspace().list_logs(), main_sample.sha256 if main_sample else None)
st.sidebar.caption(f"Workspace: `{session.root()}`")

pages = [
    st.Page("views/home.py", title="Home", icon=":material/home:", default=True),
    st.Page("views/overview.py", title="Overview", icon=":material/flight:"),
    st.Page("views/calibration.py", title="Calibration", icon=":material/tune:"),
    st.Page("views/estimators.py", title="Estimators", icon=":material/compare_arrows:"),
    st.Page("views/compare_logs.py", title="Compare logs", icon=":material/stacked_line_chart:"),
    st.Page("views/map.py", title="Map", icon=":material/map:"),
    st.Page("views/sun.py", title="Sun vector", icon=":material/wb_sunny:"),
    st.Page("views/workspace.py", title="Workspace", icon=":material/inventory_2:"),
    st.Page("views/fleet.py", title="Fleet", icon=":material/dataset:"),
]
st.navigation(pages).run()
