"""Model of the full-state indirect filter: nominal kinematics, error-state Jacobians and measurement models.

Error-state (multiplicative) EKF after Sola 2017 ("local", right-perturbation convention), design note section 5.

Nominal state ``x`` (flat float64 vector, indices ``X_*``):

======  =====  ===========================================================
slice   unit   meaning
======  =====  ===========================================================
p       m      position NED relative to the origin (down = -(alt - alt0))
v       m/s    ground velocity NED
q       -      attitude quaternion (w, x, y, z), Hamilton, body FRD -> NED
b_g     rad/s  gyro bias (body)
b_a     m/s^2  accelerometer bias (body)
w       m/s    wind (north, east): velocity of the air mass
b_m     -      magnetometer hard-iron bias (body), in units of the earth-field strength
b_b     m      barometer offset: baro height - true height
k_z     -      cross-axis sensitivity of the z accelerometer to the x and y specific force (k_zx, k_zy)
======  =====  ===========================================================

Error state ``dx`` (indices ``E_*``): ``(dp, dv, dtheta, db_g, db_a, dw, db_m, db_b, dk_z)`` with the truth
``p = p_hat + dp``, ``v = v_hat + dv``, ``R = R_hat Exp(dtheta)`` (``dtheta``: small rotation in BODY axes),
``b = b_hat + db``, ``w = w_hat + dw``, ``k = k_hat + dk``.

IMU model: ``gyro = omega + b_g + n_g``, ``accel = K^-1 R^T (a - g_n) + b_a + n_a`` with ``g_n = (0, 0, +g)``,
``K = [[1, 0, 0], [0, 1, 0], [-k_zx, -k_zy, 1]]``: the specific force is ``f = K (accel - b_a)``, i.e. the z
accelerometer also sees ``k_zx f_x + k_zy f_y`` (cross-axis coupling, Table 1: up to 2 %; it changes the
effective z bias at every climb/cruise/descent transition, math note 5 [ADD]). ``k = 0`` when not estimated.
Each IMU sample is held constant over its interval ``dt`` (zero-order hold).

Every function here is a small ``numba`` kernel; finite differences appear only in the tests.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# Nominal state layout.
X_P = 0
X_V = 3
X_Q = 6
X_BG = 10
X_BA = 13
X_W = 16
X_BM = 18
X_BB = 21
X_KZ = 22
NX = 24

# Error state layout (see ``estimators.full_state_indirect.ERROR_STATES`` for units and sigmas).
E_P = 0
E_V = 3
E_TH = 6
E_BG = 9
E_BA = 12
E_W = 15
E_BM = 17
E_BB = 20
E_KZ = 21
NE = 23

_SMALL_ANGLE_RAD = 1e-6


# ----------------------------------------------------------------------------------------------------------------
# Rotation helpers (Hamilton quaternions, scalar first)
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=True)
def skew(v):
    """Cross-product matrix [v]x with [v]x a = v x a, shape (3, 3)."""
    out = np.empty((3, 3))
    _skew_into(v[0], v[1], v[2], out)
    return out


@njit(cache=True)
def quat_multiply(a, b):
    """Hamilton product a (x) b of (w, x, y, z) quaternions."""
    out = np.empty(4)
    out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
    out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
    out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]
    return out


@njit(cache=True)
def quat_exp(rotvec_rad):
    """Unit quaternion Exp(phi) = (cos(|phi|/2), sin(|phi|/2) phi/|phi|) of a rotation vector [rad]."""
    angle = np.sqrt(rotvec_rad[0] ** 2 + rotvec_rad[1] ** 2 + rotvec_rad[2] ** 2)
    out = np.empty(4)
    if angle < _SMALL_ANGLE_RAD:
        out[0] = 1.0 - angle * angle / 8.0
        scale = 0.5 - angle * angle / 48.0
    else:
        out[0] = np.cos(0.5 * angle)
        scale = np.sin(0.5 * angle) / angle
    out[1] = scale * rotvec_rad[0]
    out[2] = scale * rotvec_rad[1]
    out[3] = scale * rotvec_rad[2]
    return out


@njit(cache=True)
def quat_to_dcm(q):
    """Rotation matrix R(q) (maps body vectors into NED for the attitude quaternion), shape (3, 3)."""
    out = np.empty((3, 3))
    _dcm_into(q[0], q[1], q[2], q[3], out)
    return out


@njit(cache=True)
def _dcm_into(w, x, y, z, out):
    """Rotation matrix of the unit quaternion (w, x, y, z) written into ``out`` (3, 3)."""
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - w * z)
    out[0, 2] = 2.0 * (x * z + w * y)
    out[1, 0] = 2.0 * (x * y + w * z)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - w * x)
    out[2, 0] = 2.0 * (x * z - w * y)
    out[2, 1] = 2.0 * (y * z + w * x)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True)
def right_jacobian_into(rx, ry, rz, out):
    """Right Jacobian of SO(3) at ``phi = (rx, ry, rz)`` [rad] into ``out`` (3, 3):
    ``Exp(phi + d) ~ Exp(phi) Exp(J_r d)``, ``J_r = I - c1 [phi]x + c2 [phi]x^2`` with ``c1 = (1 - cos a)/a^2``,
    ``c2 = (a - sin a)/a^3``, ``a = |phi|`` (``[phi]x^2 = phi phi^T - a^2 I``)."""
    angle2 = rx * rx + ry * ry + rz * rz
    angle = math.sqrt(angle2)
    if angle < 1e-4:
        c1 = 0.5 - angle2 / 24.0
        c2 = 1.0 / 6.0 - angle2 / 120.0
    else:
        c1 = (1.0 - math.cos(angle)) / angle2
        c2 = (angle - math.sin(angle)) / (angle2 * angle)
    out[0, 0] = 1.0 + c2 * (rx * rx - angle2)
    out[1, 1] = 1.0 + c2 * (ry * ry - angle2)
    out[2, 2] = 1.0 + c2 * (rz * rz - angle2)
    out[0, 1] = c1 * rz + c2 * rx * ry
    out[1, 0] = -c1 * rz + c2 * rx * ry
    out[0, 2] = -c1 * ry + c2 * rx * rz
    out[2, 0] = c1 * ry + c2 * rx * rz
    out[1, 2] = c1 * rx + c2 * ry * rz
    out[2, 1] = -c1 * rx + c2 * ry * rz


@njit(cache=True)
def _matmul3_into(A, B, out):
    """out = A B for (3, 3) matrices (plain loops: no BLAS call overhead for 3 x 3)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@njit(cache=True)
