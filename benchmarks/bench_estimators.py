"""Estimator accuracy and speed: Table 2 side by side, microseconds per IMU sample, a 1-hour replay, FilterPy.

1. Accuracy: every registered estimator on the bundled simulated paper mission (``sample_logs/paper.ulg``) with the
   simulator's true noise (:func:`estimators.evaluation.config_for_simulation`): RMS errors after 60 s next to the
   paper's Table 2 row; position and height bars are the larger of Table 2 and 1.1 x the RMS of the simulated GPS
   error of the run (the receiver's Gauss-Markov error is unobservable).
2. Compile time per estimator, cold (empty numba cache) and cached (a second process), each in a fresh process;
   then the set-up's warm-up (:func:`estimators.warmup.warm_up`: three filters, sun-vector solver, ULog reader)
   cold in one process and in two processes side by side.
3. Microseconds per IMU sample per estimator (compiled kernel only) on a simulated 1-hour, 250 Hz flight (the
   paper mission, extended at rest on the ground past its 14.4 minutes).
4. Wall time of ``solarnav replay`` of that flight with all estimators (process start, ULog read, Parquet write).
5. The full-state direct model stepped through FilterPy's ``ExtendedKalmanFilter`` (same compiled model functions,
   same measurement stream; FilterPy's ``predict`` at every IMU sample, as FilterPy is used, and on our
   covariance schedule: 100 Hz and before every update), microseconds per IMU sample, and the speed-up of our
   kernel, measured in the same run.

Run: ``.venv/bin/python benchmarks/bench_estimators.py [--minutes 60] [--filterpy-seconds 120] [--repeat 2]
[--skip-compile]`` (not part of the test suite; FilterPy is a dev dependency).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from estimators.api import ESTIMATORS, run_estimators
from estimators.config import EstimatorConfig
from estimators.core import full_state, linalg
from estimators.core.schedule import COVARIANCE, EVENT, PROPAGATE, build_schedule
from estimators.direct import measurements, model
from estimators.direct import run as direct_run
from estimators.evaluation import PAPER_TABLE_2, QUANTITIES, config_for_simulation, rms_errors
from estimators.inputs import build, records
from ingest.log_formats import load_flight_log
from sim.px4_export import write_outputs
from sim.scenarios import SCENARIOS
from sim.simulate import simulate

REPO = Path(__file__).resolve().parents[1]
SAMPLE_LOGS = REPO / "sample_logs"
PYTHON = sys.executable


def accuracy_table(names: list[str]) -> None:
    log = load_flight_log(SAMPLE_LOGS / "paper.ulg")
    sidecar = json.loads((SAMPLE_LOGS / "paper_sim.json").read_text())
    result = run_estimators(log, estimators=names, config=config_for_simulation(sidecar))
    rms = rms_errors(result.states, log, after_s=60.0)
    gps = sidecar["sensor_errors"]["gps"]
    floor = {"position_m": 1.1 * gps["position_error_rms_horizontal_m"],
             "height_m": 1.1 * gps["position_error_rms_ned_m"][2]}
    print(f"GPS floor (1.1 x simulated GPS error RMS): position {floor['position_m']:.2f} m, "
          f"height {floor['height_m']:.2f} m")
    header = f"{'':22s}" + "".join(f"{q:>17s}" for q in QUANTITIES)
    print(header)
    for name in names:
        paper = PAPER_TABLE_2[name]
        bars = {q: max(paper[q], floor.get(q, 0.0)) for q in QUANTITIES}
        print(f"{name + ' paper':22s}" + "".join(f"{paper[q]:17.2f}" for q in QUANTITIES))
        print(f"{name + ' ours':22s}" + "".join(
            f"{rms.loc[name, q]:14.3f} {'ok' if rms.loc[name, q] <= bars[q] else '!!'}" for q in QUANTITIES))
    nis = result.diagnostics.groupby(["estimator", "sensor"], observed=True)["nis"].mean().unstack()
    print("mean NIS per sensor:\n" + nis.round(2).to_string())


_COMPILE_SNIPPET = """
import sys, time
start = time.perf_counter()
from estimators.api import run_estimators
from ingest.log_formats import load_flight_log
from sim.px4_export import write_outputs
from sim.scenarios import SCENARIOS
from sim.simulate import simulate
log = load_flight_log(sys.argv[1])
loaded = time.perf_counter()
run_estimators(log, estimators=[sys.argv[2]])
first = time.perf_counter()
run_estimators(log, estimators=[sys.argv[2]])
second = time.perf_counter()
print(loaded - start, first - loaded, second - first)
"""


def compile_times(names: list[str], log_path: Path) -> None:
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        for name in names:
            row = []
            for label in ("cold", "cached"):
                out = subprocess.run([PYTHON, "-c", _COMPILE_SNIPPET, str(log_path), name], env=env, cwd=REPO,
                                     capture_output=True, text=True, check=True).stdout.split()
                _, first, second = map(float, out)
                row.append(f"{label} first run {first:6.2f} s (compile/load {first - second:6.2f} s)")
            print(f"{name:22s}" + ";  ".join(row))


_WARM_UP_SNIPPET = """
import sys
from estimators.warmup import warm_up
print(warm_up(processes=int(sys.argv[1])))
"""


def warm_up_times() -> None:
    """The set-up's cold warm-up, one process against two, each with its own empty cache."""
    for processes in (1, 2):
        with tempfile.TemporaryDirectory() as cache:
            out = subprocess.run([PYTHON, "-c", _WARM_UP_SNIPPET, str(processes)], cwd=REPO, capture_output=True,
                                 text=True, check=True, env={**os.environ, "NUMBA_CACHE_DIR": cache}).stdout
            print(f"warm-up, cold, {processes} process{'es' if processes > 1 else ''}: {float(out.split()[-1]):.1f} s "
                  "wall")


