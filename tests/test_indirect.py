"""Full-state indirect (error-state, multiplicative quaternion) filter: whole runs (:mod:`estimators.indirect.run`,
:mod:`estimators.indirect.kernel`).

The model functions (F, Q, every H, injection) are checked against finite differences and matrix forms in
``tests/test_indirect_model.py``; the real-log acceptance (all logs without NaN, onboard/ground-truth agreement)
runs for both full-state filters in ``tests/test_estimators_real_logs.py``. Here: the error-state table and the
degraded sensor plans, the GPS reset against its matrix form, the kernel against the same source run uncompiled
and its schedule, accuracy and bias recovery on the exact synthetic flight, agreement with the (independently
written, Euler-angle) direct filter and between group and per-scalar injection, divergence handling, and the
simulated paper mission against Table 2 with the mean NIS per channel.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from estimators.api import estimator_function
from estimators.config import EstimatorConfig
from estimators.core import recorder, schedule
from estimators.core.full_state import diagnostics_capacity
from estimators.evaluation import PAPER_TABLE_2, config_for_simulation, rms_errors
from estimators.indirect import kernel as indirect_kernel
from estimators.indirect import measurements as meas
from estimators.indirect import model as m
from estimators.indirect import run as fsi
from estimators.inputs import build, records
from estimators.inputs.records import GPS_POS, GPS_VEL
from ingest.flightlog import FlightLog
from ingest.frames import euler_to_matrix, quat_to_matrix
from ingest.log_formats import load_flight_log
from ingest.sun_log import load_sun_device, with_sun
from tests.conftest import SAMPLE_LOGS_DIR
from tests.estimators_synthetic import assert_same_run, synthetic_flight

CONFIG = EstimatorConfig()
TESTS_DIR = Path(__file__).resolve().parent
REPO_DIR = TESTS_DIR.parent


def direct_run(log, inputs, config):
    """The direct filter, through the registry of :mod:`estimators.api`."""
    return estimator_function("full_state_direct")(log, inputs, config)


def _run(log, config=CONFIG, **kwargs):
    return fsi.run(log, build.build_replay_inputs(log, config), config, **kwargs)


def _attitude_rms_deg(log, states, after_s):
    truth = log["truth_attitude"]
    t = states["time_s"].to_numpy()
    keep = t >= t[0] + after_s
    out = {}
    for column in ("roll_deg", "pitch_deg", "yaw_deg"):
        expected = np.interp(t, truth.index.to_numpy(), np.degrees(np.unwrap(np.radians(truth[column]))))
        err = (states[column].to_numpy() - expected + 180.0) % 360.0 - 180.0
        out[column] = float(np.sqrt(np.mean(err[keep] ** 2)))
    return out


# ----------------------------------------------------------------------------------------------------------------
# error-state table and sensor plans


def test_error_state_table_matches_the_model_layout():
    table = fsi.error_state_table(CONFIG, absolute_yaw=True)
    names = [s.name for s in table]
    assert len(table) == m.NE
    for index, name in ((m.E_P, "dpn"), (m.E_V, "dvn"), (m.E_TH, "dthx"), (m.E_BG, "dbgx"), (m.E_BA, "dbax"),
                        (m.E_W, "dwn"), (m.E_BM, "dbmx"), (m.E_BB, "dbb")):
        assert names[index] == name
    assert table[m.E_TH + 2].initial_sigma == pytest.approx(math.radians(CONFIG.initial.yaw_deg))
    unaided = fsi.error_state_table(CONFIG, absolute_yaw=False)
    assert unaided[m.E_TH + 2].initial_sigma == pytest.approx(math.radians(CONFIG.initial.yaw_unaided_deg))
    assert table[m.E_W].process_sigma == CONFIG.noise.wind_rw_m_s_sqrt_s
    assert table[m.E_BG].process_sigma == CONFIG.noise.gyro_bias_rw_rad_s2_sqrt_hz
    assert all(s.process_sigma == 0.0 for s in table[:m.E_BG])  # p, v, theta: noise through the IMU inputs


def test_initial_attitude_covariance_is_the_euler_sigmas_mapped_to_body_error():
    """P0's attitude block is W diag(sigma_Euler^2) W^T: mapped back with S = W^-1 it is the Euler diagonal."""
    log = synthetic_flight(5.0, seed=2)
    inputs = build.build_replay_inputs(log, CONFIG)
    settings = fsi.kernel_settings(inputs, CONFIG, log)
    sel = list(settings.sel)
    th = [sel.index(m.E_TH + i) for i in range(3)]
    P_th = settings.P0[np.ix_(th, th)]
    S, W = fsi.attitude_matrices(inputs.alignment.roll_rad, inputs.alignment.pitch_rad)
    np.testing.assert_allclose(S @ W, np.eye(3), atol=1e-15)
    sigmas = np.radians([CONFIG.initial.roll_pitch_deg, CONFIG.initial.roll_pitch_deg, CONFIG.initial.yaw_deg])
    np.testing.assert_allclose(S @ P_th @ S.T, np.diag(sigmas ** 2), atol=1e-15)
    # initial quaternion is the aligned attitude
    r_nb = quat_to_matrix(settings.x0[m.X_Q:m.X_Q + 4])
    align = inputs.alignment
    np.testing.assert_allclose(r_nb, euler_to_matrix(align.roll_rad, align.pitch_rad, align.yaw_rad), atol=1e-12)