def _skew_into(vx, vy, vz, out):
    """[v]x into ``out`` (3, 3)."""
    out[0, 0] = 0.0
    out[0, 1] = -vz
    out[0, 2] = vy
    out[1, 0] = vz
    out[1, 1] = 0.0
    out[1, 2] = -vx
    out[2, 0] = -vy
    out[2, 1] = vx
    out[2, 2] = 0.0


@njit(cache=True)
def _quat_exp_scalars(rx, ry, rz):
    """Exp of a rotation vector [rad] as four scalars (w, x, y, z); allocation-free."""
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    if angle < _SMALL_ANGLE_RAD:
        w = 1.0 - angle * angle / 8.0
        scale = 0.5 - angle * angle / 48.0
    else:
        w = math.cos(0.5 * angle)
        scale = math.sin(0.5 * angle) / angle
    return w, scale * rx, scale * ry, scale * rz


@njit(cache=True)
def _quat_mul_scalars(aw, ax, ay, az, bw, bx, by, bz):
    """Hamilton product of two quaternions given as scalars."""
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


@njit(cache=True)
def propagate_nominal(x, gyro_rad_s, accel_m_s2, dt_s, gravity_m_s2):
    """Advance the nominal state over one IMU interval (allocation-free; the time loop calls it per sample).

    Exact exponential map for the attitude and mid-interval attitude for the specific force, with
    ``omega = gyro - b_g`` and ``f = K (accel - b_a)`` held over the interval:
    ``q <- q (x) Exp(omega dt)``, ``a = R(q (x) Exp(omega dt/2)) f + g_n``, ``p <- p + v dt + a dt^2/2``,
    ``v <- v + a dt``; biases, wind and offsets are constant.

    Parameters
    ----------
    x : ndarray (NX,)
        Nominal state, updated in place (quaternion renormalised).
    gyro_rad_s, accel_m_s2 : ndarray (3,)
        IMU sample, body FRD [rad/s], specific force [m/s^2], held over the interval.
    dt_s : float
        Interval [s].
    gravity_m_s2 : float
        Local gravity magnitude [m/s^2] (gravity points down, +NED z).
    """
    half = 0.5 * dt_s
    hw, hx, hy, hz = _quat_exp_scalars((gyro_rad_s[0] - x[X_BG]) * half, (gyro_rad_s[1] - x[X_BG + 1]) * half,
                                       (gyro_rad_s[2] - x[X_BG + 2]) * half)
    mw, mx, my, mz = _quat_mul_scalars(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], hw, hx, hy, hz)
    fx = accel_m_s2[0] - x[X_BA]
    fy = accel_m_s2[1] - x[X_BA + 1]
    fz = accel_m_s2[2] - x[X_BA + 2] - x[X_KZ] * fx - x[X_KZ + 1] * fy
    # a = q_mid f q_mid* + g_n  (v' = v + 2 w (u x v) + 2 u x (u x v) for a unit quaternion (w, u))
    cx = my * fz - mz * fy
    cy = mz * fx - mx * fz
    cz = mx * fy - my * fx
    ax = fx + 2.0 * (mw * cx + my * cz - mz * cy)
    ay = fy + 2.0 * (mw * cy + mz * cx - mx * cz)
    az = fz + 2.0 * (mw * cz + mx * cy - my * cx) + gravity_m_s2
    half_dt2 = 0.5 * dt_s * dt_s
    x[X_P] += x[X_V] * dt_s + ax * half_dt2
    x[X_P + 1] += x[X_V + 1] * dt_s + ay * half_dt2
    x[X_P + 2] += x[X_V + 2] * dt_s + az * half_dt2
    x[X_V] += ax * dt_s
    x[X_V + 1] += ay * dt_s
    x[X_V + 2] += az * dt_s
    # Exp(omega dt) = Exp(omega dt/2)^2, so q_new = q_mid (x) Exp(omega dt/2)
    qw, qx, qy, qz = _quat_mul_scalars(mw, mx, my, mz, hw, hx, hy, hz)
    norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    x[X_Q] = qw / norm
    x[X_Q + 1] = qx / norm
    x[X_Q + 2] = qy / norm
    x[X_Q + 3] = qz / norm


