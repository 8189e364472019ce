"""Names of calibrations and runs (issue 14): readable defaults, rename rules, equal settings stored once, delete
with its cascade and its crash safety, the migration of a catalog from before the names, and the Workspace page."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from app import workspace as workspace_module
from app.workspace import MAX_NAME_LENGTH, NameRejected, Workspace, sanitize_label, sanitize_name, shorten
from estimators.api import DEFAULT_ESTIMATORS
from tests.conftest import REPO_DIR

KINDS = ("logs", "calibrations", "runs")
CALIB = {"window_s": None, "fir": [["gyro", 5.0, 31]], "noise": "sigma", "tau": 0.2712, "tau_method": "likelihood"}
RUN = {"estimators": ["full_state_direct", "three_stage", "indirect"], "heading": "mag+sun", "noise": "calibrated",
       "rate_hz": 50.0, "allow_untrusted": False}


def _frames():
    states = pd.DataFrame({"estimator": ["full_state_direct"] * 2, "time_s": [0.0, 0.02], "roll_deg": [1.0, 2.0]})
    diagnostics = pd.DataFrame({"estimator": ["full_state_direct"], "sensor": ["gps"], "nis": [0.5]})
    return states, diagnostics


@pytest.fixture
def clock(monkeypatch):
    """The first entry (a log) added at 13:00 UTC, the next at 14:03, then 14:05, then 15:00."""
    times = iter(["2026-06-01T13:00:00+00:00", "2026-06-01T14:03:07+00:00", "2026-06-01T14:05:00+00:00"]
                 + ["2026-06-01T15:00:00+00:00"] * 50)
    monkeypatch.setattr(workspace_module, "_now_utc", lambda: next(times))


def _listed(root: Path) -> dict[str, set[str]]:
    with sqlite3.connect(root / "catalog.sqlite") as db:
        return {kind: {row[0] for row in db.execute(f"SELECT {key} FROM {kind}")}
                for kind, key in workspace_module._KINDS.items()}


def _assert_clean(root: Path) -> dict[str, set[str]]:
    """Every listed entry has its directory and nothing else is there; staging is empty. Returns the listing."""
    listed = _listed(root)
    for kind in KINDS:
        assert {path.name for path in (root / kind).iterdir()} == listed[kind], kind
    assert list((root / ".staging").iterdir()) == []
    return listed


def test_default_names_say_log_settings_and_time(tmp_path, clock):
    ws = Workspace(tmp_path / "ws")
    log = ws.add_log(b"paper", "paper.ulg")
    calib = ws.store_calibration(log.sha256, CALIB, "{}")
    run = ws.store_run(log.sha256, {**RUN, "noise": calib.id}, *_frames(), {})
    assert calib.created and calib.name == "paper.ulg \u00b7 calib auto-\u03c4 0.27 \u00b7 14:03"
    assert run.name == f"paper \u00b7 calib {calib.id[:6]} \u00b7 mag+sun \u00b7 14:05"  # log, noise, time
    assert Workspace(tmp_path / "ws").entry_name("calibrations", calib.id) == calib.name  # stored in the catalog
    runs = ws.list_runs(log.sha256)
    assert list(runs["name"]) == [run.name] and "name" in ws.list_calibrations().columns
    one = ws.store_run(log.sha256, {"estimators": ["indirect"], "heading": "mag", "noise": "default",
                                    "rate_hz": 25.0, "allow_untrusted": True}, *_frames(), {})
    assert one.name == "paper \u00b7 datasheet \u00b7 indirect \u00b7 25 Hz \u00b7 untrusted \u00b7 15:00"
    assert len(DEFAULT_ESTIMATORS) == workspace_module._DEFAULT_RUN_ESTIMATORS
    manual = ws.store_calibration(log.sha256, {**CALIB, "tau": 1.0, "tau_method": "user", "window_s": [12.5, 40],
                                               "noise": "eta"}, "{}")
    assert manual.name == "paper.ulg \u00b7 calib \u03c4 1 12.5\u201340 s eta \u00b7 15:00"


def test_default_names_fit_and_stay_distinct(tmp_path, clock):
    ws = Workspace(tmp_path / "ws")
    log = ws.add_log(b"long", "x" * 300 + ".ulg")
    first = ws.store_calibration(log.sha256, {**CALIB, "tau": 0.5}, "{}")
    ws.store_calibration(log.sha256, {**CALIB, "tau": 0.6}, "{}")  # 14:05
    names = [ws.store_calibration(log.sha256, {**CALIB, "tau": 0.5, "fir": [["gyro", 5.0, n]]}, "{}").name
             for n in range(3)]  # same name in short, same minute
    assert len(first.name) <= MAX_NAME_LENGTH and first.name.endswith("\u00b7 calib auto-\u03c4 0.5 \u00b7 14:03")
    assert names[1:] == [f"{names[0]} (2)", f"{names[0]} (3)"] and all(len(n) <= MAX_NAME_LENGTH for n in names)


def test_long_names_are_cut_between_words(tmp_path, clock):
    """Issue 34: upload names were shortened mid-word (``sample_logging_tagged_and_defau``)."""
    assert shorten("sample_logging_tagged_and_default_params", 31) == "sample_logging_tagged_and"
    assert shorten("Flug über Zürich", 12) == "Flug über" and shorten("x" * 30, 10) == "x" * 10
    assert sanitize_label("my best calibration of the long flight", 24) == "my best calibration of"
    assert sanitize_name("octo flight sixty one.ulg", max_length=20) == "octo flight.ulg"
    ws = Workspace(tmp_path / "ws")
    log = ws.add_log(b"long", "sample_logging_tagged_and_default_params_of_the_long_survey_flight.ulg")
    run = ws.store_run(log.sha256, {"estimators": ["indirect"], "heading": "mag+sun", "noise": "calibrated",
                                    "rate_hz": 25.0, "allow_untrusted": True}, *_frames(), {})
    head = run.name.split(" \u00b7 ")[0]
    assert log.display_name.startswith(head) and log.display_name[len(head)] in " _-.", (head, log.display_name)


def test_identical_settings_are_stored_once_per_log(tmp_path):
    root = tmp_path / "ws"
    ws = Workspace(root)
    log, other = ws.add_log(b"a", "a.ulg"), ws.add_log(b"b", "b.ulg")
    first = ws.store_calibration(log.sha256, CALIB, '{"first": true}')
    reordered = dict(reversed(list(CALIB.items())))  # same settings, other key order: the same canonical JSON
    again = ws.store_calibration(log.sha256, reordered, '{"second": true}')
    assert (again.id, again.name, again.created) == (first.id, first.name, False)
    assert again.message("calibration") == f"Already saved as \u201c{first.name}\u201d."
    assert ws.calibration_path(first.id).read_text() == '{"first": true}'  # nothing overwritten
    assert ws.add_calibration(log.sha256, CALIB, "{}") == first.id
    assert ws.store_calibration(other.sha256, CALIB, "{}").created  # another log: its own entry
    assert ws.store_calibration(log.sha256, {**CALIB, "tau": 0.28}, "{}").created  # other settings

    run = ws.store_run(log.sha256, RUN, *_frames(), {"n": 1})
    assert ws.store_run(log.sha256, json.loads(json.dumps(RUN)), *_frames(), {"n": 2}) == \
        workspace_module.Stored(run.id, run.name, False)
    assert ws.load_run_report(run.id) == {"n": 1}
    assert len(ws.list_runs()) == 1 and len(ws.list_calibrations()) == 3
    _assert_clean(root)


def test_a_duplicate_committed_meanwhile_is_found_inside_the_transaction(tmp_path, monkeypatch):
    ws = Workspace(tmp_path / "ws")
    log = ws.add_log(b"a", "a.ulg")
    other = Workspace(tmp_path / "ws")
    write = pd.DataFrame.to_parquet
    raced = {}

    def slow_to_parquet(self, *args, **kwargs):  # another session stores the same run while this one stages
        if not raced:
            monkeypatch.setattr(pd.DataFrame, "to_parquet", write)
            raced["id"] = other.add_run(log.sha256, RUN, *_frames(), {"other": True})
        return write(self, *args, **kwargs)

    monkeypatch.setattr(pd.DataFrame, "to_parquet", slow_to_parquet)
    stored = ws.store_run(log.sha256, RUN, *_frames(), {"mine": True})
    assert stored.id == raced["id"] and not stored.created
    assert list(ws.list_runs()["run_id"]) == [raced["id"]]
    _assert_clean(tmp_path / "ws")


@pytest.mark.parametrize(("raw", "expected"), [
    ("  my   best\tcalibration ", "my best calibration"), ("a\x00b\u202ec\nd", "a b c d"),
    ("**bold** [link](javascript:x) <b>`x`</b>", "bold link (javascript:x) b x /b"),
    ("Flug über Zürich · τ 0.3 · mag+sun", "Flug über Zürich · τ 0.3 · mag+sun"), ("\uff46\uff4c\uff49", "fli"),
    ("x" * 300, "x" * MAX_NAME_LENGTH), (" \t\n ", ""), ("\u200b\u2066", ""),
])
def test_sanitize_label(raw, expected):
    assert sanitize_label(raw) == expected


def test_rename_rules(tmp_path):
    ws = Workspace(tmp_path / "ws")
    log, other = ws.add_log(b"a", "a.ulg"), ws.add_log(b"b", "b.ulg")
    first = ws.store_calibration(log.sha256, CALIB, "{}")
    second = ws.store_calibration(log.sha256, {**CALIB, "tau": 2.0}, "{}")
    elsewhere = ws.store_calibration(other.sha256, CALIB, "{}")
    run = ws.store_run(log.sha256, RUN, *_frames(), {})

    assert ws.rename("calibrations", first.id, "  hover\n*test* ") == "hover test"
    assert Workspace(tmp_path / "ws").entry_name("calibrations", first.id) == "hover test"
    with pytest.raises(NameRejected, match="taken"):
        ws.rename("calibrations", second.id, "hover   test")  # sanitises to the name taken on the same log
    assert ws.entry_name("calibrations", second.id) == second.name
    assert ws.rename("calibrations", elsewhere.id, "hover test") == "hover test"  # another log: allowed
    assert ws.rename("runs", run.id, "hover test") == "hover test"  # a run is not a calibration
    assert ws.rename("calibrations", first.id, "hover test") == "hover test"  # its own name again
    for empty in ("", "   ", "\x00\u202e", "**"):
        with pytest.raises(NameRejected, match="empty"):
            ws.rename("calibrations", first.id, empty)
    with pytest.raises(KeyError):
        ws.rename("runs", "0" * 16, "ghost")

    assert ws.rename("logs", log.sha256, "../../Zürich flight?.ulg") == "Zurich flight_.ulg"  # file-name safe
    assert ws.get_log(log.sha256).display_name == "Zurich flight_.ulg"
    with pytest.raises(NameRejected, match="taken"):
        ws.rename("logs", other.sha256, "Zurich flight_.ulg")
    with pytest.raises(NameRejected, match="empty"):
        ws.rename("logs", other.sha256, "///")
    assert ws.rename("logs", other.sha256, "unnamed") == "unnamed"


def _populated(root: Path):
    ws = Workspace(root)
    log, keep = ws.add_log(b"doomed", "doomed.ulg"), ws.add_log(b"kept", "kept.ulg")
    ids = {"calibrations": [ws.add_calibration(log.sha256, CALIB, "{}"),
                            ws.add_calibration(log.sha256, {**CALIB, "tau": 3.0}, "{}")],
           "runs": [ws.add_run(log.sha256, RUN, *_frames(), {})]}
    kept = {"calibrations": ws.add_calibration(keep.sha256, CALIB, "{}"),
            "runs": ws.add_run(keep.sha256, RUN, *_frames(), {})}
    return ws, log, keep, ids, kept


def test_delete_an_entry_and_a_log_with_its_calibrations_and_runs(tmp_path):
    root = tmp_path / "ws"
    ws, log, keep, ids, kept = _populated(root)
    assert ws.delete("calibrations", ids["calibrations"][1]) == 1
    assert not (root / "calibrations" / ids["calibrations"][1]).exists()
    assert ws.delete("calibrations", ids["calibrations"][1]) == 0  # already gone
    assert ws.delete("logs", log.sha256) == 3  # the log, its remaining calibration and its run
    assert _assert_clean(root) == {"logs": {keep.sha256}, "calibrations": {kept["calibrations"]},
                                   "runs": {kept["runs"]}}
    assert ws.get_log(log.sha256) is None and ws.list_runs(log.sha256).empty
    # the same upload again is a new entry, with no calibrations or runs
    assert ws.add_log(b"doomed", "doomed.ulg").sha256 == log.sha256 and ws.list_calibrations(log.sha256).empty
    assert ws.store_calibration(log.sha256, CALIB, "{}").created  # no longer a duplicate of a deleted entry
    _assert_clean(root)


def test_a_failed_delete_commit_puts_everything_back(tmp_path):
    root = tmp_path / "ws"
    ws, log, _, ids, _ = _populated(root)
    with sqlite3.connect(root / "catalog.sqlite") as db:  # the catalog refuses (as a full disk would)
        db.execute("CREATE TRIGGER refuse BEFORE DELETE ON runs BEGIN SELECT RAISE(ABORT, 'disk full'); END")
    with pytest.raises(sqlite3.IntegrityError, match="disk full"):
        ws.delete("logs", log.sha256)
    listed = _assert_clean(root)
    assert log.sha256 in listed["logs"] and set(ids["calibrations"]) <= listed["calibrations"]
    assert (ws.log_dir(log.sha256) / "log.ulg").read_bytes() == b"doomed"


_CRASH = """
import os, sys
from app import workspace
from app.workspace import Workspace
root, point, sha256 = sys.argv[1:]
def die(*args, **kwargs):
    os._exit(3)
