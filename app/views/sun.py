"""sun page (being wired to the library)."""

import streamlit as st

from app import session

log = session.require_log()
st.title(f"sun: {log.meta.source}")
