"""Full-state direct filter (:mod:`estimators.direct`): the process model and every measurement model against
readable matrix-form statements (NumPy, in this module) and finite differences; the compiled kernel against the
same source run uncompiled (``NUMBA_DISABLE_JIT=1``); the kernel executes the shared schedule; the paper-literal
indirect filter against the direct one (docs/direct.md, 'Corrections to the paper'); accuracy and degraded modes
on an exact synthetic flight."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from estimators.config import EstimatorConfig
from estimators.core import linalg, recorder, schedule
from estimators.core.full_state import diagnostics_capacity
from estimators.direct import kernel as direct_kernel
from estimators.direct import measurements as meas
from estimators.direct import model
from estimators.direct import run as direct_run
from estimators.inputs import build, records
from estimators.inputs.records import AIRSPEED, BARO, GPS_POS, GPS_VEL, MAG, OUTPUT, SIDESLIP, SUN, ZERO_VELOCITY
from ingest.flightlog import FlightLog
from ingest.frames import euler_to_matrix
from tests.estimators_synthetic import assert_same_run, synthetic_flight

TESTS_DIR = Path(__file__).resolve().parent
REPO_DIR = TESTS_DIR.parent
G = 9.79
FULL_LAYOUT = np.array([12, 15, 17, 20], dtype=np.int64)  # b_a, wind, mag bias, baro bias
BASE_LAYOUT = np.array([-1, -1, -1, -1], dtype=np.int64)
N_FULL = 21
#: Finite-difference step and tolerances: central differences of smooth models with step 1e-6 are accurate to
#: ~1e-9, far inside the required 1e-6 relative agreement.
FD_STEP = 1e-6
RTOL = 1e-6
ATOL = 1e-7


def _random_state(rng):
    x = np.zeros(N_FULL)
    x[0:3] = rng.normal(0, 50, 3)
    x[3:6] = [rng.uniform(8, 20), rng.normal(0, 1), rng.normal(0, 1)]
    x[6:9] = [rng.uniform(-0.6, 0.6), rng.uniform(-0.4, 0.4), rng.uniform(-3, 3)]
    x[9:12] = rng.normal(0, 0.01, 3)
    x[12:15] = rng.normal(0, 0.1, 3)
    x[15:17] = rng.normal(0, 3, 2)
    x[17:20] = rng.normal(0, 0.05, 3)
    x[20] = rng.normal(0, 1)
    return x


def _scratch():
    """``R_nb``, ``S_euler``, ``W_euler`` scratch of the leaf functions."""
    return np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))


def _central_difference(fun, x, step=FD_STEP):
    cols = []
    for i in range(len(x)):
        e = np.zeros(len(x))
        e[i] = step
        cols.append((fun(x + e) - fun(x - e)) / (2 * step))
    return np.array(cols).T


# ----------------------------------------------------------------------------------------------------------------
# the models in matrix form (docs/direct.md, 'Process model' and 'Measurement models'), written independently of
# the scalar-unrolled numba leaf functions


def skew(a):
    """[a]x with [a]x b = a x b."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def euler_np(theta3):
    """``R_nb = Rz(psi) Ry(theta) Rx(phi)``, ``S_euler`` (``Theta_dot = S_euler omega``), ``W_euler = S_euler^-1``."""
    phi, theta, psi = theta3
    rx = np.array([[1, 0, 0], [0, math.cos(phi), -math.sin(phi)], [0, math.sin(phi), math.cos(phi)]])
    ry = np.array([[math.cos(theta), 0, math.sin(theta)], [0, 1, 0], [-math.sin(theta), 0, math.cos(theta)]])
    rz = np.array([[math.cos(psi), -math.sin(psi), 0], [math.sin(psi), math.cos(psi), 0], [0, 0, 1]])
    W_euler = np.array([[1.0, 0.0, -math.sin(theta)],
                        [0.0, math.cos(phi), math.sin(phi) * math.cos(theta)],
                        [0.0, -math.sin(phi), math.cos(phi) * math.cos(theta)]])
    return rz @ ry @ rx, np.linalg.inv(W_euler), W_euler