def test_cross_axis_states_follow_the_flag():
    log = synthetic_flight(5.0, seed=4)
    off = dataclasses.replace(CONFIG, accel_cross_axis_states=False)
    states = fsi.run(log, build.build_replay_inputs(log, off), off).report.details["states"]
    assert "dkzx" not in states and "dkzy" not in states and "dbax" in states


@pytest.mark.parametrize(("kwargs", "absent"), [
    ({}, ("dkzy",)),  # fixed-wing: no lateral cross-axis state
    ({"mav_type": 2, "with_airspeed": False}, ("dwn", "dwe")),
    ({"with_gps": False}, ("dbax", "dbay", "dbaz", "dbb", "dkzx", "dkzy")),
])
def test_active_error_states_follow_the_sensor_plan(kwargs, absent):
    log = synthetic_flight(5.0, seed=4, **kwargs)
    run = _run(log)
    states = run.report.details["states"]
    full = [s.name for s in fsi.error_state_table(CONFIG, absolute_yaw=True)]
    assert states == [n for n in full if n not in absent]
    # the direct filter decides the same blocks from the same plan, and reports the same
    direct = direct_run(log, build.build_replay_inputs(log, CONFIG), CONFIG)
    for block_direct, block_indirect in (("bax", "dbax"), ("wn", "dwn"), ("bmx", "dbmx"), ("bb", "dbb")):
        assert (block_direct in direct.report.details["states"]) == (block_indirect in states)
    assert run.report.used == direct.report.used and run.report.skipped == direct.report.skipped
    assert run.report.degradations == direct.report.degradations


# ----------------------------------------------------------------------------------------------------------------
# whole runs on the exact synthetic flight


@pytest.fixture(scope="module")
def minute_flight():
    return synthetic_flight(60.0, seed=1)


