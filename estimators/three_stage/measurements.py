"""Measurement models of the three-stage series estimator (Guo et al. 2019 sec. 3.1, corrected; docs/three_stage.md,
'Corrections to the paper').

The measurement model ``h`` of each update and its Jacobian ``C = dh/dx`` (plus, where the update needs them, the
Jacobians with respect to the inputs whose errors inflate R), as numba functions over float64 arrays with the
conventions of :mod:`estimators.three_stage.model` (optional output arrays, allocated when None; analytic
Jacobians, checked against central finite differences by ``tests/test_three_stage.py``):

1. stage 1, accelerometer (docs/three_stage.md, 'Stage 1: roll and pitch'): the steady-flight specific force
   with the centripetal term from airspeed (:func:`stage1_h_airspeed`, eq 20/21 corrected, V_b = V_a (c_th, 0,
   s_th)) or the general form h = C_bn (a_n - g_n) with a GPS-derived acceleration a_n
   (:func:`stage1_h_acceleration`; a_n = 0: gravity only, the multicopter / no-airspeed model, docs/three_stage.md,
   'Missing sensors').
2. stage 2, a unit reference vector in body axes (magnetometer vs the WMM field, or the photocell sun vector vs
   the SPA sun direction): h = C_bn(phi, theta, psi) v_n (:func:`stage2_h`, eq 24/25 corrected;
   docs/three_stage.md, 'Stage 2: heading'), and the heading a measured vector implies (:func:`measured_heading`,
   for the heading re-acquisition).
3. stage 3, fixed-wing: the wind-triangle pseudo-measurement (:func:`stage3_fw_h_wind`, eq 31-33 corrected) and
   the GPS velocity (:func:`stage3_fw_h_gps_velocity`) (docs/three_stage.md, 'Stage 3: navigation and wind'); GPS
   position, and velocity in multicopter mode, are linear in the state (rows of the identity, in the kernel).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from estimators.core import rotations
from estimators.three_stage.model import I_DEVIATION, N_STAGE3_FW, corrected_heading

#: Horizontal part of a unit vector below which it gives no heading (:func:`measured_heading`).
MIN_HORIZONTAL = 0.2


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
        Columns dh/dphi, dh/dtheta, dh/dpsi (the identity d(R^T a)/dTheta = [R^T a]x W).
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


@njit(cache=True, inline="always")  # three call sites with a literal column: inlined, not three compiles
def _cross_column(h, w0, w1, w2, jac, j):
    """Column ``j`` of ``jac`` = h x w."""
    jac[0, j] = h[1] * w2 - h[2] * w1
    jac[1, j] = h[2] * w0 - h[0] * w2
    jac[2, j] = h[0] * w1 - h[1] * w0


# --------------------------------------------------------------------------------------------------------------
# Stage 1: roll and pitch, accelerometer
# --------------------------------------------------------------------------------------------------------------


@njit(cache=True)
def stage1_h_airspeed(x, rates, airspeed_m_s, gravity_m_s2, h=None, c=None):
    """Specific force of steady flight with the centripetal term from airspeed (eq 20 corrected) and its
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
    """Specific force from a known NED acceleration, h = C_bn(phi, theta, psi) (a_n - g_n) (docs/three_stage.md,
    'Stage 1: roll and pitch').

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
# Stage 2: heading, unit reference vector
# --------------------------------------------------------------------------------------------------------------


@njit(cache=True)
def stage2_h(yaw_rad, phi, theta, ref_n, h=None, jac=None):
    """A reference unit vector seen in body axes and its Jacobians (eq 24, eq 25 corrected).

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
        dh/d(phi, theta), used to inflate R by the stage-1 covariance (cascade consistency,
        docs/three_stage.md, 'Stage 2: heading').
    """
    # a tuple as stage 1 passes: one compiled body_vector_and_euler_jacobian
    h, jac = body_vector_and_euler_jacobian((ref_n[0], ref_n[1], ref_n[2]), phi, theta, yaw_rad, h, jac)
    return h, jac[:, 2:], jac[:, :2]


@njit(cache=True)
def measured_heading(z_body, ref_ned, phi, theta):
    """Heading [rad] at which the body-frame unit vector ``z_body`` points along the reference ``ref_ned`` in
    azimuth, at roll ``phi`` and pitch ``theta`` [rad]: with the levelled vector ``l = R_y(theta) R_x(phi) z`` and
    ``R_nb = R_z(psi) R_y R_x``, the reference azimuth is ``psi + azimuth(l)``. NaN when either has no horizontal
    component to speak of."""
    cph, sph, cth, sth = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta)
    level_n = cth * z_body[0] + sth * (sph * z_body[1] + cph * z_body[2])
    level_e = cph * z_body[1] - sph * z_body[2]
    if math.hypot(level_n, level_e) < MIN_HORIZONTAL or math.hypot(ref_ned[0], ref_ned[1]) < MIN_HORIZONTAL:
        return math.nan
    return rotations.wrap_pi(math.atan2(ref_ned[1], ref_ned[0]) - math.atan2(level_e, level_n))


# --------------------------------------------------------------------------------------------------------------
# Stage 3, fixed-wing mode: wind triangle and GPS velocity
# --------------------------------------------------------------------------------------------------------------


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
        dh/dx (eq 33 corrected, plus the deviation columns).
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

