"""Process models of the three-stage series estimator (Guo et al. 2019 sec. 3.1, corrected; docs/three_stage.md,
'State vectors' and 'Corrections to the paper').

Every stage is written as small numba functions over float64 arrays: the state derivative ``f``, its Jacobian
``A = df/dx`` and the input-noise Jacobian ``G = df/du``; the measurement models ``h`` and their Jacobians are in
:mod:`estimators.three_stage.measurements`. Analytic Jacobians only; ``tests/test_three_stage.py`` checks each
against central finite differences. The functions the kernel calls per sample allocate nothing: matrices go into
optional output arrays (allocated when None, as the tests call them), the scalar forms take the sines and cosines
the kernel shares between the stages, and short vectors are returned as tuples.

Frames and units: NED earth frame, FRD body frame, ZYX Euler angles (roll phi, pitch theta, yaw psi) [rad], body
rates (p, q, r) [rad/s], specific force [m/s^2] (``(0, 0, -g)`` level at rest), speeds [m/s], positions [m].
Each stage's state is laid out in a table of :class:`~estimators.core.state_table.StateSpec` rows (built from the
configuration in :mod:`estimators.three_stage.run`); :func:`~estimators.core.state_table.initial_covariance` and
:func:`~estimators.core.state_table.process_noise_psd` build P0 and the continuous process-noise density from it.

State layouts
-------------
1. roll/pitch: x = (phi, theta), u = (p, q, r) (docs/three_stage.md, 'Stage 1: roll and pitch').
2. heading: x = psi, u = (phi, theta, q, r); A = 0 (docs/three_stage.md, 'Stage 2: heading').
3. navigation, fixed-wing: x = (p_n, p_e, V_g, chi, w_n, w_e, dev_a, dev_b, dev_c) (:data:`N_STAGE3_FW` states,
   the deviation coefficients from :data:`I_DEVIATION`), u = (V_a, q, r, phi, theta, psi_2) (eq 26-33 corrected)
   with the heading psi = psi_2 - (dev_a + dev_b sin psi_2 + dev_c cos psi_2): the stage-2 heading corrected by a
   compass-deviation model, observable through the wind triangle in turns (B&M carry psi itself as a 7th state);
   multicopter / no-airspeed: x = (p_n, p_e, v_n, v_e) driven by the NED acceleration (docs/three_stage.md,
   'Stage 3: navigation and wind').
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Ground speed below which the course is undefined and the 1/V_g terms are frozen [m/s] (docs/three_stage.md,
#: 'Stage 3: navigation and wind').
MIN_GROUND_SPEED_M_S = 3.0
#: Number of stage-3 fixed-wing states.
N_STAGE3_FW = 9
#: Index of the first heading-deviation coefficient in the stage-3 fixed-wing state.
I_DEVIATION = 6


# --------------------------------------------------------------------------------------------------------------
# Shared attitude helper
# --------------------------------------------------------------------------------------------------------------


@njit(cache=True)
def euler_yaw_rate(sph, cph, cth, q, r):
    """psi_dot = q s_ph / c_th + r c_ph / c_th [rad/s] (third row of S(Theta); eq 22 corrected), from the
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
    """df/dx of :func:`stage1_f`, shape (2, 2) (eq 19 corrected), written into ``a`` when given."""
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


# --------------------------------------------------------------------------------------------------------------
# Stage 2: heading
# --------------------------------------------------------------------------------------------------------------


@njit(cache=True)
def stage2_G(sph, cph, cth):
    """d psi_dot / d(p, q, r) (gyro input-noise Jacobian of eq 22), a 3-tuple, from the roll sine and cosine and
    the pitch cosine; A = 0 (eq 23)."""
    return 0.0, sph / cth, cph / cth


# --------------------------------------------------------------------------------------------------------------
# Stage 3, fixed-wing mode: x = (p_n, p_e, V_g, chi, w_n, w_e, dev_a, dev_b, dev_c)
# --------------------------------------------------------------------------------------------------------------


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
    """Navigation kinematics with the coordinated-turn course model (eq 26-29 corrected).

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
    """Jacobians of :func:`stage3_fw_f`: df/dx (9, 9) (eq 30 corrected, plus the deviation columns) and the
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