if point == "before_commit":  # rows deleted and directories moved to staging, not committed
    workspace._fsync_directory = die
else:  # committed, the directories not removed yet
    workspace._remove = die
Workspace(root).delete("logs", sha256)
raise SystemExit("the delete was expected to die")
"""


@pytest.mark.parametrize("point", ["before_commit", "after_commit"])
def test_a_crash_while_deleting_leaves_the_entries_complete_or_gone(tmp_path, point):
    root = tmp_path / "ws"
    _, log, keep, ids, kept = _populated(root)
    before = _listed(root)
    crashed = subprocess.run([sys.executable, "-c", _CRASH, str(root), point, log.sha256], cwd=REPO_DIR,
                             capture_output=True, text=True, timeout=120)
    assert crashed.returncode == 3, crashed.stderr
    debris = list((root / ".staging").iterdir())
    assert len(debris) == 4 and all(path.name.endswith(".deleting") for path in debris)  # log, 2 calibs, run
    assert all(not (root / kind / entry_id).exists() for kind in KINDS for entry_id in before[kind] - {
        keep.sha256, *kept.values()})

    reopened = Workspace(root)
    listed = _assert_clean(root)
    if point == "before_commit":  # rolled back: everything listed and complete again
        assert listed == before
        assert (reopened.log_dir(log.sha256) / "log.ulg").read_bytes() == b"doomed"
        assert reopened.calibration_path(ids["calibrations"][0]).read_text() == "{}"
        pd.testing.assert_frame_equal(reopened.load_run_table(ids["runs"][0], "states"), _frames()[0])
        assert reopened.delete("logs", log.sha256) == 4  # and it can be deleted now
    else:
        assert listed == {"logs": {keep.sha256}, "calibrations": {kept["calibrations"]}, "runs": {kept["runs"]}}
    _assert_clean(root)
    assert [entry.sha256 for entry in reopened.list_logs()] == [keep.sha256]


_OLD_SCHEMA = """
CREATE TABLE logs (sha256 TEXT PRIMARY KEY, display_name TEXT NOT NULL, size_bytes INTEGER NOT NULL,
                   added_utc TEXT NOT NULL, has_sun INTEGER NOT NULL DEFAULT 0);
