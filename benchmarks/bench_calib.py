"""Calibration speed on long static IMU records (Allan analysis wants >= 1-2 h of data, docs/calibration.md, 'Allan
deviation').

Builds a stationary 250 Hz IMU stream of ``--minutes`` with seeded white noise and a gyro rate random walk, then
times :func:`calib.calibration.calibrate` (automatic segment, FIR, eq 50 / sigma, biases, Allan) and prints the
recovered figures beside the injected ones.

Run: ``.venv/bin/python benchmarks/bench_calib.py [--minutes 60] [--repeat 1]`` (not part of the test suite).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd

from calib.calibration import calibrate
from ingest.flightlog import STREAM_COLUMNS, FlightLog, LogMetadata, stream_info

RATE_HZ = 250.0
GYRO_SIGMA_RAD_S = 0.005
ACCEL_SIGMA_M_S2 = 0.05
GYRO_RANDOM_WALK = 2e-5  # K [rad/s/sqrt(s)]


def static_log(minutes: float, rng: np.random.Generator) -> FlightLog:
    """A level, motionless IMU record with white noise and a gyro bias random walk."""
    n = int(minutes * 60 * RATE_HZ)
    time_s = np.arange(n) / RATE_HZ
    walk = np.cumsum(rng.normal(0.0, GYRO_RANDOM_WALK / np.sqrt(RATE_HZ), size=(n, 3)), axis=0)
    gyro = rng.normal(0.0, GYRO_SIGMA_RAD_S, size=(n, 3)) + walk
    accel = rng.normal(0.0, ACCEL_SIGMA_M_S2, size=(n, 3)) + np.array([0.0, 0.0, -9.80665])
    imu = pd.DataFrame(np.hstack([gyro, accel]), columns=list(STREAM_COLUMNS["imu"]),
                       index=pd.Index(time_s, name="time_s"))
    meta = LogMetadata(source=f"static_{minutes:g}min", start_time_s=0.0, end_time_s=float(time_s[-1]),
                       duration_s=float(time_s[-1]), streams={"imu": stream_info("imu", time_s)})
    return FlightLog(streams={"imu": imu}, meta=meta)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0, help="length of the static record [min]")
    parser.add_argument("--repeat", type=int, default=1, help="timed runs (best is kept)")
    args = parser.parse_args()
    log = static_log(args.minutes, np.random.default_rng(0))
    times = []
    for _ in range(args.repeat):
        start = time.perf_counter()
        cal = calibrate(log)
        times.append(time.perf_counter() - start)
    n = len(log["imu"])
    print(f"{args.minutes:g} min static IMU ({n} samples at {RATE_HZ:g} Hz): calibrate {min(times):.2f} s")
    gyro = cal.sensors["gyroscope"]
    print(f"gyro sigma [rad/s]: {', '.join(f'{s:.4g}' for s in gyro.sigma)} (injected {GYRO_SIGMA_RAD_S:g})")
    print(f"accel sigma [m/s^2]: {', '.join(f'{s:.4g}' for s in cal.sensors['accelerometer'].sigma)} "
          f"(injected {ACCEL_SIGMA_M_S2:g})")
    for f in cal.allan["gyroscope"]:
        print(f"gyro Allan: N {f.white_density:.3g} rad/s/sqrt(Hz) (injected {GYRO_SIGMA_RAD_S / np.sqrt(RATE_HZ):.3g})"
              f", K {f.rate_random_walk:.3g} (injected {GYRO_RANDOM_WALK:g}), B {f.bias_instability:.3g}")


if __name__ == "__main__":
    main()
