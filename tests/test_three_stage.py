"""Three-stage series estimator: analytic Jacobians vs finite differences, model identities, whole runs (numba vs
uncompiled twin, degraded modes, real logs, the simulated paper mission)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from estimators_synthetic import synthetic_flight

from estimators.api import run_estimators
from estimators.config import EstimatorConfig
from estimators.core import recorder, state_table
from estimators.core.results import STATE_COLUMNS
from estimators.evaluation import PAPER_TABLE_2, config_for_simulation, rms_errors
from estimators.inputs import alignment, build, records
from estimators.three_stage import control as ts_control
from estimators.three_stage import kernel as ts_kernel
from estimators.three_stage import measurements as meas
from estimators.three_stage import model as m
from estimators.three_stage import run as three_stage
from estimators.three_stage import stages
from ingest.frames import euler_to_matrix
from ingest.log_formats import load_flight_log
from ingest.sun_log import with_sun

TESTS_DIR = Path(__file__).resolve().parent
REPO_DIR = TESTS_DIR.parent
SAMPLE_LOGS_DIR = REPO_DIR / "sample_logs"

GRAVITY = 9.80665
RTOL = 1e-6  # relative tolerance of every analytic-vs-numerical Jacobian comparison
ATOL = 1e-8  # absolute floor for entries that are analytically zero
N_RANDOM = 20  # random states per Jacobian


def numerical_jacobian(fun, x, *args, step=1e-6):
    """Central finite-difference Jacobian of ``fun(x, *args)`` w.r.t. ``x`` (the test oracle)."""
    x = np.asarray(x, dtype=float)
    columns = []
    for i in range(x.size):
        dx = np.zeros_like(x)
        dx[i] = step
        columns.append((np.asarray(fun(x + dx, *args)) - np.asarray(fun(x - dx, *args))) / (2 * step))
    return np.stack(columns, axis=-1)


def random_attitude(rng):
    """(phi, theta, psi) [rad] away from the Euler singularity."""
    return rng.uniform(-1.2, 1.2), rng.uniform(-1.2, 1.2), rng.uniform(-np.pi, np.pi)


@pytest.fixture
def rng():
    return np.random.default_rng(20191024)


def unit(v):
    return v / np.linalg.norm(v)


# ---------------------------------------------------------------- stage 1


def test_stage1_f_is_euler_kinematics(rng):
    """f equals the first two rows of S(Theta) omega, i.e. d/dt of roll/pitch of R_nb under body rates."""
    for _ in range(N_RANDOM):
        phi, theta, psi = random_attitude(rng)
        rates = rng.normal(0, 0.5, 3)
        dt = 1e-6
        r0 = euler_to_matrix(phi, theta, psi)
        wx = np.array([[0, -rates[2], rates[1]], [rates[2], 0, -rates[0]], [-rates[1], rates[0], 0]])
        r1 = r0 @ (np.eye(3) + wx * dt)
        phi1 = np.arctan2(r1[2, 1], r1[2, 2])
        theta1 = -np.arcsin(r1[2, 0])
        np.testing.assert_allclose(m.stage1_f(np.array([phi, theta]), rates),
                                   [(phi1 - phi) / dt, (theta1 - theta) / dt], rtol=1e-4, atol=1e-5)


def test_stage1_A_matches_finite_differences(rng):
    for _ in range(N_RANDOM):
        x = np.array(random_attitude(rng)[:2])
        rates = rng.normal(0, 0.5, 3)
        np.testing.assert_allclose(m.stage1_A(x, rates), numerical_jacobian(m.stage1_f, x, rates),
                                   rtol=RTOL, atol=ATOL)
        out = np.full((2, 2), np.nan)  # the output-array form writes every entry
        np.testing.assert_array_equal(m.stage1_A(x, rates, out), m.stage1_A(x, rates))


def test_stage1_G_matches_finite_differences(rng):
    for _ in range(N_RANDOM):
        x = np.array(random_attitude(rng)[:2])
        rates = rng.normal(0, 0.5, 3)
        np.testing.assert_allclose(m.stage1_G(x), numerical_jacobian(lambda w, s: m.stage1_f(s, w), rates, x),
                                   rtol=RTOL, atol=ATOL)


def test_stage1_C_airspeed_matches_finite_differences(rng):
    for _ in range(N_RANDOM):
        x = np.array(random_attitude(rng)[:2])
        rates = rng.normal(0, 0.5, 3)
        va = rng.uniform(0, 30)
        numerical = numerical_jacobian(lambda s, *a: meas.stage1_h_airspeed(s, *a)[0], x, rates, va, GRAVITY)
        np.testing.assert_allclose(meas.stage1_h_airspeed(x, rates, va, GRAVITY)[1], numerical, rtol=RTOL, atol=ATOL)


def test_stage1_h_airspeed_is_steady_flight_specific_force(rng):
    """h = omega x V_b - C_bn g_n with V_b = V_a (c_th, 0, s_th) (corrected eq 20 from corrected eq 1)."""
    for _ in range(N_RANDOM):
        phi, theta, psi = random_attitude(rng)
        rates = rng.normal(0, 0.5, 3)
        va = rng.uniform(0, 30)
        v_b = va * np.array([np.cos(theta), 0.0, np.sin(theta)])
        expected = np.cross(rates, v_b) - euler_to_matrix(phi, theta, psi).T @ [0.0, 0.0, GRAVITY]
        np.testing.assert_allclose(meas.stage1_h_airspeed(np.array([phi, theta]), rates, va, GRAVITY)[0], expected,
                                   rtol=1e-12, atol=1e-12)


def test_stage1_acceleration_form(rng):
    """General form: value = C_bn (a_n - g_n); Jacobian vs finite differences; a_n = 0 equals V_a = 0."""
    for _ in range(N_RANDOM):
        phi, theta, psi = random_attitude(rng)
        x = np.array([phi, theta])
        accel = rng.normal(0, 3, 3)
        h, c = meas.stage1_h_acceleration(x, psi, accel, GRAVITY)
        expected = euler_to_matrix(phi, theta, psi).T @ (accel - [0.0, 0.0, GRAVITY])
        np.testing.assert_allclose(h, expected, rtol=1e-12, atol=1e-12)
        numerical = numerical_jacobian(lambda s, *a: meas.stage1_h_acceleration(s, *a)[0], x, psi, accel,
                                       GRAVITY)
        np.testing.assert_allclose(c, numerical, rtol=RTOL, atol=ATOL)
        h0, c0 = meas.stage1_h_acceleration(x, psi, np.zeros(3), GRAVITY)
        rates = rng.normal(0, 0.5, 3)
        h_va0, c_va0 = meas.stage1_h_airspeed(x, rates, 0.0, GRAVITY)
        np.testing.assert_allclose(h0, h_va0, atol=1e-12)
        np.testing.assert_allclose(c0, c_va0, atol=1e-12)


# ---------------------------------------------------------------- stage 2


def test_stage2_G_matches_finite_differences(rng):
    for _ in range(N_RANDOM):
        phi, theta, _ = random_attitude(rng)
        rates = rng.normal(0, 0.5, 3)
        trig = np.sin(phi), np.cos(phi), np.cos(theta)
        numerical = numerical_jacobian(lambda w, a: [m.euler_yaw_rate(*a, w[1], w[2])], rates, trig)
        np.testing.assert_allclose(m.stage2_G(*trig), numerical[0], rtol=RTOL, atol=ATOL)


def test_stage2_h_and_jacobians(rng):
    """h = C_bn v_n (eq 24); dh/dpsi (corrected eq 25) and dh/d(phi, theta) vs finite differences."""
    for _ in range(N_RANDOM):
        phi, theta, psi = random_attitude(rng)
        ref = unit(rng.normal(size=3))
        h, c, j_tilt = meas.stage2_h(psi, phi, theta, ref)
        np.testing.assert_allclose(h, euler_to_matrix(phi, theta, psi).T @ ref, rtol=1e-12, atol=1e-12)
        numerical = numerical_jacobian(lambda s, *a: meas.stage2_h(s[0], *a)[0], [psi], phi, theta, ref)
        np.testing.assert_allclose(c, numerical, rtol=RTOL, atol=ATOL)
        numerical_tilt = numerical_jacobian(lambda s, a, v: meas.stage2_h(a, s[0], s[1], v)[0], [phi, theta], psi, ref)
        np.testing.assert_allclose(j_tilt, numerical_tilt, rtol=RTOL, atol=ATOL)
        # the explicit corrected eq 25 (docs/three_stage.md, 'Corrections to the paper'), row by row
        cph, sph, cth, sth, cps, sps = (np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi),
                                        np.sin(psi))
        eq25 = [-cth * sps * ref[0] + cth * cps * ref[1],
                (-sph * sth * sps - cph * cps) * ref[0] + (sph * sth * cps - cph * sps) * ref[1],
                (-cph * sth * sps + sph * cps) * ref[0] + (cph * sth * cps + sph * sps) * ref[1]]
        np.testing.assert_allclose(c[:, 0], eq25, rtol=1e-12, atol=1e-12)


# ---------------------------------------------------------------- stage 3, fixed wing


def random_fw_state(rng):
    x = np.array([rng.normal(0, 100), rng.normal(0, 100), rng.uniform(5, 30), rng.uniform(-np.pi, np.pi),
                  rng.normal(0, 5), rng.normal(0, 5), rng.normal(0, 0.1), rng.normal(0, 0.1), rng.normal(0, 0.1)])
    phi, theta, psi = random_attitude(rng)
    u = np.array([rng.uniform(5, 30), rng.normal(0, 0.3), rng.normal(0, 0.3), phi, theta, psi])
    return x, u


def test_stage3_fw_A_matches_finite_differences(rng):
    for _ in range(N_RANDOM):
        x, u = random_fw_state(rng)
        numerical = numerical_jacobian(m.stage3_fw_f, x, u, GRAVITY)
        np.testing.assert_allclose(m.stage3_fw_jacobians(x, u, GRAVITY)[0], numerical, rtol=RTOL, atol=ATOL)


def test_stage3_fw_G_matches_finite_differences(rng):
    for _ in range(N_RANDOM):
        x, u = random_fw_state(rng)

        def f_of_inputs(va_psi, x=x, u=u):
            v = u.copy()
            v[0], v[5] = va_psi
            return m.stage3_fw_f(x, v, GRAVITY)

        numerical = numerical_jacobian(f_of_inputs, u[[0, 5]])
        np.testing.assert_allclose(m.stage3_fw_jacobians(x, u, GRAVITY)[1], numerical, rtol=RTOL, atol=ATOL)
        a_out, g_out = np.full((9, 9), np.nan), np.full((9, 2), np.nan)  # the output-array form writes everything
        m.stage3_fw_jacobians(x, u, GRAVITY, a_out, g_out)
        np.testing.assert_array_equal(a_out, m.stage3_fw_jacobians(x, u, GRAVITY)[0])
        np.testing.assert_array_equal(g_out, m.stage3_fw_jacobians(x, u, GRAVITY)[1])


def test_stage3_fw_ground_speed_rate_is_wind_triangle_derivative(rng):
    """V_g_dot of f equals d/dt |V_a (c_psi, s_psi) + w| with psi_dot from the gyro (eq 27)."""
    for _ in range(N_RANDOM):
        x, u = random_fw_state(rng)
        va, psi = u[0], m.corrected_heading(x, u[5])[0]
        wind = x[4:6] * min(1.0, 0.5 * va / np.linalg.norm(x[4:6]))  # keep V_g > V_min: no frozen 1/V_g
        x[4:6] = wind
        psi_dot = m.euler_yaw_rate(np.sin(u[3]), np.cos(u[3]), np.cos(u[4]), u[1], u[2])
        ground = va * np.array([np.cos(psi), np.sin(psi)]) + wind
        x[2] = np.linalg.norm(ground)
        dt = 1e-6
        ground1 = va * np.array([np.cos(psi + psi_dot * dt), np.sin(psi + psi_dot * dt)]) + wind
        expected = (np.linalg.norm(ground1) - x[2]) / dt
        np.testing.assert_allclose(m.stage3_fw_f(x, u, GRAVITY)[2], expected, rtol=1e-4, atol=1e-6)


def test_stage3_fw_low_speed_guard_is_consistent():
    """Below V_min the 1/V_g factors freeze: f stays finite and A's V_g column has no 1/V_g^2 terms."""
    x = np.array([0.0, 0.0, 0.5, 0.3, 1.0, -2.0, 0.1, -0.05, 0.03])
    u = np.array([12.0, 0.1, 0.2, 0.3, 0.05, 0.4])
    np.testing.assert_allclose(m.stage3_fw_jacobians(x, u, GRAVITY)[0],
                               numerical_jacobian(m.stage3_fw_f, x, u, GRAVITY), rtol=RTOL, atol=ATOL)
    assert np.all(np.isfinite(m.stage3_fw_f(np.zeros(m.N_STAGE3_FW), u, GRAVITY)))


