"""Snapshot of every estimator's states on the bundled sample logs and the real PX4 logs, and the comparison of two
snapshots (the before/after check of a refactor).

    .venv/bin/python benchmarks/replay_snapshot.py save DIR      # run all estimators, write DIR/<case>.parquet
    .venv/bin/python benchmarks/replay_snapshot.py compare A B   # max |difference| per case and estimator, and
                                                                 # the RMS against truth/onboard of both

Cases: the bundled simulated logs (magnetometer heading and magnetometer + sun) and every PX4 log in
``../shared/real_logs/`` that loads (skipped with a line when the folder is absent).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from estimators.api import run_estimators
from estimators.evaluation import evaluate
from ingest.errors import InputError
from ingest.log_formats import load_flight_log
from ingest.sun_log import load_sun_device, with_sun

ROOT = Path(__file__).resolve().parents[1]
REAL_LOGS = ROOT.parent / "shared" / "real_logs"


def cases():
    """(case name, FlightLog, heading) for every snapshot case."""
    for name in ("paper", "failed_cell"):
        log = load_flight_log(ROOT / "sample_logs" / f"{name}.ulg")
        yield f"{name}_mag", log, "mag"
        device = load_sun_device(ROOT / "sample_logs" / f"{name}_device.json")
        yield f"{name}_mag+sun", with_sun(log, ROOT / "sample_logs" / f"{name}_sun.csv", device=device), "mag+sun"
    if not REAL_LOGS.is_dir():
        print(f"no {REAL_LOGS}: real logs left out")
        return
    for path in sorted(REAL_LOGS.glob("*.ulg")):
        try:
            log = load_flight_log(path)
        except InputError as error:
            print(f"{path.name}: {error}")
            continue
        yield path.stem, log, "mag"


def save(directory: Path) -> None:
    directory.mkdir(parents=True, exist_ok=True)
    for name, log, heading in cases():
        try:
            result = run_estimators(log, heading=heading)
        except InputError as error:
            print(f"{name}: {error}")
            continue
        result.states.to_parquet(directory / f"{name}.parquet")
        rms = evaluate(result.states, log).rms()
        rms.to_csv(directory / f"{name}_rms.csv")
        print(f"{name}: {len(result.states)} rows")


def compare_snapshots(before: Path, after: Path) -> None:
    for path in sorted(before.glob("*.parquet")):
        other = after / path.name
        if not other.exists():
            print(f"{path.stem}: missing in {after}")
            continue
        a, b = pd.read_parquet(path), pd.read_parquet(other)
        for estimator, frame in a.groupby("estimator", observed=True):
            other_frame = b[b["estimator"] == estimator]
            numeric = [c for c in frame.columns if c != "estimator" and c in other_frame]
            if len(frame) != len(other_frame):
                print(f"{path.stem:45s} {estimator:20s} rows {len(frame)} -> {len(other_frame)}")
                continue
            x, y = frame[numeric].to_numpy(float), other_frame[numeric].to_numpy(float)
            same_nan = np.array_equal(np.isnan(x), np.isnan(y))
            difference = np.nanmax(np.abs(x - y)) if np.isfinite(x - y).any() else 0.0
            print(f"{path.stem:45s} {estimator:20s} max|diff| {difference:.3e}  NaN pattern "
                  f"{'same' if same_nan else 'DIFFERENT'}")
        rms_a = pd.read_csv(before / f"{path.stem}_rms.csv", index_col=0)
        rms_b = pd.read_csv(after / f"{path.stem}_rms.csv", index_col=0)
        change = 100.0 * (rms_b - rms_a) / rms_a
        if (change.abs() > 1e-6).any().any():
            print(f"  RMS change [%] of {path.stem}:\n{change.round(3).to_string()}")


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "save":
        save(Path(sys.argv[2]))
    elif len(sys.argv) == 4 and sys.argv[1] == "compare":
        compare_snapshots(Path(sys.argv[2]), Path(sys.argv[3]))
    else:
        sys.exit(__doc__)