def _accel_bias(x, layout):
    return x[layout[0]:layout[0] + 3] if layout[0] >= 0 else np.zeros(3)


def f_np(x, gyro, accel, g, layout):
    """Corrected eq 36: ``p_dot = R_nb V``, ``V_dot = V x omega + f + R_nb^T g_n``, ``Theta_dot = S_euler omega``."""
    V, theta3, bg = x[3:6], x[6:9], x[9:12]
    R_nb, S_euler, _ = euler_np(theta3)
    omega = gyro - bg
    xdot = np.zeros_like(x)
    xdot[0:3] = R_nb @ V
    xdot[3:6] = np.cross(V, omega) + (accel - _accel_bias(x, layout)) + R_nb.T @ np.array([0.0, 0.0, g])
    xdot[6:9] = S_euler @ omega
    return xdot


def A_np(x, gyro, g, layout):
    """Eq 37 in blocks."""
    n = len(x)
    V, theta3, bg = x[3:6], x[6:9], x[9:12]
    R_nb, S_euler, W_euler = euler_np(theta3)
    _, q, r = gyro - bg
    phi, theta = theta3[0], theta3[1]
    cph, sph, cth, sth = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta)
    A = np.zeros((n, n))
    A[0:3, 3:6] = R_nb
    A[0:3, 6:9] = -R_nb @ skew(V) @ W_euler
    A[3:6, 3:6] = -skew(gyro - bg)
    A[3:6, 6:9] = skew(R_nb.T @ np.array([0.0, 0.0, g])) @ W_euler
    A[3:6, 9:12] = -skew(V)
    if layout[0] >= 0:
        A[3:6, layout[0]:layout[0] + 3] = -np.eye(3)
    A[6:9, 6:9] = [[(q * cph - r * sph) * sth / cth, (q * sph + r * cph) / cth ** 2, 0.0],
                   [-q * sph - r * cph, 0.0, 0.0],
                   [(q * cph - r * sph) / cth, (q * sph + r * cph) * sth / cth ** 2, 0.0]]
    A[6:9, 9:12] = -S_euler
    return A


def Qc_np(x, gyro_psd, accel_psd, walk_psd):
    """``G_g N_g^2 G_g^T + G_a N_a^2 G_a^T + diag(walk_psd)``, ``G_g = [0; -[V]x; -S_euler; 0]``,
    ``G_a = [0; -I; 0; 0]``."""
    n = len(x)
    _, S_euler, _ = euler_np(x[6:9])
    G_g = np.zeros((n, 3))
    G_g[3:6] = -skew(x[3:6])
    G_g[6:9] = -S_euler
    G_a = np.zeros((n, 3))
    G_a[3:6] = -np.eye(3)
    return gyro_psd * G_g @ G_g.T + accel_psd * G_a @ G_a.T + np.diag(walk_psd)


def rk4_np(x, gyro, accel, dt, g, layout):
    k1 = f_np(x, gyro, accel, g, layout)
    k2 = f_np(x + 0.5 * dt * k1, gyro, accel, g, layout)
    k3 = f_np(x + 0.5 * dt * k2, gyro, accel, g, layout)
    k4 = f_np(x + dt * k3, gyro, accel, g, layout)
    out = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    out[6], out[8] = ((out[[6, 8]] + math.pi) % (2.0 * math.pi)) - math.pi
    return out


def baro_np(x, layout):
    H = -np.eye(len(x))[2]
    if layout[3] >= 0:
        H[layout[3]] = 1.0
    return H @ x, H


def gps_position_np(x, comp):
    return x[comp], np.eye(len(x))[comp]


def _air_relative(x, layout):
    """``v_r = V - R_nb^T wbar``, ``dv_r/dTheta = -[a]x W_euler`` and ``dv_r/dw`` (3, 2)."""
    R_nb, _, W_euler = euler_np(x[6:9])
    iw = layout[1]
    wbar = np.array([x[iw], x[iw + 1], 0.0]) if iw >= 0 else np.zeros(3)
    a = R_nb.T @ wbar
    return x[3:6] - a, -skew(a) @ W_euler, -R_nb.T[:, 0:2]


