"""Ingest speed: ``load_flight_log`` against pyulog's own parse of the same file with the same topic filter.

Builds a long log at PX4's default logging rates by tiling every topic of a real PX4 1.15 SITL log
(``sample_px4_events.ulg``, 31 s) with shifted timestamps, writes it with pyulog's ``ULog.write_ulog`` into a
temporary directory, then times both readers (best of ``--repeat`` alternating rounds, wall and CPU time; numba
is compiled before timing).
Target: ``load_flight_log`` within 1.5x of pyulog's parse.

Run: ``.venv/bin/python benchmarks/bench_ingest.py [--minutes 60] [--repeat 1]`` (writing the one-hour file takes
pyulog a few minutes; it is not part of the test suite).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from pyulog import ULog

from ingest.px4_topics import ALL_TOPICS
from ingest.ulog_reader import load_flight_log

SOURCE_LOG = Path(__file__).resolve().parents[2] / "shared" / "real_logs" / "sample_px4_events.ulg"
#: Fields holding absolute times [us] that move with the copy (0 means "not set" and stays 0).
TIME_FIELDS = ("timestamp", "timestamp_sample", "time_utc_usec")


def tiled_log(source: Path, minutes: float) -> ULog:
    """``source`` with every topic repeated back to back until it spans ``minutes``."""
    ulog = ULog(str(source))
    first_us = min(int(d.data["timestamp"][d.data["timestamp"] > 0].min(initial=2**62)) for d in ulog.data_list)
    period_us = ulog.last_timestamp - first_us + 4000
    copies = int(np.ceil(minutes * 60e6 / period_us))
    for data_set in ulog.data_list:
        n_rows = len(data_set.data["timestamp"])
        shift_us = np.repeat(np.arange(copies, dtype=np.uint64) * np.uint64(period_us), n_rows)
        for field, values in data_set.data.items():
            tiled = np.tile(values, copies)
            if field in TIME_FIELDS:
                tiled = np.where(tiled > 0, tiled + shift_us.astype(tiled.dtype), tiled)
            data_set.data[field] = tiled
    return ulog


def best_times_s(readers: dict, repeat: int) -> dict[str, tuple[float, float]]:
    """Shortest wall and CPU time [s] of each reader over ``repeat`` rounds; the readers alternate within a
    round so that load from other processes on a shared machine hits both alike."""
    best = {name: (np.inf, np.inf) for name in readers}
    for _ in range(repeat):
        for name, read in readers.items():
            wall, cpu = time.perf_counter(), time.process_time()
            read()
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            best[name] = (min(best[name][0], wall), min(best[name][1], cpu))
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0, help="length of the built log [min]")
    parser.add_argument("--repeat", type=int, default=1, help="timed runs per reader (best is kept)")
    args = parser.parse_args()

    load_flight_log(SOURCE_LOG)  # compile the numba kernel outside the timed region
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "long.ulg"
        start = time.perf_counter()
        tiled_log(SOURCE_LOG, args.minutes).write_ulog(str(path))
        print(f"built {path.stat().st_size / 1e6:.1f} MB ({args.minutes:g} min) in "
              f"{time.perf_counter() - start:.0f} s with ULog.write_ulog")

        times = best_times_s({"pyulog parse (same topic filter)": lambda: ULog(
            str(path), message_name_filter_list=list(ALL_TOPICS)), "load_flight_log": lambda: load_flight_log(path)},
            args.repeat)
        log = load_flight_log(path)
    print(f"log: {log.meta.duration_s / 60:.1f} min of IMU data, {len(log['imu'])} IMU rows, "
          f"{len(log.streams)} streams")
    for name, (wall_s, cpu_s) in times.items():
        print(f"{name:<34} wall {wall_s:6.2f} s   cpu {cpu_s:6.2f} s")
    (pyulog_wall, pyulog_cpu), (ingest_wall, ingest_cpu) = times.values()
    print(f"ratio: wall {ingest_wall / pyulog_wall:.2f}, cpu {ingest_cpu / pyulog_cpu:.2f} (target <= 1.5)")


if __name__ == "__main__":
    main()
