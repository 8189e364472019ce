"""Model of the full-state indirect filter: state layout, nominal kinematics, error-state transition, process
noise and injection (docs/indirect.md, 'State vector', 'Process model', 'Injection and reset').

Error-state (multiplicative) EKF after Sola 2017 ("local", right-perturbation convention). The measurement models
are in :mod:`estimators.indirect.measurements`.

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
effective z bias at every climb/cruise/descent transition). ``k = 0`` when not estimated.
Each IMU sample is held constant over its interval ``dt`` (zero-order hold).

Every function here is a small ``numba`` kernel; finite differences appear only in the tests.
"""


from __future__ import annotations

import math

import numpy as np
from numba import njit

from estimators.core.rotations import (
    dcm_into,
    matmul3_into,
    quat_exp,
    quat_multiply,
    right_jacobian_into,
    rotate,
    skew_into,
)

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

# Error state layout (units and sigmas: ``estimators.indirect.run.error_state_table``).
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
#: Error states with dynamics (p, v, theta): the only rows of the transition that differ from the identity.
N_DYNAMIC = E_BG


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
    hw, hx, hy, hz = quat_exp((gyro_rad_s[0] - x[X_BG]) * half, (gyro_rad_s[1] - x[X_BG + 1]) * half,
                              (gyro_rad_s[2] - x[X_BG + 2]) * half)
    mw, mx, my, mz = quat_multiply(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], hw, hx, hy, hz)
    fx = accel_m_s2[0] - x[X_BA]
    fy = accel_m_s2[1] - x[X_BA + 1]
    fz = accel_m_s2[2] - x[X_BA + 2] - x[X_KZ] * fx - x[X_KZ + 1] * fy
    ax, ay, az = rotate(mw, mx, my, mz, fx, fy, fz)
    az += gravity_m_s2
    half_dt2 = 0.5 * dt_s * dt_s
    x[X_P] += x[X_V] * dt_s + ax * half_dt2
    x[X_P + 1] += x[X_V + 1] * dt_s + ay * half_dt2
    x[X_P + 2] += x[X_V + 2] * dt_s + az * half_dt2
    x[X_V] += ax * dt_s
    x[X_V + 1] += ay * dt_s
    x[X_V + 2] += az * dt_s
    # Exp(omega dt) = Exp(omega dt/2)^2, so q_new = q_mid (x) Exp(omega dt/2)
    qw, qx, qy, qz = quat_multiply(mw, mx, my, mz, hw, hx, hy, hz)
    norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    x[X_Q] = qw / norm
    x[X_Q + 1] = qx / norm
    x[X_Q + 2] = qy / norm
    x[X_Q + 3] = qz / norm