@njit(cache=True)
def transition(x, gyro_rad_s, accel_m_s2, dt_s, F):
    """Error-state transition matrix of one :func:`propagate_nominal` step, at the pre-step nominal ``x``.

    ``F`` is the exact first-order Jacobian of the discrete map with respect to the error at the start of the
    interval (right perturbation), so that ``dx_{k+1} = F dx_k`` to first order; with
    ``R_h = Exp(omega dt/2)``, ``R_mid = R R_h``, ``J_r`` the right Jacobian of SO(3) and
    ``a_theta = -R [R_h f]x``, ``a_bg = R_mid [f]x J_r(omega dt/2) dt/2``, ``a_ba = -R_mid K``,
    ``a_kz = -R_mid e_z (f_x, f_y)`` (``f = K (accel - b_a)``):
    ``F_pv = I dt``, ``F_p* = a_* dt^2/2``, ``F_v* = a_* dt``, ``F_thth = Exp(omega dt)^T``,
    ``F_thbg = -J_r(omega dt) dt``; identity elsewhere. Input noise enters as the bias errors do
    (``gyro = omega + b_g + n_g``), so the noise input matrices are the bias columns of ``F``
    (:func:`process_noise`).

    Parameters
    ----------
    x : ndarray (NX,)
        Nominal state at the start of the interval (not modified).
    gyro_rad_s, accel_m_s2 : ndarray (3,)
        IMU input held over the interval, body FRD [rad/s], [m/s^2].
    dt_s : float
        Interval [s].
    F : ndarray (NE, NE)
        Output. Only the non-identity blocks are written; the caller keeps the rest at the identity
        (see :func:`identity_transition`).
    """
    wx = gyro_rad_s[0] - x[X_BG]
    wy = gyro_rad_s[1] - x[X_BG + 1]
    wz = gyro_rad_s[2] - x[X_BG + 2]
    fx = accel_m_s2[0] - x[X_BA]
    fy = accel_m_s2[1] - x[X_BA + 1]
    kzx, kzy = x[X_KZ], x[X_KZ + 1]
    fz = accel_m_s2[2] - x[X_BA + 2] - kzx * fx - kzy * fy
    half = 0.5 * dt_s
    work = np.empty((7, 3, 3))  # R, R_half, R_mid, Exp(omega dt), J_r(full), J_r(half), scratch
    R, R_half, R_mid, R_full, J_full, J_half, tmp = (work[0], work[1], work[2], work[3], work[4], work[5],
                                                      work[6])
    _dcm_into(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], R)
    hw, hx, hy, hz = _quat_exp_scalars(wx * half, wy * half, wz * half)
    _dcm_into(hw, hx, hy, hz, R_half)
    _matmul3_into(R, R_half, R_mid)
    _dcm_into(*_quat_exp_scalars(wx * dt_s, wy * dt_s, wz * dt_s), R_full)
    right_jacobian_into(wx * dt_s, wy * dt_s, wz * dt_s, J_full)
    right_jacobian_into(wx * half, wy * half, wz * half, J_half)
    # a_theta = -R [R_half f]x
    yx = R_half[0, 0] * fx + R_half[0, 1] * fy + R_half[0, 2] * fz
    yy = R_half[1, 0] * fx + R_half[1, 1] * fy + R_half[1, 2] * fz
    yz = R_half[2, 0] * fx + R_half[2, 1] * fy + R_half[2, 2] * fz
    _skew_into(yx, yy, yz, tmp)
    a_th = np.empty((3, 3))
    _matmul3_into(R, tmp, a_th)
    # a_bg = R_mid [f]x J_r(half) dt/2 (R_half is no longer needed: reuse it as scratch)
    _skew_into(fx, fy, fz, tmp)
    _matmul3_into(tmp, J_half, R_half)
    a_bg = np.empty((3, 3))
    _matmul3_into(R_mid, R_half, a_bg)
    half_dt2 = 0.5 * dt_s * dt_s
    for i in range(3):
        # a_ba = -R_mid K: K's third row (-k_zx, -k_zy, 1) mixes the x and y bias errors into f_z
        a_ba0 = -(R_mid[i, 0] - R_mid[i, 2] * kzx)
        a_ba1 = -(R_mid[i, 1] - R_mid[i, 2] * kzy)
        a_ba2 = -R_mid[i, 2]
        F[E_P + i, E_V + i] = dt_s
        F[E_P + i, E_BA] = a_ba0 * half_dt2
        F[E_P + i, E_BA + 1] = a_ba1 * half_dt2
        F[E_P + i, E_BA + 2] = a_ba2 * half_dt2
        F[E_V + i, E_BA] = a_ba0 * dt_s
        F[E_V + i, E_BA + 1] = a_ba1 * dt_s
        F[E_V + i, E_BA + 2] = a_ba2 * dt_s
        F[E_P + i, E_KZ] = -R_mid[i, 2] * fx * half_dt2
        F[E_P + i, E_KZ + 1] = -R_mid[i, 2] * fy * half_dt2
        F[E_V + i, E_KZ] = -R_mid[i, 2] * fx * dt_s
        F[E_V + i, E_KZ + 1] = -R_mid[i, 2] * fy * dt_s
        for j in range(3):
            F[E_P + i, E_TH + j] = -a_th[i, j] * half_dt2
            F[E_P + i, E_BG + j] = a_bg[i, j] * half * half_dt2
            F[E_V + i, E_TH + j] = -a_th[i, j] * dt_s
            F[E_V + i, E_BG + j] = a_bg[i, j] * half * dt_s
            F[E_TH + i, E_TH + j] = R_full[j, i]
            F[E_TH + i, E_BG + j] = -J_full[i, j] * dt_s


