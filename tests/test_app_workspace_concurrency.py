"""The workspace under real concurrency: several processes storing logs, calibrations and runs while others open
the workspace (which runs its recovery) again and again; a writer paused inside its store while another session
opens the workspace; a process killed (``os._exit``) between writing the files and inserting the catalog row.

The children are started with ``multiprocessing`` in *spawn* mode (fresh interpreters, as separate dashboard
servers or a batch would be). The pauses are synchronised with events, not timed, so the outcome is deterministic.
pandas is imported only where runs are stored or compared, so that the children that store logs start fast.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import random
import sqlite3
import sys
import threading
import time
import types
from pathlib import Path

import pytest

from app import workspace as workspace_module
from app.workspace import Workspace

SPAWN = multiprocessing.get_context("spawn")
#: Longest wait [s] for a child or an event (a hung child fails the test instead of hanging it).
WAIT_S = 120.0
KINDS = ("logs", "calibrations", "runs")


def _frames(tag: str):
    """Small states and diagnostics tables of a run (pandas imported here: children storing only logs skip it)."""
    import pandas as pd

    states = pd.DataFrame({"estimator": ["full_state_direct"] * 3, "time_s": [0.0, 0.02, 0.04],
                           "tag": [tag] * 3})
    diagnostics = pd.DataFrame({"estimator": ["full_state_direct"], "sensor": ["gps"], "nis": [0.5], "tag": [tag]})
    return states, diagnostics


def _calibration_json(tag: str) -> str:
    return json.dumps({"schema": "solarnav.calibration/1", "tag": tag})


def _after_replace(action) -> None:
    """In a child: call ``action(dst)`` right after every ``os.replace`` that moves an entry into its kind folder
    (between the files and the catalog row)."""
    real_replace = os.replace

    def replace(src, dst, *args, **kwargs):
        real_replace(src, dst, *args, **kwargs)
        if Path(dst).parent.name in KINDS:
            action(Path(dst))

    os.replace = replace


# ---------------------------------------------------------------------------------------------------- children
def _writer(root: str, index: int, rounds: int, barrier, out: str) -> None:
    """Store logs (own and shared content), calibrations and runs; commits slowed down at random to widen the gap
    between the move and the catalog row; writes what it stored to ``out``."""
    rng = random.Random(index)
    _after_replace(lambda dst: time.sleep(rng.uniform(0.0, 0.004)))
    barrier.wait(WAIT_S)
    stored = []
    for j in range(rounds):
        ws = Workspace(root)  # reopened every round: recovery runs while the other writers store
        own = ws.add_log(f"writer {index} log {j}".encode(), f"../w{index}/flight#{j}.ulg")
        shared = ws.add_log(f"shared log {j}".encode(), f"shared {j}.ulg", sun_csv=b"unix_time_s\n")
        tag = f"{index}-{j}"
        calib_id = ws.add_calibration(own.sha256, {"tag": tag}, _calibration_json(tag))
        run_id = ws.add_run(shared.sha256, {"tag": tag}, *_frames(tag), {"tag": tag})
        stored += [("logs", own.sha256, f"writer {index} log {j}"), ("logs", shared.sha256, f"shared log {j}"),
                   ("calibrations", calib_id, tag), ("runs", run_id, tag)]
    Path(out).write_text(json.dumps(stored))


def _opener(root: str, barrier, stop, out: str) -> None:
    """Open the workspace (recovery) until ``stop``; record how many entries recovery removed and any listed log
    whose file was missing at that moment."""
    barrier.wait(WAIT_S)
    removed, missing, opens = 0, [], 0
    while not stop.is_set() and opens < 500:
        ws = Workspace(root)
        removed += ws.recover()
        missing += [entry.sha256 for entry in ws.list_logs() if not (ws.log_dir(entry.sha256) / "log.ulg").exists()]
        opens += 1
        time.sleep(0.002)  # a busy loop would only starve the writers of the two cores
    Path(out).write_text(json.dumps({"removed": removed, "missing": missing, "opens": opens}))


def _paused_after_move(root: str, moved, go) -> None:
    """Store a log, pausing between the move into ``logs/`` and the catalog row until ``go``."""
    def pause(dst: Path) -> None:
        moved.set()
        if not go.wait(WAIT_S):
            raise TimeoutError("never released")

    _after_replace(pause)
    Workspace(root).add_log(b"paused upload", "paused.ulg")


def _paused_while_staging(root: str, staged, go) -> None:
    """Store a run, pausing while its files are being written in staging until ``go``."""
    states, diagnostics = _frames("staged")
    write = states.to_parquet

    def pausing_to_parquet(*args, **kwargs):
        staged.set()
        if not go.wait(WAIT_S):
            raise TimeoutError("never released")
        return write(*args, **kwargs)

    states.to_parquet = pausing_to_parquet
    Workspace(root).add_run("a" * 64, {"tag": "staged"}, states, diagnostics, {"tag": "staged"})


def _crashing(root: str, kind: str, point: str) -> None:
    """Store one entry of ``kind`` and die (``os._exit(3)``, no clean-up) at ``point``."""
    def die(*_args, **_kwargs):
        os._exit(3)

    if point == "after_move":
        _after_replace(die)
    elif point == "in_transaction":  # after the move, inside the catalog transaction (logs only)
        workspace_module._distinct_name = die
    ws = Workspace(root)
    if kind == "logs":
        ws.add_log(b"crash log", "crash.ulg")
    elif kind == "calibrations":
        ws.add_calibration("a" * 64, {}, _calibration_json("crash"))
    else:
        states, diagnostics = _frames("crash")
        if point == "while_staging":
            diagnostics.to_parquet = die  # states written, diagnostics never
        ws.add_run("a" * 64, {}, states, diagnostics, {})
    raise AssertionError("the store was expected to die")


def _run(target, *args) -> multiprocessing.Process:
    """Start ``target(*args)`` in a spawned child, from a bare ``__main__``: spawn re-runs the parent's main script
    in the child, and after a Streamlit ``AppTest`` in this process that is the dashboard (seconds per child)."""
    process = SPAWN.Process(target=target, args=args)
    main = sys.modules["__main__"]
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        process.start()
    finally:
        sys.modules["__main__"] = main
    return process


def _join(process: multiprocessing.Process) -> int:
    process.join(WAIT_S)
    if process.is_alive():
        process.kill()
        process.join()
        pytest.fail(f"{process.name} hung")
    return process.exitcode


# ---------------------------------------------------------------------------------------------------- checks
def _listed(root: Path) -> dict[str, set[str]]:
    with sqlite3.connect(root / "catalog.sqlite") as db:
        return {kind: {row[0] for row in db.execute(f"SELECT {workspace_module._KINDS[kind]} FROM {kind}")}
                for kind in KINDS}


def _assert_consistent(root: Path) -> dict[str, set[str]]:
    """Every listed entry has its directory and nothing unlisted remains (entry folders, staging)."""
    listed = _listed(root)
    for kind in KINDS:
        assert {path.name for path in (root / kind).iterdir()} == listed[kind], kind
    assert list((root / ".staging").iterdir()) == []
    return listed


# ---------------------------------------------------------------------------------------------------- tests
def test_concurrent_writers_and_openers_lose_nothing_and_leave_nothing(tmp_path):
    import pandas as pd

    root = tmp_path / "ws"
    Workspace(root)
    writers, openers, rounds = 3, 1, 4
    barrier, stop = SPAWN.Barrier(writers + openers), SPAWN.Event()
    children = [_run(_writer, str(root), i, rounds, barrier, str(tmp_path / f"writer{i}.json"))
                for i in range(writers)]
    children += [_run(_opener, str(root), barrier, stop, str(tmp_path / f"opener{i}.json")) for i in range(openers)]
    try:
        assert [_join(child) for child in children[:writers]] == [0] * writers
    finally:
        stop.set()
    assert [_join(child) for child in children[writers:]] == [0] * openers

    for i in range(openers):  # recovery never removed an entry in flight, the catalog never listed a missing file
        report = json.loads((tmp_path / f"opener{i}.json").read_text())
        assert report["opens"] >= 1 and report["removed"] == 0 and report["missing"] == []
    ws = Workspace(root)
    listed = _assert_consistent(root)
    stored = [entry for i in range(writers) for entry in json.loads((tmp_path / f"writer{i}.json").read_text())]
    for kind, entry_id, content in stored:
        assert entry_id in listed[kind]
        if kind == "logs":
            assert (ws.log_dir(entry_id) / "log.ulg").read_bytes() == content.encode()
            assert hashlib.sha256(content.encode()).hexdigest() == entry_id
        elif kind == "calibrations":
            assert ws.calibration_path(entry_id).read_text() == _calibration_json(content)
        else:
            states, diagnostics, report = ws.load_run(entry_id)
            pd.testing.assert_frame_equal(states, _frames(content)[0])
            pd.testing.assert_frame_equal(diagnostics, _frames(content)[1])
            assert report == {"tag": content}
    # shared content was stored once however many writers raced for it; every entry listed was reported stored
    assert len(listed["logs"]) == writers * rounds + rounds
    assert {kind: {e for k, e, _ in stored if k == kind} for kind in KINDS} == listed
    names = [entry.display_name for entry in ws.list_logs()]
    assert len(set(names)) == len(names)  # "flight#0.ulg" of every writer sanitises alike: numbered, distinct


def test_opening_between_a_writers_move_and_its_row_keeps_the_entry(tmp_path):
    root = tmp_path / "ws"
    Workspace(root)
    moved, go = SPAWN.Event(), SPAWN.Event()
    writer = _run(_paused_after_move, str(root), moved, go)
    try:
        assert moved.wait(WAIT_S), "the writer never reached its move"
        opener = threading.Thread(target=Workspace, args=(root,))  # a second session opening the workspace
        opener.start()
        opener.join(0.5)
        assert opener.is_alive()  # its recovery waits for the writer's catalog transaction
    finally:
        go.set()
    assert _join(writer) == 0
    opener.join(WAIT_S)
    assert not opener.is_alive()

    sha256 = hashlib.sha256(b"paused upload").hexdigest()
    ws = Workspace(root)
    assert [entry.sha256 for entry in ws.list_logs()] == [sha256]
    assert (ws.log_dir(sha256) / "log.ulg").read_bytes() == b"paused upload"
    _assert_consistent(root)


def test_opening_while_a_writer_stages_neither_waits_nor_removes_its_files(tmp_path):
    root = tmp_path / "ws"
    Workspace(root)
    staged, go = SPAWN.Event(), SPAWN.Event()
    writer = _run(_paused_while_staging, str(root), staged, go)
    try:
        assert staged.wait(WAIT_S), "the writer never started staging"
        Workspace(root)  # returns at once although an upload is being written
        assert len(list((root / ".staging").iterdir())) == 1  # the writer's staging is left alone
    finally:
        go.set()
    assert _join(writer) == 0
    ws = Workspace(root)
    [run_id] = ws.list_runs()["run_id"]
    assert ws.load_run_report(run_id) == {"tag": "staged"}
    _assert_consistent(root)


CRASHES = [("logs", "after_move"), ("logs", "in_transaction"), ("calibrations", "after_move"),
           ("runs", "after_move"), ("runs", "while_staging")]


@pytest.fixture(scope="module")
def crashed(tmp_path_factory) -> dict[tuple[str, str], tuple[Path, int]]:
    """A workspace per crash case, each left by a child that died at that point (all started at once)."""
    roots = {case: tmp_path_factory.mktemp("crash") / "ws" for case in CRASHES}
    for root in roots.values():
        Workspace(root)
    children = {case: _run(_crashing, str(roots[case]), *case) for case in CRASHES}
    return {case: (roots[case], _join(child)) for case, child in children.items()}


@pytest.mark.parametrize(("kind", "point"), CRASHES)
def test_a_crash_before_the_catalog_row_reopens_clean_and_the_retry_succeeds(crashed, kind, point):
    import pandas as pd

    root, exitcode = crashed[kind, point]
    assert exitcode == 3
    # the crash left its files (moved in, or half-staged) but no row
    leftovers = list((root / kind).iterdir()) + list((root / ".staging").iterdir())
    assert leftovers and _listed(root)[kind] == set()

    ws = Workspace(root)
    assert _assert_consistent(root) == {k: set() for k in KINDS}
    if kind == "logs":  # the same upload again, at once
        entry = ws.add_log(b"crash log", "crash.ulg")
        assert entry.display_name == "crash.ulg"
        assert (ws.log_dir(entry.sha256) / "log.ulg").read_bytes() == b"crash log"
    elif kind == "calibrations":
        assert ws.calibration_path(ws.add_calibration("a" * 64, {}, "{}")).read_text() == "{}"
    else:
        states, diagnostics = _frames("retry")
        pd.testing.assert_frame_equal(ws.load_run(ws.add_run("a" * 64, {}, states, diagnostics, {}))[0], states)
    assert all(len(ids) == (k == kind) for k, ids in _assert_consistent(root).items())