@njit(cache=True)
def transition(x, gyro_rad_s, accel_m_s2, dt_s, F, work):
    """Error-state transition matrix of one :func:`propagate_nominal` step, at the pre-step nominal ``x``.

    ``F`` is the exact first-order Jacobian of the discrete map with respect to the error at the start of the
    interval (right perturbation), so that ``dx_{k+1} = F dx_k`` to first order; with
    ``R_h = Exp(omega dt/2)``, ``R_mid = R R_h``, ``J_r`` the right Jacobian of SO(3) and
    ``a_theta = -R [R_h f]x``, ``a_bg = R_mid [f]x J_r(omega dt/2) dt/2``, ``a_ba = -R_mid K``,
    ``a_kz = -R_mid e_z (f_x, f_y)`` (``f = K (accel - b_a)``):
    ``F_pv = I dt``, ``F_p* = a_* dt^2/2``, ``F_v* = a_* dt``, ``F_thth = Exp(omega dt)^T``,
    ``F_thbg = -J_r(omega dt) dt``; identity elsewhere. Only the first :data:`N_DYNAMIC` rows (p, v, theta)
    differ from the identity. Input noise enters as the bias errors do (``gyro = omega + b_g + n_g``), so the
    noise input matrices are the bias columns of ``F`` (:func:`process_noise`).

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
    work : ndarray (8, 3, 3)
        Scratch (:func:`transition_work`).
    """
    wx = gyro_rad_s[0] - x[X_BG]
    wy = gyro_rad_s[1] - x[X_BG + 1]
    wz = gyro_rad_s[2] - x[X_BG + 2]
    fx = accel_m_s2[0] - x[X_BA]
    fy = accel_m_s2[1] - x[X_BA + 1]
    kzx, kzy = x[X_KZ], x[X_KZ + 1]
    fz = accel_m_s2[2] - x[X_BA + 2] - kzx * fx - kzy * fy
    half = 0.5 * dt_s
    R, R_mid, R_full, J_full, J_half, f_cross, f_cross_J, a_bg = (work[0], work[1], work[2], work[3], work[4],
                                                                  work[5], work[6], work[7])
    qw, qx, qy, qz = x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3]
    hw, hx, hy, hz = quat_exp(wx * half, wy * half, wz * half)
    dcm_into(qw, qx, qy, qz, R)
    dcm_into(*quat_multiply(qw, qx, qy, qz, hw, hx, hy, hz), R_mid)
    dcm_into(*quat_multiply(hw, hx, hy, hz, hw, hx, hy, hz), R_full)  # Exp(omega dt) = Exp(omega dt/2)^2
    right_jacobian_into(wx * dt_s, wy * dt_s, wz * dt_s, J_full)
    right_jacobian_into(wx * half, wy * half, wz * half, J_half)
    yx, yy, yz = rotate(hw, hx, hy, hz, fx, fy, fz)  # y = R_half f; a_theta = -R [y]x, row i = -(R_i x y)
    skew_into(fx, fy, fz, f_cross)
    matmul3_into(f_cross, J_half, f_cross_J)
    matmul3_into(R_mid, f_cross_J, a_bg)  # a_bg = R_mid [f]x J_r(omega dt/2) (times dt/2 below)
    half_dt2 = 0.5 * dt_s * dt_s
    for i in range(3):
        # a_theta row i = -(R_i x y) (R_i: row i of R)
        a_th0 = R[i, 2] * yy - R[i, 1] * yz
        a_th1 = R[i, 0] * yz - R[i, 2] * yx
        a_th2 = R[i, 1] * yx - R[i, 0] * yy
        # a_ba = -R_mid K: K's third row (-k_zx, -k_zy, 1) mixes the x and y bias errors into f_z
        a_ba0 = -(R_mid[i, 0] - R_mid[i, 2] * kzx)
        a_ba1 = -(R_mid[i, 1] - R_mid[i, 2] * kzy)
        a_ba2 = -R_mid[i, 2]
        a_kz0 = -R_mid[i, 2] * fx
        a_kz1 = -R_mid[i, 2] * fy
        F[E_P + i, E_V + i] = dt_s
        # the velocity row of each block is its rate times dt, the position row integrates it once more (dt^2/2)
        for row, scale in ((E_P + i, half_dt2), (E_V + i, dt_s)):
            F[row, E_TH] = a_th0 * scale
            F[row, E_TH + 1] = a_th1 * scale
            F[row, E_TH + 2] = a_th2 * scale
            F[row, E_BA] = a_ba0 * scale
            F[row, E_BA + 1] = a_ba1 * scale
            F[row, E_BA + 2] = a_ba2 * scale
            F[row, E_KZ] = a_kz0 * scale
            F[row, E_KZ + 1] = a_kz1 * scale
            for j in range(3):
                F[row, E_BG + j] = a_bg[i, j] * half * scale
        for j in range(3):
            F[E_TH + i, E_TH + j] = R_full[j, i]
            F[E_TH + i, E_BG + j] = -J_full[i, j] * dt_s


@njit(cache=True)
def identity_transition():
    """An (NE, NE) identity to be filled by :func:`transition` (its off-identity pattern never changes)."""
    return np.eye(NE)


@njit(cache=True)
def transition_work():
    """Scratch of :func:`transition`."""
    return np.empty((8, 3, 3))