@njit(cache=True)
def identity_transition():
    """An (NE, NE) identity to be filled by :func:`transition` (its off-identity pattern never changes)."""
    return np.eye(NE)


@njit(cache=True)
def process_noise(F, gyro_psd, accel_psd, random_walk_psd, dt_s, Q):
    """Discrete process noise of one IMU interval.

    ``Q = F_bg diag(N_g^2 / dt) F_bg^T + F_ba diag(N_a^2 / dt) F_ba^T + diag(K^2) dt`` where ``F_bg``, ``F_ba``
    are the gyro- and accelerometer-bias columns of ``F`` (white input noise enters exactly like a bias error),
    ``N^2 / dt`` is the variance of one IMU sample averaged over ``dt`` (math note 2.2: N^2 dt = sigma^2 dt^2) and
    ``K`` the random-walk densities.

    Parameters
    ----------
    F : ndarray (NE, NE)
        Transition matrix of the interval (:func:`transition`).
    gyro_psd, accel_psd : ndarray (3,)
        Squared white-noise densities N^2 of the gyro [rad^2/s^2/Hz] and accelerometer [m^2/s^4/Hz].
    random_walk_psd : ndarray (NE,)
        Squared random-walk densities K^2 per error state [unit^2/s] (zero for p, v, theta).
    dt_s : float
        Interval [s].
    Q : ndarray (NE, NE)
        Output, overwritten.
    """
    Q[:, :] = 0.0
    for i in range(NE):
        Q[i, i] = random_walk_psd[i] * dt_s
    _add_input_noise(F, E_BG, gyro_psd / dt_s, Q)
    _add_input_noise(F, E_BA, accel_psd / dt_s, Q)


