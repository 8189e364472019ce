"""Workspace persistence: restart keeps entries; an interrupted or failed write leaves the catalog consistent and
can be retried at once; hostile upload names never reach a path and stay distinct; the upload page shows the
reader's warnings. Concurrency with real processes: ``test_app_workspace_concurrency.py``."""

from __future__ import annotations

import hashlib
import random
import re
import sqlite3

import pandas as pd
import pytest

from app.workspace import MAX_NAME_LENGTH, Workspace, sanitize_name


def _run_frames():
    states = pd.DataFrame({"estimator": ["full_state_direct"] * 3, "time_s": [0.0, 0.02, 0.04],
                           "roll_deg": [1.0, 2.0, 3.0]})
    diagnostics = pd.DataFrame({"estimator": ["full_state_direct"], "time_s": [0.01], "sensor": ["gps"],
                                "component": ["pn"], "innovation": [0.1], "innovation_var": [1.0], "nis": [0.01],
                                "accepted": [True]})
    return states, diagnostics


def test_restart_keeps_uploads_runs_and_calibrations(tmp_path):
    ws = Workspace(tmp_path / "ws")
    entry = ws.add_log(b"ULog bytes", "../../etc/passwd flight#1.ulg", sun_csv=b"unix_time_s\n")
    states, diagnostics = _run_frames()
    run_id = ws.add_run(entry.sha256, {"estimators": ["full_state_direct"]}, states, diagnostics, {"ok": True})
    calib_id = ws.add_calibration(entry.sha256, {"cutoff_hz": 5}, '{"schema": "solarnav.calibration/1"}')

    reopened = Workspace(tmp_path / "ws")
    assert [log.sha256 for log in reopened.list_logs()] == [entry.sha256]
    assert reopened.get_log(entry.sha256).display_name == "passwd flight_1.ulg"
    assert (reopened.log_dir(entry.sha256) / "log.ulg").read_bytes() == b"ULog bytes"
    assert (reopened.log_dir(entry.sha256) / "sun.csv").exists()
    loaded_states, loaded_diag, report = reopened.load_run(run_id)
    pd.testing.assert_frame_equal(loaded_states, states)
    pd.testing.assert_frame_equal(loaded_diag, diagnostics)
    assert report == {"ok": True}
    assert list(reopened.list_runs(entry.sha256)["run_id"]) == [run_id]
    assert reopened.calibration_path(calib_id).read_text().startswith('{"schema"')
    # same content again: same entry, no duplicate
    assert reopened.add_log(b"ULog bytes", "other.ulg").sha256 == entry.sha256
    assert len(reopened.list_logs()) == 1


def test_crash_during_write_leaves_no_half_entry(tmp_path):
    ws = Workspace(tmp_path / "ws")
    entry = ws.add_log(b"abc", "a.ulg")
    states, diagnostics = _run_frames()

    class Crash(RuntimeError):
        pass

    def crashing_to_parquet(*args, **kwargs):
        raise Crash("power cut while writing")

    bad_states = states.copy()
    bad_states.to_parquet = crashing_to_parquet  # the diagnostics file never gets written
    with pytest.raises(Crash):
        ws.add_run(entry.sha256, {}, bad_states, diagnostics, {})
    assert ws.list_runs().empty
    assert list((tmp_path / "ws" / "runs").iterdir()) == []

    # a crash between moving the files in and inserting the row: the directory is unlisted -> removed on open
    orphan = tmp_path / "ws" / "runs" / "deadbeef"
    orphan.mkdir()
    (orphan / "states.parquet").write_bytes(b"partial")
    reopened = Workspace(tmp_path / "ws")
    assert not orphan.exists()
    assert reopened.list_runs().empty
    assert [log.sha256 for log in reopened.list_logs()] == [entry.sha256]


def _store(ws: Workspace, kind: str) -> str:
    """Store one entry of ``kind`` (the same content every time); its id."""
    if kind == "logs":
        return ws.add_log(b"retry me", "retry.ulg", sun_csv=b"unix_time_s\n").sha256
    if kind == "calibrations":
        return ws.add_calibration("a" * 64, {"cutoff_hz": 5}, "{}")
    return ws.add_run("a" * 64, {}, *_run_frames(), {"ok": True})


def _assert_nothing_unlisted(root) -> None:
    with sqlite3.connect(root / "catalog.sqlite") as db:
        for kind, key in (("logs", "sha256"), ("calibrations", "calib_id"), ("runs", "run_id")):
            listed = {row[0] for row in db.execute(f"SELECT {key} FROM {kind}")}
            assert {path.name for path in (root / kind).iterdir()} == listed, kind
    assert list((root / ".staging").iterdir()) == []