def airspeed_np(x, layout):
    vr, dvr_dtheta, dvr_dw = _air_relative(x, layout)
    va = np.linalg.norm(vr)
    H = np.zeros(len(x))
    H[3:6] = vr / va
    H[6:9] = vr @ dvr_dtheta / va
    if layout[1] >= 0:
        H[layout[1]:layout[1] + 2] = vr @ dvr_dw / va
    return va, H


def sideslip_np(x, layout):
    vr, dvr_dtheta, dvr_dw = _air_relative(x, layout)
    H = np.zeros(len(x))
    H[3:6] = [0.0, 1.0, 0.0]
    H[6:9] = dvr_dtheta[1]
    if layout[1] >= 0:
        H[layout[1]:layout[1] + 2] = dvr_dw[1]
    return vr[1], H


def gps_velocity_np(x, comp):
    """NED velocity ``R_nb V`` (components 0..2), ground speed (3) and course (4) from its rows."""
    R_nb, _, W_euler = euler_np(x[6:9])
    vel = R_nb @ x[3:6]
    rows = np.zeros((3, len(x)))
    rows[:, 3:6] = R_nb
    rows[:, 6:9] = -R_nb @ skew(x[3:6]) @ W_euler
    if comp < 3:
        return vel[comp], rows[comp]
    vg = math.hypot(vel[0], vel[1])
    if comp == 3:
        return vg, (vel[0] * rows[0] + vel[1] * rows[1]) / vg
    return math.atan2(vel[1], vel[0]), (-vel[1] * rows[0] + vel[0] * rows[1]) / vg ** 2


def body_vector_np(x, ref_ned, comp, bias_first):
    """``b = R_nb^T r_n (+ b_m)``, ``db/dTheta = [b]x W_euler``."""
    R_nb, _, W_euler = euler_np(x[6:9])
    b = R_nb.T @ ref_ned
    H = np.zeros(len(x))
    H[6:9] = (skew(b) @ W_euler)[comp]
    h = b[comp]
    if bias_first >= 0:
        H[bias_first + comp] = 1.0
        h += x[bias_first + comp]
    return h, H


# ----------------------------------------------------------------------------------------------------------------
# process model


def _numba_f(gyro, accel, layout=FULL_LAYOUT):
    def f(x):
        out = np.empty(len(x))
        model.derivative(x, gyro, accel, G, layout, *_scratch(), out)
        return out
    return f


def test_euler_matrices():
    rng = np.random.default_rng(11)
    for _ in range(5):
        theta3 = _random_state(rng)[6:9]
        R_nb, S_euler, W_euler = _scratch()
        model.euler_matrices(*theta3, R_nb, S_euler, W_euler)
        np.testing.assert_allclose(R_nb, euler_to_matrix(*theta3), atol=1e-14)
        for got, expected in zip((R_nb, S_euler, W_euler), euler_np(theta3), strict=True):
            np.testing.assert_allclose(got, expected, atol=1e-14)


