"""Measurement models of the full-state indirect filter (docs/indirect.md, 'Measurement models').

Each ``h_<sensor>`` returns the predicted scalar ``h(x_hat)`` and writes its row ``H = dh/d(dx)`` over all
:data:`~estimators.indirect.model.NE` error states into ``H`` (zeroed first), at the nominal state ``x`` of
:mod:`estimators.indirect.model` (attitude error ``dtheta`` in body axes, right perturbation). :func:`measurement`
dispatches one scalar component of a measurement event to its model. Every function is a small ``numba`` kernel;
finite differences appear only in the tests.
"""

from __future__ import annotations

import math

from numba import njit

from estimators.core.full_state import mag_heading_innovation
from estimators.core.rotations import dcm_into, rotate
from estimators.indirect.model import E_BB, E_BG, E_BM, E_P, E_TH, E_V, E_W, X_BB, X_BG, X_BM, X_P, X_Q, X_V, X_W
from estimators.inputs.records import AIRSPEED, BARO, GPS_POS, GPS_VEL, MAG, SIDESLIP, ZERO_VELOCITY


@njit(cache=True)
def _ned_axis_in_body(x, axis):
    """Row ``axis`` of R(q): the NED axis ``axis`` in body axes, ``R^T e_axis``."""
    return rotate(x[X_Q], -x[X_Q + 1], -x[X_Q + 2], -x[X_Q + 3], 1.0 if axis == 0 else 0.0,
                  1.0 if axis == 1 else 0.0, 1.0 if axis == 2 else 0.0)


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

    ``H_dp = e_axis^T``, ``H_dtheta = -e_axis^T R [l_b]x = (l_b x r)^T`` with ``r = R^T e_axis``.
    """
    H[:] = 0.0
    rx, ry, rz = _ned_axis_in_body(x, axis)
    lx, ly, lz = lever_arm_b_m[0], lever_arm_b_m[1], lever_arm_b_m[2]
    H[E_P + axis] = 1.0
    H[E_TH] = ly * rz - lz * ry
    H[E_TH + 1] = lz * rx - lx * rz
    H[E_TH + 2] = lx * ry - ly * rx
    return x[X_P + axis] + rx * lx + ry * ly + rz * lz


@njit(cache=True)
def h_gps_velocity(x, gyro_rad_s, lever_arm_b_m, axis, H):
    """GPS antenna velocity [m/s] NED, component ``axis``: ``h = v + R (omega x l_b)``, ``omega = gyro - b_g``.

    With ``r = R^T e_axis`` and ``u = omega x l_b``: ``H_dv = e_axis^T``, ``H_dtheta = -e_axis^T R [u]x = (u x r)^T``,
    ``H_dbg = e_axis^T R [l_b]x = (r x l_b)^T``.
    """
    H[:] = 0.0
    rx, ry, rz = _ned_axis_in_body(x, axis)
    lx, ly, lz = lever_arm_b_m[0], lever_arm_b_m[1], lever_arm_b_m[2]
    wx = gyro_rad_s[0] - x[X_BG]
    wy = gyro_rad_s[1] - x[X_BG + 1]
    wz = gyro_rad_s[2] - x[X_BG + 2]
    ux = wy * lz - wz * ly
    uy = wz * lx - wx * lz
    uz = wx * ly - wy * lx
    H[E_V + axis] = 1.0
    H[E_TH] = uy * rz - uz * ry
    H[E_TH + 1] = uz * rx - ux * rz
    H[E_TH + 2] = ux * ry - uy * rx
    H[E_BG] = ry * lz - rz * ly
    H[E_BG + 1] = rz * lx - rx * lz
    H[E_BG + 2] = rx * ly - ry * lx
    return x[X_V + axis] + rx * ux + ry * uy + rz * uz


@njit(cache=True)
def h_body_origin_velocity(x, axis, H):
    """Velocity [m/s] NED of the body origin (the zero-velocity pseudo-measurement), component ``axis``:
    ``h = v``, ``H_dv = e_axis^T``."""
    H[:] = 0.0
    H[E_V + axis] = 1.0
    return x[X_V + axis]


@njit(cache=True)
def h_ground_speed(x, H):
    """Horizontal ground speed [m/s] (paper-mode GPS, eq. 43 corrected): ``h = |(v_n, v_e)|``.

    ``H_dv = (v_n, v_e, 0) / V_g``; zero row when ``V_g`` is ~0 (the caller skips such updates).
    """
    H[:] = 0.0
    speed = math.hypot(x[X_V], x[X_V + 1])
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
    return math.atan2(x[X_V + 1], x[X_V])


@njit(cache=True)
def h_airspeed(x, H):
    """True airspeed [m/s]: ``h = |v - w|`` (pitot aligned with the air flow; the wind has no vertical component).

    ``H_dv = (v - w)^T / V_a``, ``H_dw = -(v - w)_{n,e}^T / V_a``; zero row when ``V_a`` is ~0.
    """
    H[:] = 0.0
    air_n, air_e, air_d = x[X_V] - x[X_W], x[X_V + 1] - x[X_W + 1], x[X_V + 2]
    airspeed = math.sqrt(air_n * air_n + air_e * air_e + air_d * air_d)
    if airspeed > 1e-3:
        H[E_V] = air_n / airspeed
        H[E_V + 1] = air_e / airspeed
        H[E_V + 2] = air_d / airspeed
        H[E_W] = -air_n / airspeed
        H[E_W + 1] = -air_e / airspeed
    return airspeed


@njit(cache=True)
def h_sideslip(x, H):
    """Lateral body air velocity [m/s] (zero-sideslip pseudo-measurement, fixed-wing): ``h = e2^T R^T (v - w)``.

    ``H_dv = e2^T R^T``, ``H_dtheta = e2^T [R^T (v - w)]x``, ``H_dw = -e2^T R^T[:, 0:2]``.
    """
    H[:] = 0.0
    qw, qx, qy, qz = x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3]
    air_bx, air_by, air_bz = rotate(qw, -qx, -qy, -qz, x[X_V] - x[X_W], x[X_V + 1] - x[X_W + 1], x[X_V + 2])
    # e2^T [a]x = (a_z, 0, -a_x).
    H[E_TH] = air_bz
    H[E_TH + 2] = -air_bx
    r_n, r_e, r_d = rotate(qw, qx, qy, qz, 0.0, 1.0, 0.0)  # e2^T R^T = (R e2)^T
    H[E_V] = r_n
    H[E_V + 1] = r_e
    H[E_V + 2] = r_d
    H[E_W] = -r_n
    H[E_W + 1] = -r_e
    return air_by


@njit(cache=True)
def h_body_vector(x, ref_ned, axis, with_mag_bias, H):
    """A known NED vector seen in the body, component ``axis``: ``h = R^T r_n (+ b_m)``.

    Magnetometer (``r_n`` = earth field [gauss], ``with_mag_bias``) or sun direction (unit vector).
    ``H_dtheta = e_axis^T [R^T r_n]x``, ``H_dbm = e_axis^T`` with the bias.
    """
    H[:] = 0.0
    b0, b1, b2 = rotate(x[X_Q], -x[X_Q + 1], -x[X_Q + 2], -x[X_Q + 3], ref_ned[0], ref_ned[1], ref_ned[2])
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


@njit(cache=True)
def mag_heading(x, values, variances, field, R_nb, H):
    """Magnetometer heading update (:func:`estimators.core.full_state.mag_heading_innovation`): returns
    ``(nu, r_var)`` and fills ``H`` over all NE error states: the NED-down component of the body-frame attitude
    error (row 3 of ``R_nb``, written here from the nominal quaternion) and the bias gradient on ``db_m``; no
    roll or pitch part (``R_nb`` (3, 3) scratch)."""
    H[:] = 0.0
    dcm_into(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], R_nb)
    nu, r_var = mag_heading_innovation(R_nb, values[0] - x[X_BM], values[1] - x[X_BM + 1], values[2] - x[X_BM + 2],
                                       variances, field, H[E_BM:E_BM + 3])
    for j in range(3):  # R (I + [dtheta]x) = (I + [R dtheta]x) R: the yaw error is (R dtheta)_down
        H[E_TH + j] = R_nb[2, j]
    return nu, r_var


@njit(cache=True)
def measurement(x, kind, comp, values, field, lever_b, gyro, H):
    """Predicted scalar ``h`` and its row ``H`` over all NE error states.

    ``kind``/``comp`` as in :mod:`estimators.inputs.records` (GPS_VEL components 3/4: ground speed and course,
    paper mode; SUN components 0..2: body axes, projected on the tangent plane by the caller); ``values`` the
    event's value row (SUN: NED sun vector in 3..5); ``field`` the unit earth field NED; ``lever_b`` the GPS
    antenna position [m] body; ``gyro`` the IMU rate [rad/s] of the event's interval.
    """
    if kind == BARO:
        return h_baro(x, H)
    if kind == AIRSPEED:
        return h_airspeed(x, H)
    if kind == SIDESLIP:
        return h_sideslip(x, H)
    if kind == GPS_POS:
        return h_gps_position(x, lever_b, comp, H)
    if kind == GPS_VEL:
        if comp == 3:
            return h_ground_speed(x, H)
        if comp == 4:
            return h_course(x, H)
        return h_gps_velocity(x, gyro, lever_b, comp, H)
    if kind == ZERO_VELOCITY:
        return h_body_origin_velocity(x, comp, H)
    with_mag_bias = kind == MAG  # a bool variable, not a literal per call: one compiled h_body_vector
    return h_body_vector(x, field if with_mag_bias else values[3:6], comp, with_mag_bias, H)
