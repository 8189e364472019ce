"""``solarnav batch`` as a user runs it: on an existing Dask cluster (``dask scheduler`` and two ``dask worker``
processes on 127.0.0.1) with the worker of a running task killed (SIGKILL), and on a local cluster (its dashboard
link served) interrupted with Ctrl-C (SIGINT) then re-run: every log exactly once in the summary."""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
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


def _assert_every_log_once(outdir: Path) -> pd.DataFrame:
    fleet, _ = read_summary(outdir)
    assert (fleet["status"] == "ok").all(), fleet.loc[fleet["status"] != "ok", ["name", "message"]]
    assert fleet.groupby("name").size().eq(3).all() and fleet["name"].nunique() == N_LOGS
    assert fleet.groupby(["name", "estimator"]).size().eq(1).all()
    return fleet


def _a_running_task(client: Client, batch: subprocess.Popen) -> tuple[str, str]:
    """(worker address, log path) of a batch task that a worker is executing (Dask's worker state: not one
    assigned to it and waiting), polled from the start of the batch so that the task has only just started."""
    deadline = time.monotonic() + TIMEOUT_S
    while True:
        executing = client.run(lambda dask_worker: [ts.run_spec.args[0].path for ts in dask_worker.state.executing])
        running = [(worker, paths[0]) for worker, paths in executing.items() if paths]
        if running:
            return running[0]
        assert batch.poll() is None, batch.communicate()
        assert time.monotonic() < deadline, "no task started"
        time.sleep(0.05)


def test_batch_on_a_dask_scheduler_with_two_worker_processes_survives_a_killed_worker(logs, tmp_path):
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    # a task whose worker dies is retried once (the local cluster sets the same)
    env = {**os.environ, "DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "1"}
    processes = []
    try:
        processes.append(subprocess.Popen([str(DASK), "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                           "--no-dashboard"], env=env, stderr=subprocess.DEVNULL))
        workers = {}
        for name in ("w0", "w1"):
            workers[name] = subprocess.Popen([str(DASK), "worker", address, "--nthreads", "1", "--no-nanny",
                                              "--no-dashboard", "--host", "127.0.0.1", "--name", name],
                                             env=env, cwd=REPO_DIR, stderr=subprocess.DEVNULL)
            processes.append(workers[name])
        outdir = tmp_path / "out"
        with Client(address, timeout=60) as client:  # the test's own client: which worker runs which log
            client.wait_for_workers(2, timeout=120)
            batch = subprocess.Popen(_batch_command(logs, outdir, "--scheduler", address), cwd=REPO_DIR,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            processes.append(batch)
            worker, log_path = _a_running_task(client, batch)
            killed = workers[client.scheduler_info()["workers"][worker]["name"]]
            killed.send_signal(signal.SIGKILL)  # in the middle of that log: it takes seconds
        stdout, stderr = batch.communicate(timeout=TIMEOUT_S)
        assert killed.wait(timeout=20) == -signal.SIGKILL
        assert batch.returncode == 0, stderr
        assert f"Dask scheduler {address}, 2 workers; Dask dashboard: none (the scheduler serves no dashboard" \
            in stderr  # started with --no-dashboard
        assert f"batch: {N_LOGS}/{N_LOGS} logs (0 failed, 0 resumed)" in stderr
        fleet = _assert_every_log_once(outdir)
        pids = fleet["worker"].str.split(":").str[1].astype(int)
        retried = fleet["name"] == Path(log_path).name
        assert retried.any() and (pids[retried] != killed.pid).all()  # once (above), rerun on the survivor
        assert (pids.groupby(fleet["name"]).first() != killed.pid).sum() >= N_LOGS // 2  # which took over the rest
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


def test_a_local_cluster_batch_serves_its_dashboard_and_resumes_every_log_once_after_ctrl_c(logs, tmp_path):
    outdir = tmp_path / "out"
    batch = subprocess.Popen(_batch_command(logs, outdir, "--workers", "1"), cwd=REPO_DIR, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        seen, dashboard_status = [], None
        while not seen or not seen[-1].startswith(f"batch: 1/{N_LOGS} logs"):  # the client has the first log
            seen.append(batch.stderr.readline())
            assert seen[-1], "".join(seen)
            link = re.search(r"Dask dashboard: (http://\S+)", seen[-1])
            if link:  # the printed link, while the cluster runs
                with urllib.request.urlopen(link[1], timeout=60) as response:
                    dashboard_status, page = response.status, response.read().decode()
        batch.send_signal(signal.SIGINT)
        _, stderr = batch.communicate(timeout=TIMEOUT_S)
    finally:
        if batch.poll() is None:
            batch.kill()
            batch.wait()
    assert dashboard_status == 200 and "Dask" in page, "".join(seen)
    assert batch.returncode == 130, stderr
    assert "interrupted: run the same command again" in stderr
    done = _done(outdir)
    assert 1 <= done < N_LOGS
    partial, _ = read_summary(outdir)
    assert 1 <= partial["name"].nunique() <= done  # (a log may finish while the client stops)
    assert main(["batch", str(logs), "--calibrate", "--replay", "--workers", "2", "-o", str(outdir)]) == 0
    fleet = _assert_every_log_once(outdir)
    assert int(fleet.drop_duplicates("name")["resumed"].sum()) == done
