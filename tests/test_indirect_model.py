"""Error-state model and measurement models of the full-state indirect filter (:mod:`estimators.indirect.model`,
:mod:`estimators.indirect.measurements`): F, Q, the injection and every H against finite differences, and the
scalar-unrolled kernels against readable matrix forms (docs/indirect.md, 'Process model', 'Measurement models',
'Injection and reset') at random states.

The error is defined by the right perturbation R = R_hat Exp(dtheta) (body axes); other states are additive.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from estimators.core import linalg, rotations
from estimators.indirect import measurements as meas
from estimators.indirect import model as m
from estimators.inputs.records import AIRSPEED, BARO, GPS_POS, GPS_VEL, MAG, SIDESLIP, SUN, ZERO_VELOCITY
from ingest.frames import quat_to_matrix

GRAVITY_M_S2 = 9.80665


def random_state(rng: np.random.Generator) -> np.ndarray:
    """A non-trivial nominal state: attitude anywhere, 15 m/s flight, biases, wind, mag bias."""
    x = np.zeros(m.NX)
    x[m.X_P:m.X_P + 3] = rng.normal(0.0, 50.0, 3)
    x[m.X_V:m.X_V + 3] = rng.normal(0.0, 8.0, 3)
    quat_xyzw = Rotation.random(random_state=rng).as_quat()
    x[m.X_Q:m.X_Q + 4] = np.roll(quat_xyzw, 1)
    x[m.X_BG:m.X_BG + 3] = rng.normal(0.0, 0.02, 3)
    x[m.X_BA:m.X_BA + 3] = rng.normal(0.0, 0.3, 3)
    x[m.X_W:m.X_W + 2] = rng.normal(0.0, 4.0, 2)
    x[m.X_BM:m.X_BM + 3] = rng.normal(0.0, 0.05, 3)
    x[m.X_BB] = rng.normal(0.0, 3.0)
    x[m.X_KZ:m.X_KZ + 2] = rng.normal(0.0, 0.02, 2)
    return x


def boxplus(x: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """x (+) dx through the filter's own injection (P is a dummy)."""
    out = x.copy()
    m.inject(out, dx.copy(), np.eye(m.NE))
    return out