@njit(cache=True)
def process_noise(F, gyro_psd, accel_psd, dt_s, Q_dyn):
    """Discrete input noise of one IMU interval on the dynamic error states (p, v, theta).

    ``Q_dyn = F_bg diag(N_g^2 / dt) F_bg^T + F_ba diag(N_a^2 / dt) F_ba^T`` over the first :data:`N_DYNAMIC` rows,
    where ``F_bg``, ``F_ba`` are the gyro- and accelerometer-bias columns of ``F`` (white input noise enters
    exactly like a bias error) and ``N^2 / dt`` is the variance of one IMU sample averaged over ``dt``
    (``N^2 dt = sigma^2 dt^2``, docs/indirect.md, 'Process model'). The rest of Q is the random walks
    ``diag(K^2) dt``, added by :func:`add_process_noise`.

    Parameters
    ----------
    F : ndarray (NE, NE)
        Transition matrix of the interval (:func:`transition`).
    gyro_psd, accel_psd : ndarray (3,)
        Squared white-noise densities N^2 of the gyro [rad^2/s^2/Hz] and accelerometer [m^2/s^4/Hz].
    dt_s : float
        Interval [s].
    Q_dyn : ndarray (N_DYNAMIC, N_DYNAMIC)
        Output, overwritten.
    """
    gyro_var = (gyro_psd[0] / dt_s, gyro_psd[1] / dt_s, gyro_psd[2] / dt_s)  # divisions out of the loops
    accel_var = (accel_psd[0] / dt_s, accel_psd[1] / dt_s, accel_psd[2] / dt_s)
    for i in range(N_DYNAMIC):
        for j in range(i, N_DYNAMIC):
            q = 0.0
            for k in range(3):
                q += F[i, E_BG + k] * gyro_var[k] * F[j, E_BG + k]
                q += F[i, E_BA + k] * accel_var[k] * F[j, E_BA + k]
            Q_dyn[i, j] = q
            Q_dyn[j, i] = q


@njit(cache=True)
def add_process_noise(P, Q_dyn, walk_psd, dt_s):
    """``P += Q`` after :func:`estimators.core.linalg.propagate_sparse`: ``Q_dyn`` (N_DYNAMIC, N_DYNAMIC, symmetric,
    :func:`process_noise`) on the dynamic block plus ``diag(K^2) dt`` (``walk_psd`` (n,): squared random-walk
    densities of the active error states [unit^2/s]); exactly symmetric."""
    for i in range(N_DYNAMIC):
        for j in range(i, N_DYNAMIC):
            P[i, j] += Q_dyn[i, j]
            if j != i:
                P[j, i] += Q_dyn[i, j]
    for i in range(P.shape[0]):
        P[i, i] += walk_psd[i] * dt_s


# ----------------------------------------------------------------------------------------------------------------
# Injection and reset
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=True)
def inject(x, dx, P):
    """Inject an estimated error into the nominal state and reset the error to zero (docs/indirect.md,
    'Injection and reset').

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
    qw, qx, qy, qz = quat_multiply(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3],
                                   *quat_exp(dx[E_TH], dx[E_TH + 1], dx[E_TH + 2]))
    norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    x[X_Q] = qw / norm
    x[X_Q + 1] = qx / norm
    x[X_Q + 2] = qy / norm
    x[X_Q + 3] = qz / norm
    # G v = v - g x v with g = dtheta/2: first on the theta rows (G P), then on the theta columns (P G^T)
    gx, gy, gz = 0.5 * dx[E_TH], 0.5 * dx[E_TH + 1], 0.5 * dx[E_TH + 2]
    n = P.shape[0]
    for j in range(n):
        a, b, c = P[E_TH, j], P[E_TH + 1, j], P[E_TH + 2, j]
        P[E_TH, j] = a - (gy * c - gz * b)
        P[E_TH + 1, j] = b - (gz * a - gx * c)
        P[E_TH + 2, j] = c - (gx * b - gy * a)
    for i in range(n):
        a, b, c = P[i, E_TH], P[i, E_TH + 1], P[i, E_TH + 2]
        P[i, E_TH] = a - (gy * c - gz * b)
        P[i, E_TH + 1] = b - (gz * a - gx * c)
        P[i, E_TH + 2] = c - (gx * b - gy * a)
    for i in range(NE):
        dx[i] = 0.0