def test_accuracy_bias_recovery_and_consistency(minute_flight):
    """60 s of fixed-wing flight in wind (a straight leg, a 12 deg/s turn, straight): attitude within a few
    tenths of a degree, wind within 0.2 m/s, IMU biases recovered, GPS channels consistent."""
    run = _run(minute_flight)
    rms = _attitude_rms_deg(minute_flight, run.states, after_s=20.0)
    assert rms["roll_deg"] < 0.3 and rms["pitch_deg"] < 0.3 and rms["yaw_deg"] < 0.5, rms
    t = run.states["time_s"].to_numpy()
    keep = t >= t[0] + 20.0
    wind = minute_flight["truth_wind"].iloc[0]
    wind_err = np.hypot(run.states["wind_n_m_s"] - wind["wind_n_m_s"], run.states["wind_e_m_s"] - wind["wind_e_m_s"])
    assert float(np.sqrt(np.mean(wind_err[keep] ** 2))) < 0.2
    final = run.report.details["final_state"]
    np.testing.assert_allclose([final["bgx"], final["bgy"], final["bgz"]], [0.002, -0.001, 0.0015], atol=5e-4)
    np.testing.assert_allclose([final["bax"], final["bay"], final["baz"]], [0.05, -0.03, 0.08], atol=0.03)
    assert run.report.resets == 0 and run.report.gps_resets == 0 and run.report.covariance_repairs == 0
    nis = run.diagnostics.groupby("sensor", observed=True)["nis"].mean()
    assert 0.5 < nis["gps_vel"] < 2.0 and 0.5 < nis["gps_pos"] < 2.0, nis
    # the reported attitude std covers the error (2 sigma on > 90 % of the epochs after convergence)
    truth = minute_flight["truth_attitude"]
    for column in ("roll_deg", "pitch_deg"):
        expected = np.interp(t, truth.index.to_numpy(), truth[column].to_numpy())
        inside = np.abs(run.states[column] - expected) <= 2.0 * run.states[f"{column}_std"]
        assert inside[keep].mean() > 0.9, column


def test_agrees_with_the_direct_filter(minute_flight):
    """Two independent implementations of the same estimation problem (Euler angles and body velocity, RK4,
    additive update vs quaternion, NED velocity, exact exponential map, multiplicative injection): after 5 s of
    convergence they agree to a small fraction of their own uncertainty."""
    inputs = build.build_replay_inputs(minute_flight, CONFIG)
    indirect = fsi.run(minute_flight, inputs, CONFIG).states
    direct = direct_run(minute_flight, inputs, CONFIG).states
    t = indirect["time_s"].to_numpy()
    keep = t >= t[0] + 5.0
    for column, tol in (("roll_deg", 0.1), ("pitch_deg", 0.1), ("yaw_deg", 0.2), ("vn_m_s", 0.01),
                        ("ve_m_s", 0.01), ("alt_m", 0.01), ("wind_n_m_s", 0.05), ("wind_e_m_s", 0.05)):
        diff = indirect[column].to_numpy() - direct[column].to_numpy()
        if column == "yaw_deg":
            diff = (diff + 180.0) % 360.0 - 180.0
        assert np.abs(diff[keep]).max() < tol, column
        if column.endswith("_deg"):  # pointwise, against the filter's own standard deviation
            assert (np.abs(diff[keep]) < 0.5 * indirect[f"{column}_std"].to_numpy()[keep]).all(), column


def twin_case(name):
    """(log, config, inject) of an uncompiled-twin case: 10 s of flight with every sensor; ``gps_step``: the GPS
    north position jumps 20 m at 2 s, so a GPS re-acquisition reset happens (at about 7 s)."""
    log = synthetic_flight(10.0, seed=3)
    if name == "gps_step":
        gps = log["gps"].copy()
        later = gps.index.to_numpy() >= log["imu"].index[0] + 2.0
        gps.loc[later, "lat_deg"] += math.degrees(20.0 / 6_378_137.0)
        log = FlightLog(streams={**log.streams, "gps": gps}, meta=log.meta)
    config = EstimatorConfig(gps_velocity_mode="paper" if name == "paper_scalar" else "ned")
    return log, config, "scalar" if name == "paper_scalar" else "group"


TWIN_SCRIPT = """
import pickle
import sys
from test_indirect import twin_case
from estimators.indirect import run as fsi
from estimators.inputs import build
log, config, inject = twin_case(sys.argv[2])
run = fsi.run(log, build.build_replay_inputs(log, config), config, inject=inject)
with open(sys.argv[1], "wb") as file:
    pickle.dump((run.states, run.diagnostics, run.report.details["final_state"], run.report.gps_resets), file)
"""