def boxminus(x1: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """The error dx with x1 = x0 (+) dx (attitude: Log(R0^T R1), body axes)."""
    dx = np.zeros(m.NE)
    dx[m.E_P:m.E_P + 3] = x1[m.X_P:m.X_P + 3] - x0[m.X_P:m.X_P + 3]
    dx[m.E_V:m.E_V + 3] = x1[m.X_V:m.X_V + 3] - x0[m.X_V:m.X_V + 3]
    r0 = Rotation.from_quat(np.roll(x0[m.X_Q:m.X_Q + 4], -1))
    r1 = Rotation.from_quat(np.roll(x1[m.X_Q:m.X_Q + 4], -1))
    dx[m.E_TH:m.E_TH + 3] = (r0.inv() * r1).as_rotvec()
    dx[m.E_BG:m.E_BG + 3] = x1[m.X_BG:m.X_BG + 3] - x0[m.X_BG:m.X_BG + 3]
    dx[m.E_BA:m.E_BA + 3] = x1[m.X_BA:m.X_BA + 3] - x0[m.X_BA:m.X_BA + 3]
    dx[m.E_W:m.E_W + 2] = x1[m.X_W:m.X_W + 2] - x0[m.X_W:m.X_W + 2]
    dx[m.E_BM:m.E_BM + 3] = x1[m.X_BM:m.X_BM + 3] - x0[m.X_BM:m.X_BM + 3]
    dx[m.E_BB] = x1[m.X_BB] - x0[m.X_BB]
    dx[m.E_KZ:m.E_KZ + 2] = x1[m.X_KZ:m.X_KZ + 2] - x0[m.X_KZ:m.X_KZ + 2]
    return dx


def propagated(x: np.ndarray, gyro: np.ndarray, accel: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    out = x.copy()
    F = m.identity_transition()
    m.transition(x, gyro, accel, dt, F, m.transition_work())
    m.propagate_nominal(out, gyro, accel, dt, GRAVITY_M_S2)
    return out, F


def numeric_jacobian(fun, x: np.ndarray, n_out: int, step: float = 1e-6) -> np.ndarray:
    """Central differences of ``fun(x (+) dx)`` with respect to dx."""
    jac = np.zeros((n_out, m.NE))
    for j in range(m.NE):
        dx = np.zeros(m.NE)
        dx[j] = step
        jac[:, j] = (fun(boxplus(x, dx)) - fun(boxplus(x, -dx))) / (2 * step)
    return jac


def assert_jacobian_close(analytic: np.ndarray, numeric: np.ndarray, rtol: float = 1e-6) -> None:
    """Elementwise |A - N| <= rtol * max(|N|, 1) (relative, with an absolute floor for near-zero entries)."""
    scale = np.maximum(np.abs(numeric), 1.0)
    err = np.abs(analytic - numeric) / scale
    worst = np.unravel_index(np.argmax(err), err.shape)
    assert err.max() <= rtol, f"worst entry {worst}: analytic {analytic[worst]}, numeric {numeric[worst]}"


@pytest.fixture(params=range(4))
def rng(request) -> np.random.Generator:
    return np.random.default_rng(1000 + request.param)


def test_rotation_helpers_match_scipy(rng):
    rotvec = rng.normal(0.0, 1.0, 3)
    q = np.array(rotations.quat_exp(*rotvec))
    expected = Rotation.from_rotvec(rotvec)
    np.testing.assert_allclose(quat_to_matrix(q), expected.as_matrix(), atol=1e-14)
    q2 = np.roll(Rotation.random(random_state=rng).as_quat(), 1)
    product = np.array(rotations.quat_multiply(*q2, *q))
    expected_product = Rotation.from_quat(np.roll(q2, -1)) * expected
    np.testing.assert_allclose(quat_to_matrix(product), expected_product.as_matrix(), atol=1e-14)
    v = rng.normal(size=3)
    r2 = Rotation.from_quat(np.roll(q2, -1))
    np.testing.assert_allclose(rotations.rotate(*q2, *v), r2.apply(v), atol=1e-14)
    np.testing.assert_allclose(rotations.rotate(q2[0], *-q2[1:], *v), r2.inv().apply(v), atol=1e-14)
    # Small-angle branch continuous with the closed form.
    tiny = np.array([3e-7, -2e-7, 1e-7])
    np.testing.assert_allclose(quat_to_matrix(np.array(rotations.quat_exp(*tiny))),
                               Rotation.from_rotvec(tiny).as_matrix(), atol=1e-15)


def test_right_jacobian(rng):
    for rotvec in (rng.normal(0.0, 0.8, 3), np.array([2e-5, -1e-5, 3e-5])):
        d = rng.normal(0.0, 1.0, 3) * 1e-7
        lhs = Rotation.from_rotvec(rotvec + d)
        J = np.empty((3, 3))
        rotations.right_jacobian_into(*rotvec, J)
        rhs = Rotation.from_rotvec(rotvec) * Rotation.from_rotvec(J @ d)
        np.testing.assert_allclose((lhs.inv() * rhs).as_rotvec(), 0.0, atol=1e-13)


@pytest.mark.parametrize("dt", [0.004, 0.02, 0.1])
def test_transition_matches_finite_differences(rng, dt):
    x = random_state(rng)
    gyro = rng.normal(0.0, 1.5, 3)
    accel = np.array([0.0, 0.0, -GRAVITY_M_S2]) + rng.normal(0.0, 3.0, 3)
    x_next, F = propagated(x, gyro, accel, dt)
    numeric = numeric_jacobian(lambda xp: boxminus(propagated(xp, gyro, accel, dt)[0], x_next), x, m.NE)
    assert_jacobian_close(F, numeric, rtol=1e-6)


def test_error_dynamics_first_order(rng):
    """The linearised error F dx predicts the propagated error with a residual shrinking ~10x per 10x smaller dx."""
    x = random_state(rng)
    gyro = rng.normal(0.0, 1.0, 3)
    accel = np.array([0.5, -0.3, -GRAVITY_M_S2]) + rng.normal(0.0, 2.0, 3)
    x_next, F = propagated(x, gyro, accel, 0.02)
    direction = rng.normal(0.0, 1.0, m.NE)
    relative = []
    for scale in (1e-2, 1e-3, 1e-4):
        dx = direction * scale
        actual = boxminus(propagated(boxplus(x, dx), gyro, accel, 0.02)[0], x_next)
        relative.append(np.linalg.norm(actual - F @ dx) / np.linalg.norm(dx))
    ratios = np.array(relative[:-1]) / np.array(relative[1:])
    assert np.all((ratios > 7.0) & (ratios < 14.0)), relative


def test_nominal_propagation_constant_rate_is_exact():
    """Constant body rate and zero specific force beyond gravity: attitude follows Exp(omega t) exactly."""
    x = np.zeros(m.NX)
    x[m.X_Q] = 1.0
    gyro = np.array([0.3, -0.2, 0.5])
    accel = np.zeros(3)  # free fall
    for _ in range(100):
        m.propagate_nominal(x, gyro, accel, 0.01, GRAVITY_M_S2)
    np.testing.assert_allclose(quat_to_matrix(x[m.X_Q:m.X_Q + 4]), Rotation.from_rotvec(gyro).as_matrix(),
                               atol=1e-12)
    np.testing.assert_allclose(x[m.X_V:m.X_V + 3], [0.0, 0.0, GRAVITY_M_S2], atol=1e-12)
    np.testing.assert_allclose(x[m.X_P:m.X_P + 3], [0.0, 0.0, GRAVITY_M_S2 / 2], atol=1e-12)


def test_process_noise_is_input_noise_through_f(rng):
    """Q equals G diag(sigma^2) G^T with G = d(next error)/d(IMU sample) by finite differences, plus the walks."""
    x = random_state(rng)
    gyro = rng.normal(0.0, 1.0, 3)
    accel = np.array([0.0, 0.0, -GRAVITY_M_S2]) + rng.normal(0.0, 2.0, 3)
    dt = 0.01
    x_next, F = propagated(x, gyro, accel, dt)
    step = 1e-6
    G = np.zeros((m.NE, 6))
    for j in range(6):
        du = np.zeros(6)
        du[j] = step
        plus = propagated(x, gyro + du[:3], accel + du[3:], dt)[0]
        minus = propagated(x, gyro - du[:3], accel - du[3:], dt)[0]
        G[:, j] = (boxminus(plus, x_next) - boxminus(minus, x_next)) / (2 * step)
    # The IMU sample enters exactly like minus the bias: G = -F[:, (b_g, b_a)] (bias rows excluded: noise is white).
    G_analytic = -np.concatenate([F[:, m.E_BG:m.E_BG + 3], F[:, m.E_BA:m.E_BA + 3]], axis=1)
    G_analytic[m.E_BG:] = 0.0
    assert_jacobian_close(G_analytic, G, rtol=1e-6)
    gyro_psd = np.array([1e-4, 2e-4, 3e-4]) ** 2
    accel_psd = np.array([1e-2, 2e-2, 4e-2]) ** 2
    Q_dyn = np.zeros((m.N_DYNAMIC, m.N_DYNAMIC))
    m.process_noise(F, gyro_psd, accel_psd, dt, Q_dyn)
    # A density N holds per-sample variance N^2 / dt; only the dynamic rows (p, v, theta) see the input noise.
    per_sample_var = np.concatenate([gyro_psd, accel_psd]) / dt
    expected = G_analytic @ np.diag(per_sample_var) @ G_analytic.T
    np.testing.assert_allclose(Q_dyn, expected[:m.N_DYNAMIC, :m.N_DYNAMIC], rtol=1e-12, atol=1e-20)
    assert not np.any(expected[m.N_DYNAMIC:]) and not np.any(expected[:, m.N_DYNAMIC:])


@pytest.mark.parametrize("drop", [(), (m.E_W, m.E_W + 1, m.E_KZ + 1)])
def test_covariance_propagation_is_f_p_ft_plus_q(rng, drop):
    """The structured propagation (dynamic rows only) equals the dense F P F^T + Q over the active states."""
    x = random_state(rng)
    gyro = rng.normal(0.0, 1.0, 3)
    accel = np.array([0.0, 0.0, -GRAVITY_M_S2]) + rng.normal(0.0, 2.0, 3)
    dt = 0.01
    _, F = propagated(x, gyro, accel, dt)
    Q_dyn = np.zeros((m.N_DYNAMIC, m.N_DYNAMIC))
    m.process_noise(F, np.full(3, 1e-6), np.full(3, 1e-3), dt, Q_dyn)
    walk_psd = rng.uniform(0.0, 1e-4, m.NE)
    sel = np.array([i for i in range(m.NE) if i not in drop])
    root = rng.normal(size=(len(sel), len(sel)))
    P = root @ root.T
    Q = np.diag(walk_psd * dt)
    Q[:m.N_DYNAMIC, :m.N_DYNAMIC] += Q_dyn
    Fs = F[np.ix_(sel, sel)]
    expected = Fs @ P @ Fs.T + Q[np.ix_(sel, sel)]
    values, cols = np.empty((m.N_DYNAMIC, len(sel))), np.empty((m.N_DYNAMIC, len(sel)), dtype=np.int64)
    counts = np.empty(m.N_DYNAMIC, dtype=np.int64)
    linalg.sparse_rows(F, sel, values, cols, counts)
    for i in range(m.N_DYNAMIC):
        nonzero = np.flatnonzero(F[i, sel])
        np.testing.assert_array_equal(cols[i, :counts[i]], nonzero)
        np.testing.assert_array_equal(values[i, :counts[i]], F[i, sel[nonzero]])
    linalg.propagate_sparse(P, values, cols, counts, np.empty_like(P))
    m.add_process_noise(P, Q_dyn, walk_psd[sel], dt)
    np.testing.assert_allclose(P, expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(P, P.T)


def test_injection_covariance_reset(rng):
    """The reset Jacobian G: the error w.r.t. the new nominal is G (dx_true - dx_injected) to first order."""
    x = random_state(rng)
    dx_hat = rng.normal(0.0, 0.05, m.NE)
    x_new = boxplus(x, dx_hat)
    step = 1e-6
    jac = np.zeros((m.NE, m.NE))
    for j in range(m.NE):
        d = np.zeros(m.NE)
        d[j] = step
        jac[:, j] = (boxminus(boxplus(x, dx_hat + d), x_new) - boxminus(boxplus(x, dx_hat - d), x_new)) / (2 * step)
    P = np.eye(m.NE)
    m.inject(x.copy(), dx_hat.copy(), P)
    # G G^T from the injection equals jac jac^T to first order in dtheta (Sola's G is the first-order form).
    np.testing.assert_allclose(P, jac @ jac.T, atol=np.linalg.norm(dx_hat[m.E_TH:m.E_TH + 3]) ** 2)


def _check_h(fun, x, rtol=1e-6):
    H = np.zeros(m.NE)
    fun(x, H)
    numeric = numeric_jacobian(lambda xp: np.array([fun(xp, np.zeros(m.NE))]), x, 1)[0]
    assert_jacobian_close(H[None, :], numeric[None, :], rtol=rtol)


def test_h_baro(rng):
    _check_h(meas.h_baro, random_state(rng))


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_h_gps_position_with_lever_arm(rng, axis):
    lever = np.array([0.3, -0.1, -0.2])
    _check_h(lambda x, H: meas.h_gps_position(x, lever, axis, H), random_state(rng))


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_h_gps_velocity_with_lever_arm(rng, axis):
    lever = np.array([0.3, -0.1, -0.2])
    gyro = rng.normal(0.0, 1.0, 3)
    _check_h(lambda x, H: meas.h_gps_velocity(x, gyro, lever, axis, H), random_state(rng))


def test_h_ground_speed_and_course(rng):
    _check_h(meas.h_ground_speed, random_state(rng))
    _check_h(meas.h_course, random_state(rng))


def test_h_airspeed(rng):
    _check_h(meas.h_airspeed, random_state(rng))


def test_h_sideslip(rng):
    _check_h(meas.h_sideslip, random_state(rng))


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_h_magnetometer(rng, axis):
    field = np.array([0.21, 0.01, 0.42])
    _check_h(lambda x, H: meas.h_body_vector(x, field, axis, True, H), random_state(rng))


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_h_sun(rng, axis):
    sun = np.array([0.3, 0.5, -0.81])
    sun /= np.linalg.norm(sun)
    _check_h(lambda x, H: meas.h_body_vector(x, sun, axis, False, H), random_state(rng))


def test_h_first_order(rng):
    """Linearisation residual of the attitude-dependent models shrinks ~10x per 10x smaller error."""
    x = random_state(rng)
    field = np.array([0.21, 0.01, 0.42])
    models = [meas.h_sideslip, lambda xx, H: meas.h_body_vector(xx, field, 1, True, H),
              lambda xx, H: meas.h_gps_position(xx, np.array([0.5, 0.2, -0.3]), 0, H)]
    direction = rng.normal(0.0, 1.0, m.NE)
    for fun in models:
        H = np.zeros(m.NE)
        h0 = fun(x, H)
        residual = [abs(fun(boxplus(x, direction * s), np.zeros(m.NE)) - h0 - H @ direction * s) / s
                    for s in (1e-2, 1e-3, 1e-4)]
        ratios = np.array(residual[:-1]) / np.array(residual[1:])
        assert np.all((ratios > 7.0) & (ratios < 14.0)), residual


def test_nominal_step_matches_matrix_form(rng):
    """The scalar-unrolled step equals the matrix form (docs/indirect.md, 'Process model': mid-interval attitude
    for f), with the specific force f = K (accel - b_a) of the z accelerometer's cross-axis states."""
    x = random_state(rng)
    gyro = rng.normal(0.0, 2.0, 3)
    accel = rng.normal(0.0, 5.0, 3)
    dt = 0.02
    out = x.copy()
    m.propagate_nominal(out, gyro, accel, dt, GRAVITY_M_S2)
    omega = gyro - x[m.X_BG:m.X_BG + 3]
    r0 = Rotation.from_quat(np.roll(x[m.X_Q:m.X_Q + 4], -1))
    f = accel - x[m.X_BA:m.X_BA + 3]
    f[2] -= x[m.X_KZ] * f[0] + x[m.X_KZ + 1] * f[1]
    a = (r0 * Rotation.from_rotvec(omega * dt / 2)).apply(f) + np.array([0, 0, GRAVITY_M_S2])
    np.testing.assert_allclose(out[m.X_V:m.X_V + 3], x[m.X_V:m.X_V + 3] + a * dt, atol=1e-12)
    np.testing.assert_allclose(out[m.X_P:m.X_P + 3], x[m.X_P:m.X_P + 3] + x[m.X_V:m.X_V + 3] * dt + a * dt ** 2 / 2,
                               atol=1e-12)
    expected_r = (r0 * Rotation.from_rotvec(omega * dt)).as_matrix()
    np.testing.assert_allclose(quat_to_matrix(out[m.X_Q:m.X_Q + 4]), expected_r, atol=1e-14)
    np.testing.assert_array_equal(out[m.X_BG:], x[m.X_BG:])


# ----------------------------------------------------------------------------------------------------------------
# readable matrix forms (rotation matrices and rotation vectors from scipy, blocks assigned by slices), written
# independently of the scalar-unrolled numba kernels and compared with them at random states

P_, V_, Q_, BG_, BA_, W_, BM_, KZ_ = (slice(m.X_P, m.X_P + 3), slice(m.X_V, m.X_V + 3), slice(m.X_Q, m.X_Q + 4),
                                      slice(m.X_BG, m.X_BG + 3), slice(m.X_BA, m.X_BA + 3), slice(m.X_W, m.X_W + 2),
                                      slice(m.X_BM, m.X_BM + 3), slice(m.X_KZ, m.X_KZ + 2))
DP, DV, DTH, DBG, DBA, DW, DBM, DKZ = (slice(m.E_P, m.E_P + 3), slice(m.E_V, m.E_V + 3), slice(m.E_TH, m.E_TH + 3),
                                       slice(m.E_BG, m.E_BG + 3), slice(m.E_BA, m.E_BA + 3), slice(m.E_W, m.E_W + 2),
                                       slice(m.E_BM, m.E_BM + 3), slice(m.E_KZ, m.E_KZ + 2))
FIELD = np.array([0.45, 0.02, 0.89]) / np.linalg.norm([0.45, 0.02, 0.89])
LEVER = np.array([0.3, -0.1, -0.2])


def skew(v):
    """[v]x, so that [v]x u = v x u."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotation(q):
    """R(q) of a (w, x, y, z) quaternion, body -> NED."""
    return Rotation.from_quat(np.roll(q, -1)).as_matrix()


def exp_so3(phi):
    return Rotation.from_rotvec(phi).as_matrix()


def quat_product(a, b):
    """Hamilton product a (x) b = L(a) b."""
    w, x, y, z = a
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]]) @ b


def right_jacobian(phi):
    """J_r(phi) = I - (1 - cos a)/a^2 [phi]x + (a - sin a)/a^3 [phi]x^2."""
    a = np.linalg.norm(phi)
    K = skew(phi)
    return np.eye(3) - (1.0 - np.cos(a)) / a ** 2 * K + (a - np.sin(a)) / a ** 3 * K @ K


def cross_axis(x):
    """K with f = K (accel - b_a): the z accelerometer's cross-axis sensitivities removed."""
    K = np.eye(3)
    K[2, 0:2] = -x[KZ_]
    return K


def transition_matrix_form(x, gyro, accel, dt, gyro_psd, accel_psd):
    """F of one step and its input noise G diag(N^2 / dt) G^T (docs/indirect.md, 'Process model')."""
    K = cross_axis(x)
    omega, f = gyro - x[BG_], K @ (accel - x[BA_])
    R, R_half = rotation(x[Q_]), exp_so3(omega * dt / 2)
    R_mid = R @ R_half
    a_th = -R @ skew(R_half @ f)
    a_bg = R_mid @ skew(f) @ right_jacobian(omega * dt / 2) * dt / 2
    a_kz = -np.outer(R_mid[:, 2], f[0:2])  # f_z = ... - k_zx f_x - k_zy f_y
    F = np.eye(m.NE)
    F[DP, DV] = np.eye(3) * dt
    for block, deriv in ((DTH, a_th), (DBG, a_bg), (DBA, -R_mid @ K), (DKZ, a_kz)):
        F[DP, block] = deriv * dt * dt / 2
        F[DV, block] = deriv * dt
    F[DTH, DTH] = exp_so3(omega * dt).T
    F[DTH, DBG] = -right_jacobian(omega * dt) * dt
    G = np.zeros((m.NE, 6))  # input noise (gyro, accel) enters as the bias errors, minus the bias rows
    G[:m.E_BG, 0:3] = F[:m.E_BG, DBG]
    G[:m.E_BG, 3:6] = F[:m.E_BG, DBA]
    return F, G @ np.diag(np.r_[gyro_psd, accel_psd] / dt) @ G.T


def measurement_matrix_form(x, kind, comp, values, field, lever, gyro):
    """Predicted scalar and its row over the NE error states (docs/indirect.md, 'Measurement models')."""
    R = rotation(x[Q_])
    H = np.zeros(m.NE)
    wind = np.r_[x[W_], 0.0]
    if kind == BARO:
        H[m.E_P + 2], H[m.E_BB] = -1.0, 1.0
        return x[m.X_BB] - x[m.X_P + 2], H
    if kind == GPS_POS:
        H[m.E_P + comp] = 1.0
        H[DTH] = (-R @ skew(lever))[comp]
        return (x[P_] + R @ lever)[comp], H
    if kind in (GPS_VEL, ZERO_VELOCITY) and comp < 3:
        arm = lever if kind == GPS_VEL else np.zeros(3)
        omega = gyro - x[BG_]
        H[m.E_V + comp] = 1.0
        H[DTH] = (-R @ skew(np.cross(omega, arm)))[comp]
        H[DBG] = (R @ skew(arm))[comp]
        return (x[V_] + R @ np.cross(omega, arm))[comp], H
    if kind == GPS_VEL:  # paper mode: ground speed (3) and course (4)
        vn, ve = x[m.X_V], x[m.X_V + 1]
        vg2 = vn * vn + ve * ve
        if comp == 3:
            H[m.E_V:m.E_V + 2] = np.array([vn, ve]) / np.sqrt(vg2)
            return np.sqrt(vg2), H
        H[m.E_V:m.E_V + 2] = np.array([-ve, vn]) / vg2
        return np.arctan2(ve, vn), H
    if kind == AIRSPEED:
        air = x[V_] - wind
        va = np.linalg.norm(air)
        H[DV], H[DW] = air / va, -air[:2] / va
        return va, H
    if kind == SIDESLIP:
        air_b = R.T @ (x[V_] - wind)
        H[DV], H[DTH], H[DW] = R[:, 1], skew(air_b)[1], -R[:2, 1]
        return air_b[1], H
    ref = field if kind == MAG else values[3:6]
    body = R.T @ ref
    H[DTH] = skew(body)[comp]
    if kind == MAG:
        H[m.E_BM + comp] = 1.0
        return body[comp] + x[m.X_BM + comp], H
    return body[comp], H


def inject_matrix_form(x, dx, P):
    """x (+) dx and P <- G P G^T with G_thth = I - [dtheta/2]x (docs/indirect.md, 'Injection and reset')."""
    out = x.copy()
    for xs, es in ((P_, DP), (V_, DV), (BG_, DBG), (BA_, DBA), (W_, DW), (BM_, DBM), (KZ_, DKZ)):
        out[xs] += dx[es]
    out[m.X_BB] += dx[m.E_BB]
    q = quat_product(x[Q_], np.r_[np.cos(np.linalg.norm(dx[DTH]) / 2),
                                  np.sin(np.linalg.norm(dx[DTH]) / 2) * dx[DTH] / np.linalg.norm(dx[DTH])])
    out[Q_] = q / np.linalg.norm(q)
    G = np.eye(len(P))
    G[DTH, DTH] = np.eye(3) - skew(dx[DTH] / 2)
    return out, G @ P @ G.T


def test_transition_and_process_noise_match_matrix_form(rng):
    x = random_state(rng)
    gyro = rng.normal(0.0, 1.5, 3)
    accel = np.array([0.0, 0.0, -GRAVITY_M_S2]) + rng.normal(0.0, 3.0, 3)
    dt = 0.02
    gyro_psd, accel_psd = np.full(3, 2e-3) ** 2, np.full(3, 0.035) ** 2
    _, F = propagated(x, gyro, accel, dt)
    Q_dyn = np.zeros((m.N_DYNAMIC, m.N_DYNAMIC))
    m.process_noise(F, gyro_psd, accel_psd, dt, Q_dyn)
    F_ref, Q_ref = transition_matrix_form(x, gyro, accel, dt, gyro_psd, accel_psd)
    np.testing.assert_allclose(F, F_ref, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(Q_dyn, Q_ref[:m.N_DYNAMIC, :m.N_DYNAMIC], rtol=1e-10, atol=1e-20)


MEASUREMENT_COMPONENTS = [(BARO, 0), (AIRSPEED, 0), (SIDESLIP, 0), *((GPS_POS, c) for c in range(3)),
                          *((GPS_VEL, c) for c in range(5)), *((ZERO_VELOCITY, c) for c in range(3)),
                          *((MAG, c) for c in range(3)), *((SUN, c) for c in range(3))]


@pytest.mark.parametrize(("kind", "comp"), MEASUREMENT_COMPONENTS)
def test_measurements_match_matrix_form(rng, kind, comp):
    """The dispatcher :func:`estimators.indirect.measurements.measurement` and its leaf models: value and row."""
    x = random_state(rng)
    gyro = rng.normal(0.0, 1.0, 3)
    values = np.zeros(6)
    values[3:6] = Rotation.random(random_state=rng).apply([1.0, 0.0, 0.0])  # NED sun vector (SUN events)
    H = np.full(m.NE, np.nan)
    h = meas.measurement(x, kind, comp, values, FIELD, LEVER, gyro, H)
    h_ref, H_ref = measurement_matrix_form(x, kind, comp, values, FIELD, LEVER, gyro)
    assert h == pytest.approx(h_ref, rel=1e-12, abs=1e-12)
    np.testing.assert_allclose(H, H_ref, rtol=1e-12, atol=1e-12)


def test_injection_matches_matrix_form(rng):
    x = random_state(rng)
    dx = rng.normal(0.0, 0.05, m.NE)
    root = rng.normal(size=(m.NE, m.NE))
    P = root @ root.T
    x_ref, P_ref = inject_matrix_form(x, dx, P)
    x_new, dx_new, P_new = x.copy(), dx.copy(), P.copy()
    m.inject(x_new, dx_new, P_new)
    np.testing.assert_allclose(x_new, x_ref, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(P_new, P_ref, rtol=1e-12, atol=1e-12)
    assert not dx_new.any()
