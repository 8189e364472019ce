"""``solarnav batch INPUT... [--calibrate [--tune]] [--replay] [--estimators a,b,c] [--heading auto|mag|sun|mag+sun]
[--vehicles MAP.json] [--scheduler tcp://HOST:8786 | --workers N] -o OUTDIR``: process many logs on a Dask
cluster, one task per log, and write per log its calibration, states and diagnostics (the files of ``calibrate``
and ``replay``) plus the summary ``fleet.parquet`` / ``fleet.csv`` and the per-vehicle noise history.

INPUT: log files, directories (searched recursively for .ulg and .bin) or glob patterns; a log's sun-device CSV
and device JSON are the ``<stem>_sun.csv`` / ``<stem>_device.json`` beside it. Without ``--scheduler`` (or
``DASK_SCHEDULER_ADDRESS``) a local cluster of N worker processes with one thread each runs the tasks. A re-run
skips the logs whose outputs exist for the same content and settings; a bad log gives one error row and the batch
goes on. Exit status 0 when every log was processed, 1 when some failed, 130 when interrupted (docs/batch.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from app.batch.history import read_vehicle_map
from app.batch.plan import LOGS_DIR, BatchSettings, discover_inputs
from app.batch.run import Progress, batch_client, dashboard_text, run_batch, scheduler_address
from app.batch.summary import fleet_table, write_summary
from app.batch.task import ERROR
from estimators.api import DEFAULT_ESTIMATORS, ESTIMATORS
from estimators.inputs.records import AUTO_HEADING, HEADING_SOURCES
from estimators.tuning import DEFAULT_BUDGET
from estimators.warmup import prepare_compile, warm_up
from ingest.errors import InputError

#: Exit status of an interrupted batch (128 + SIGINT).
EXIT_INTERRUPTED = 130


def add_parser(subparsers) -> None:
    """Register the ``batch`` sub-parser."""
    parser = subparsers.add_parser("batch", help="process many logs on a Dask cluster into a fleet summary",
                                   description=__doc__)
    parser.add_argument("inputs", nargs="+", metavar="INPUT", help="log files, directories or glob patterns")
    parser.add_argument("--calibrate", action="store_true", help="calibrate every log (calibrate's defaults)")
    parser.add_argument("--tune", action="store_true", help="with --calibrate: identify each estimator's noise")
    parser.add_argument("--tune-budget", type=int, default=DEFAULT_BUDGET, metavar="N",
                        help=f"filter replays per estimator for --tune (default {DEFAULT_BUDGET})")
    parser.add_argument("--replay", action="store_true",
                        help="re-run the estimators (with the log's calibration under --calibrate)")
    parser.add_argument("--estimators", default=",".join(DEFAULT_ESTIMATORS), metavar="A,B,C",
                        help=f"comma-separated subset of {', '.join(ESTIMATORS)} (default: all)")
    parser.add_argument("--heading", choices=HEADING_SOURCES, default=AUTO_HEADING, help="replay heading source")
    parser.add_argument("--rate-hz", type=float, default=50.0, metavar="HZ", help="replay output rate")
    parser.add_argument("--force", action="store_true", help="replay logs whose inputs are refused")
    parser.add_argument("--vehicles", metavar="MAP.json",
                        help='vehicle of each log: {"vehicle": ["file pattern or sys_uuid", ...]} (default: the '
                             "log's sys_uuid)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="tcp://HOST:8786", help="an existing Dask scheduler")
    where.add_argument("--workers", type=int, metavar="N", help="local worker processes (default: CPUs)")
    parser.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="output directory (created)")


def run(args: argparse.Namespace) -> int:
    """Plan, run the tasks, write the summary and print what happened."""
    settings = BatchSettings(calibrate=args.calibrate, tune=args.tune, tune_budget=args.tune_budget,
                             replay=args.replay, estimators=args.estimators, heading=args.heading,
                             rate_hz=args.rate_hz, force=args.force)
    if args.workers is not None and args.workers < 1:
        raise InputError(f"must be at least 1, got {args.workers}", field="--workers")
    vehicles = read_vehicle_map(args.vehicles) if args.vehicles else None
    items = discover_inputs(args.inputs)
    outdir = Path(args.output).resolve()
    (outdir / LOGS_DIR).mkdir(parents=True, exist_ok=True)
    message = prepare_compile(settings.estimators) if settings.calibrate or settings.replay else None
    if message is not None and scheduler_address(args.scheduler) is None:
        # once here rather than in every local worker at the same time (they share this machine's numba cache)
        print(f"{message}, once before the workers start ...", file=sys.stderr, flush=True)
        warm_up()
    elif message is not None:
        print(f"{message}: each worker host compiles on its first log ...", file=sys.stderr, flush=True)
    print(f"batch: {len(items)} logs, settings {settings.digest()} -> {outdir}", file=sys.stderr, flush=True)
    with batch_client(args.scheduler, args.workers) as client:
        workers = len(client.scheduler_info().get("workers", {}))
        print(f"Dask scheduler {client.scheduler.address}, {workers} workers; {dashboard_text(client)}",
              file=sys.stderr, flush=True)
        rows, interrupted = run_batch(client, items, settings, str(outdir), Progress(len(items)))
    failed = 0
    if rows:  # (none when interrupted before the first log finished)
        fleet, history = fleet_table(rows, vehicles)
        written = write_summary(fleet, history, outdir)
        print(format_summary(fleet, history, len(items)))
        print("\n".join(f"wrote {path}" for path in written))
        failed = int((fleet.drop_duplicates("file")["status"] == ERROR).sum())
    if interrupted:
        print("interrupted: run the same command again to process the remaining logs", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 1 if failed else 0


def format_summary(fleet: pd.DataFrame, history: pd.DataFrame, n_inputs: int) -> str:
    """Logs summarised, ok (resumed) and failed, each failure with its message, each noise change flag."""
    logs = fleet.drop_duplicates("file")
    failed = logs[logs["status"] == ERROR]
    lines = [f"{len(logs)} of {n_inputs} logs summarised: {len(logs) - len(failed)} ok "
             f"({int(logs['resumed'].sum())} resumed), {len(failed)} failed"]
    lines += [f"  error: {row.file}: {row.message}" for row in failed.itertuples()]
    lines += [f"  note: {row.file}: {row.message}" for row in logs[(logs["status"] != ERROR)
                                                                   & logs["message"].astype(bool)].itertuples()]
    lines += [f"  noise change: {row.vehicle}: {row.name}: {row.figure} {row.ratio:.2f} x its median over the "
              "earlier logs" for row in history[history["flagged"].astype(bool)].itertuples()]
    return "\n".join(lines)