def test_stage3_fw_wind_pseudo_measurement(rng):
    for _ in range(N_RANDOM):
        x, u = random_fw_state(rng)
        vah, psi = u[0], u[5]
        _, c = meas.stage3_fw_h_wind(x, vah, psi)
        np.testing.assert_allclose(c, numerical_jacobian(lambda s, *a: meas.stage3_fw_h_wind(s, *a)[0], x, vah, psi),
                                   rtol=RTOL, atol=ATOL)
        numerical_inputs = numerical_jacobian(lambda w, s: meas.stage3_fw_h_wind(s, w[0], w[1])[0], [vah, psi], x)
        np.testing.assert_allclose(meas.stage3_fw_wind_input_jacobian(x, vah, psi), numerical_inputs,
                                   rtol=RTOL, atol=ATOL)
        # an exact wind triangle (at the corrected heading) gives a zero residual
        heading = m.corrected_heading(x, psi)[0]
        x[2:4] = [np.hypot(vah * np.cos(heading) + x[4], vah * np.sin(heading) + x[5]),
                  np.arctan2(vah * np.sin(heading) + x[5], vah * np.cos(heading) + x[4])]
        np.testing.assert_allclose(meas.stage3_fw_h_wind(x, vah, psi)[0], 0.0, atol=1e-12)


