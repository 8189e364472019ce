"""Workspace persistence: restart keeps entries; an interrupted write leaves the catalog consistent."""

from __future__ import annotations

import pandas as pd
import pytest

from app.workspace import Workspace, sanitize_name


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


@pytest.mark.parametrize(("raw", "expected"), [
    ("flight.ulg", "flight.ulg"), ("C:\\Users\\x\\log 1.ulg", "log 1.ulg"), ("../../..", "unnamed"),
    ("a/b/<script>.ulg", "_script_.ulg"), ("", "unnamed"),
])
def test_sanitize_name(raw, expected):
    assert sanitize_name(raw) == expected
