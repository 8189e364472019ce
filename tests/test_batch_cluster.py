"""``solarnav batch`` as a user runs it: on an existing Dask cluster (``dask scheduler`` and two ``dask worker``
processes on 127.0.0.1) with one worker killed (SIGKILL) mid-batch, and interrupted with Ctrl-C (SIGINT) then
re-run: every log exactly once in the summary."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from distributed import Client

from app.batch.plan import LOGS_DIR
from app.batch.summary import read_summary
from app.batch.task import ROWS_FILE
from app.cli import main
from tests.batch_logs import N_FLIGHTS, flight_name, write_fleet
from tests.conftest import REPO_DIR

DASK = Path(sys.executable).with_name("dask")
#: Copies of the simulated flights: enough logs that the batch is still running when a process is killed.
COPIES = 2
N_LOGS = N_FLIGHTS * COPIES
TIMEOUT_S = 300


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Path:
    """``N_LOGS`` good logs (the simulated flights under ``COPIES`` names each, with their companions)."""
    simulated = tmp_path_factory.mktemp("simulated") / "logs"
    write_fleet(simulated, bad_files=False)
    directory = tmp_path_factory.mktemp("inputs")
    for copy in range(COPIES):
        for k in range(N_FLIGHTS):
            for suffix in (".ulg", "_sun.csv", "_device.json"):
                shutil.copy(simulated / f"{flight_name(k)}{suffix}", directory / f"c{copy}_{flight_name(k)}{suffix}")
    return directory


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _batch_command(logs: Path, outdir: Path, *options: str) -> list[str]:
    return [sys.executable, "-m", "app.cli", "batch", str(logs), "--calibrate", "--replay", *options, "-o",
            str(outdir)]


def _done(outdir: Path) -> int:
    return len(list((outdir / LOGS_DIR).glob(f"*/{ROWS_FILE}")))


def _wait_for_first_log(outdir: Path, process: subprocess.Popen) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while _done(outdir) == 0:
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, "no log finished"
        time.sleep(0.1)


def _assert_every_log_once(outdir: Path) -> pd.DataFrame:
    fleet, _ = read_summary(outdir)
    assert (fleet["status"] == "ok").all(), fleet.loc[fleet["status"] != "ok", ["name", "message"]]
    assert fleet.groupby("name").size().eq(3).all() and fleet["name"].nunique() == N_LOGS
    assert fleet.groupby(["name", "estimator"]).size().eq(1).all()
    return fleet


def test_batch_on_a_dask_scheduler_with_two_worker_processes_survives_a_killed_worker(logs, tmp_path):
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    # a task whose worker dies is retried once (the local cluster sets the same)
    env = {**os.environ, "DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "1"}
    processes = []
    try:
        processes.append(subprocess.Popen([str(DASK), "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                           "--no-dashboard"], env=env, stderr=subprocess.DEVNULL))
        for k in range(2):
            processes.append(subprocess.Popen([str(DASK), "worker", address, "--nthreads", "1", "--no-nanny",
                                               "--no-dashboard", "--host", "127.0.0.1", "--name", f"w{k}"],
                                              env=env, cwd=REPO_DIR, stderr=subprocess.DEVNULL))
        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=120)
        outdir = tmp_path / "out"
        batch = subprocess.Popen(_batch_command(logs, outdir, "--scheduler", address), cwd=REPO_DIR,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        processes.append(batch)
        _wait_for_first_log(outdir, batch)
        killed = processes[1]
        killed.send_signal(signal.SIGKILL)
        stdout, stderr = batch.communicate(timeout=TIMEOUT_S)
        assert batch.returncode == 0, stderr
        assert f"Dask scheduler {address}, 2 workers; Dask dashboard:" in stderr
        assert f"batch: {N_LOGS}/{N_LOGS} logs (0 failed, 0 resumed)" in stderr
        fleet = _assert_every_log_once(outdir)
        workers = fleet.drop_duplicates("name")["worker"].str.split(":").str[1].astype(int)
        assert (workers != killed.pid).sum() >= N_LOGS // 2  # the survivor took over the rest
        assert f"{N_LOGS} of {N_LOGS} logs summarised: {N_LOGS} ok (0 resumed), 0 failed" in stdout
    finally:
        for process in reversed(processes):
            if process.poll() is None:
                process.terminate()
                try:
                    process.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()


def test_a_batch_interrupted_with_ctrl_c_resumes_and_summarises_every_log_once(logs, tmp_path):
    outdir = tmp_path / "out"
    batch = subprocess.Popen(_batch_command(logs, outdir, "--workers", "1"), cwd=REPO_DIR, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        seen = []
        while not seen or not seen[-1].startswith(f"batch: 1/{N_LOGS} logs"):  # the client has the first log
            seen.append(batch.stderr.readline())
            assert seen[-1], "".join(seen)
        batch.send_signal(signal.SIGINT)
        _, stderr = batch.communicate(timeout=TIMEOUT_S)
    finally:
        if batch.poll() is None:
            batch.kill()
            batch.wait()
    assert batch.returncode == 130, stderr
    assert "interrupted: run the same command again" in stderr
    done = _done(outdir)
    assert 1 <= done < N_LOGS
    partial, _ = read_summary(outdir)
    assert 1 <= partial["name"].nunique() <= done  # (a log may finish while the client stops)
    assert main(["batch", str(logs), "--calibrate", "--replay", "--workers", "2", "-o", str(outdir)]) == 0
    fleet = _assert_every_log_once(outdir)
    assert int(fleet.drop_duplicates("name")["resumed"].sum()) == done