@pytest.mark.parametrize("kind", ["logs", "calibrations", "runs"])
def test_a_failed_catalog_insert_leaves_nothing_and_the_retry_succeeds_at_once(tmp_path, kind):
    root = tmp_path / "ws"
    ws = Workspace(root)
    with sqlite3.connect(root / "catalog.sqlite") as db:  # the catalog refuses the row (as a full disk would)
        db.execute(f"CREATE TRIGGER refuse BEFORE INSERT ON {kind} BEGIN SELECT RAISE(ABORT, 'disk full'); END")
    with pytest.raises(sqlite3.IntegrityError, match="disk full"):
        _store(ws, kind)
    _assert_nothing_unlisted(root)  # the moved directory was taken back out

    with sqlite3.connect(root / "catalog.sqlite") as db:
        db.execute("DROP TRIGGER refuse")
    entry_id = _store(ws, kind)  # same workspace object, no reopen
    _assert_nothing_unlisted(root)
    assert (root / kind / entry_id).is_dir()
    if kind == "logs":
        assert (ws.log_dir(entry_id) / "log.ulg").read_bytes() == b"retry me"
        assert ws.get_log(entry_id).has_sun


def test_remains_of_a_crashed_store_do_not_block_the_same_upload(tmp_path):
    root = tmp_path / "ws"
    ws = Workspace(root)
    sha256 = hashlib.sha256(b"retry me").hexdigest()
    (root / "logs" / sha256).mkdir()  # moved in by a writer that died before its catalog row
    (root / "logs" / sha256 / "log.ulg").write_bytes(b"retry")
    entry = ws.add_log(b"retry me", "retry.ulg")  # without reopening
    assert entry.sha256 == sha256 and (ws.log_dir(sha256) / "log.ulg").read_bytes() == b"retry me"
    _assert_nothing_unlisted(root)


@pytest.mark.parametrize(("raw", "expected"), [
    ("flight.ulg", "flight.ulg"), ("C:\\Users\\x\\log 1.ulg", "log 1.ulg"), ("../../..", "unnamed"),
    ("a/b/<script>.ulg", "_script_.ulg"), ("", "unnamed"),
    # path traversal, also spelt with full-width or mixed separators
    ("../../../etc/passwd", "passwd"), ("..\\..\\boot.ini", "boot.ini"), ("\uff0e\uff0e\uff0fsecret.ulg", "secret.ulg"),
    ("/", "unnamed"), (".", "unnamed"), ("..", "unnamed"), (" . .hidden.ulg. ", "hidden.ulg"),
    # NUL, control and bidi characters
    ("log\x00.ulg", "log_.ulg"), ("a\nb\rc\td.ulg", "a_b_c_d.ulg"), ("\u202egnp.ulg", "_gnp.ulg"),
    # unicode: accents dropped, compatibility forms folded, the rest replaced
    ("Flug über Zürich.ulg", "Flug uber Zurich.ulg"), ("\uff46\uff4c\uff49\uff47\uff48\uff54.ulg", "flight.ulg"),
    ("飛行.ulg", "__.ulg"), ("🚁.ulg", "_.ulg"),
    # names Windows reserves, whatever the case or extension
    ("CON", "_CON"), ("nul.ulg", "_nul.ulg"), ("Com1.tar.gz", "_Com1.tar.gz"), ("lpt9", "_lpt9"),
    ("AUX .ulg", "_AUX.ulg"), ("COM10.ulg", "COM10.ulg"), ("console.ulg", "console.ulg"),
    # very long: cut, the extension kept
    ("x" * 500 + ".ulg", "x" * (MAX_NAME_LENGTH - 4) + ".ulg"), ("y" * 500, "y" * MAX_NAME_LENGTH),
])
def test_sanitize_name(raw, expected):
    assert sanitize_name(raw) == expected


def _assert_display_safe(name: str, max_length: int = MAX_NAME_LENGTH) -> None:
    assert 1 <= len(name) <= max_length
    # " (2)" before the extension only ever comes from numbering (sanitising replaces brackets)
    assert re.fullmatch(r"[A-Za-z0-9._\- ]+", re.sub(r" \(\d+\)(?=(\.[^.]*)?$)", "", name)), name
    assert name[0] not in " ." and name[-1] not in " .", name
    assert not re.fullmatch(r"(CON|PRN|AUX|NUL|COM[0-9]|LPT[0-9]) *(\..*)?", name, re.IGNORECASE), name