@njit(cache=True)
def _add_input_noise(F, col0, var, Q):
    """Q += F[:, col0:col0+3] diag(var) F[:, col0:col0+3]^T over the p, v, theta rows (the only non-zero ones)."""
    for i in range(E_BG):
        for j in range(E_BG):
            acc = 0.0
            for k in range(3):
                acc += F[i, col0 + k] * var[k] * F[j, col0 + k]
            Q[i, j] += acc


# ----------------------------------------------------------------------------------------------------------------
# Injection and reset
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=True)
def inject(x, dx, P):
    """Inject an estimated error into the nominal state and reset the error to zero (design note 5.4).

    ``p += dp, v += dv, q <- q (x) Exp(dtheta), b += db, w += dw, k += dk``; the covariance of the reset error is
    ``G P G^T`` with ``G = blockdiag(I, I, I - [dtheta/2]x, I, ...)`` (Sola 2017 sec. 7.2). ``dx`` is zeroed.
    """
    for i in range(3):
        x[X_P + i] += dx[E_P + i]
        x[X_V + i] += dx[E_V + i]
        x[X_BG + i] += dx[E_BG + i]
        x[X_BA + i] += dx[E_BA + i]
        x[X_BM + i] += dx[E_BM + i]
    x[X_W] += dx[E_W]
    x[X_W + 1] += dx[E_W + 1]
    x[X_BB] += dx[E_BB]
    x[X_KZ] += dx[E_KZ]
    x[X_KZ + 1] += dx[E_KZ + 1]
    q = quat_multiply(x[X_Q:X_Q + 4], quat_exp(dx[E_TH:E_TH + 3]))
    x[X_Q:X_Q + 4] = q / np.sqrt(np.sum(q * q))

    G = np.eye(3) - 0.5 * skew(dx[E_TH:E_TH + 3])
    n = P.shape[0]
    block = np.empty(3)
    for j in range(n):  # rows of the theta block: P[th, :] <- G P[th, :]
        for i in range(3):
            block[i] = G[i, 0] * P[E_TH, j] + G[i, 1] * P[E_TH + 1, j] + G[i, 2] * P[E_TH + 2, j]
        P[E_TH:E_TH + 3, j] = block
    for i in range(n):  # columns: P[:, th] <- P[:, th] G^T
        for j in range(3):
            block[j] = P[i, E_TH] * G[j, 0] + P[i, E_TH + 1] * G[j, 1] + P[i, E_TH + 2] * G[j, 2]
        P[i, E_TH:E_TH + 3] = block
    dx[:] = 0.0


