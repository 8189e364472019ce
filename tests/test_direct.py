"""Full-state direct filter: analytic Jacobians against finite differences, numba kernel against the NumPy twin,
the paper-literal indirect filter against the direct one (math note 5.1), accuracy and degraded modes on an exact
synthetic flight."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.config import EstimatorConfig
from estimators.core import linalg
from estimators.direct import kernel as direct_kernel
from estimators.direct import reference as ref
from estimators.inputs import build, records
from estimators.inputs.records import AIRSPEED, BARO, GPS_POS, GPS_VEL, MAG, SIDESLIP, SUN, ZERO_VELOCITY
from tests.estimators_synthetic import synthetic_flight

G = 9.79
FULL_LAYOUT = np.array([12, 15, 17, 20], dtype=np.int64)  # b_a, wind, mag bias, baro bias
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
    return np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))


def _central_difference(fun, x, step=FD_STEP):
    cols = []
    for i in range(len(x)):
        e = np.zeros(len(x))
        e[i] = step
        cols.append((fun(x + e) - fun(x - e)) / (2 * step))
    return np.array(cols).T


def _numba_f(gyro, accel, layout=FULL_LAYOUT):
    def f(x):
        out = np.empty(len(x))
        direct_kernel.derivative(x, gyro, accel, G, layout, *_scratch(), out)
        return out
    return f


@pytest.mark.parametrize("seed", range(5))
def test_process_jacobian_matches_finite_differences(seed):
    rng = np.random.default_rng(seed)
    x = _random_state(rng)
    gyro, accel = rng.normal(0, 0.3, 3), rng.normal(0, 3, 3) + np.array([0, 0, -G])
    A = np.zeros((N_FULL, N_FULL))
    direct_kernel.jacobian(x, gyro, G, FULL_LAYOUT, *_scratch(), A)
    A_fd = _central_difference(_numba_f(gyro, accel), x)
    np.testing.assert_allclose(A, A_fd, rtol=RTOL, atol=ATOL)
    # the twin's matrix-form Jacobian and dynamics agree with the kernel's
    np.testing.assert_allclose(ref.A_matrix(x, gyro, G, FULL_LAYOUT), A, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ref.f(x, gyro, accel, G, FULL_LAYOUT), _numba_f(gyro, accel)(x), rtol=1e-12,
                               atol=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_process_noise_is_input_jacobian_quadratic_form(seed):
    """Qc = G_g N_g^2 G_g^T + G_a N_a^2 G_a^T + diag(rw) with G = df/d(input) from finite differences."""
    rng = np.random.default_rng(seed)
    x = _random_state(rng)
    gyro, accel = rng.normal(0, 0.3, 3), rng.normal(0, 3, 3)
    ng2, na2 = 3e-6, 1e-3
    rw = rng.uniform(0, 1e-6, N_FULL)
    Qc = np.zeros((N_FULL, N_FULL))
    direct_kernel.process_noise(x, ng2, na2, rw, 1.0, *_scratch(), Qc)
    G_g = _central_difference(lambda g: _numba_f(g, accel)(x), gyro)
    G_a = _central_difference(lambda a: _numba_f(gyro, a)(x), accel)
    expected = ng2 * G_g @ G_g.T + na2 * G_a @ G_a.T + np.diag(rw)
    np.testing.assert_allclose(Qc, expected, rtol=RTOL, atol=1e-12)
    np.testing.assert_allclose(ref.Qc_matrix(x, ng2, na2, rw, FULL_LAYOUT), Qc, rtol=1e-12, atol=1e-15)


MEASUREMENTS = [(BARO, 0), (AIRSPEED, 0), (SIDESLIP, 0), *((GPS_POS, c) for c in range(3)),
                *((GPS_VEL, c) for c in range(5)), *((MAG, c) for c in range(3)), *((SUN, c) for c in range(3)),
                *((ZERO_VELOCITY, c) for c in range(3))]


@pytest.mark.parametrize(("kind", "comp"), MEASUREMENTS)
@pytest.mark.parametrize("layout", [FULL_LAYOUT, np.array([-1, -1, -1, -1])], ids=["all_states", "base"])
def test_measurement_jacobians_match_finite_differences(kind, comp, layout):
    rng = np.random.default_rng(100 + kind * 10 + comp)
    field = rng.normal(size=3)
    field /= np.linalg.norm(field)
    values = np.zeros(6)
    sun = rng.normal(size=3)
    values[3:6] = sun / np.linalg.norm(sun)
    n = N_FULL if layout[0] >= 0 else 12
    for _ in range(3):
        x = _random_state(rng)[:n]
        H = np.empty(n)

        def h(xx):
            return direct_kernel.measurement(xx, kind, comp, values, field, layout, *_scratch(), np.empty(n))

        h0 = direct_kernel.measurement(x, kind, comp, values, field, layout, *_scratch(), H)
        H_fd = _central_difference(lambda xx: np.array([h(xx)]), x)[0]
        np.testing.assert_allclose(H, H_fd, rtol=RTOL, atol=ATOL)
        h_ref, H_ref = ref.h_and_H(x, kind, comp, values, field, layout)
        assert h_ref == pytest.approx(h0, rel=1e-12, abs=1e-12)
        np.testing.assert_allclose(H_ref, H, rtol=1e-12, atol=1e-12)


def test_transition_matches_matrix_exponential_for_small_steps():
    """F = I + A dt + (A dt)^2/2 agrees with expm(A dt) to third order."""
    from scipy.linalg import expm

    rng = np.random.default_rng(7)
    x = _random_state(rng)
    A = np.zeros((N_FULL, N_FULL))
    direct_kernel.jacobian(x, rng.normal(0, 0.3, 3), G, FULL_LAYOUT, *_scratch(), A)
    F = np.empty_like(A)

    linalg.transition_matrix(A, 0.01, F)
    assert np.abs(F - expm(A * 0.01)).max() < np.linalg.norm(A * 0.01, 2) ** 3


# ----------------------------------------------------------------------------------------------------------------
# whole runs


@pytest.fixture(scope="module")
def short_flight():
    """10 s of fixed-wing flight in wind with every sensor (IMU 250 Hz)."""
    return synthetic_flight(10.0, seed=3)


@pytest.mark.parametrize("velocity_mode", ["ned", "paper"])
def test_numba_kernel_equals_numpy_twin(short_flight, velocity_mode):
    config = EstimatorConfig(gps_velocity_mode=velocity_mode)
    inputs = build.build_replay_inputs(short_flight, config)
    assert set(inputs.plan.used) == {"baro", "airspeed", "sideslip", "gps_pos", "gps_vel", "mag"}
    fast = direct_kernel.run(short_flight, inputs, config, backend="numba")
    slow = direct_kernel.run(short_flight, inputs, config, backend="numpy")
    numeric = [c for c in fast.states.columns if c != "time_s"]
    assert len(fast.states) == len(slow.states) == inputs.output_time_s.size
    diff = np.abs(fast.states[numeric].to_numpy() - slow.states[numeric].to_numpy())
    assert np.nanmax(diff) < 1e-9
    assert np.array_equal(np.isnan(fast.states[numeric].to_numpy()), np.isnan(slow.states[numeric].to_numpy()))
    assert len(fast.diagnostics) == len(slow.diagnostics) > 0
    for column in ("innovation", "innovation_var", "nis"):
        assert np.nanmax(np.abs(fast.diagnostics[column] - slow.diagnostics[column])) < 1e-9
    assert (fast.diagnostics["accepted"] == slow.diagnostics["accepted"]).all()
    final_fast, final_slow = fast.report.details["final_state"], slow.report.details["final_state"]
    assert max(abs(final_fast[k] - final_slow[k]) for k in final_fast) < 1e-9


def test_paper_literal_indirect_equals_direct(short_flight):
    """Math note 5.1: the paper's indirect filter (additive error in the same coordinates, reset after each
    update) is the direct filter. With linear measurement models (baro, GPS position) the two agree to
    round-off; with the nonlinear ones the only difference is the re-linearisation between the scalars of one
    sensor, a second-order effect."""
    config = EstimatorConfig()
    inputs = build.build_replay_inputs(short_flight, config)
    linear = records.ReplayInputs(**{**inputs.__dict__,
                                    "events": inputs.events.without((AIRSPEED, SIDESLIP, GPS_VEL, MAG))})
    direct = direct_kernel.run(short_flight, linear, config)
    paper = direct_kernel.run(short_flight, linear, config, mode="paper_indirect")
    numeric = [c for c in direct.states.columns if c != "time_s"]
    assert np.nanmax(np.abs(direct.states[numeric].to_numpy() - paper.states[numeric].to_numpy())) < 1e-9
    direct_all = direct_kernel.run(short_flight, inputs, config)
    paper_all = direct_kernel.run(short_flight, inputs, config, mode="paper_indirect")
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
    run = direct_kernel.run(log, build.build_replay_inputs(log, config), config)
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
    run = direct_kernel.run(copter, build.build_replay_inputs(copter, config), config)
    assert run.states["wind_n_m_s"].isna().all()
    assert "sideslip" not in run.report.used and "wn" not in run.report.details["states"]
    assert run.states[["roll_deg", "pitch_deg", "yaw_deg", "lat_deg", "vn_m_s"]].notna().all().all()
    # no GPS: attitude and height only, no accelerometer bias states
    blind = synthetic_flight(10.0, seed=5, with_gps=False)
    run = direct_kernel.run(blind, build.build_replay_inputs(blind, config), config)
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
    run = direct_kernel.run(short_flight, broken, config)
    assert run.report.resets >= 1
    assert any("reset" in w for w in run.report.warnings)
    assert run.states.drop(columns=["wind_n_m_s_std", "wind_e_m_s_std"]).notna().all().all()


def test_state_table_builds_x0_p0_q():
    config = EstimatorConfig()
    table = direct_kernel.state_table(config, accel_bias=True, wind=True, mag_bias=False, baro_bias=True, absolute_yaw=False)
    names = [s.name for s in table]
    assert names[:12] == ["pn", "pe", "pd", "u", "v", "w", "roll", "pitch", "yaw", "bgx", "bgy", "bgz"]
    layout = direct_kernel.layout_of(table)
    assert names[layout[direct_kernel.L_BA]] == "bax" and names[layout[direct_kernel.L_W]] == "wn" and layout[direct_kernel.L_BM] == -1
    yaw = table[names.index("yaw")]
    assert yaw.initial_sigma == pytest.approx(math.radians(config.initial.yaw_unaided_deg))
    assert table[names.index("wn")].process_sigma == config.noise.wind_rw_m_s_sqrt_s
