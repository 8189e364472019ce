"""Batch throughput on this machine: ``solarnav batch --calibrate --replay`` over N simulated flights on a local
Dask cluster of 1 and 2 worker processes.

Simulates ``--n`` flights of the paper mission cut to ``--minutes`` (250 Hz IMU, each with its own seed and day),
then for each worker count runs the batch into a fresh OUTDIR and reports: wall time, throughput [logs/min], the
mean task time (a task's own wall time, measured on the worker), the client-side overhead per log (wall x workers
- the sum of the task times, over N: scheduling, transfers, idle workers at the end), the scheduler's round trip per
task (N no-op tasks on the same cluster), and each worker's peak RSS (``getrusage`` on the worker after the batch).

Run: ``.venv/bin/python benchmarks/bench_batch.py [--n 200] [--minutes 5] [--workers 1,2]`` (not part of the test
suite; the 200 x 5 min default takes long on two shared cores: give a smaller N and say so).
"""

from __future__ import annotations

import argparse
import dataclasses
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

from app.batch.plan import LOGS_DIR, BatchSettings, discover_inputs
from app.batch.run import Progress, batch_client, run_batch
from app.batch.summary import fleet_table, write_summary
from estimators.warmup import warm_up
from sim.px4_export import write_outputs
from sim.scenarios import SCENARIOS
from sim.simulate import simulate


def simulate_fleet(directory: Path, n: int, minutes: float) -> None:
    """``n`` flights ``paper_<k>`` of ``minutes`` each into ``directory``."""
    base = SCENARIOS["paper"]
    for k in range(n):
        scenario = dataclasses.replace(base, name=f"paper_{k:04d}", site=dataclasses.replace(
            base.site, start_utc=f"2025-{1 + k // 28 % 12:02d}-{1 + k % 28:02d}T01:30:00Z"))
        write_outputs(simulate(scenario, np.random.default_rng(k), duration_s=60.0 * minutes), directory)


def _noop(k: int) -> int:
    return k


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kilobytes


def bench(logs: Path, outdir: Path, workers: int, settings: BatchSettings) -> dict:
    """One batch on a fresh local cluster; the figures of the module docstring."""
    items = discover_inputs([str(logs)])
    (outdir / LOGS_DIR).mkdir(parents=True)
    with batch_client(workers=workers) as client:
        start = time.perf_counter()
        rows, _ = run_batch(client, items, settings, str(outdir), Progress(len(items)))
        wall_s = time.perf_counter() - start
        write_summary(*fleet_table(rows), outdir)
        start = time.perf_counter()
        client.gather(client.map(_noop, range(len(items)), pure=False))
        round_trip_s = (time.perf_counter() - start) / len(items)
        peaks = client.run(_peak_rss_mb)
    task_s = {row["file"]: row["wall_s"] for row in rows}
    failed = sum(row["status"] != "ok" for row in rows)
    return {"workers": workers, "logs": len(items), "failed": failed, "wall_s": wall_s,
            "logs_per_min": 60.0 * len(items) / wall_s, "task_s": float(np.mean(list(task_s.values()))),
            "overhead_s": (wall_s * workers - sum(task_s.values())) / len(items), "round_trip_ms": 1e3 * round_trip_s,
            "peak_rss_mb": sorted(peaks.values())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=200, help="simulated logs (default 200)")
    parser.add_argument("--minutes", type=float, default=5.0, help="length of each log (default 5)")
    parser.add_argument("--workers", default="1,2", help="worker counts to compare (default 1,2)")
    args = parser.parse_args()
    settings = BatchSettings(calibrate=True, replay=True)
    warm_up()
    with tempfile.TemporaryDirectory() as tmp:
        logs = Path(tmp) / "logs"
        start = time.perf_counter()
        simulate_fleet(logs, args.n, args.minutes)
        size_mb = sum(p.stat().st_size for p in logs.glob("*.ulg")) / 1e6
        print(f"simulated {args.n} x {args.minutes:g} min in {time.perf_counter() - start:.0f} s "
              f"({size_mb:.0f} MB of ULog)")
        results = [bench(logs, Path(tmp) / f"out_{w}", int(w), settings) for w in args.workers.split(",")]
    print(f"{'workers':>7} {'logs':>5} {'failed':>6} {'wall [s]':>9} {'logs/min':>9} {'task [s]':>9} "
          f"{'overhead/log [s]':>17} {'round trip [ms]':>16}  peak RSS per worker [MB]")
    for r in results:
        print(f"{r['workers']:>7} {r['logs']:>5} {r['failed']:>6} {r['wall_s']:>9.1f} {r['logs_per_min']:>9.2f} "
              f"{r['task_s']:>9.2f} {r['overhead_s']:>17.2f} {r['round_trip_ms']:>16.1f}  "
              f"{', '.join(f'{v:.0f}' for v in r['peak_rss_mb'])}")


if __name__ == "__main__":
    main()