@pytest.mark.parametrize("case", ["ned_group", "paper_scalar", "gps_step"])
def test_numba_kernel_equals_uncompiled_python(tmp_path, case):
    """The compiled kernel and the same code run as plain Python/NumPy (NUMBA_DISABLE_JIT=1, a fresh process) on
    10 s of flight with every sensor (NED or paper GPS velocity, group or per-scalar injection, a GPS reset): same
    trajectory, innovations and final state to 1e-9."""
    path = tmp_path / "twin.pkl"
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1", "PYTHONPATH": os.pathsep.join([str(REPO_DIR), str(TESTS_DIR)])}
    subprocess.run([sys.executable, "-c", TWIN_SCRIPT, str(path), case], env=env, check=True, cwd=REPO_DIR,
                   timeout=900)
    slow_states, slow_diag, slow_final, slow_gps_resets = pd.read_pickle(path)
    log, config, inject = twin_case(case)
    inputs = build.build_replay_inputs(log, config)
    fast = fsi.run(log, inputs, config, inject=inject)
    assert fast.report.gps_resets == slow_gps_resets == (1 if case == "gps_step" else 0)
    assert_same_run(fast, slow_states, slow_diag, slow_final, inputs.output_time_s.size)


def test_kernel_executes_the_schedule():
    """One covariance propagation per COVARIANCE operation of the shared schedule (docs/estimators.md,
    'Scheduling rule'), one output row per OUTPUT event, one diagnostics row per scalar update."""
    log = synthetic_flight(5.0, seed=2)
    inputs = build.build_replay_inputs(log, CONFIG)
    settings = fsi.kernel_settings(inputs, CONFIG, log)
    ev, imu = inputs.events, inputs.imu
    op, op_dt, op_index = schedule.build_schedule(imu.time_s, ev.time_s, ev.kind, ev.imu_index,
                                                  settings.covariance_dt_s, math.inf)
    n_out = ev.count(records.OUTPUT)
    n = len(settings.sel)
    out_f, out_sd = np.full((n_out, len(indirect_kernel.OUT_COLUMNS)), np.nan), np.full((n_out, n + 3), np.nan)
    diag_f, diag_i = recorder.diagnostics_arrays(diagnostics_capacity(ev))
    counters = np.zeros(indirect_kernel.N_COUNTERS, dtype=np.int64)
    indirect_kernel.run_kernel(imu.gyro_rad_s, imu.accel_m_s2, ev.kind, ev.imu_index, ev.values, ev.variances, op,
                               op_dt, op_index, settings, out_f, out_sd, diag_f, diag_i, counters)
    assert counters[indirect_kernel.C_FLUSHES] == np.count_nonzero(op == schedule.COVARIANCE)
    assert counters[recorder.C_OUTPUTS] == n_out and np.isfinite(out_f).all() and np.isfinite(out_sd).all()
    assert counters[recorder.C_DIAG] == counters[recorder.C_UPDATES] > 0
    # the time of every propagation step adds up to the log
    assert op_dt[op == schedule.PROPAGATE].sum() == pytest.approx(imu.time_s[-1] - imu.time_s[0], abs=1e-9)


def _reset_to_gps_matrix_form(x, P, kind, values, variances, lever, gyro, sel, move_wind):
    """The nominal position or velocity to the GPS (lever arm included), the block's error the GPS noise; with
    ``move_wind`` the wind moves with the velocity (north, east): ``e' = T e + G n``, ``P' = T P T^T + G R G^T``
    over the active error states ``sel`` (position and velocity lead them)."""
    x, P = x.copy(), P.copy()
    rows = []
    for c in range(3):
        H = np.zeros(m.NE)
        rows.append((meas.measurement(x, kind, c, values, np.zeros(3), lever, gyro, H), H))
    correction = values[0:3] - np.array([h for h, _ in rows])
    dp, dv = slice(m.E_P, m.E_P + 3), slice(m.E_V, m.E_V + 3)
    if kind == GPS_POS:
        x[m.X_P:m.X_P + 3] += correction
        P[dp, :] = 0.0
        P[:, dp] = 0.0
        P[dp, dp] = np.diag(variances[0:3])
        return x, P
    n = len(sel)
    T, G = np.eye(n), np.zeros((n, 3))
    x[m.X_V:m.X_V + 3] += correction
    T[dv] = 0.0
    G[dv] = np.eye(3)
    if move_wind:
        aw = int(np.flatnonzero(sel == m.E_W)[0])
        x[m.X_W:m.X_W + 2] += correction[:2]
        for c in range(2):
            T[aw + c] -= rows[c][1][sel]
            G[aw + c, c] = 1.0
    return x, T @ P @ T.T + G @ np.diag(variances[0:3]) @ G.T