@pytest.mark.parametrize("seed", range(5))
def test_process_jacobian_matches_finite_differences(seed):
    rng = np.random.default_rng(seed)
    x = _random_state(rng)
    gyro, accel = rng.normal(0, 0.3, 3), rng.normal(0, 3, 3) + np.array([0, 0, -G])
    A = np.zeros((N_FULL, N_FULL))
    model.jacobian(x, gyro, G, FULL_LAYOUT, *_scratch(), A)
    A_fd = _central_difference(_numba_f(gyro, accel), x)
    np.testing.assert_allclose(A, A_fd, rtol=RTOL, atol=ATOL)
    # the matrix-form Jacobian and dynamics agree with the kernel's
    np.testing.assert_allclose(A_np(x, gyro, G, FULL_LAYOUT), A, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(f_np(x, gyro, accel, G, FULL_LAYOUT), _numba_f(gyro, accel)(x), rtol=1e-12,
                               atol=1e-12)
    # without the optional blocks
    x12 = x[:12]
    A12 = np.zeros((12, 12))
    model.jacobian(x12, gyro, G, BASE_LAYOUT, *_scratch(), A12)
    np.testing.assert_allclose(A12, _central_difference(_numba_f(gyro, accel, BASE_LAYOUT), x12), rtol=RTOL,
                               atol=ATOL)
    np.testing.assert_allclose(A_np(x12, gyro, G, BASE_LAYOUT), A12, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_process_noise_is_input_jacobian_quadratic_form(seed):
    """Qc = G_g N_g^2 G_g^T + G_a N_a^2 G_a^T + diag(rw) with G = df/d(input) from finite differences."""
    rng = np.random.default_rng(seed)
    x = _random_state(rng)
    gyro, accel = rng.normal(0, 0.3, 3), rng.normal(0, 3, 3)
    gyro_psd, accel_psd = 3e-6, 1e-3
    walk_psd = rng.uniform(0, 1e-6, N_FULL)
    Qc = np.zeros((N_FULL, N_FULL))
    model.process_noise(x, gyro_psd, accel_psd, walk_psd, 1.0, *_scratch(), Qc)
    G_g = _central_difference(lambda g: _numba_f(g, accel)(x), gyro)
    G_a = _central_difference(lambda a: _numba_f(gyro, a)(x), accel)
    expected = gyro_psd * G_g @ G_g.T + accel_psd * G_a @ G_a.T + np.diag(walk_psd)
    np.testing.assert_allclose(Qc, expected, rtol=RTOL, atol=1e-12)
    np.testing.assert_allclose(Qc_np(x, gyro_psd, accel_psd, walk_psd), Qc, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("seed", range(3))
def test_propagate_state_is_rk4_of_f(seed):
    rng = np.random.default_rng(200 + seed)
    x = _random_state(rng)
    gyro, accel = rng.normal(0, 0.3, 3), rng.normal(0, 3, 3) + np.array([0, 0, -G])
    for dt in (0.004, 0.0013):
        got = x.copy()
        model.propagate_state(got, gyro, accel, dt, G, FULL_LAYOUT, *_scratch(), *(np.empty(N_FULL) for _ in range(5)))
        np.testing.assert_allclose(got, rk4_np(x, gyro, accel, dt, G, FULL_LAYOUT), rtol=1e-12, atol=1e-12)


def test_transition_matches_matrix_exponential_for_small_steps():
    """F = I + A dt + (A dt)^2/2 agrees with expm(A dt) to third order."""
    from scipy.linalg import expm

    rng = np.random.default_rng(7)
    x = _random_state(rng)
    A = np.zeros((N_FULL, N_FULL))
    model.jacobian(x, rng.normal(0, 0.3, 3), G, FULL_LAYOUT, *_scratch(), A)
    F = np.empty_like(A)
    linalg.transition_matrix(A, 0.01, F)
    assert np.abs(F - expm(A * 0.01)).max() < np.linalg.norm(A * 0.01, 2) ** 3


# ----------------------------------------------------------------------------------------------------------------
# measurement models

MEASUREMENTS = [(BARO, 0), (AIRSPEED, 0), (SIDESLIP, 0), *((GPS_POS, c) for c in range(3)),
                *((GPS_VEL, c) for c in range(5)), *((MAG, c) for c in range(3)), *((SUN, c) for c in range(3)),
                *((ZERO_VELOCITY, c) for c in range(3))]


def _event_values(rng):
    """(unit earth field NED, event value row with the unit NED sun vector in 3..5)."""
    field = rng.normal(size=3)
    values = np.zeros(records.N_EVENT_VALUES)
    sun = rng.normal(size=3)
    values[3:6] = sun / np.linalg.norm(sun)
    return field / np.linalg.norm(field), values


@pytest.mark.parametrize(("kind", "comp"), MEASUREMENTS)
@pytest.mark.parametrize("layout", [FULL_LAYOUT, BASE_LAYOUT], ids=["all_states", "base"])
def test_measurement_jacobians_match_finite_differences(kind, comp, layout):
    rng = np.random.default_rng(100 + kind * 10 + comp)
    field, values = _event_values(rng)
    n = N_FULL if layout[0] >= 0 else 12
    for _ in range(3):
        x = _random_state(rng)[:n]
        H = np.empty(n)

        def h(xx):
            return meas.measurement(xx, kind, comp, values, field, layout, *_scratch(), np.empty(n))

        meas.measurement(x, kind, comp, values, field, layout, *_scratch(), H)
        H_fd = _central_difference(lambda xx: np.array([h(xx)]), x)[0]
        np.testing.assert_allclose(H, H_fd, rtol=RTOL, atol=ATOL)


#: (sensor, component, event kind of the dispatcher)
SENSORS = [("baro", 0, BARO), ("airspeed", 0, AIRSPEED), ("sideslip", 0, SIDESLIP),
           *(("gps_position", c, GPS_POS) for c in range(3)), *(("gps_velocity", c, GPS_VEL) for c in range(5)),
           *(("zero_velocity", c, ZERO_VELOCITY) for c in range(3)), *(("mag", c, MAG) for c in range(3)),
           *(("sun", c, SUN) for c in range(3))]


def _leaf_and_matrix_form(sensor, comp, x, layout, field, values):
    """(h, H) of the numba leaf function ``h_<sensor>`` and of its matrix form above."""
    n = len(x)
    H = np.empty(n)
    E = _scratch()
    if sensor == "baro":
        return (meas.h_baro(x, layout, H), H), baro_np(x, layout)
    if sensor == "airspeed":
        return (meas.h_airspeed(x, layout, *E, H), H), airspeed_np(x, layout)
    if sensor == "sideslip":
        return (meas.h_sideslip(x, layout, *E, H), H), sideslip_np(x, layout)
    if sensor == "gps_position":
        return (meas.h_gps_position(x, comp, H), H), gps_position_np(x, comp)
    if sensor == "gps_velocity":
        return (meas.h_gps_velocity(x, comp, *E, H), H), gps_velocity_np(x, comp)
    if sensor == "zero_velocity":
        return (meas.h_zero_velocity(x, comp, *E, H), H), gps_velocity_np(x, comp)
    ref, bias_first = (field, layout[2]) if sensor == "mag" else (values[3:6], -1)
    return (meas.h_body_vector(x, ref, comp, bias_first, *E, H), H), body_vector_np(x, ref, comp, bias_first)


@pytest.mark.parametrize(("sensor", "comp", "kind"), SENSORS, ids=[f"{s}{c}" for s, c, _ in SENSORS])
@pytest.mark.parametrize("layout", [FULL_LAYOUT, BASE_LAYOUT], ids=["all_states", "base"])
def test_sensor_models_match_matrix_form(sensor, comp, kind, layout):
    """Every leaf ``h_<sensor>`` equals its matrix form at random states, and the dispatcher routes to it."""
    rng = np.random.default_rng(300 + kind * 10 + comp)
    field, values = _event_values(rng)
    n = N_FULL if layout[0] >= 0 else 12
    for _ in range(5):
        x = _random_state(rng)[:n]
        (h, H), (h_ref, H_ref) = _leaf_and_matrix_form(sensor, comp, x, layout, field, values)
        assert h == pytest.approx(h_ref, rel=1e-12, abs=1e-12)
        np.testing.assert_allclose(H, H_ref, rtol=1e-12, atol=1e-12)
        H_dispatch = np.empty(n)
        assert meas.measurement(x, kind, comp, values, field, layout, *_scratch(), H_dispatch) == h
        np.testing.assert_array_equal(H_dispatch, H)


# ----------------------------------------------------------------------------------------------------------------
# whole runs


@pytest.fixture(scope="module")
def short_flight():
    """10 s of fixed-wing flight in wind with every sensor (IMU 250 Hz)."""
    return synthetic_flight(10.0, seed=3)


def north_step(log: FlightLog, at_s: float, step_m: float) -> FlightLog:
    """The GPS north position jumps by ``step_m`` from ``at_s`` seconds after the log start on."""
    gps = log["gps"].copy()
    later = gps.index.to_numpy() >= log["imu"].index[0] + at_s
    gps.loc[later, "lat_deg"] += math.degrees(step_m / 6_378_137.0)
    return FlightLog(streams={**log.streams, "gps": gps}, meta=log.meta)


#: Cases of the compiled-against-uncompiled comparison: (GPS velocity mode, GPS north step [m] at 2 s).
TWIN_CASES = {"ned": ("ned", 0.0), "paper": ("paper", 0.0), "gps_reset": ("ned", 20.0)}


def twin_case(name):
    """(log, inputs, config) of a :data:`TWIN_CASES` entry (also run by the uncompiled subprocess)."""
    velocity_mode, step_m = TWIN_CASES[name]
    log = synthetic_flight(10.0, seed=3)
    if step_m:
        log = north_step(log, 2.0, step_m)
    config = EstimatorConfig(gps_velocity_mode=velocity_mode)
    return log, build.build_replay_inputs(log, config), config


TWIN_SCRIPT = """
import pickle
import sys
from numba.core import config as numba_config
from test_direct import TWIN_CASES, twin_case
from estimators.direct import run as direct_run
assert numba_config.DISABLE_JIT
runs = {}
for name in TWIN_CASES:
    log, inputs, config = twin_case(name)
    run = direct_run.run(log, inputs, config)
    runs[name] = (run.states, run.diagnostics, run.report.details["final_state"], run.report.gps_resets)
with open(sys.argv[1], "wb") as f:
    pickle.dump(runs, f)
"""


@pytest.fixture(scope="module")
def uncompiled_runs(tmp_path_factory):
    """The :data:`TWIN_CASES` run by the same kernel source as plain Python/NumPy (NUMBA_DISABLE_JIT=1, a fresh
    process)."""
    path = tmp_path_factory.mktemp("direct_twin") / "runs.pkl"
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1", "PYTHONPATH": os.pathsep.join([str(REPO_DIR), str(TESTS_DIR)])}
    subprocess.run([sys.executable, "-c", TWIN_SCRIPT, str(path)], env=env, check=True, cwd=REPO_DIR, timeout=900)
    return pd.read_pickle(path)


@pytest.mark.parametrize("case", TWIN_CASES)
def test_numba_kernel_equals_uncompiled_python(uncompiled_runs, case):
    """The compiled kernel and its uncompiled source give the same trajectory, diagnostics and final state
    (max abs difference < 1e-9), also through a GPS re-acquisition reset (the GPS north stepping 20 m at 2 s:
    one reset, at about 7 s)."""
    log, inputs, config = twin_case(case)
    assert set(inputs.plan.used) == {"baro", "airspeed", "sideslip", "gps_pos", "gps_vel", "mag"}
    fast = direct_run.run(log, inputs, config)
    slow_states, slow_diag, slow_final, slow_gps_resets = uncompiled_runs[case]
    assert fast.report.gps_resets == slow_gps_resets == (1 if case == "gps_reset" else 0)
    assert_same_run(fast, slow_states, slow_diag, slow_final, inputs.output_time_s.size)


def test_kernel_executes_the_shared_schedule(short_flight):
    """One covariance propagation per COVARIANCE operation of :func:`estimators.core.schedule.build_schedule`
    (every covariance interval and before every measurement update), one output row per OUTPUT event."""
    config = EstimatorConfig()
    inputs = build.build_replay_inputs(short_flight, config)
    settings = direct_run.kernel_settings(inputs, config)
    ev, imu = inputs.events, inputs.imu
    op, op_dt, op_index = schedule.build_schedule(imu.time_s, ev.time_s, ev.kind, ev.imu_index,
                                                  settings.covariance_dt_s, math.inf)
    n, n_out = len(settings.x0), ev.count(OUTPUT)
    out_f = np.full((n_out, len(direct_kernel.OUT_COLUMNS)), np.nan)
    out_x, out_sx = np.full((n_out, n), np.nan), np.full((n_out, n), np.nan)
    diag_f, diag_i = recorder.diagnostics_arrays(diagnostics_capacity(ev))
    counters = np.zeros(direct_kernel.N_COUNTERS, dtype=np.int64)
    direct_kernel.run_kernel(imu.gyro_rad_s, imu.accel_m_s2, ev.kind, ev.values, ev.variances, op, op_dt, op_index,
                             settings, out_f, out_x, out_sx, diag_f, diag_i, counters)
    assert counters[direct_kernel.C_FLUSHES] == np.count_nonzero(op == schedule.COVARIANCE)
    assert counters[recorder.C_OUTPUTS] == n_out and np.isfinite(out_f).all()
    # the covariance is brought up to date before every update: no propagation since the last COVARIANCE
    stale = False
    for code, index in zip(op, op_index, strict=True):
        if code == schedule.PROPAGATE:
            stale = True
        elif code == schedule.COVARIANCE:
            stale = False
        elif code == schedule.EVENT and ev.kind[index] != OUTPUT:
            assert not stale
    with pytest.raises(ValueError, match="mode"):
        direct_run.kernel_settings(inputs, config, mode="indirect")


def test_paper_literal_indirect_equals_direct(short_flight):
    """The paper's indirect filter (additive error in the same coordinates, reset after each update) is the
    direct filter (docs/direct.md, 'Corrections to the paper'). With linear measurement models (baro, GPS
    position) the two agree to round-off; with the nonlinear ones the only difference is the re-linearisation
    between the scalars of one sensor, a second-order effect."""
    config = EstimatorConfig()
    inputs = build.build_replay_inputs(short_flight, config)
    linear = records.ReplayInputs(**{**inputs.__dict__,
                                    "events": inputs.events.without((AIRSPEED, SIDESLIP, GPS_VEL, MAG))})
    direct = direct_run.run(short_flight, linear, config)
    paper = direct_run.run(short_flight, linear, config, mode="paper_indirect")
    numeric = [c for c in direct.states.columns if c != "time_s"]
    assert np.nanmax(np.abs(direct.states[numeric].to_numpy() - paper.states[numeric].to_numpy())) < 1e-9
    direct_all = direct_run.run(short_flight, inputs, config)
    paper_all = direct_run.run(short_flight, inputs, config, mode="paper_indirect")
    # after the first 5 s (large initial corrections, where the missing re-linearisation matters most)
    half = slice(len(direct_all.states) // 2, None)
    d, p = direct_all.states.iloc[half], paper_all.states.iloc[half]
    for column, tol in (("roll_deg", 0.05), ("pitch_deg", 0.05), ("yaw_deg", 0.05), ("vn_m_s", 0.005),
                        ("ve_m_s", 0.005), ("alt_m", 0.005), ("wind_n_m_s", 0.02), ("wind_e_m_s", 0.02)):
        assert np.abs(d[column] - p[column]).max() < tol, column
    assert np.abs(direct_all.states["yaw_deg"] - paper_all.states["yaw_deg"]).max() < 0.5


def _rms_vs_truth(log, states, after_s):
    truth = log["truth_attitude"]
    t = states["time_s"].to_numpy()
    keep = t >= t[0] + after_s
    out = {}
    for column in ("roll_deg", "pitch_deg", "yaw_deg"):
        expected = np.interp(t, truth.index.to_numpy(), np.degrees(np.unwrap(np.radians(truth[column]))))
        err = (states[column].to_numpy() - expected + 180) % 360 - 180
        out[column] = float(np.sqrt(np.mean(err[keep] ** 2)))
    wind = log["truth_wind"]
    dn = states["wind_n_m_s"].to_numpy()[keep] - wind["wind_n_m_s"].iloc[0]
    de = states["wind_e_m_s"].to_numpy()[keep] - wind["wind_e_m_s"].iloc[0]
    out["wind_m_s"] = float(np.sqrt(np.mean(dn ** 2 + de ** 2)))
    return out


def test_accuracy_and_bias_estimation_on_synthetic_flight():
    log = synthetic_flight(60.0, seed=1)
    config = EstimatorConfig()
    run = direct_run.run(log, build.build_replay_inputs(log, config), config)
    rms = _rms_vs_truth(log, run.states, after_s=20.0)
    assert rms["roll_deg"] < 0.3 and rms["pitch_deg"] < 0.3 and rms["yaw_deg"] < 0.5, rms
    assert rms["wind_m_s"] < 0.2, rms
    final = run.report.details["final_state"]
    np.testing.assert_allclose([final["bgx"], final["bgy"], final["bgz"]], [0.002, -0.001, 0.0015], atol=5e-4)
    np.testing.assert_allclose([final["bax"], final["bay"], final["baz"]], [0.05, -0.03, 0.08], atol=0.03)
    assert run.report.resets == 0 and run.report.gps_resets == 0
    # NIS of the channels whose simulated noise equals the configured one (GPS) is consistent
    nis = run.diagnostics.groupby("sensor", observed=True)["nis"].mean()
    assert 0.5 < nis["gps_vel"] < 2.0 and 0.5 < nis["gps_pos"] < 2.0


def test_degraded_modes_run_without_nan():
    config = EstimatorConfig()
    # multicopter without airspeed: no wind, no sideslip
    copter = synthetic_flight(10.0, seed=4, mav_type=2, with_airspeed=False)
    run = direct_run.run(copter, build.build_replay_inputs(copter, config), config)
    assert run.states["wind_n_m_s"].isna().all()
    assert "sideslip" not in run.report.used and "wn" not in run.report.details["states"]
    assert run.states[["roll_deg", "pitch_deg", "yaw_deg", "lat_deg", "vn_m_s"]].notna().all().all()
    # no GPS: attitude and height only, no accelerometer bias states
    blind = synthetic_flight(10.0, seed=5, with_gps=False)
    run = direct_run.run(blind, build.build_replay_inputs(blind, config), config)
    assert run.states["lat_deg"].isna().all() and run.states["vn_m_s"].isna().all()
    assert run.states[["roll_deg", "pitch_deg", "yaw_deg", "alt_m"]].notna().all().all()
    assert "bax" not in run.report.details["states"]
    assert any("accelerometer bias" in d for d in run.report.degradations)


def test_divergence_is_reset_never_nan(short_flight):
    config = EstimatorConfig()
    inputs = build.build_replay_inputs(short_flight, config)
    gyro = inputs.imu.gyro_rad_s.copy()
    gyro[1200] = 1e300  # an absurd sample makes the state overflow
    broken = records.ReplayInputs(**{**inputs.__dict__, "imu": records.ImuSamples(
        **{**inputs.imu.__dict__, "gyro_rad_s": gyro})})
    run = direct_run.run(short_flight, broken, config)
    assert run.report.resets >= 1
    assert any("reset" in w for w in run.report.warnings)
    assert run.states.drop(columns=["wind_n_m_s_std", "wind_e_m_s_std"]).notna().all().all()


def test_state_table_builds_x0_p0_q():
    config = EstimatorConfig()
    table = model.state_table(config, accel_bias=True, wind=True, mag_bias=False, baro_bias=True,
                              absolute_yaw=False)
    names = [s.name for s in table]
    assert names[:12] == ["pn", "pe", "pd", "u", "v", "w", "roll", "pitch", "yaw", "bgx", "bgy", "bgz"]
    layout = model.layout_of(table)
    assert names[layout[model.L_BA]] == "bax" and names[layout[model.L_W]] == "wn" and layout[model.L_BM] == -1
    yaw = table[names.index("yaw")]
    assert yaw.initial_sigma == pytest.approx(math.radians(config.initial.yaw_unaided_deg))
    assert table[names.index("wn")].process_sigma == config.noise.wind_rw_m_s_sqrt_s