# ----------------------------------------------------------------------------------------------------------------
# Measurement models: each returns h(x) and writes the row H = dh/d(dx) into ``H`` (length NE, zeroed first)
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=True)
def h_baro(x, H):
    """Barometric height above the origin [m]: ``h = -p_d + b_b`` (``b_b`` stays 0 when not estimated)."""
    H[:] = 0.0
    H[E_P + 2] = -1.0
    H[E_BB] = 1.0
    return x[X_BB] - x[X_P + 2]


@njit(cache=True)
def h_gps_position(x, lever_arm_b_m, axis, H):
    """GPS antenna position [m] NED, component ``axis``: ``h = p + R l_b``.

    ``H_dp = e_axis^T``, ``H_dtheta = -e_axis^T R [l_b]x``.
    """
    H[:] = 0.0
    R = quat_to_dcm(x[X_Q:X_Q + 4])
    H[E_P + axis] = 1.0
    h_th = -(R @ skew(lever_arm_b_m))
    for j in range(3):
        H[E_TH + j] = h_th[axis, j]
    return x[X_P + axis] + R[axis, 0] * lever_arm_b_m[0] + R[axis, 1] * lever_arm_b_m[1] \
        + R[axis, 2] * lever_arm_b_m[2]


@njit(cache=True)
def h_gps_velocity(x, gyro_rad_s, lever_arm_b_m, axis, H):
    """GPS antenna velocity [m/s] NED, component ``axis``: ``h = v + R (omega x l_b)``, ``omega = gyro - b_g``.

    ``H_dv = e_axis^T``, ``H_dtheta = -e_axis^T R [omega x l_b]x``, ``H_dbg = e_axis^T R [l_b]x``.
    """
    H[:] = 0.0
    R = quat_to_dcm(x[X_Q:X_Q + 4])
    omega = gyro_rad_s - x[X_BG:X_BG + 3]
    lever_velocity = np.cross(omega, lever_arm_b_m)
    H[E_V + axis] = 1.0
    h_th = -(R @ skew(lever_velocity))
    h_bg = R @ skew(lever_arm_b_m)
    for j in range(3):
        H[E_TH + j] = h_th[axis, j]
        H[E_BG + j] = h_bg[axis, j]
    return x[X_V + axis] + R[axis, 0] * lever_velocity[0] + R[axis, 1] * lever_velocity[1] \
        + R[axis, 2] * lever_velocity[2]


@njit(cache=True)
def h_ground_speed(x, H):
    """Horizontal ground speed [m/s] (paper-mode GPS, eq. 43 corrected): ``h = |(v_n, v_e)|``.

    ``H_dv = (v_n, v_e, 0) / V_g``; zero row when ``V_g`` is ~0 (the caller skips such updates).
    """
    H[:] = 0.0
    speed = np.hypot(x[X_V], x[X_V + 1])
    if speed > 1e-3:
        H[E_V] = x[X_V] / speed
        H[E_V + 1] = x[X_V + 1] / speed
    return speed