@pytest.mark.parametrize(("kind", "move_wind"), [(GPS_POS, False), (GPS_VEL, False), (GPS_VEL, True)])
def test_reset_to_gps_matches_matrix_form(kind, move_wind):
    """GPS re-acquisition (docs/estimators.md, 'GPS re-acquisition') against its matrix form at a random state."""
    rng = np.random.default_rng(7 + kind)
    x = np.zeros(m.NX)
    x[m.X_P:m.X_P + 3] = rng.normal(0.0, 50.0, 3)
    x[m.X_V:m.X_V + 3] = rng.normal(0.0, 8.0, 3)
    x[m.X_Q:m.X_Q + 4] = np.roll(Rotation.random(random_state=rng).as_quat(), 1)
    x[m.X_BG:m.X_BG + 3] = rng.normal(0.0, 0.02, 3)
    x[m.X_W:m.X_W + 2] = rng.normal(0.0, 4.0, 2)
    sel = np.array([i for i in range(m.NE) if i not in (m.E_BB, m.E_KZ + 1)], dtype=np.int64)
    n = len(sel)
    root = rng.normal(size=(n, n))
    P = root @ root.T
    values, variances = np.r_[rng.normal(0.0, 10.0, 3), np.zeros(3)], np.r_[rng.uniform(0.1, 1.0, 3), np.zeros(3)]
    lever, gyro = np.array([0.3, -0.1, -0.2]), rng.normal(0.0, 1.0, 3)
    x_ref, P_ref = _reset_to_gps_matrix_form(x, P, kind, values, variances, lever, gyro, sel, move_wind)
    x_new, P_new = x.copy(), P.copy()
    indirect_kernel.reset_to_gps(x_new, P_new, kind, values, variances, np.zeros(3), lever, gyro, sel, move_wind,
                                 np.zeros(m.NE), np.empty((3, 3)), np.empty((n, n)), np.empty((n, n)))
    np.testing.assert_allclose(x_new, x_ref, rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(P_new, P_ref, rtol=1e-11, atol=1e-11)
    # the reset block now predicts the GPS value
    H = np.zeros(m.NE)
    np.testing.assert_allclose([meas.measurement(x_new, kind, c, values, np.zeros(3), lever, gyro, H)
                                for c in range(3)], values[0:3], atol=1e-9)


def test_group_and_scalar_injection_agree(minute_flight):
    """Injecting after each sensor group (linearised innovations within the group, eq 49 corrected) or after
    every scalar (re-linearised) differ only to second order."""
    inputs = build.build_replay_inputs(minute_flight, CONFIG)
    group = fsi.run(minute_flight, inputs, CONFIG)
    scalar = fsi.run(minute_flight, inputs, CONFIG, inject="scalar")
    for column, tol in (("roll_deg", 0.01), ("pitch_deg", 0.01), ("yaw_deg", 0.02), ("vn_m_s", 1e-3),
                        ("wind_n_m_s", 0.005)):
        assert np.abs(group.states[column] - scalar.states[column]).max() < tol, column
    assert len(group.diagnostics) == len(scalar.diagnostics)
    with pytest.raises(ValueError, match="inject"):
        fsi.run(minute_flight, inputs, CONFIG, inject="never")


def test_degraded_modes_run_without_nan():
    copter = synthetic_flight(10.0, seed=4, mav_type=2, with_airspeed=False)
    run = _run(copter)
    assert run.states["wind_n_m_s"].isna().all() and "sideslip" not in run.report.used
    assert run.states[["roll_deg", "pitch_deg", "yaw_deg", "lat_deg", "vn_m_s"]].notna().all().all()
    blind = synthetic_flight(10.0, seed=5, with_gps=False)
    run = _run(blind)
    assert run.states["lat_deg"].isna().all() and run.states["vn_m_s"].isna().all()
    assert run.states[["roll_deg", "pitch_deg", "yaw_deg", "alt_m"]].notna().all().all()
    assert "zero_velocity" in run.report.used
    assert any("accelerometer bias" in d for d in run.report.degradations)


def test_divergence_is_reset_never_nan():
    log = synthetic_flight(10.0, seed=3)
    inputs = build.build_replay_inputs(log, CONFIG)
    gyro = inputs.imu.gyro_rad_s.copy()
    gyro[1200] = 1e300  # an absurd sample makes the nominal state overflow
    broken = records.ReplayInputs(**{**inputs.__dict__, "imu": records.ImuSamples(
        **{**inputs.imu.__dict__, "gyro_rad_s": gyro})})
    run = fsi.run(log, broken, CONFIG)
    assert run.report.resets >= 1 and any("reset" in w for w in run.report.warnings)
    assert run.states.notna().all().all()
    assert np.isfinite(run.states.drop(columns="time_s").to_numpy()).all()


# ----------------------------------------------------------------------------------------------------------------
# the simulated paper mission (sample_logs/paper.ulg) against Table 2


@pytest.fixture(scope="module")
def paper_mission():
    """The bundled simulated paper mission replayed with the true noise parameters of its sensors (the shared
    :func:`estimators.evaluation.config_for_simulation`, as the direct filter's test), Table 2 indirect bars."""
    log = load_flight_log(SAMPLE_LOGS_DIR / "paper.ulg")
    sidecar = json.loads((SAMPLE_LOGS_DIR / "paper_sim.json").read_text())
    config = config_for_simulation(sidecar)
    run = _run(log, config)
    errors = rms_errors(run.states, log, after_s=60.0).iloc[0]
    gps = sidecar["sensor_errors"]["gps"]
    bars = dict(PAPER_TABLE_2[fsi.NAME])
    # position and height cannot beat the receiver's own slowly varying (Gauss-Markov) error (issue 4: 1.1 x)
    bars["position_m"] = max(bars["position_m"], 1.1 * gps["position_error_rms_horizontal_m"])
    bars["height_m"] = max(bars["height_m"], 1.1 * gps["position_error_rms_ned_m"][2])
    print("\nfull_state_indirect on sample_logs/paper.ulg, RMS after 60 s (ours / bar):")
    print("  " + "  ".join(f"{q} {errors[q]:.3f}/{bars[q]:.2f}" for q in bars))
    return run, errors, bars


#: Pitch: the simulated MPU6050's cross-axis sensitivity (+-2 %) couples the forward specific force into the z
#: accelerometer, whose effective bias then changes at every climb/cruise/descent transition; with the z bias
#: random walk alone (``SIM_ACCEL_BIAS_RW_Z``) the residual leaked into pitch (0.36 deg; without the simulated
#: cross-axis errors 0.17 deg). The error-state filter now estimates the z accelerometer's cross-axis
#: sensitivities (``accel_cross_axis_states``, k_zx converges to the simulated 0.015): 0.25 deg, within Table 2's
#: 0.30 (test below). The looser bar holds with those states switched off too.
PITCH_BAR_DEG = 0.45


@pytest.mark.parametrize("quantity", ["roll_deg", "yaw_deg", "position_m", "height_m", "airspeed_m_s",
                                      "ground_speed_m_s", "course_deg", "wind_m_s"])
def test_paper_mission_meets_table_2(paper_mission, quantity):
    _, errors, bars = paper_mission
    assert errors[quantity] <= bars[quantity], (quantity, errors[quantity], bars[quantity])


def test_paper_mission_pitch(paper_mission):
    _, errors, _ = paper_mission
    assert errors["pitch_deg"] <= PITCH_BAR_DEG, errors["pitch_deg"]


def test_paper_mission_pitch_table_2(paper_mission):
    _, errors, bars = paper_mission
    assert errors["pitch_deg"] <= bars["pitch_deg"]


def test_paper_mission_estimates_the_z_accelerometer_cross_axis(paper_mission):
    """k_zx (z accelerometer's sensitivity to the forward specific force) converges to the simulated coupling:
    observable through the vertical channel as the forward specific force changes (launch, climbs, descents).
    k_zy is not estimated on a fixed-wing: coordinated flight keeps the lateral specific force near zero."""
    run, _, _ = paper_mission
    details = run.report.details
    simulated = json.loads((SAMPLE_LOGS_DIR / "paper_sim.json").read_text())["sensor_errors"]["imu"]["accel_matrix"]
    estimate, sigma = details["final_state"]["kzx"], details["final_state_std"]["dkzx"]
    print(f"k_zx {estimate:.4f} +- {sigma:.4f}, simulated {simulated[2][0]:.4f}")
    assert sigma < 0.5 * CONFIG.initial.accel_cross_axis
    assert abs(estimate - simulated[2][0]) < 3.0 * sigma
    assert "dkzy" not in details["states"]


@pytest.fixture(scope="module")
def paper_mission_with_sun():
    """The paper mission with the photocell sun vector fused as well (heading "mag+sun")."""
    log = load_flight_log(SAMPLE_LOGS_DIR / "paper.ulg")
    device = load_sun_device(SAMPLE_LOGS_DIR / "paper_device.json")
    log = with_sun(log, SAMPLE_LOGS_DIR / "paper_sun.csv", device=device)
    sidecar = json.loads((SAMPLE_LOGS_DIR / "paper_sim.json").read_text())
    config = config_for_simulation(sidecar)
    run = fsi.run(log, build.build_replay_inputs(log, config, heading="mag+sun"), config)
    return run, rms_errors(run.states, log, after_s=60.0).iloc[0]


def test_paper_mission_with_sun_vector_meets_the_whole_row(paper_mission, paper_mission_with_sun):
    """The sun vector fixes two attitude axes independently of the accelerometer: with it the tilt is no longer
    limited by the accelerometer's cross-axis error and the whole Table 2 row is met."""
    _, _, bars = paper_mission
    run, errors = paper_mission_with_sun
    print("\nwith the sun vector (ours / bar):", "  ".join(f"{q} {errors[q]:.3f}/{bars[q]:.2f}" for q in bars))
    assert "sun" in run.report.used
    failing = {q: (round(errors[q], 3), bars[q]) for q in bars if not errors[q] <= bars[q]}
    assert not failing, failing
    sun = run.diagnostics[run.diagnostics["sensor"] == "sun"]
    assert len(sun) > 1000 and sun["accepted"].mean() > 0.99


def test_paper_mission_nis_per_channel(paper_mission):
    """Mean NIS per measured channel in [0.5, 2] (pseudo-measurements excluded: their sigma is a modelling
    allowance, not a sensor noise)."""
    run, _, _ = paper_mission
    diagnostics = run.diagnostics
    measured = diagnostics[~diagnostics["sensor"].isin([records.SENSOR_NAMES[k] for k in records.PSEUDO_KINDS])]
    nis = measured.groupby(["sensor", "component"], observed=True)["nis"].mean()
    print("mean NIS per channel:", nis.round(2).to_dict())
    assert set(nis.index.get_level_values("sensor")) == {"baro", "airspeed", "gps_pos", "gps_vel", "mag"}
    assert ((nis >= 0.5) & (nis <= 2.0)).all(), nis
    assert measured["accepted"].mean() > 0.99
    assert run.report.resets == 0 and run.report.gps_resets == 0
