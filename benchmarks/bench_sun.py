"""Sun-vector solvers: least squares (LS) vs adaptive least squares (ALS) accuracy table, and solver speed.

Accuracy: simulated currents of the default device (k = 100 mA, sky light 10 mA, noise 0.5 mA) at random yaw
and roll/pitch within +-20 deg (+-5 deg for the low sun), seeded, one case per row:
faults are a cell stuck at 0 A, a cell in the airframe's shadow (sky light only), a cell with a 30 mA glint.
Columns: share of epochs with a solution, median / 95th-percentile angular error [deg] over those epochs, and for
the faulty cell the share of epochs with a solution in which it is flagged while lit (ALS only).

Speed: 10 Hz x 1 h = 36 000 epochs through ``solve_sun_ls``, ``solve_sun_adaptive`` (healthy cells, and one cell
stuck, which makes every epoch try the alternative fault hypotheses) and ``solve_sun_log`` (which adds the noise
estimate and the DataFrame); best of ``--repeat`` rounds, wall and CPU time; numba is compiled before timing.

Run: ``.venv/bin/python benchmarks/bench_sun.py [--epochs 36000] [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd

from estimators.sun import photocells
from estimators.sun import solver as sun_solver
from ingest.frames import euler_to_matrix
from ingest.sun_device import SunDevice

K_A, SKY_A, NOISE_A = 0.1, 0.01, 5e-4
DEVICE = SunDevice()
COS_LIT_MIN = np.cos(np.radians(sun_solver.SunSolverConfig().max_incidence_deg))

#: name -> (sun elevation [deg], roll/pitch range [deg], fault kind, faulty cell index, direct-sun k [A])
CASES = {
    "healthy, sun 60 deg": (60.0, 20.0, None, None, K_A),
    "healthy, sun 30 deg": (30.0, 20.0, None, None, K_A),
    "healthy, sun 10 deg": (10.0, 5.0, None, None, K_A),
    "side cell 4 stuck at 0": (35.0, 20.0, "stuck", 3, K_A),
    "top cell 1 stuck at 0": (35.0, 20.0, "stuck", 0, K_A),
    "side cell 3 shaded": (35.0, 20.0, "shaded", 2, K_A),
    "side cell 6 glint +30 mA": (35.0, 20.0, "glint", 5, K_A),
    "night": (30.0, 20.0, None, None, 0.0),
}


def simulate(seed: int, n: int, elevation_deg: float, tilt_deg: float, fault: str | None, cell: int | None,
             k_a: float):
    """Currents (n, 7) [A], true device-frame sun vectors (n, 3), up vectors (n, 3)."""
    rng = np.random.default_rng(seed)
    tilt = np.radians(tilt_deg)
    r_nb = euler_to_matrix(rng.uniform(-tilt, tilt, n), rng.uniform(-tilt, tilt, n), rng.uniform(-np.pi, np.pi, n))
    e, a = np.radians(elevation_deg), np.radians(57.0)
    s_ned = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), -np.sin(e)])
    s_device, up = photocells.device_sun_and_up(r_nb, np.broadcast_to(s_ned, (n, 3)), DEVICE)
    currents = photocells.photocell_currents(s_device, k_a, SKY_A, DEVICE, up) + rng.normal(0.0, NOISE_A, (n, 7))
    if fault == "stuck":
        currents[:, cell] = 0.0
    elif fault == "shaded":
        currents[:, cell] = photocells.photocell_currents(s_device, 0.0, SKY_A, DEVICE, up)[:, cell]
    elif fault == "glint":
        currents[:, cell] += 0.03
    return currents, s_device, up


def accuracy_table(n: int) -> pd.DataFrame:
    rows = []
    for index, (name, (elevation, tilt, fault, cell, k_a)) in enumerate(CASES.items()):
        currents, s_true, up = simulate(index, n, elevation, tilt, fault, cell, k_a)
        row = {"case": name}
        for label, solve in (("LS", sun_solver.solve_sun_ls), ("ALS", sun_solver.solve_sun_adaptive)):
            solution = solve(currents, DEVICE, NOISE_A, up)
            valid = solution.valid
            error = np.degrees(np.arccos(np.clip(np.sum(solution.s_device[valid] * s_true[valid], axis=1), -1, 1)))
            row[f"{label} solved"] = valid.mean()
            row[f"{label} median deg"] = np.median(error) if valid.any() else np.nan
            row[f"{label} p95 deg"] = np.percentile(error, 95) if valid.any() else np.nan
            if label == "ALS":
                lit = valid & (s_true @ DEVICE.normals_device[cell] > COS_LIT_MIN) if cell is not None else valid
                row["ALS flagged"] = solution.faulty[lit, cell].mean() if cell is not None and lit.any() else np.nan
        rows.append(row)
    return pd.DataFrame(rows).set_index("case")


def best_times_s(calls: dict, repeat: int) -> dict[str, tuple[float, float]]:
    """Shortest wall and CPU time [s] of each call over ``repeat`` alternating rounds."""
    best = {name: (np.inf, np.inf) for name in calls}
    for _ in range(repeat):
        for name, call in calls.items():
            wall, cpu = time.perf_counter(), time.process_time()
            call()
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            best[name] = (min(best[name][0], wall), min(best[name][1], cpu))
    return best


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=36000, help="epochs to time (default 10 Hz x 1 h)")
    parser.add_argument("--table-epochs", type=int, default=5000, help="epochs per accuracy case")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)

    with pd.option_context("display.float_format", "{:.3f}".format, "display.width", 160):
        print(f"LS vs adaptive LS, {args.table_epochs} epochs per case "
              f"(k {K_A * 1e3:.0f} mA, sky {SKY_A * 1e3:.0f} mA, noise {NOISE_A * 1e3:.1f} mA)")
        print(accuracy_table(args.table_epochs).to_string())

    healthy, _, up_healthy = simulate(98, args.epochs, 35.0, 20.0, None, None, K_A)
    stuck, _, up = simulate(99, args.epochs, 35.0, 20.0, "stuck", 3, K_A)
    frame = pd.DataFrame(stuck, columns=list(photocells.CURRENT_COLUMNS),
                         index=pd.Index(0.1 * np.arange(args.epochs), name="time_s"))
    calls = {
        "solve_sun_ls": lambda: sun_solver.solve_sun_ls(stuck, DEVICE, NOISE_A, up),
        "solve_sun_adaptive, healthy": lambda: sun_solver.solve_sun_adaptive(healthy, DEVICE, NOISE_A, up_healthy),
        "solve_sun_adaptive, stuck cell": lambda: sun_solver.solve_sun_adaptive(stuck, DEVICE, NOISE_A, up),
        "solve_sun_log, stuck cell": lambda: sun_solver.solve_sun_log(frame, DEVICE),
    }
    for call in calls.values():  # compile / warm up
        call()
    print(f"\nspeed, {args.epochs} epochs, best of {args.repeat}:")
    for name, (wall, cpu) in best_times_s(calls, args.repeat).items():
        print(f"  {name:32s} wall {wall * 1e3:7.1f} ms   cpu {cpu * 1e3:7.1f} ms   "
              f"{cpu / args.epochs * 1e6:5.2f} us/epoch")


if __name__ == "__main__":
    main()
