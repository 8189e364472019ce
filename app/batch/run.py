"""Running a batch on Dask: the client (a local cluster of worker processes, or the user's scheduler), one task
per log, the live progress line, and the rows gathered as the tasks finish (docs/batch.md, 'Running on a
cluster').

Failure isolation: a task that raises (other than bad input, which :func:`app.batch.task.process_log` turns into an
error row itself) is retried once (``retries=1``); a task whose worker dies is rescheduled on another worker once
(the local cluster's ``distributed.scheduler.allowed-failures`` = :data:`ALLOWED_FAILURES`; a user's scheduler
has its own setting). When it fails again, the client records one error row with the one-line message.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TextIO

import dask
from distributed import Client, LocalCluster, as_completed

from app.batch.plan import BatchSettings, LogInput
from app.batch.task import ERROR, error_row, one_line, process_log
from ingest.errors import InputError

#: Times a task may be on a worker that dies before the scheduler gives up on it (1: retried once).
ALLOWED_FAILURES = 1
#: Retries of a task that raised (a transient read error on shared storage, a worker out of memory).
TASK_RETRIES = 1


@contextmanager
def batch_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Client]:
    """A Dask client for the batch.

    Parameters
    ----------
    scheduler : str, optional
        Address of an existing scheduler (``tcp://host:8786``); default the ``DASK_SCHEDULER_ADDRESS``
        environment variable (Dask's ``scheduler-address`` setting), else a local cluster.
    workers : int, optional
        Worker processes of the local cluster (one thread each); default the number of CPUs. Not allowed with a
        scheduler (its workers are the cluster's).

    Yields
    ------
    distributed.Client
        Closed (and the local cluster shut down) on exit.
    """
    address = scheduler_address(scheduler)
    if address is not None:
        if workers is not None:
            raise InputError(f"sets up a local cluster: not with the scheduler {address}", field="--workers")
        with Client(address) as client:
            yield client
        return
    with dask.config.set({"distributed.scheduler.allowed-failures": ALLOWED_FAILURES}), \
            LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                         dashboard_address=":0", silence_logs=logging.CRITICAL) as cluster, \
            Client(cluster) as client:
        yield client


def scheduler_address(scheduler: str | None = None) -> str | None:
    """The scheduler the batch uses: ``scheduler``, else ``DASK_SCHEDULER_ADDRESS`` (Dask's ``scheduler-address``
    setting); None for a local cluster."""
    return scheduler or dask.config.get("scheduler-address", None)


def dashboard_text(client: Client) -> str:
    """The Dask dashboard's link, or why the scheduler serves none.

    The local cluster serves it (bokeh is a dependency of solarnav); a user's scheduler serves none when it was
    started with ``--no-dashboard`` or where bokeh>=3.1 is not installed (its link would not show the dashboard).
    """
    # Dask adds the dashboard's (bokeh) pages to the scheduler's HTTP server only when it is enabled and bokeh
    # imports; a lambda travels by value: the scheduler need not have solarnav installed
    if client.run_on_scheduler(lambda dask_scheduler: bool(dask_scheduler.http_application.applications)):
        return f"Dask dashboard: {client.dashboard_link}"
    return ("Dask dashboard: none (the scheduler serves no dashboard: started with --no-dashboard, or bokeh>=3.1 "
            "is not installed where it runs)")


@dataclass
class Progress:
    """The live progress line: logs done / failed / remaining, throughput and ETA.

    On a terminal the line is rewritten in place; otherwise one line per finished log.
    """

    total: int
    stream: TextIO = field(default_factory=lambda: sys.stderr)
    done: int = 0
    failed: int = 0
    resumed: int = 0
    started_s: float = field(default_factory=time.perf_counter)

    def update(self, rows: list[dict]) -> None:
        """Count one finished log (its rows) and redraw the line."""
        self.done += 1
        self.failed += any(row["status"] == ERROR for row in rows)
        self.resumed += all(row.get("resumed") for row in rows)
        self.stream.write(("\r\033[K" if self._live else "") + self.line() + ("" if self._live else "\n"))
        self.stream.flush()

    def line(self) -> str:
        """``batch: 12/200 logs (1 failed, 3 resumed), 188 remaining, 4.2 logs/min, ETA 0:44:45``."""
        elapsed_min = (time.perf_counter() - self.started_s) / 60.0
        processed = self.done - self.resumed
        rate = processed / elapsed_min if elapsed_min > 0 else 0.0
        remaining = self.total - self.done
        eta = _clock(60.0 * remaining / rate) if rate > 0 else "-"
        return (f"batch: {self.done}/{self.total} logs ({self.failed} failed, {self.resumed} resumed), "
                f"{remaining} remaining, {rate:.1f} logs/min, ETA {eta}")

    def close(self) -> None:
        """End the live line."""
        if self._live:
            self.stream.write("\n")
            self.stream.flush()

    @property
    def _live(self) -> bool:
        return bool(getattr(self.stream, "isatty", lambda: False)())


def run_batch(client: Client, items: list[LogInput], settings: BatchSettings, outdir: str,
              progress: Progress | None = None) -> tuple[list[dict], bool]:
    """Submit one task per log and gather their rows as they finish.

    Parameters
    ----------
    client : distributed.Client
        Where the tasks run (the workers must see ``items`` and ``outdir`` at the same paths).
    items : list of LogInput
        The logs.
    settings : BatchSettings
        What every task does.
    outdir : str
        Output directory (with its ``logs/`` subdirectory).
    progress : Progress, optional
        Updated after every log.

    Returns
    -------
    rows : list of dict
        Every finished log's rows, in input order.
    interrupted : bool
        True when Ctrl-C (SIGINT) stopped the batch: the unfinished tasks were cancelled and are missing from
        ``rows`` (a re-run does them, and resumes the finished ones).
    """
    futures = {client.submit(process_log, item, settings, outdir, pure=False, retries=TASK_RETRIES): k
               for k, item in enumerate(items)}
    finished: dict[int, list[dict]] = {}
    interrupted = False
    try:
        for future in as_completed(futures):
            k = futures[future]
            try:
                rows = future.result()
            except Exception as exc:  # the task failed twice, or its workers died: one error row, the batch goes on
                rows = [error_row(items[k], one_line(exc), settings_hash=settings.digest())]
            finished[k] = rows
            if progress is not None:
                progress.update(rows)
    except KeyboardInterrupt:
        interrupted = True
        client.cancel(list(futures))
    finally:
        if progress is not None:
            progress.close()
    return [row for k in sorted(finished) for row in finished[k]], interrupted


def _clock(seconds: float) -> str:
    """``H:MM:SS``."""
    minutes, second = divmod(round(seconds), 60)
    return f"{minutes // 60}:{minutes % 60:02d}:{second:02d}"
