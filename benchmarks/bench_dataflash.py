"""Ingest speed of ArduPilot DataFlash logs: ``ingest.dataflash_reader`` against pymavlink's ``DFReader``.

On each file, from the bytes in memory (the file is read once before timing; numba compiled before timing), best
of ``--repeat`` alternating rounds, wall time and MB/s:

* ``DFReader_binary(path)``: DFReader opening and indexing the file (offsets and counts of every type, FMT, PARM),
  no message decoded; with its Cython indexer (``dfindexer``, the default where it is built) and without it;
* DFReader decoding the message types the reader uses (``recv_match`` over them, one Python object each);
* ``flightlog_from_dataflash``: the whole canonical ``FlightLog`` (record walk, FMT, numpy decoding, mapping).

Files: the two real ArduPlane 4.0.8 logs of ``shared/real_logs`` and the paper mission simulated for
``--minutes`` and written by ``sim.dataflash_writer`` (250 Hz IMU, 50 Hz magnetometer and barometer, 10 Hz GPS,
ground truth) into a temporary directory.

Target (issue 17): the whole FlightLog within 1.5x of the time DFReader needs just to open and index.

Run: ``.venv/bin/python benchmarks/bench_dataflash.py [--minutes 30] [--repeat 3]`` (not part of the test suite).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from pymavlink import DFReader

from ingest.dataflash_reader import flightlog_from_dataflash
from sim.dataflash_writer import write_dataflash
from sim.scenarios import SCENARIOS
from sim.simulate import simulate

REAL_LOGS = Path(__file__).resolve().parents[2] / "shared" / "real_logs"
REAL_FILES = ("arduplane_4.0.8_ground_static.bin", "arduplane_4.0.8_ground_walk.bin")
#: Message types the reader decodes.
READ_TYPES = ["IMU", "MAG", "BARO", "GPS", "GPA", "ARSP", "XKF1", "XKF2", "NKF1", "NKF2", "ATT", "POS", "PARM",
              "MSG", "SIM", "SIM2", "SWND"]


def _dfreader_decode(path: Path) -> int:
    reader = DFReader.DFReader_binary(str(path), zero_time_base=False)
    count = 0
    while reader.recv_match(type=READ_TYPES) is not None:
        count += 1
    return count


def _dfreader_python_index(path: Path) -> None:
    """DFReader's indexing without its Cython indexer (``PYMAVLINK_FAST_INDEX=0``; older pymavlink releases and
    installs without a compiler)."""
    os.environ["PYMAVLINK_FAST_INDEX"] = "0"
    try:
        DFReader.DFReader_binary(str(path), zero_time_base=False)
    finally:
        del os.environ["PYMAVLINK_FAST_INDEX"]


def bench_file(path: Path, repeat: int) -> dict[str, float]:
    """Best wall time [s] of each reader on ``path``."""
    content = path.read_bytes()
    runs = {"DFReader open+index": lambda: DFReader.DFReader_binary(str(path), zero_time_base=False),
            "DFReader open+index, Python": lambda: _dfreader_python_index(path),
            "DFReader decode used types": lambda: _dfreader_decode(path),
            "solarnav FlightLog": lambda: flightlog_from_dataflash(content, source=path.name)}
    best = dict.fromkeys(runs, np.inf)
    for _ in range(repeat):
        for name, run in runs.items():
            start = time.perf_counter()
            run()
            best[name] = min(best[name], time.perf_counter() - start)
    return best


def report(path: Path, best: dict[str, float]) -> None:
    size_mb = path.stat().st_size / 1e6
    print(f"\n{path.name}: {size_mb:.2f} MB")
    for name, seconds in best.items():
        print(f"  {name:<28} {seconds * 1e3:9.1f} ms  {size_mb / seconds:8.1f} MB/s")
    ratio = best["solarnav FlightLog"] / best["DFReader open+index"]
    python = best["solarnav FlightLog"] / best["DFReader open+index, Python"]
    print(f"  FlightLog / DFReader index: {ratio:.2f} (Cython indexer), {python:.2f} (Python; target <= 1.5); "
          f"DFReader decode / FlightLog: {best['DFReader decode used types'] / best['solarnav FlightLog']:.1f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=30.0, help="simulated mission length (default 30)")
    parser.add_argument("--repeat", type=int, default=3, help="rounds per reader (default 3)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as directory:
        result = simulate(SCENARIOS["paper"], np.random.default_rng(1), duration_s=args.minutes * 60.0, seed=1)
        simulated = write_dataflash(result, Path(directory) / "paper.bin")
        flightlog_from_dataflash(simulated.read_bytes(), source=simulated.name)  # numba compiled before timing
        paths = [REAL_LOGS / name for name in REAL_FILES if (REAL_LOGS / name).is_file()] + [simulated]
        for path in paths:
            report(path, bench_file(path, args.repeat))


if __name__ == "__main__":
    main()
