"""Workspace: the stored logs, calibrations and runs by name; rename or delete one (deleting asks to confirm)."""

import pandas as pd
import streamlit as st

from app import session
from app.workspace import NameRejected

#: Session-state key of the message of the last rename or delete, shown after the rerun that lists the result.
MESSAGE_KEY = "_workspace_message"
#: Widget keys.
ENTRY_KEY = "ws_entry"
RENAME_KEY = "ws_rename"
DELETE_KEY = "ws_delete"
KIND_LABELS = {"logs": "Log", "calibrations": "Calibration", "runs": "Run"}

st.title("Workspace")
st.caption("Everything stored in the workspace. Names are yours to change; deleting a log deletes its "
           "calibrations and runs with it.")
for kind, text in st.session_state.pop(MESSAGE_KEY, ()):
    (st.success if kind == "success" else st.error)(session.markdown_text(text))

workspace = session.workspace()
logs = workspace.list_logs()
calibrations = workspace.list_calibrations()
runs = workspace.list_runs()
log_names = {entry.sha256: entry.display_name for entry in logs}


def _count(table: pd.DataFrame, sha256: str) -> int:
    return int((table["log_sha256"] == sha256).sum()) if len(table) else 0


st.subheader("Logs")
st.dataframe(pd.DataFrame({
    "name": [entry.display_name for entry in logs],
    "size [MB]": [round(entry.size_bytes / 1e6, 2) for entry in logs],
    "added (UTC)": [entry.added_utc for entry in logs],
    "calibrations": [_count(calibrations, entry.sha256) for entry in logs],
    "runs": [_count(runs, entry.sha256) for entry in logs],
    "sha256": [entry.sha256[:12] for entry in logs],
}), hide_index=True, key="ws_logs_table")


def _entries(table: pd.DataFrame, key: str) -> pd.DataFrame:
    return pd.DataFrame({
        "name": table["name"].to_numpy(dtype=object),
        "log": [log_names.get(sha, sha[:12]) for sha in table["log_sha256"]],
        "created (UTC)": table["created_utc"].to_numpy(dtype=object),
        "id": table[key].to_numpy(dtype=object),
    })


st.subheader("Calibrations")
if len(calibrations):
    st.dataframe(_entries(calibrations, "calib_id"), hide_index=True, key="ws_calibrations_table")
else:
    st.caption("No saved calibrations: save one on the Calibration page.")
st.subheader("Runs")
if len(runs):
    st.dataframe(_entries(runs, "run_id"), hide_index=True, key="ws_runs_table")
else:
    st.caption("No estimator runs: run them on the Estimators page.")

# ------------------------------------------------------------------ rename and delete
st.subheader("Rename or delete")
names = {f"logs:{entry.sha256}": entry.display_name for entry in logs}
names |= {f"calibrations:{i}": name for i, name in zip(calibrations["calib_id"], calibrations["name"], strict=True)}
names |= {f"runs:{i}": name for i, name in zip(runs["run_id"], runs["name"], strict=True)}
if not names:
    st.info("The workspace is empty: upload a log on the Home page.")
    st.stop()
if st.session_state.get(ENTRY_KEY) not in names:
    st.session_state.pop(ENTRY_KEY, None)
choice = st.selectbox("Entry", list(names), key=ENTRY_KEY,
                      format_func=lambda option: f"{KIND_LABELS[option.split(':')[0]]}: {names[option]}")
kind, entry_id = choice.split(":", 1)
name = names[choice]

left, right = st.columns(2)
name_key = f"ws_name_{choice}"
new_name = left.text_input("New name", value=name, key=name_key, max_chars=200)
if left.button("Rename", key=RENAME_KEY):
    try:
        stored = workspace.rename(kind, entry_id, new_name)
    except NameRejected as exc:
        st.error(session.markdown_text(f"Not renamed: {exc}."))
    except KeyError:
        st.error("Not renamed: the entry is gone (deleted in another session).")
    else:
        st.session_state[MESSAGE_KEY] = [("success", f"Renamed \u201c{name}\u201d to \u201c{stored}\u201d.")]
        del st.session_state[name_key]  # the box shows the name stored (sanitised), not the one typed
        st.rerun()

if kind == "logs":
    cascade = f" with its {_count(calibrations, entry_id)} calibration(s) and {_count(runs, entry_id)} run(s)"
else:
    cascade = ""
confirmed = right.checkbox(f"Yes, delete \u201c{name}\u201d{cascade}", key=f"ws_confirm_{choice}")
if right.button("Delete", key=DELETE_KEY, disabled=not confirmed, type="primary") and confirmed:
    deleted = workspace.delete(kind, entry_id)
    st.session_state[MESSAGE_KEY] = [("success", f"Deleted \u201c{name}\u201d{cascade}.") if deleted
                                     else ("error", f"\u201c{name}\u201d was already deleted.")]
    st.rerun()