#: Pieces hostile names are made of (seeded random draws: the same names on every run).
_HOSTILE_PIECES = ["..", "/", "\\", ".", " ", "\x00", "\n", "\x7f", "\u202e", "\uff0f", "\uff0e", "CON", "nul", "com1",
                   "é", "ß", "飛", "🚁", "\ud800", "%2e%2e", "~", "$", "*", "?", ":", "|", "<", ">", '"', "'",
                   "flight", ".ulg", "x" * 40]


def test_sanitize_name_fuzz_gives_display_safe_names():
    rng = random.Random(20240601)
    for _ in range(3000):
        raw = "".join(rng.choice(_HOSTILE_PIECES) for _ in range(rng.randint(0, 12)))
        _assert_display_safe(sanitize_name(raw))
        short = rng.randint(1, 12)
        _assert_display_safe(sanitize_name(raw, max_length=short), max_length=short)


def test_hostile_names_never_become_paths_and_stay_distinct(tmp_path):
    root = tmp_path / "ws"
    ws = Workspace(root)
    rng = random.Random(7)
    names = ["../../outside.ulg", "/etc/passwd", "..\\..\\CON", "NUL", "a\x00b", "x" * 300 + ".ulg", "\u202e.ulg",
             ".", "", "飛行.ulg", *("".join(rng.choice(_HOSTILE_PIECES) for _ in range(6)) for _ in range(16))]
    entries = [ws.add_log(f"log {i}".encode(), name) for i, name in enumerate(names)]

    display = [entry.display_name for entry in entries]
    assert len(set(display)) == len(names)  # one entry per content, each with its own name
    for name in display:
        _assert_display_safe(name)
    expected = {root / "logs" / hashlib.sha256(f"log {i}".encode()).hexdigest() / "log.ulg" for i in range(len(names))}
    assert {path for path in (root / "logs").rglob("*") if path.is_file()} == expected
    assert {path.name for path in tmp_path.iterdir()} == {"ws"}  # nothing written beside the workspace
    assert sorted(entry.display_name for entry in Workspace(root).list_logs()) == sorted(display)


def test_names_that_sanitise_alike_are_both_kept_and_distinct(tmp_path):
    ws = Workspace(tmp_path / "ws")
    first = ws.add_log(b"first flight", "a/flight#1.ulg")
    second = ws.add_log(b"second flight", "b\\flight?1.ulg")
    third = ws.add_log(b"third flight", "flight:1.ulg")
    long_a, long_b = (ws.add_log(content, "z" * 200 + ".ulg") for content in (b"long a", b"long b"))
    assert [first.display_name, second.display_name, third.display_name] == [
        "flight_1.ulg", "flight_1 (2).ulg", "flight_1 (3).ulg"]
    assert long_b.display_name == "z" * (MAX_NAME_LENGTH - 8) + " (2).ulg" != long_a.display_name
    for entry, content in [(first, b"first flight"), (second, b"second flight"), (third, b"third flight")]:
        assert (ws.log_dir(entry.sha256) / "log.ulg").read_bytes() == content
    # the same content under another name is the same entry (the hash is the identity)
    assert ws.add_log(b"second flight", "renamed.ulg") == second
    assert len(ws.list_logs()) == 5


def test_upload_page_shows_the_reader_warnings_of_a_corrupt_log(tmp_path, monkeypatch, real_logs_dir):
    from streamlit.testing.v1 import AppTest

    from app import adapters, samples, session
    from tests.conftest import REPO_DIR

    monkeypatch.setenv(session.WORKSPACE_ENV, str(tmp_path / "ws"))
    monkeypatch.setattr(samples, "find_samples", lambda *args: [])  # an empty workspace opens faster
    at = AppTest.from_file(str(REPO_DIR / "app" / "dashboard.py"), default_timeout=120)
    at.run()
    corrupt = real_logs_dir / "px4_1.17_quad_flight_corrupt.ulg"
    at.file_uploader(key="upload_ulog").set_value((corrupt.name, corrupt.read_bytes(), "application/octet"))
    at.button[0].click()
    at.run()
    assert not at.exception and not at.error
    shown = {warning.value for warning in at.warning}
    log = adapters.validate_upload(corrupt.read_bytes(), corrupt.name, None, None)  # the page's cached parse
    assert any("corrupt" in warning for warning in log.meta.warnings)  # what `solarnav info` prints
    assert {f"{corrupt.name}: {warning}" for warning in log.meta.warnings} <= shown, shown
    assert [entry.display_name for entry in Workspace(tmp_path / "ws").list_logs()] == [corrupt.name]