CREATE TABLE calibrations (calib_id TEXT PRIMARY KEY, log_sha256 TEXT NOT NULL, settings_json TEXT NOT NULL,
                           created_utc TEXT NOT NULL);
CREATE TABLE runs (run_id TEXT PRIMARY KEY, log_sha256 TEXT NOT NULL, settings_json TEXT NOT NULL,
                   created_utc TEXT NOT NULL);
"""


def test_a_catalog_from_before_the_names_is_migrated(tmp_path):
    root = tmp_path / "ws"
    sha = "a" * 64
    for kind, entry_id, name in [("logs", sha, "log.ulg"), ("calibrations", "c1", "calib.json"),
                                 ("calibrations", "c2", "calib.json"), ("runs", "r1", "report.json")]:
        (root / kind / entry_id).mkdir(parents=True)
        (root / kind / entry_id / name).write_text("{}")
    with sqlite3.connect(root / "catalog.sqlite") as db:
        db.executescript(_OLD_SCHEMA)
        db.execute("INSERT INTO logs VALUES (?, 'paper.ulg', 5, '2025-01-01T09:00:00+00:00', 0)", (sha,))
        for calib_id in ("c1", "c2"):  # the same settings twice (stored before the dedupe): both kept, distinct
            db.execute("INSERT INTO calibrations VALUES (?, ?, ?, '2025-01-01T14:03:00+00:00')",
                       (calib_id, sha, json.dumps(CALIB, sort_keys=True)))
        db.execute("INSERT INTO runs VALUES ('r1', ?, ?, '2025-01-01T14:05:59+00:00')",
                   (sha, json.dumps(RUN, sort_keys=True)))

    ws = Workspace(root)
    calibs = ws.list_calibrations().set_index("calib_id")["name"]
    assert calibs["c1"] == "paper.ulg \u00b7 calib auto-\u03c4 0.27 \u00b7 14:03"
    assert calibs["c2"] == calibs["c1"] + " (2)"
    assert list(ws.list_runs()["name"]) == [
        "paper \u00b7 calibrated \u00b7 mag+sun \u00b7 14:05"]
    assert _assert_clean(root)["calibrations"] == {"c1", "c2"}  # nothing lost
    assert ws.rename("calibrations", "c2", "second") == "second"
    assert ws.add_calibration(sha, CALIB, "{}") == "c2"  # the old rows take part in the dedupe (newest first)
    new = ws.store_run(sha, {**RUN, "heading": "mag"}, *_frames(), {})
    assert new.created and new.name.startswith("paper \u00b7 calibrated \u00b7 ") and "mag" not in new.name
    assert Workspace(root).list_calibrations().set_index("calib_id")["name"]["c2"] == "second"  # reopen: kept
    with sqlite3.connect(root / "catalog.sqlite") as db:
        assert [row[1] for row in db.execute("PRAGMA table_info(runs)")][-1] == "name"


def test_workspace_page_renames_and_deletes(tmp_path, monkeypatch):
    from streamlit.testing.v1 import AppTest

    from app import samples, session

    root = tmp_path / "ws"
    ws = Workspace(root)
    keep = ws.add_log(b"kept bytes", "kept.ulg")
    log = ws.add_log(b"not a real ulog", "doomed.ulg")  # the newest: the log the sidebar opens, then deleted
    calib = ws.store_calibration(log.sha256, CALIB, "{}")
    run = ws.store_run(log.sha256, RUN, *_frames(), {})
    monkeypatch.setenv(session.WORKSPACE_ENV, str(root))
    monkeypatch.setattr(samples, "find_samples", lambda *args: [])
    at = AppTest.from_file(str(REPO_DIR / "app" / "dashboard.py"), default_timeout=120)
    at.run()
    assert at.sidebar.selectbox[0].value == log.sha256
    at.switch_page("views/workspace.py")
    at.run()
    assert not at.exception
    tables = [frame.value for frame in at.dataframe]
    assert set(tables[0]["name"]) == {"doomed.ulg", "kept.ulg"}
    assert list(tables[1]["name"]) == [calib.name] and list(tables[2]["name"]) == [run.name]

    # rename the calibration
    at.selectbox(key="ws_entry").set_value(f"calibrations:{calib.id}").run()
    at.text_input(key=f"ws_name_calibrations:{calib.id}").set_value("  hover  test ").run()
    at.button(key="ws_rename").click().run()
    assert not at.exception and not at.error
    assert Workspace(root).entry_name("calibrations", calib.id) == "hover test"
    assert "hover test" in set(at.dataframe[1].value["name"])
    assert any("hover test" in message.value for message in at.success)
    # an empty name is refused and said so
    at.selectbox(key="ws_entry").set_value(f"runs:{run.id}").run()
    at.text_input(key=f"ws_name_runs:{run.id}").set_value("   ").run()
    at.button(key="ws_rename").click().run()
    assert any("empty" in error.value for error in at.error)
    assert Workspace(root).entry_name("runs", run.id) == run.name

    # rename the log (issue 34): the entry box and the default run name show the name stored
    choice = f"logs:{log.sha256}"
    at.selectbox(key="ws_entry").set_value(choice).run()
    at.text_input(key=f"ws_name_{choice}").set_value("ruined flight?.ulg").run()
    at.button(key="ws_rename").click().run()
    assert not at.exception and not at.error
    assert at.text_input(key=f"ws_name_{choice}").value == "ruined flight_.ulg"
    assert "ruined flight_.ulg" in at.selectbox(key="ws_entry").format_func(choice)
    assert list(at.dataframe[2].value["name"]) == [Workspace(root).entry_name("runs", run.id)]
    assert run.name.startswith("doomed · ")  # the log stem starts a default run name (the new one without "_")
    assert Workspace(root).entry_name("runs", run.id) == run.name.replace("doomed", "ruined flight", 1)
    assert Workspace(root).entry_name("calibrations", calib.id) == "hover test"  # a name given stays

    # delete the log: nothing happens without the confirmation, then log, calibration and run go
    assert at.button(key="ws_delete").disabled  # a browser cannot click it before the confirmation
    assert "1 calibration(s) and 1 run(s)" in at.checkbox(key=f"ws_confirm_{choice}").label
    at.checkbox(key=f"ws_confirm_{choice}").check().run()
    at.button(key="ws_delete").click().run()
    assert not at.exception and not at.error
    assert [entry.sha256 for entry in Workspace(root).list_logs()] == [keep.sha256]
    assert Workspace(root).list_calibrations().empty and Workspace(root).list_runs().empty
    assert any("Deleted" in message.value for message in at.success)
    assert list(at.dataframe[0].value["name"]) == ["kept.ulg"]
    assert at.selectbox(key="ws_entry").value == f"logs:{keep.sha256}"
    assert at.sidebar.selectbox[0].value == keep.sha256  # the deleted log is no longer open
    _assert_clean(root)
