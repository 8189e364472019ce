"""Simulator speed: fly a scenario, sample every sensor and write the files, for flights of a given length.

Times :func:`sim.simulate.simulate` and :func:`sim.px4_export.write_outputs` separately for each ``--minutes``
value (the paper mission, extended at rest on the ground past its 14.4 minutes), and pyulog's own
``ULog.write_ulog`` on the shortest one for comparison with the vectorised writer.

Run: ``.venv/bin/python benchmarks/bench_sim.py [--minutes 15 60] [--repeat 1]`` (not part of the test suite).
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
from pathlib import Path

import numpy as np
from pyulog import ULog

from sim.px4_export import write_outputs
from sim.scenarios import SCENARIOS
from sim.simulate import simulate


def _best(function, repeat: int):
    times, value = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        value = function()
        times.append(time.perf_counter() - start)
    return min(times), value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, nargs="+", default=[15.0, 60.0], help="flight lengths [min]")
    parser.add_argument("--scenario", default="paper", choices=sorted(SCENARIOS))
    parser.add_argument("--repeat", type=int, default=1, help="timed runs (best is kept)")
    args = parser.parse_args()
    scenario = SCENARIOS[args.scenario]
    simulate(scenario, np.random.default_rng(0), duration_s=5.0)  # imports and caches outside the timing
    with tempfile.TemporaryDirectory() as directory:
        for minutes in args.minutes:
            duration_s = 60 * minutes
            sim_s, result = _best(lambda d=duration_s: simulate(scenario, np.random.default_rng(0), duration_s=d),
                                  args.repeat)
            write_s, paths = _best(lambda r=result: write_outputs(r, directory), args.repeat)
            n = len(result.truth.time_us)
            size_mb = sum(path.stat().st_size for path in paths.values()) / 1e6
            print(f"{minutes:g} min ({n} IMU samples): simulate {sim_s:.2f} s, write {write_s:.2f} s "
                  f"({size_mb:.1f} MB)")
        shortest = min(args.minutes)
        content = Path(directory, f"{scenario.name}.ulg")
        if shortest != args.minutes[-1]:  # the file on disk is from the last run
            write_outputs(simulate(scenario, np.random.default_rng(0), duration_s=60 * shortest), directory)
        parsed = ULog(str(content))
        pyulog_s, _ = _best(lambda: parsed.write_ulog(io.BytesIO()), 1)
        print(f"pyulog ULog.write_ulog of the {shortest:g} min log: {pyulog_s:.2f} s")


if __name__ == "__main__":
    main()
