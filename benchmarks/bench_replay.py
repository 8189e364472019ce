"""End-to-end replay speed: ``solarnav replay`` of a long log against pyulog's full parse of the same file, measured
in the same run, and the split of the replay's wall time by stage (issue 32).

Builds the paper mission simulated over ``--minutes`` (default one hour; 250 Hz IMU, 50 Hz magnetometer and
barometer, 10 Hz GPS and sun device), or takes ``--log PATH`` (with ``--sun``/``--device`` when it has a sun-device
log), then alternates ``--repeat`` rounds of

* pyulog's full parse (``ULog(path)``, every topic) in this process,
* ``solarnav replay LOG [--sun SUN --device DEV] -o OUT.parquet`` as a user runs it (a new process, warm numba
  cache: one replay before the rounds), wall time from start to exit;

and reports the best of each and their ratio (goal <= 2.0). Then one replay in this process, timed by stage: the
imports of the replay command, ``load_flight_log`` and the sun-device log, the replay inputs, each filter's kernel
and its report (consistency checks), the wait of the three-stage filter for the error-state filter's bias states
(docs/three_stage.md, 'Pre-processing'), the stacked tables and the Parquet write.

Run: ``.venv/bin/python benchmarks/bench_replay.py [--minutes 60] [--repeat 3] [--log PATH [--sun CSV --device
JSON]]`` (not part of the test suite).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SOLARNAV = Path(sys.executable).parent / "solarnav"
IMPORTS_SNIPPET = ("import time; t = time.perf_counter(); import app.commands.replay, app.commands.sun_options; "
                   "print(time.perf_counter() - t)")


def build_log(minutes: float, directory: Path) -> dict[str, Path]:
    """The paper mission simulated over ``minutes``, written as ``solarnav simulate`` writes it."""
    from sim.px4_export import write_outputs
    from sim.scenarios import SCENARIOS
    from sim.simulate import simulate

    started = time.perf_counter()
    paths = write_outputs(simulate(SCENARIOS["paper"], np.random.default_rng(0), duration_s=60.0 * minutes),
                          directory)
    print(f"built {paths['ulog'].stat().st_size / 1e6:.1f} MB ({minutes:g} min) in "
          f"{time.perf_counter() - started:.0f} s")
    return paths


def replay_command(log: Path, sun: Path | None, device: Path | None, out: Path) -> list[str]:
    command = [str(SOLARNAV), "replay", str(log), "-o", str(out)]
    if sun is not None:
        command += ["--sun", str(sun)] + (["--device", str(device)] if device is not None else [])
    return command


def rounds(log: Path, command: list[str], repeat: int) -> tuple[float, float]:
    """Best wall time of pyulog's full parse and of the replay command, alternating [s]."""
    from pyulog import ULog

    subprocess.run(command, cwd=REPO, check=True, capture_output=True)  # numba cache warm, file in the page cache
    parse, replay = [], []
    for _ in range(repeat):
        started = time.perf_counter()
        ULog(str(log))
        parse.append(time.perf_counter() - started)
        started = time.perf_counter()
        subprocess.run(command, cwd=REPO, check=True, capture_output=True)
        replay.append(time.perf_counter() - started)
    return min(parse), min(replay)


def stage_split(log_path: Path, sun: Path | None, device: Path | None, out: Path) -> list[tuple[str, float]]:
    """One replay in this process, timed by stage [s] (the imports measured in a new process)."""
    imports = subprocess.run([sys.executable, "-c", IMPORTS_SNIPPET], cwd=REPO, check=True, capture_output=True,
                             text=True)
    from ingest.log_formats import load_flight_log
    from ingest.sun_log import load_sun_device, with_sun
    from workflows.replay import replay_log, write_table

    stages = [("python start and imports of the replay command", float(imports.stdout))]
    started = time.perf_counter()
    log = load_flight_log(log_path)
    stages.append(("load_flight_log", time.perf_counter() - started))
    if sun is not None:
        started = time.perf_counter()
        log = with_sun(log, sun, device=load_sun_device(device) if device is not None else None)
        stages.append(("sun-device log", time.perf_counter() - started))
    events: list[tuple[float, str, str]] = []
    started = time.perf_counter()
    result = replay_log(log, progress=lambda stage, name: events.append((time.perf_counter(), stage, name)))
    replay_s = time.perf_counter() - started
    at = {(stage, name): t - started for t, stage, name in events}
    first_run = min(t for (stage, _), t in at.items() if stage == "run")
    stages.append(("replay inputs (build_replay_inputs, sun-vector solver)", first_run))
    for name, report in result.reports.items():
        stages.append((f"  {name}: kernel (on its thread)", report.timings_s["kernel"]))
        stages.append((f"  {name}: run to report done (on its thread)", at[("done", name)] - at[("run", name)]))
    stages.append(("filters, wall (first run to last report)", at[("report", "")] - first_run))
    stages.append(("stacked tables", replay_s - at[("report", "")]))
    started = time.perf_counter()
    write_table(result.states, out)
    stages.append(("Parquet write", time.perf_counter() - started))
    return stages


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=60.0, help="length of the simulated log [min]")
    parser.add_argument("--repeat", type=int, default=3, help="alternating rounds (best is kept)")
    parser.add_argument("--log", type=Path, default=None, help="an existing log instead of the simulated one")
    parser.add_argument("--sun", type=Path, default=None, help="its sun-device CSV")
    parser.add_argument("--device", type=Path, default=None, help="its sun-device JSON")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        if args.log is None:
            paths = build_log(args.minutes, Path(tmp))
            log, sun, device = paths["ulog"], paths["sun_csv"], paths["device_json"]
        else:
            log, sun, device = args.log, args.sun, args.device
        out = Path(tmp) / "states.parquet"
        parse_s, replay_s = rounds(log, replay_command(log, sun, device, out), args.repeat)
        megabytes = log.stat().st_size / 1e6
        print(f"pyulog full parse       {parse_s:6.2f} s ({megabytes / parse_s:.0f} MB/s)")
        print(f"solarnav replay (wall)  {replay_s:6.2f} s  = {replay_s / parse_s:.2f} x pyulog's parse (goal <= 2.0)")
        print("split of one replay in this process [s]:")
        for label, seconds in stage_split(log, sun, device, out):
            print(f"  {label:58s} {seconds:6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