def per_sample_times(names: list[str], log, repeat: int) -> dict[str, float]:
    n = len(log["imu"])
    out = {}
    for name in names:
        run_estimators(log, estimators=[name])  # compile / load outside the timing
        best = math.inf
        for _ in range(repeat):
            result = run_estimators(log, estimators=[name])
            best = min(best, result.reports[name].timings_s["kernel"])
        out[name] = best / n * 1e6
        print(f"{name:22s} {out[name]:6.2f} us per IMU sample ({best:.2f} s kernel for {n} samples)")
    return out


def replay_wall_time(log_path: Path, names: list[str]) -> float:
    with tempfile.TemporaryDirectory() as directory:
        out = Path(directory, "states.parquet")
        command = [str(Path(PYTHON).parent / "solarnav"), "replay", str(log_path), "--estimators", ",".join(names),
                   "-o", str(out)]
        subprocess.run(command, cwd=REPO, check=True, capture_output=True)  # warm caches
        start = time.perf_counter()
        subprocess.run(command, cwd=REPO, check=True, capture_output=True)
        wall = time.perf_counter() - start
        rows = len(pd.read_parquet(out))
    print(f"solarnav replay --estimators {','.join(names)}: {wall:.2f} s wall ({rows} rows written)")
    return wall


def filterpy_direct_us_per_sample(log, seconds: float, *, covariance_every_sample: bool) -> tuple[float, float]:
    """The direct model through FilterPy's EKF on the first ``seconds`` of the log, and our kernel on the same
    inputs; returns (filterpy, ours) microseconds per IMU sample.

    FilterPy gets the same compiled model functions (RK4 state step, Jacobian, process noise, measurement
    models), the same measurement stream and the filters' schedule (:func:`estimators.core.schedule.build_schedule`);
    its ``predict`` (covariance) runs either after every propagation step (how FilterPy is used: one predict per
    step) or as our kernel's (every covariance interval and before every update; docs/estimators.md, 'Scheduling
    rule').
    """
    from filterpy.kalman import ExtendedKalmanFilter

    config = EstimatorConfig(mag_fusion="vector")  # the three-axis magnetometer model of measurements.measurement
    inputs = build.build_replay_inputs(log, config)
    t0 = inputs.imu.time_s[0]
    keep_imu = inputs.imu.time_s <= t0 + seconds
    imu = records.ImuSamples(**{**inputs.imu.__dict__, "time_s": inputs.imu.time_s[keep_imu],
                               "gyro_rad_s": inputs.imu.gyro_rad_s[keep_imu],
                               "accel_m_s2": inputs.imu.accel_m_s2[keep_imu]})
    ev = inputs.events
    keep_ev = (ev.time_s <= imu.time_s[-1]) & (ev.kind != records.OUTPUT)
    ev = records.MeasurementEvents(ev.time_s[keep_ev], ev.kind[keep_ev], ev.imu_index[keep_ev], ev.values[keep_ev],
                                  ev.variances[keep_ev])
    short = records.ReplayInputs(**{**inputs.__dict__, "imu": imu, "events": ev})
    settings = direct_run.kernel_settings(short, config)
    n = len(settings.x0)
    direct_run.run(log, short, config)
    ours = min(direct_run.run(log, short, config).report.timings_s["kernel"] for _ in range(3)) / len(imu.time_s) * 1e6

    ekf = ExtendedKalmanFilter(dim_x=n, dim_z=1)
    ekf.x = settings.x0.reshape(n, 1).copy()
    ekf.P = settings.P0.copy()
    ekf.predict_x = lambda u=0: None  # the state is integrated below (RK4, same model)
    R_nb, S_euler, W_euler = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    k1, k2, k3, k4, xt = (np.empty(n) for _ in range(5))
    A, F, Qd, H = np.zeros((n, n)), np.empty((n, n)), np.zeros((n, n)), np.empty(n)
    g, field, layout = settings.gravity_m_s2, settings.field_ned, settings.layout
    # the shared scheduling rule (a covariance interval of 0: a predict after every propagation step)
    op, op_dt, op_index = build_schedule(imu.time_s, ev.time_s, ev.kind, ev.imu_index,
                                         0.0 if covariance_every_sample else settings.covariance_dt_s, math.inf)
    acc_dt, acc_gyro, x_cov = 0.0, np.zeros(3), settings.x0.copy()
    start = time.perf_counter()
    for s in range(len(op)):
        if op[s] == PROPAGATE:
            row, dt = op_index[s], op_dt[s]
            gyro, accel = imu.gyro_rad_s[row], imu.accel_m_s2[row]
            x = ekf.x.reshape(n)
            if acc_dt == 0.0:
                x_cov = x.copy()
            model.propagate_state(x, gyro, accel, dt, g, layout, R_nb, S_euler, W_euler, k1, k2, k3, k4, xt)
            ekf.x = x.reshape(n, 1)
            acc_dt += dt
            acc_gyro += gyro * dt
        elif op[s] == COVARIANCE and acc_dt > 0.0:
            model.jacobian(x_cov, acc_gyro / acc_dt, g, layout, R_nb, S_euler, W_euler, A)
            linalg.transition_matrix(A, acc_dt, F)
            model.process_noise(x_cov, settings.gyro_psd, settings.accel_psd, settings.walk_psd, acc_dt, R_nb, S_euler,
                                W_euler, Qd)
            ekf.F, ekf.Q = F, Qd
            ekf.predict()
            acc_dt, acc_gyro = 0.0, np.zeros(3)
        elif op[s] == EVENT:
            j = op_index[s]
            kind, values = ev.kind[j], ev.values[j]
            c0, c1 = full_state.component_range(kind, values, False, 3.0, settings.mag_heading)
            for c in range(c0, c1):  # (no sun events with the default magnetometer heading)
                h = measurements.measurement(ekf.x.reshape(n), kind, c, values, field, layout, R_nb, S_euler, W_euler,
                                             H)
                z, r_var = full_state.measured_value(kind, c, values, ev.variances[j])
                ekf.update(np.array([[z]]), HJacobian=lambda _x, H=H: H.reshape(1, n),
                           Hx=lambda _x, h=h: np.array([[h]]), R=np.array([[r_var]]))
    filterpy = (time.perf_counter() - start) / len(imu.time_s) * 1e6
    schedule = "predict at every IMU sample" if covariance_every_sample else "our covariance schedule"
    print(f"FilterPy ExtendedKalmanFilter, full-state direct model ({n} states, {seconds:g} s, {schedule}): "
          f"{filterpy:.1f} us per IMU sample; ours {ours:.2f} us -> {filterpy / ours:.0f}x faster")
    return filterpy, ours


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0, help="simulated flight length [min]")
    parser.add_argument("--filterpy-seconds", type=float, default=120.0,
                        help="seconds from the log start stepped in FilterPy (120: the still window, the hand launch "
                             "and the climb, so every sensor's updates are in the comparison)")
    parser.add_argument("--repeat", type=int, default=2, help="timed kernel runs (best is kept)")
    parser.add_argument("--skip-compile", action="store_true", help="skip the cold/cached compile measurement")
    args = parser.parse_args()
    names = list(ESTIMATORS)
    print("== 1. Table 2 on the simulated paper mission (RMS after 60 s; ok = within the bar)")
    accuracy_table(names)
    if not args.skip_compile:
        print("== 2. compile time (fresh process each; cold = empty numba cache)")
        compile_times(names, SAMPLE_LOGS / "paper.ulg")
        warm_up_times()
    with tempfile.TemporaryDirectory() as directory:
        print(f"== 3. simulating a {args.minutes:g} min flight (250 Hz IMU) ...")
        scenario = SCENARIOS["paper"]
        result = simulate(scenario, np.random.default_rng(scenario.seed), duration_s=60.0 * args.minutes)
        write_outputs(result, directory)
        log_path = Path(directory, f"{scenario.name}.ulg")
        log = load_flight_log(log_path)
        print(f"   {len(log['imu'])} IMU samples")
        per_sample_times(names, log, args.repeat)
        start = time.perf_counter()
        run_estimators(log, estimators=names)
        print(f"run_estimators with {', '.join(names)} (events, kernels, tables; log already loaded): "
              f"{time.perf_counter() - start:.2f} s")
        print("== 4. replay wall time")
        replay_wall_time(log_path, names)
        print("== 5. FilterPy comparison")
        for every in (True, False):
            filterpy_direct_us_per_sample(log, args.filterpy_seconds, covariance_every_sample=every)


if __name__ == "__main__":
    main()