@njit(cache=True)
def h_course(x, H):
    """Course over ground [rad] (paper-mode GPS): ``h = atan2(v_e, v_n)``; the caller wraps the innovation.

    ``H_dv = (-v_e, v_n, 0) / V_g^2``.
    """
    H[:] = 0.0
    speed2 = x[X_V] ** 2 + x[X_V + 1] ** 2
    if speed2 > 1e-6:
        H[E_V] = -x[X_V + 1] / speed2
        H[E_V + 1] = x[X_V] / speed2
    return np.arctan2(x[X_V + 1], x[X_V])


@njit(cache=True)
def _air_velocity_ned(x):
    """Air-relative velocity v - (w_n, w_e, 0) [m/s] NED (the wind has no vertical component)."""
    air = x[X_V:X_V + 3].copy()
    air[0] -= x[X_W]
    air[1] -= x[X_W + 1]
    return air


@njit(cache=True)
def h_airspeed(x, H):
    """True airspeed [m/s]: ``h = |v - w|`` (pitot aligned with the air flow).

    ``H_dv = (v - w)^T / V_a``, ``H_dw = -(v - w)_{n,e}^T / V_a``; zero row when ``V_a`` is ~0.
    """
    H[:] = 0.0
    air = _air_velocity_ned(x)
    airspeed = np.sqrt(np.sum(air * air))
    if airspeed > 1e-3:
        for j in range(3):
            H[E_V + j] = air[j] / airspeed
        H[E_W] = -air[0] / airspeed
        H[E_W + 1] = -air[1] / airspeed
    return airspeed


@njit(cache=True)
def h_sideslip(x, H):
    """Lateral body air velocity [m/s] (zero-sideslip pseudo-measurement, fixed-wing): ``h = e2^T R^T (v - w)``.

    ``H_dv = e2^T R^T``, ``H_dtheta = e2^T [R^T (v - w)]x``, ``H_dw = -e2^T R^T[:, 0:2]``.
    """
    H[:] = 0.0
    R = quat_to_dcm(x[X_Q:X_Q + 4])
    air_n, air_e, air_d = x[X_V] - x[X_W], x[X_V + 1] - x[X_W + 1], x[X_V + 2]
    air_bx = R[0, 0] * air_n + R[1, 0] * air_e + R[2, 0] * air_d
    air_by = R[0, 1] * air_n + R[1, 1] * air_e + R[2, 1] * air_d
    air_bz = R[0, 2] * air_n + R[1, 2] * air_e + R[2, 2] * air_d
    # e2^T [a]x = (a_z, 0, -a_x).
    H[E_TH] = air_bz
    H[E_TH + 2] = -air_bx
    for j in range(3):
        H[E_V + j] = R[j, 1]
    H[E_W] = -R[0, 1]
    H[E_W + 1] = -R[1, 1]
    return air_by


@njit(cache=True)
def h_body_vector(x, ref_ned, axis, with_mag_bias, H):
    """A known NED vector seen in the body, component ``axis``: ``h = R^T r_n (+ b_m)``.

    Magnetometer (``r_n`` = earth field [gauss], ``with_mag_bias``) or sun direction (unit vector).
    ``H_dtheta = e_axis^T [R^T r_n]x``, ``H_dbm = e_axis^T`` with the bias.
    """
    H[:] = 0.0
    R = quat_to_dcm(x[X_Q:X_Q + 4])
    b0 = R[0, 0] * ref_ned[0] + R[1, 0] * ref_ned[1] + R[2, 0] * ref_ned[2]
    b1 = R[0, 1] * ref_ned[0] + R[1, 1] * ref_ned[1] + R[2, 1] * ref_ned[2]
    b2 = R[0, 2] * ref_ned[0] + R[1, 2] * ref_ned[1] + R[2, 2] * ref_ned[2]
    # row ``axis`` of [b]x
    if axis == 0:
        H[E_TH + 1], H[E_TH + 2], value = -b2, b1, b0
    elif axis == 1:
        H[E_TH], H[E_TH + 2], value = b2, -b0, b1
    else:
        H[E_TH], H[E_TH + 1], value = -b1, b0, b2
    if with_mag_bias:
        H[E_BM + axis] = 1.0
        value += x[X_BM + axis]
    return value