def test_corrected_heading_derivatives(rng):
    for _ in range(N_RANDOM):
        x, u = random_fw_state(rng)
        _, dpsi_dyaw2, dpsi_ddev = m.corrected_heading(x, u[5])
        numerical = numerical_jacobian(lambda s, x: [m.corrected_heading(x, s[0])[0]], [u[5]], x)
        np.testing.assert_allclose(dpsi_dyaw2, numerical[0, 0], rtol=RTOL)
        numerical = numerical_jacobian(lambda d, x, y: [m.corrected_heading(np.r_[x[:6], d], y)[0]], x[6:], x, u[5])
        np.testing.assert_allclose(dpsi_ddev, numerical[0], rtol=RTOL, atol=ATOL)


def test_stage3_fw_zero_deviation_is_the_paper_model(rng):
    """With zero deviation the model is the paper's 6-state one; a deviation acts as the corrected heading."""
    for _ in range(N_RANDOM):
        x, u = random_fw_state(rng)
        shifted = u.copy()
        shifted[5] = m.corrected_heading(x, u[5])[0]
        unbiased = x.copy()
        unbiased[6:] = 0.0
        np.testing.assert_allclose(m.stage3_fw_f(x, u, GRAVITY), m.stage3_fw_f(unbiased, shifted, GRAVITY),
                                   rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(meas.stage3_fw_h_wind(x, u[0], u[5])[0],
                                   meas.stage3_fw_h_wind(unbiased, u[0], shifted[5])[0], rtol=1e-12, atol=1e-12)


def test_stage3_fw_gps_velocity_model(rng):
    for _ in range(N_RANDOM):
        x, _ = random_fw_state(rng)
        h, c = meas.stage3_fw_h_gps_velocity(x)
        np.testing.assert_allclose(h, x[2] * np.array([np.cos(x[3]), np.sin(x[3])]), rtol=1e-12)
        np.testing.assert_allclose(c, numerical_jacobian(lambda s: meas.stage3_fw_h_gps_velocity(s)[0], x),
                                   rtol=RTOL, atol=ATOL)


# ---------------------------------------------------------------- stage 3, multicopter


def test_stage3_mc_A_matches_finite_differences(rng):
    for _ in range(N_RANDOM):
        x = rng.normal(0, 10, 4)
        accel = rng.normal(0, 2, 2)
        np.testing.assert_allclose(m.stage3_mc_A(), numerical_jacobian(m.stage3_mc_f, x, accel),
                                   rtol=RTOL, atol=ATOL)


def test_ned_acceleration_at_rest_is_zero(rng):
    for _ in range(N_RANDOM):
        phi, theta, psi = random_attitude(rng)
        f_b = euler_to_matrix(phi, theta, psi).T @ [0.0, 0.0, -GRAVITY]
        a = m.ned_acceleration(phi, theta, psi, f_b, GRAVITY)
        np.testing.assert_allclose(a, 0.0, atol=1e-12)


# ---------------------------------------------------------------- vector updates


def test_whitened_vector_update_equals_the_batch_update(rng):
    """A correlated vector measurement, whitened with the Cholesky factor of R and fused by sequential scalar
    updates (the stage-2 and wind updates), gives the batch Kalman update x + K nu, (I - K H) P."""
    n, m_components = 4, 3
    w, mw = ts_kernel._stage_work(n, 2, 6), ts_kernel._measurement_work()
    diag_f, diag_i = recorder.diagnostics_arrays(8)
    counters = np.zeros(ts_control.N_COUNTERS, dtype=np.int64)
    for _ in range(N_RANDOM):
        a = rng.normal(size=(n, n))
        P = a @ a.T + 0.1 * np.eye(n)
        b = rng.normal(size=(m_components, m_components))
        R = b @ b.T + 0.1 * np.eye(m_components)
        H, nu, x = rng.normal(size=(m_components, n)), rng.normal(size=(m_components, 1)), rng.normal(size=n)
        S = H @ P @ H.T + R
        gain = P @ H.T @ np.linalg.inv(S)
        expected_x, expected_P = x + gain @ nu[:, 0], (np.eye(n) - gain @ H) @ P
        counters[:] = 0
        passed = stages.whitened_update(0.0, records.MAG, x, P, m_components, nu.copy(), H.copy(), R.copy(), np.inf,
                                        w, mw, diag_f, diag_i, counters)
        assert passed
        np.testing.assert_allclose(x, expected_x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(P, expected_P, rtol=1e-9, atol=1e-9)


# ---------------------------------------------------------------- state tables


def all_tables():
    config = EstimatorConfig()
    return [three_stage.stage1_states(config), three_stage.stage2_states(config, absolute_yaw=True),
            three_stage.stage2_states(config, absolute_yaw=False),
            three_stage.stage3_fixed_wing_states(config, three_stage.ThreeStageOptions()),
            three_stage.stage3_multicopter_states(config)]


@pytest.mark.parametrize("table", all_tables())
def test_state_tables_build_positive_definite_matrices(table):
    p0 = state_table.initial_covariance(table)
    qc = state_table.process_noise_psd(table)
    assert p0.shape == qc.shape == (len(table), len(table))
    assert np.all(np.linalg.eigvalsh(p0) > 0) and np.all(np.linalg.eigvalsh(qc) > 0)
    names = [spec.name for spec in table]
    assert len(set(names)) == len(names)
    suffix = {"rad": "_rad", "m": "_m", "m/s": "_m_s"}
    assert all(spec.name.endswith(suffix[spec.unit]) for spec in table)  # units in the names


# ---------------------------------------------------------------- whole runs


def run_three_stage(log, config=None, options=None, **inputs_kwargs):
    config = EstimatorConfig() if config is None else config
    inputs = build.build_replay_inputs(log, config, **inputs_kwargs)
    return three_stage.run(log, inputs, config, options=options)


@pytest.fixture(scope="module")
def short_flight():
    """10 s of fixed-wing flight in wind with every sensor (IMU 250 Hz)."""
    return synthetic_flight(10.0, seed=3)


TWIN_SCRIPT = """
import sys
from estimators_synthetic import synthetic_flight
from estimators.inputs import build
from estimators.three_stage import run as three_stage
from estimators.api import run_estimators
from estimators.config import EstimatorConfig
log = synthetic_flight(10.0, seed=3, mav_type={mav_type}, with_airspeed={with_airspeed})
config = EstimatorConfig()
run = three_stage.run(log, build.build_replay_inputs(log, config), config)
run.states.to_pickle(sys.argv[1])
run.diagnostics.to_pickle(sys.argv[2])
"""


@pytest.mark.parametrize(("mav_type", "with_airspeed"), [(1, True), (2, False)], ids=["fixed_wing", "multicopter"])
def test_numba_kernel_equals_uncompiled_python(tmp_path, mav_type, with_airspeed):
    """The compiled kernel and the same code run as plain Python/NumPy (NUMBA_DISABLE_JIT=1, a fresh process)
    give the same trajectory and diagnostics on a 10 s log (max abs difference < 1e-9)."""
    states_path, diag_path = tmp_path / "states.pkl", tmp_path / "diag.pkl"
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1", "PYTHONPATH": os.pathsep.join([str(REPO_DIR), str(TESTS_DIR)])}
    script = TWIN_SCRIPT.format(mav_type=mav_type, with_airspeed=with_airspeed)
    subprocess.run([sys.executable, "-c", script, str(states_path), str(diag_path)], env=env, check=True,
                   cwd=REPO_DIR, timeout=600)
    slow_states, slow_diag = pd.read_pickle(states_path), pd.read_pickle(diag_path)
    fast = run_three_stage(synthetic_flight(10.0, seed=3, mav_type=mav_type, with_airspeed=with_airspeed))
    numeric = [c for c in fast.states.columns if c != "time_s"]
    assert len(fast.states) == len(slow_states) > 400
    fast_values, slow_values = fast.states[numeric].to_numpy(), slow_states[numeric].to_numpy()
    assert np.array_equal(np.isnan(fast_values), np.isnan(slow_values))
    assert np.nanmax(np.abs(fast_values - slow_values)) < 1e-9
    assert len(fast.diagnostics) == len(slow_diag) > 0
    for column in ("time_s", "innovation", "innovation_var", "nis"):
        assert np.nanmax(np.abs(fast.diagnostics[column].to_numpy() - slow_diag[column].to_numpy())) < 1e-9
    assert (fast.diagnostics["accepted"].to_numpy() == slow_diag["accepted"].to_numpy()).all()


def test_fixed_wing_run_on_synthetic_flight(short_flight):
    run = run_three_stage(short_flight)
    report = run.report
    assert report.details["modes"] == {"stage1": "airspeed (centripetal)", "stage2": "mag", "stage3": "fixed_wing",
                                       "height": "baro"}
    assert "sideslip" not in report.used and report.skipped["sideslip"].startswith("not part of")
    assert report.resets == 0 and report.gps_resets == 0
    assert set(run.diagnostics["sensor"].unique()) == {"accel", "mag", "gps_pos", "gps_vel", "wind"}
    # stage 3 runs from the first GPS epoch (flying from the start): every output after it is complete
    after = run.states["time_s"] >= report.details["stage3_start_s"]
    assert after.mean() > 0.95
    assert run.states.loc[after, list(STATE_COLUMNS[1:])].notna().all().all()
    truth = short_flight["truth_attitude"]
    t = run.states["time_s"].to_numpy()
    for column, tolerance_deg in (("roll_deg", 1.0), ("pitch_deg", 1.0)):
        expected = np.interp(t, truth.index.to_numpy(), truth[column].to_numpy())
        assert np.sqrt(np.mean((run.states[column].to_numpy() - expected) ** 2)) < tolerance_deg, column


def test_paper_gps_velocity_mode_and_gps_acceleration_option():
    """Ground speed and course as GPS measurements (eq 9 corrected); the GPS-acceleration stage-1 form without
    airspeed."""
    log = synthetic_flight(10.0, seed=6)
    run = run_three_stage(log, EstimatorConfig(gps_velocity_mode="paper"))
    components = set(run.diagnostics.loc[run.diagnostics["sensor"] == "gps_vel", "component"].unique())
    assert components == {"vg", "chi"}
    assert run.states[["vn_m_s", "ve_m_s"]].iloc[-100:].notna().all().all()
    copter = synthetic_flight(10.0, seed=7, mav_type=2, with_airspeed=False)
    run = run_three_stage(copter, options=three_stage.ThreeStageOptions(gps_acceleration=True))
    assert run.report.details["modes"]["stage1"] == "gps_acceleration"
    assert run.states[["roll_deg", "pitch_deg", "yaw_deg"]].notna().all().all()


def test_degraded_modes_run_without_nan():
    # multicopter (no airspeed): Cartesian stage 3, no wind
    copter = synthetic_flight(10.0, seed=4, mav_type=2, with_airspeed=False)
    run = run_three_stage(copter)
    assert run.report.details["modes"]["stage3"] == "multicopter"
    assert run.report.details["modes"]["stage1"] == "gravity_only"
    assert run.states["wind_n_m_s"].isna().all()
    assert run.states[["roll_deg", "pitch_deg", "yaw_deg", "alt_m"]].notna().all().all()
    assert run.states[["lat_deg", "vn_m_s"]].iloc[5:].notna().all().all()
    # no GPS: attitude and height only
    blind = synthetic_flight(10.0, seed=5, with_gps=False)
    run = run_three_stage(blind)
    assert run.report.details["modes"]["stage3"] == "none"
    assert run.states["lat_deg"].isna().all() and run.states["vn_m_s"].isna().all()
    assert run.states[["roll_deg", "pitch_deg", "yaw_deg", "alt_m"]].notna().all().all()
    assert "zero_velocity" not in run.report.used


# the overflowed attitude drives stage 3 to huge (finite) positions until the GPS reset: geodetic conversion warns
@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning", "ignore:invalid value:RuntimeWarning")
def test_divergence_is_reset_never_nan(short_flight):
    config = EstimatorConfig()
    inputs = build.build_replay_inputs(short_flight, config)
    gyro = inputs.imu.gyro_rad_s.copy()
    gyro[1200] = 1e300  # an absurd sample makes the attitude overflow
    broken = records.ReplayInputs(**{**inputs.__dict__, "imu": records.ImuSamples(
        **{**inputs.imu.__dict__, "gyro_rad_s": gyro})})
    run = three_stage.run(short_flight, broken, config)
    assert run.report.resets >= 1
    assert any("reset" in w for w in run.report.warnings)
    assert run.states[["roll_deg", "pitch_deg", "yaw_deg"]].notna().all().all()


REAL_LOGS = ("sample.ulg", "sample_appended_multiple.ulg", "sample_log_small.ulg",
             "sample_logging_tagged_and_default_params.ulg", "sample_px4_events.ulg")


@pytest.mark.parametrize("name", REAL_LOGS)
def test_real_logs_run_to_the_end_without_nan(real_logs_dir, name):
    log = load_flight_log(real_logs_dir / name)
    run = run_three_stage(log)
    states = run.states
    assert len(states) > 100 and run.report.resets == 0
    assert states[["roll_deg", "pitch_deg", "yaw_deg"]].notna().all().all()
    modes = run.report.details["modes"]
    if modes["height"] != "none":  # from the first height sample on
        has_height = states["alt_m"].notna().to_numpy()
        first = int(np.argmax(has_height))
        assert has_height[first:].all() and states["time_s"].iloc[first] - states["time_s"].iloc[0] < 1.0
    if modes["stage3"] != "none":
        start = run.report.details["stage3_start_s"]
        assert start is not None
        after = states["time_s"] >= start
        assert states.loc[after, ["lat_deg", "lon_deg", "vn_m_s", "ve_m_s"]].notna().all().all()
    assert np.isfinite(run.diagnostics[["innovation", "innovation_var"]].to_numpy()).all()


# ---------------------------------------------------------------- the simulated paper mission


#: Position and height cannot beat the receiver's own slowly varying (Gauss-Markov) error, roll and pitch cannot beat
#: the accelerometer's levelling error (bias and misalignment: no bias states in this estimator): the bar is the
#: larger of Table 2 and this factor times the error the run cannot remove.
FLOOR_FACTOR = 1.1


@pytest.fixture(scope="module")
def paper_mission():
    """All three estimators on sample_logs/paper.ulg with the simulation's true noise settings."""
    log = load_flight_log(SAMPLE_LOGS_DIR / "paper.ulg")
    sidecar = json.loads((SAMPLE_LOGS_DIR / "paper_sim.json").read_text())
    config = config_for_simulation(sidecar)
    result = run_estimators(log, config=config)
    inputs = build.build_replay_inputs(log, config)
    return log, sidecar, inputs, result, rms_errors(result.states, log, after_s=60.0)


def levelling_error_deg(log, inputs):
    """|roll|, |pitch| error [deg] of levelling with the accelerometer over the still window at the start (what a
    filter without accelerometer-bias states keeps: bias and misalignment tilt the measured gravity)."""
    start, end = inputs.alignment.still_window_s
    imu, truth = log["imu"], log["truth_attitude"]
    still = (imu.index >= start) & (imu.index <= end)
    f_b = imu.loc[still, ["accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"]].to_numpy().mean(axis=0)
    roll, pitch = np.degrees(alignment.tilt_from_specific_force(f_b))
    at_rest = (truth.index >= start) & (truth.index <= end)
    return abs(roll - truth.loc[at_rest, "roll_deg"].mean()), abs(pitch - truth.loc[at_rest, "pitch_deg"].mean())


def test_paper_mission_meets_table_2(paper_mission):
    log, sidecar, inputs, result, rms = paper_mission
    ours = rms.loc["three_stage"]
    gps = sidecar["sensor_errors"]["gps"]
    bars = {q: PAPER_TABLE_2["three_stage"][q] for q in ("roll_deg", "pitch_deg", "yaw_deg", "position_m",
                                                          "height_m", "ground_speed_m_s", "course_deg", "wind_m_s")}
    roll_floor, pitch_floor = levelling_error_deg(log, inputs)
    for quantity, floor in (("position_m", gps["position_error_rms_horizontal_m"]),
                            ("height_m", gps["position_error_rms_ned_m"][2]), ("roll_deg", roll_floor),
                            ("pitch_deg", pitch_floor)):
        bars[quantity] = max(bars[quantity], FLOOR_FACTOR * floor)
    print("\n".join(f"{q:18s} ours {ours[q]:7.3f}  bar {bars[q]:7.3f}  Table 2 {PAPER_TABLE_2['three_stage'][q]}"
                    for q in bars))
    failing = {q: (round(ours[q], 3), round(bars[q], 3)) for q in bars if not ours[q] <= bars[q]}
    assert not failing, failing
    report = result.reports["three_stage"]
    assert report.resets == 0 and report.gps_resets == 0
    assert report.details["modes"] == {"stage1": "airspeed (centripetal)", "stage2": "mag", "stage3": "fixed_wing",
                                       "height": "baro"}


def test_paper_mission_three_stage_is_the_least_accurate(paper_mission):
    """Largest RMS error of the three in pitch, height and the speeds and course; in position, where all three sit
    at the GPS floor, within 2 % of the best. In roll, yaw and wind it is not the worst: it levels with the
    error-state filter's in-flight accelerometer bias removed (docs/three_stage.md, 'Pre-processing'; roll 0.41
    against 0.43 and 0.47 deg), its heading is on a par (0.73 against 1.08 and 0.42 deg), its wind too (0.10 against
    0.20 and 0.10 m/s); there it stays inside its Table-2 row and never beats the best full-state filter by more than
    a tenth of a degree or 0.05 m/s."""
    *_, rms = paper_mission
    print(rms.round(3).to_string())
    others = rms.drop(index="three_stage")
    row = PAPER_TABLE_2["three_stage"]
    for quantity in rms.columns:
        ours = rms.loc["three_stage", quantity]
        if quantity == "position_m":
            assert ours >= 0.98 * others[quantity].min(), quantity
        elif quantity in ("roll_deg", "yaw_deg", "wind_m_s"):
            assert ours <= row[quantity], quantity
            assert ours >= others[quantity].min() - (0.05 if quantity == "wind_m_s" else 0.1), quantity
        else:
            assert ours >= others[quantity].max(), quantity


@pytest.mark.parametrize("heading", ["sun", "mag+sun"])
def test_sun_vector_heading_on_simulated_flight(heading):
    """Stage 2 with the photocell sun vector (tangent-plane updates), alone or with the magnetometer, on the bundled
    flight with a failing cell; without the magnetometer the initial heading comes from gravity and the sun."""
    log = with_sun(load_flight_log(SAMPLE_LOGS_DIR / "failed_cell.ulg"), SAMPLE_LOGS_DIR / "failed_cell_sun.csv")
    config = config_for_simulation(json.loads((SAMPLE_LOGS_DIR / "failed_cell_sim.json").read_text()))
    result = run_estimators(log, estimators="three_stage", config=config, heading=heading)
    report = result.reports["three_stage"]
    assert report.details["modes"]["stage2"] == heading
    assert report.details["alignment"]["yaw_source"] == ("sun" if heading == "sun" else "mag")
    sun = result.diagnostics[result.diagnostics["sensor"] == "sun"]
    assert len(sun) > 1000 and sun["accepted"].mean() > 0.95
    rms = rms_errors(result.states, log, after_s=60.0).loc["three_stage"]
    assert rms["yaw_deg"] < 1.5 and rms["wind_m_s"] < 0.3, rms


def test_measured_heading_inverts_the_body_vector_model(rng):
    """Heading re-acquisition: a reference rotated into body axes at (phi, theta, psi) gives back psi at that roll
    and pitch (magnetometer-like and sun-like references); no heading from a vertical reference."""
    for _ in range(200):
        phi, theta = rng.uniform(-1.2, 1.2), rng.uniform(-1.2, 1.2)
        psi = rng.uniform(-np.pi, np.pi)
        ref = rng.normal(size=3)
        ref /= np.linalg.norm(ref)
        if np.hypot(ref[0], ref[1]) < 0.3:
            continue
        z_body = euler_to_matrix(phi, theta, psi).T @ ref
        if np.hypot(*(euler_to_matrix(phi, theta, 0.0) @ z_body)[:2]) < 0.3:
            continue
        heading = meas.measured_heading(z_body, ref, phi, theta)
        assert abs(np.angle(np.exp(1j * (heading - psi)))) < 1e-9
    assert np.isnan(meas.measured_heading(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0]), 0.0, 0.0))
