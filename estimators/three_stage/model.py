"""Models of the three-stage series estimator (Guo et al. 2019 sec. 3.1, corrected; math note section 3).

Every stage is written as small numba functions over float64 arrays: the state derivative ``f``, its Jacobian
``A = df/dx``, the input-noise Jacobian ``G = df/du``, the measurement model ``h`` and its Jacobian ``C = dh/dx``.
Analytic Jacobians only; ``tests/test_three_stage.py`` checks each against central finite differences. The
functions the kernel calls per sample or per update allocate nothing: matrices go into optional output arrays
(allocated when None, as the tests call them), the scalar forms take the sines and cosines the kernel shares
between the stages, and short vectors are returned as tuples.

Frames and units: NED earth frame, FRD body frame, ZYX Euler angles (roll phi, pitch theta, yaw psi) [rad], body
rates (p, q, r) [rad/s], specific force [m/s^2] (``(0, 0, -g)`` level at rest), speeds [m/s], positions [m].
Each stage's state is laid out in a table of :class:`~estimators.core.state_table.StateSpec` rows (built from the
configuration in :mod:`estimators.three_stage.kernel`); :func:`~estimators.core.state_table.initial_covariance` and
:func:`~estimators.core.state_table.process_noise_psd` build P0 and the continuous process-noise density from it.

Stages
------
1. roll/pitch: x = (phi, theta), u = (p, q, r, V_a); z = accelerometer (f_x, f_y, f_z). Airspeed form (eq 20/21
   corrected, centripetal term from V_b = V_a (c_th, 0, s_th)) or the general form h = C_bn (a_n - g_n) with a
   GPS-derived acceleration a_n (a_n = 0: gravity only, the multicopter / no-airspeed model, math note 7.1).
2. heading: x = psi, u = (phi, theta, q, r); z = a unit reference vector in body axes (magnetometer vs WMM field,
   or the photocell sun vector vs the SPA sun direction): h = C_bn(phi, theta, psi) v_n (eq 24/25 corrected).
3. navigation, fixed-wing: x = (p_n, p_e, V_g, chi, w_n, w_e, dev_a, dev_b, dev_c), u = (V_a, q, r, phi, theta,
   psi_2) (eq 26-33 corrected) with the heading psi = psi_2 - (dev_a + dev_b sin psi_2 + dev_c cos psi_2): the
   stage-2 heading corrected by a compass-deviation model, observable through the wind triangle in turns (B&M carry
   psi itself as a 7th state, math note 3.3 / 7.2); multicopter / no-airspeed: x = (p_n, p_e, v_n, v_e) driven by
   the NED acceleration (math note 3.4).
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Ground speed below which the course is undefined and the 1/V_g terms are frozen [m/s] (math note 3.3, 7.5).
MIN_GROUND_SPEED_M_S = 3.0


# --------------------------------------------------------------------------------------------------------------
# Shared attitude helpers
# --------------------------------------------------------------------------------------------------------------


@njit(cache=True)
def body_vector_and_euler_jacobian(v_n, phi, theta, psi, h=None, jac=None):
    """A NED vector in body axes, h = C_bn v_n, and its Jacobian dh/d(phi, theta, psi) = [h]x W(Theta).

    Parameters
    ----------
    v_n : ndarray or tuple, shape (3,)
        Vector in NED [any unit].
    phi, theta, psi : float
        ZYX Euler angles [rad].
    h, jac : ndarray, optional
        Output arrays (3,) and (3, 3) (allocated when None; the kernel passes preallocated ones).

    Returns
    -------
    h : ndarray, shape (3,)
        The vector in body FRD [same unit].
    jac : ndarray, shape (3, 3)
        Columns dh/dphi, dh/dtheta, dh/dpsi (math note 1.1 identity d(R^T a)/dTheta = [R^T a]x W).
    """
    if h is None:
        h = np.empty(3)
    if jac is None:
        jac = np.empty((3, 3))
    cph, sph = np.cos(phi), np.sin(phi)
    cth, sth = np.cos(theta), np.sin(theta)
    cps, sps = np.cos(psi), np.sin(psi)
    # C_bn = R_x(phi)^T R_y(theta)^T R_z(psi)^T: rotate by yaw, then pitch, then roll
    a0 = cps * v_n[0] + sps * v_n[1]
    a1 = cps * v_n[1] - sps * v_n[0]
    b2 = sth * a0 + cth * v_n[2]
    h[0] = cth * a0 - sth * v_n[2]
    h[1] = cph * a1 + sph * b2
    h[2] = cph * b2 - sph * a1
    _cross_column(h, 1.0, 0.0, 0.0, jac, 0)  # columns of W(Theta)
    _cross_column(h, 0.0, cph, -sph, jac, 1)
    _cross_column(h, -sth, sph * cth, cph * cth, jac, 2)
    return h, jac


@njit(cache=True)
def _cross_column(h, w0, w1, w2, jac, j):
    """Column ``j`` of ``jac`` = h x w."""
    jac[0, j] = h[1] * w2 - h[2] * w1
    jac[1, j] = h[2] * w0 - h[0] * w2
    jac[2, j] = h[0] * w1 - h[1] * w0


@njit(cache=True)
def euler_yaw_rate(sph, cph, cth, q, r):
    """psi_dot = q s_ph / c_th + r c_ph / c_th [rad/s] (third row of S(Theta); eq 22 corrected, T10), from the
    roll sine and cosine and the pitch cosine (shared with the other stages by the caller)."""
    return (q * sph + r * cph) / cth


# --------------------------------------------------------------------------------------------------------------
# Stage 1: roll and pitch
# --------------------------------------------------------------------------------------------------------------


@njit(cache=True)
def stage1_f(x, rates):
    """Euler roll/pitch rates (eq 18).

    Parameters
    ----------
    x : ndarray, shape (2,)
        (phi, theta) [rad].
    rates : ndarray, shape (3,)
        Bias-corrected body rates (p, q, r) [rad/s].

    Returns
    -------
    ndarray, shape (2,)
        (phi_dot, theta_dot) [rad/s].
    """
    phi_dot, theta_dot = stage1_rates(np.sin(x[0]), np.cos(x[0]), np.tan(x[1]), rates[0], rates[1], rates[2])
    return np.array((phi_dot, theta_dot))


@njit(cache=True)
def stage1_rates(sph, cph, tth, p, q, r):
    """Scalar form of :func:`stage1_f`: (phi_dot, theta_dot) [rad/s] from the roll sine and cosine, the pitch
    tangent and (p, q, r)."""
    return p + (q * sph + r * cph) * tth, q * cph - r * sph


@njit(cache=True)
def stage1_A(x, rates, a=None):
    """df/dx of :func:`stage1_f`, shape (2, 2) (eq 19 corrected, T7), written into ``a`` when given."""
    if a is None:
        a = np.empty((2, 2))
    sph, cph = np.sin(x[0]), np.cos(x[0])
    tth, cth = np.tan(x[1]), np.cos(x[1])
    q, r = rates[1], rates[2]
    a[0, 0] = (q * cph - r * sph) * tth
    a[0, 1] = (q * sph + r * cph) / (cth * cth)
    a[1, 0] = -q * sph - r * cph
    a[1, 1] = 0.0
    return a


@njit(cache=True)
def stage1_G(x, g=None):
    """df/d(p, q, r) of :func:`stage1_f` (gyro input-noise Jacobian), shape (2, 3), written into ``g`` when given."""
    if g is None:
        g = np.empty((2, 3))
    sph, cph, tth = np.sin(x[0]), np.cos(x[0]), np.tan(x[1])
    g[0, 0], g[0, 1], g[0, 2] = 1.0, sph * tth, cph * tth
    g[1, 0], g[1, 1], g[1, 2] = 0.0, cph, -sph
    return g


@njit(cache=True)
def stage1_h_airspeed(x, rates, airspeed_m_s, gravity_m_s2, h=None, c=None):
    """Specific force of steady flight with the centripetal term from airspeed (eq 20 corrected, T8) and its
    Jacobian (eq 21).

    Assumes u_dot = v_dot = w_dot = 0 and V_b = V_a (c_th, 0, s_th) (zero flight-path angle, no sideslip), so
    h = omega x V_b - C_bn g_n.

    Parameters
    ----------
    x : ndarray, shape (2,)
        (phi, theta) [rad].
    rates : ndarray, shape (3,)
        Body rates (p, q, r) [rad/s].
    airspeed_m_s : float
        True airspeed V_a [m/s] (0 gives the gravity-only model).
    gravity_m_s2 : float
        Local gravity [m/s^2].
    h, c : ndarray, optional
        Output arrays (3,) and (3, 2) (allocated when None).

    Returns
    -------
    h : ndarray, shape (3,)
        Predicted accelerometer reading (f_x, f_y, f_z), body FRD [m/s^2].
    c : ndarray, shape (3, 2)
        dh/d(phi, theta).
    """
    if h is None:
        h = np.empty(3)
    if c is None:
        c = np.empty((3, 2))
    sph, cph = np.sin(x[0]), np.cos(x[0])
    sth, cth = np.sin(x[1]), np.cos(x[1])
    p, q, r = rates[0], rates[1], rates[2]
    va, g = airspeed_m_s, gravity_m_s2
    h[0] = q * va * sth + g * sth
    h[1] = r * va * cth - p * va * sth - g * cth * sph
    h[2] = -q * va * cth - g * cth * cph
    c[0, 0] = 0.0
    c[0, 1] = (q * va + g) * cth
    c[1, 0] = -g * cph * cth
    c[1, 1] = -r * va * sth - p * va * cth + g * sph * sth
    c[2, 0] = g * sph * cth
    c[2, 1] = (q * va + g * cph) * sth
    return h, c


@njit(cache=True)
def stage1_h_acceleration(x, yaw_rad, accel_ned_m_s2, gravity_m_s2, h=None, jac=None):
    """Specific force from a known NED acceleration, h = C_bn(phi, theta, psi) (a_n - g_n) (math note 3.1).

    Parameters
    ----------
    x : ndarray, shape (2,)
        (phi, theta) [rad].
    yaw_rad : float
        Heading estimate psi (stage 2, previous step) [rad].
    accel_ned_m_s2 : ndarray, shape (3,)
        Kinematic acceleration a_n (e.g. from GPS velocity) [m/s^2]; zeros give the gravity-only model.
    gravity_m_s2 : float
        Local gravity [m/s^2]; g_n = (0, 0, g).
    h, jac : ndarray, optional
        Output arrays (3,) and (3, 3) (allocated when None); ``jac`` receives dh/d(phi, theta, psi).

    Returns
    -------
    h : ndarray, shape (3,)
        Predicted accelerometer reading, body FRD [m/s^2].
    c : ndarray, shape (3, 2)
        dh/d(phi, theta) (a view of ``jac``).
    """
    specific_n = (accel_ned_m_s2[0], accel_ned_m_s2[1], accel_ned_m_s2[2] - gravity_m_s2)
    h, jac = body_vector_and_euler_jacobian(specific_n, x[0], x[1], yaw_rad, h, jac)
    return h, jac[:, :2]


# --------------------------------------------------------------------------------------------------------------
# Stage 2: heading
# --------------------------------------------------------------------------------------------------------------


@njit(cache=True)
def stage2_G(sph, cph, cth):
    """d psi_dot / d(p, q, r) (gyro input-noise Jacobian of eq 22), a 3-tuple, from the roll sine and cosine and
    the pitch cosine; A = 0 (eq 23)."""
    return 0.0, sph / cth, cph / cth


@njit(cache=True)
def stage2_h(yaw_rad, phi, theta, ref_n, h=None, jac=None):
    """A reference unit vector seen in body axes and its Jacobians (eq 24, eq 25 corrected, T11).

    Parameters
    ----------
    yaw_rad : float
        Heading state psi [rad].
    phi, theta : float
        Stage-1 roll and pitch [rad] (inputs).
    ref_n : ndarray, shape (3,)
        Reference unit vector in NED (earth magnetic field direction from WMM, or the sun direction).
    h, jac : ndarray, optional
        Output arrays (3,) and (3, 3) (allocated when None); ``jac`` receives dh/d(phi, theta, psi).

    Returns
    -------
    h : ndarray, shape (3,)
        Predicted body-frame unit vector.
    c : ndarray, shape (3, 1)
        dh/dpsi = h x (-s_th, s_ph c_th, c_ph c_th) (a view of ``jac``).
    j_tilt : ndarray, shape (3, 2)
        dh/d(phi, theta), used to inflate R by the stage-1 covariance (cascade consistency, math note 3.2).
    """
    h, jac = body_vector_and_euler_jacobian(ref_n, phi, theta, yaw_rad, h, jac)
    return h, jac[:, 2:], jac[:, :2]


# --------------------------------------------------------------------------------------------------------------
# Stage 3, fixed-wing mode: x = (p_n, p_e, V_g, chi, w_n, w_e, dev_a, dev_b, dev_c)
# --------------------------------------------------------------------------------------------------------------
#: Number of stage-3 fixed-wing states.
N_STAGE3_FW = 9
#: Index of the first heading-deviation coefficient in the stage-3 fixed-wing state.
I_DEVIATION = 6


@njit(cache=True)
def _inverse_speed(vg):
    """(1 / max(V_g, V_min), its derivative w.r.t. V_g): the 1/V_g terms are frozen below V_min."""
    if vg > MIN_GROUND_SPEED_M_S:
        return 1.0 / vg, -1.0 / (vg * vg)
    return 1.0 / MIN_GROUND_SPEED_M_S, 0.0


@njit(cache=True)
def corrected_heading(x, yaw2_rad):
    """Heading corrected by the deviation model, psi = psi_2 - (a + b sin psi_2 + c cos psi_2), and its
    derivatives.

    The stage-2 heading error of a magnetometer with a body-fixed horizontal field error (hard iron, and the
    vertical field seen through a stage-1 tilt error) is a constant plus a sinusoid of the heading: the compass
    deviation of a classical compass swing.

    Parameters
    ----------
    x : ndarray, shape (9,)
        Stage-3 fixed-wing state; ``x[6:9]`` = (a, b, c) [rad].
    yaw2_rad : float
        Stage-2 heading psi_2 [rad].

    Returns
    -------
    psi : float
        Corrected heading [rad].
    dpsi_dyaw2 : float
        d psi / d psi_2 [-].
    dpsi_ddev : tuple of 3 float
        d psi / d(a, b, c) [-].
    """
    s, c = np.sin(yaw2_rad), np.cos(yaw2_rad)
    dev_a, dev_b, dev_c = x[I_DEVIATION], x[I_DEVIATION + 1], x[I_DEVIATION + 2]
    return yaw2_rad - (dev_a + dev_b * s + dev_c * c), 1.0 - dev_b * c + dev_c * s, (-1.0, -s, -c)


@njit(cache=True)
def stage3_fw_f(x, u, gravity_m_s2):
    """Navigation kinematics with the coordinated-turn course model (eq 26-29 corrected, T12/T13).

    The heading is the stage-2 heading corrected by the deviation states (:func:`corrected_heading`); with zero
    initial and process variance for them it stays the stage-2 heading and this is the paper's 6-state filter.

    Parameters
    ----------
    x : ndarray, shape (9,)
        (p_n [m], p_e [m], V_g [m/s], chi [rad], w_n [m/s], w_e [m/s], dev_a, dev_b, dev_c [rad]).
    u : ndarray, shape (6,)
        (V_a [m/s], q [rad/s], r [rad/s], phi [rad], theta [rad], psi_2 [rad]).
    gravity_m_s2 : float
        Local gravity [m/s^2].

    Returns
    -------
    ndarray, shape (9,)
        State derivative (wind and deviation: 0).
    """
    sph, cph = np.sin(u[3]), np.cos(u[3])
    psi, _, _ = corrected_heading(x, u[5])
    out = np.zeros(N_STAGE3_FW)
    out[0], out[1], out[2], out[3] = stage3_fw_rates(x[2], x[3], x[4], x[5], u[0],
                                                     euler_yaw_rate(sph, cph, np.cos(u[4]), u[1], u[2]),
                                                     np.cos(psi), np.sin(psi), gravity_m_s2 * sph / cph)
    return out


@njit(cache=True)
def stage3_fw_rates(vg, chi, wn, we, va, psi_dot, cps, sps, turn_m_s2):
    """Scalar form of :func:`stage3_fw_f`: (p_n_dot, p_e_dot, V_g_dot, chi_dot).

    Parameters
    ----------
    vg, chi, wn, we : float
        Ground speed [m/s], course [rad], wind north/east [m/s].
    va, psi_dot : float
        Airspeed [m/s], heading rate [rad/s].
    cps, sps : float
        Cosine and sine of the (corrected) heading.
    turn_m_s2 : float
        g tan(phi) [m/s^2] (coordinated turn).
    """
    inv_vg, _ = _inverse_speed(vg)
    cch, sch = np.cos(chi), np.sin(chi)
    cos_chi_psi = cch * cps + sch * sps
    return (vg * cch, vg * sch, va * psi_dot * (we * cps - wn * sps) * inv_vg, turn_m_s2 * cos_chi_psi * inv_vg)


@njit(cache=True)
def stage3_fw_jacobians(x, u, gravity_m_s2, a=None, g=None):
    """Jacobians of :func:`stage3_fw_f`: df/dx (9, 9) (eq 30 corrected, T14, plus the deviation columns) and the
    input-noise Jacobian df/d(V_a, psi_2) (9, 2) for the airspeed and stage-2 heading errors; written into ``a``
    and ``g`` when given (allocated when None)."""
    if a is None:
        a = np.empty((N_STAGE3_FW, N_STAGE3_FW))
    if g is None:
        g = np.empty((N_STAGE3_FW, 2))
    vg, chi, wn, we = x[2], x[3], x[4], x[5]
    va, q, r, phi, theta = u[0], u[1], u[2], u[3], u[4]
    psi, dpsi_dyaw2, dpsi_ddev = corrected_heading(x, u[5])
    inv_vg, dinv_vg = _inverse_speed(vg)
    sph, cph = np.sin(phi), np.cos(phi)
    psi_dot = euler_yaw_rate(sph, cph, np.cos(theta), q, r)
    cps, sps = np.cos(psi), np.sin(psi)
    cch, sch = np.cos(chi), np.sin(chi)
    cos_chi_psi, sin_chi_psi = cch * cps + sch * sps, sch * cps - cch * sps
    turn = gravity_m_s2 * sph / cph
    a[:, :] = 0.0
    a[0, 2] = cch
    a[0, 3] = -vg * sch
    a[1, 2] = sch
    a[1, 3] = vg * cch
    a[2, 2] = va * psi_dot * (we * cps - wn * sps) * dinv_vg
    a[2, 4] = -va * psi_dot * sps * inv_vg
    a[2, 5] = va * psi_dot * cps * inv_vg
    a[3, 2] = turn * cos_chi_psi * dinv_vg
    a[3, 3] = -turn * sin_chi_psi * inv_vg
    # d(V_g_dot, chi_dot)/dpsi at the corrected heading: the deviation columns and the heading input
    dvg_dpsi = -va * psi_dot * (wn * cps + we * sps) * inv_vg
    dchi_dpsi = turn * sin_chi_psi * inv_vg
    for j in range(3):
        a[2, I_DEVIATION + j] = dvg_dpsi * dpsi_ddev[j]
        a[3, I_DEVIATION + j] = dchi_dpsi * dpsi_ddev[j]
    g[:, :] = 0.0
    g[2, 0] = psi_dot * (we * cps - wn * sps) * inv_vg
    g[2, 1] = dvg_dpsi * dpsi_dyaw2
    g[3, 1] = dchi_dpsi * dpsi_dyaw2
    return a, g


@njit(cache=True)
def stage3_fw_h_wind(x, air_speed_h_m_s, yaw_rad):
    """Wind-triangle pseudo-measurement residual model (eq 31/32), z = (0, 0).

    Parameters
    ----------
    x : ndarray, shape (9,)
        Stage-3 fixed-wing state.
    air_speed_h_m_s : float
        Horizontal air-relative speed V_ah [m/s].
    yaw_rad : float
        Stage-2 heading psi_2 [rad] (the model uses the corrected heading psi).

    Returns
    -------
    h : ndarray, shape (2,)
        (V_ah c_psi + w_n - V_g c_chi, V_ah s_psi + w_e - V_g s_chi) [m/s].
    c : ndarray, shape (2, 9)
        dh/dx (eq 33 corrected, T15, plus the deviation columns).
    """
    vg, chi = x[2], x[3]
    psi, _, dpsi_ddev = corrected_heading(x, yaw_rad)
    cch, sch = np.cos(chi), np.sin(chi)
    cps, sps = np.cos(psi), np.sin(psi)
    h = np.array((air_speed_h_m_s * cps + x[4] - vg * cch, air_speed_h_m_s * sps + x[5] - vg * sch))
    c = np.zeros((2, N_STAGE3_FW))
    c[0, 2] = -cch
    c[0, 3] = vg * sch
    c[0, 4] = 1.0
    c[1, 2] = -sch
    c[1, 3] = -vg * cch
    c[1, 5] = 1.0
    for j in range(3):
        c[0, I_DEVIATION + j] = -air_speed_h_m_s * sps * dpsi_ddev[j]
        c[1, I_DEVIATION + j] = air_speed_h_m_s * cps * dpsi_ddev[j]
    return h, c


@njit(cache=True)
def stage3_fw_wind_input_jacobian(x, air_speed_h_m_s, yaw_rad):
    """d h_wind / d(V_ah, psi_2), shape (2, 2): maps airspeed and heading variances into the pseudo R."""
    psi, dpsi_dyaw2, _ = corrected_heading(x, yaw_rad)
    cps, sps = np.cos(psi), np.sin(psi)
    return np.array(((cps, -air_speed_h_m_s * sps * dpsi_dyaw2), (sps, air_speed_h_m_s * cps * dpsi_dyaw2)))


@njit(cache=True)
def stage3_fw_h_gps_velocity(x):
    """GPS NED horizontal velocity model (v_n, v_e) = V_g (c_chi, s_chi) and its Jacobian (2, 9)."""
    vg, chi = x[2], x[3]
    cch, sch = np.cos(chi), np.sin(chi)
    c = np.zeros((2, N_STAGE3_FW))
    c[0, 2] = cch
    c[0, 3] = -vg * sch
    c[1, 2] = sch
    c[1, 3] = vg * cch
    return np.array((vg * cch, vg * sch)), c


# --------------------------------------------------------------------------------------------------------------
# Stage 3, multicopter / no-airspeed mode: x = (p_n, p_e, v_n, v_e)
# --------------------------------------------------------------------------------------------------------------


@njit(cache=True)
def ned_acceleration(phi, theta, psi, specific_force_b, gravity_m_s2):
    """Kinematic NED acceleration a_n = R_nb f_b + g_n [m/s^2], a 3-tuple."""
    cph, sph = np.cos(phi), np.sin(phi)
    cth, sth = np.cos(theta), np.sin(theta)
    cps, sps = np.cos(psi), np.sin(psi)
    f0, f1, f2 = specific_force_b[0], specific_force_b[1], specific_force_b[2]
    # R_nb = R_z(psi) R_y(theta) R_x(phi): rotate by roll, then pitch, then yaw
    a1 = cph * f1 - sph * f2
    a2 = sph * f1 + cph * f2
    b0 = cth * f0 + sth * a2
    return cps * b0 - sps * a1, sps * b0 + cps * a1, cth * a2 - sth * f0 + gravity_m_s2


@njit(cache=True)
def stage3_mc_f(x, accel_ne_m_s2):
    """Constant-acceleration kinematics (p_n, p_e, v_n, v_e)_dot = (v_n, v_e, a_n, a_e), a 4-tuple;
    A = [[0, I], [0, 0]]."""
    return x[2], x[3], accel_ne_m_s2[0], accel_ne_m_s2[1]


@njit(cache=True)
def stage3_mc_A():
    """df/dx of :func:`stage3_mc_f`, shape (4, 4)."""
    a = np.zeros((4, 4))
    a[0, 2] = 1.0
    a[1, 3] = 1.0
    return a
