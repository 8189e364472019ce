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
from functools import partial
from pathlib import Path

import plotly.graph_objects as go
import streamlit as st

from app import adapters, figures, time_range
from app.workspace import LogEntry, Stored, Workspace
from ingest.errors import InputError
from ingest.flightlog import FlightLog

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


# ---------------------------------------------------------------------------------------------------- time range
#: Plotly mode-bar buttons removed from the time charts: their zoom and pan would move one chart only.
LOCAL_ZOOM_BUTTONS = ("zoom2d", "pan2d", "lasso2d", "zoomIn2d", "zoomOut2d", "autoScale2d")


def time_range_slider(range_key: str, span: tuple[float, float], help_text: str,
                      owner: object = None) -> tuple[float, float]:
    """The page's shared time range [s since start] (:mod:`app.time_range`): a slider keyed ``range_key`` over
    ``span`` with a *Full span* button; a box dragged on any :func:`time_chart` of the page sets it too.

    The range belongs to ``owner`` (default: the selected log's SHA-256; a page of runs or of several logs passes
    them too): another owner starts on the full span (:func:`app.time_range.owned_range`)."""
    time_range.owned_range(st.session_state, range_key, selected_sha256() if owner is None else owner, span)
    left, right = st.columns([6, 1], vertical_alignment="bottom")
    right.button("Full span", key=f"{range_key}_reset", on_click=time_range.reset_range,
                 args=(st.session_state, range_key, span), disabled=st.session_state[range_key] == span,
                 help="Show the whole log again on every time chart of the page.")
    return left.slider("Time range [s since log start]", *span, step=time_range.STEP_S, format="%.2f",
                       key=range_key, help=f"{help_text} Drag across any time chart to zoom all of them to that "
                                           "range; *Full span* resets it.")


def time_chart(fig: go.Figure, key: str, range_key: str, span: tuple[float, float], container=st) -> None:
    """Draw a time chart of the page (x: seconds since start) on which a horizontal box drag sets the page's
    range ``range_key`` (:func:`app.time_range.take_box_selection`), so every chart of the page follows; a
    chart showing part of the log says so on its time axis (:func:`app.time_range.partial_text`)."""
    figures.note_partial(fig, time_range.partial_text(st.session_state.get(range_key), span))
    fig.update_layout(dragmode="select", selectdirection="h")
    container.plotly_chart(fig, key=key, selection_mode="box",
                           on_select=partial(time_range.take_box_selection, st.session_state, key, range_key, span),
                           config={"modeBarButtonsToRemove": list(LOCAL_ZOOM_BUTTONS), "displaylogo": False})
