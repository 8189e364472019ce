"""Per-session helpers shared by the pages: the workspace, the selected log, and how bad input is shown.

The workspace root comes from ``--workspace DIR`` after the script arguments separator
(``streamlit run app/dashboard.py -- --workspace DIR``, which ``solarnav dashboard`` uses), else from the
``SOLARNAV_WORKSPACE`` environment variable, else ``./workspace``.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import streamlit as st

from app import adapters
from app.workspace import LogEntry, Stored, Workspace
from ingest import FlightLog, InputError

WORKSPACE_ENV = "SOLARNAV_WORKSPACE"
DEFAULT_WORKSPACE = "workspace"
#: Session-state key of the selected log's SHA-256 (the sidebar picker's widget key).
LOG_KEY = "log_sha256"
#: Session-state key a page sets to open another log on the next run (the picker cannot change mid-run).
PENDING_LOG_KEY = "_open_log_sha256"
#: Widget key of the Home page's table of stored logs (its hidden ``sha256`` column identifies the rows).
LOGS_TABLE_KEY = "logs_table"


def workspace_root(argv: Sequence[str] | None = None) -> Path:
    """Absolute workspace directory from the script arguments, the environment or the default."""
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--workspace")
    args, _ = parser.parse_known_args(sys.argv[1:] if argv is None else argv)
    return Path(args.workspace or os.environ.get(WORKSPACE_ENV) or DEFAULT_WORKSPACE).resolve()


def root() -> str:
    """The workspace root as the string every cached adapter takes."""
    return str(workspace_root())


def workspace() -> Workspace:
    """This server's workspace (bundled samples added on first start)."""
    return adapters.open_workspace(root())


def open_log(sha256: str) -> None:
    """Select ``sha256`` in the log picker and rerun the page."""
    st.session_state[PENDING_LOG_KEY] = sha256
    st.rerun()


def open_selected_row() -> None:
    """Callback of the Home page's log table: open the log of the row just selected."""
    rows = st.session_state[LOGS_TABLE_KEY].selection.rows
    if rows:
        entries = workspace().list_logs()
        if rows[0] < len(entries):
            st.session_state[PENDING_LOG_KEY] = entries[rows[0]].sha256


def log_picker(entries: list[LogEntry], default_sha256: str | None) -> str | None:
    """Sidebar select box of the workspace's logs; returns the selected SHA-256 (None for an empty workspace)."""
    if PENDING_LOG_KEY in st.session_state:
        st.session_state[LOG_KEY] = st.session_state.pop(PENDING_LOG_KEY)
    names = {entry.sha256: f"{entry.display_name} ({entry.sha256[:8]})" for entry in entries}
    if not names:
        st.sidebar.info("The workspace is empty: upload a log on the Home page.")
        return None
    if st.session_state.get(LOG_KEY) not in names:
        st.session_state[LOG_KEY] = default_sha256 if default_sha256 in names else next(iter(names))
    return st.sidebar.selectbox("Flight log", list(names), format_func=names.get, key=LOG_KEY)


@contextmanager
def input_errors(*, stop: bool = True) -> Iterator[None]:
    """Show bad user input (:class:`~ingest.errors.InputError`) as an error box, never a traceback.

    Parameters
    ----------
    stop : bool
        Stop the page after the message (default); otherwise skip the rest of the ``with`` block and go on.
    """
    try:
        yield
    except InputError as exc:
        st.error(f"This file cannot be used: {exc}")
        if stop:
            st.stop()


def selected_sha256() -> str | None:
    """SHA-256 of the log selected in the sidebar (None when the workspace is empty)."""
    return st.session_state.get(LOG_KEY)


def require_log() -> FlightLog:
    """The selected log, parsed (cached); stops the page with a hint when there is none or it cannot be read."""
    sha256 = selected_sha256()
    if sha256 is None:
        st.info("No flight log selected: upload one on the Home page.")
        st.stop()
    with input_errors():
        return adapters.stored_log(root(), sha256)


def markdown_text(text: str) -> str:
    """``text`` with Markdown's special characters escaped (names shown in messages stay plain text)."""
    return re.sub(r"([\\`*_{}\[\]()<>#+\-.!|~$:])", r"\\\1", str(text))


def stored_message(stored: Stored, what: str) -> None:
    """Tell the user that ``what`` was stored as ``stored.name``, or was already stored under that name."""
    text = markdown_text(stored.message(what))
    if stored.created:
        st.success(text)
    else:
        st.info(text)


def save_calibration(sha256: str, settings: dict, calibration_json: str) -> Stored:
    """Store a calibration of the log (unless one with the same settings is stored) and say under which name."""
    stored = workspace().store_calibration(sha256, settings, calibration_json)
    stored_message(stored, "calibration")
    return stored
