"""Measurement models of the full-state direct filter (docs/direct.md, 'Measurement models').

Each ``h_<sensor>`` returns the predicted scalar ``h(x)`` and writes its Jacobian row ``H = dh/dx`` (length n,
zeroed first) into ``H``; :func:`measurement` dispatches on the event kind. The scratch matrices ``R_nb``,
``S_euler``, ``W_euler`` (3, 3) are filled by :func:`estimators.direct.model.euler_matrices` from the state.

=================  =========================================  ===========================================
function           model                                      notes
=================  =========================================  ===========================================
h_baro             ``-pd + bb``                               ``bb`` only with the barometer-offset state
h_airspeed         ``|V - R_nb^T wbar|``                      ``wbar = (wn, we, 0)``; 0 without wind states
h_sideslip         ``e2^T (V - R_nb^T wbar)``                 zero-sideslip pseudo-measurement (fixed-wing)
h_gps_position     ``p``                                      NED component
h_gps_velocity     ``R_nb V``; ground speed, course           components 3, 4: paper mode (eqs 42-43 corr.)
h_zero_velocity    ``R_nb V``                                 no-GPS pseudo-measurement of zero velocity
h_body_vector      ``R_nb^T r_n (+ b_m)``                     magnetometer (unit earth field) and sun
=================  =========================================  ===========================================

The sun's two scalars on the tangent plane of its prediction are formed by the kernel from the three body-axis
components (:func:`estimators.sun.measurement.tangent_projection`).

The leaves are ``inline="always"``: compiled into :func:`measurement` (one function, as the kernel calls it once per
scalar update), a non-inlined numba call keeps a reference-count pair per array argument, which costs more than
these small computations.
"""

from __future__ import annotations

import math

from numba import njit

from estimators.core.full_state import mag_heading_innovation
from estimators.direct.model import I_P, I_TH, I_V, L_BB, L_BM, L_W, euler_matrices
from estimators.inputs.records import AIRSPEED, BARO, GPS_POS, GPS_VEL, MAG, SIDESLIP, ZERO_VELOCITY


@njit(cache=True, inline="always")
def _zero(H):
    for i in range(H.shape[0]):
        H[i] = 0.0


@njit(cache=True, inline="always")
def h_baro(x, layout, H):
    """Barometric height above the origin [m]: ``h = -pd + bb`` (without the offset state ``h = -pd``)."""
    _zero(H)
    H[I_P + 2] = -1.0
    ibb = layout[L_BB]
    if ibb >= 0:
        H[ibb] = 1.0
        return -x[I_P + 2] + x[ibb]
    return -x[I_P + 2]


@njit(cache=True, inline="always")
def h_gps_position(x, comp, H):
    """GPS position [m] NED, component ``comp``: ``h = p[comp]``."""
    _zero(H)
    H[I_P + comp] = 1.0
    return x[I_P + comp]


@njit(cache=True, inline="always")
def _air_mass_in_body(x, iw, R_nb):
    """``a = R_nb^T wbar`` (air mass velocity in body axes, ``wbar = (wn, we, 0)``) [m/s]; 0 without wind."""
    if iw < 0:
        return 0.0, 0.0, 0.0
    return (R_nb[0, 0] * x[iw] + R_nb[1, 0] * x[iw + 1], R_nb[0, 1] * x[iw] + R_nb[1, 1] * x[iw + 1],
            R_nb[0, 2] * x[iw] + R_nb[1, 2] * x[iw + 1])


@njit(cache=True, inline="always")
def h_airspeed(x, layout, R_nb, S_euler, W_euler, H):
    """True airspeed [m/s]: ``h = |v_r|``, ``v_r = V - R_nb^T wbar`` (the air-relative velocity in body axes).

    ``H_V = v_r^T / Va``; ``d v_r/dTheta = -[a]x W_euler`` and ``v_r^T [a]x = (v_r x a)^T``, so
    ``H_Theta = -(v_r x a)^T W_euler / Va``; ``H_w = -v_r^T R_nb^T[:, 0:2] / Va``. ``Va`` floored at 1 mm/s.
    """
    _zero(H)
    euler_matrices(x[I_TH], x[I_TH + 1], x[I_TH + 2], R_nb, S_euler, W_euler)
    iw = layout[L_W]
    a0, a1, a2 = _air_mass_in_body(x, iw, R_nb)
    vr0, vr1, vr2 = x[I_V] - a0, x[I_V + 1] - a1, x[I_V + 2] - a2
    va = max(math.sqrt(vr0 * vr0 + vr1 * vr1 + vr2 * vr2), 1e-3)
    H[I_V], H[I_V + 1], H[I_V + 2] = vr0 / va, vr1 / va, vr2 / va
    c0 = vr1 * a2 - vr2 * a1
    c1 = vr2 * a0 - vr0 * a2
    c2 = vr0 * a1 - vr1 * a0
    for j in range(3):
        H[I_TH + j] = -(c0 * W_euler[0, j] + c1 * W_euler[1, j] + c2 * W_euler[2, j]) / va
    if iw >= 0:
        H[iw] = -(vr0 * R_nb[0, 0] + vr1 * R_nb[0, 1] + vr2 * R_nb[0, 2]) / va
        H[iw + 1] = -(vr0 * R_nb[1, 0] + vr1 * R_nb[1, 1] + vr2 * R_nb[1, 2]) / va
    return va


@njit(cache=True, inline="always")
def h_sideslip(x, layout, R_nb, S_euler, W_euler, H):
    """Lateral body air velocity [m/s] (zero-sideslip pseudo-measurement): ``h = e2^T v_r``.

    ``H_V = e2^T``, ``H_Theta = -e2^T [a]x W_euler`` with ``e2^T [a]x = (a2, 0, -a0)``, ``H_w = -R_nb[0:2, 1]``.
    """
    _zero(H)
    euler_matrices(x[I_TH], x[I_TH + 1], x[I_TH + 2], R_nb, S_euler, W_euler)
    iw = layout[L_W]
    a0, a1, a2 = _air_mass_in_body(x, iw, R_nb)
    H[I_V + 1] = 1.0
    for j in range(3):
        H[I_TH + j] = -(a2 * W_euler[0, j] - a0 * W_euler[2, j])
    if iw >= 0:
        H[iw] = -R_nb[0, 1]
        H[iw + 1] = -R_nb[1, 1]
    return x[I_V + 1] - a1


@njit(cache=True, inline="always")
def h_gps_velocity(x, comp, R_nb, S_euler, W_euler, H):
    """GPS velocity: NED component ``comp`` (0..2) of ``R_nb V`` [m/s], or (paper mode, eqs 42-43 corrected)
    the ground speed ``|(vn, ve)|`` [m/s] (``comp == 3``, floored at 1 mm/s) or the course ``atan2(ve, vn)``
    [rad] (``comp == 4``; the caller wraps the innovation).

    Every component is a weighted sum of the NED rows, ``h = sum_i w_i (R_nb V)_i``: ``H_V = sum_i w_i
    R_nb[i, :]``, ``H_Theta = -sum_i w_i (R_nb [V]x W_euler)[i, :]``.
    """
    _zero(H)
    euler_matrices(x[I_TH], x[I_TH + 1], x[I_TH + 2], R_nb, S_euler, W_euler)
    u, v, w = x[I_V], x[I_V + 1], x[I_V + 2]
    vel0 = R_nb[0, 0] * u + R_nb[0, 1] * v + R_nb[0, 2] * w
    vel1 = R_nb[1, 0] * u + R_nb[1, 1] * v + R_nb[1, 2] * w
    vel2 = R_nb[2, 0] * u + R_nb[2, 1] * v + R_nb[2, 2] * w
    if comp < 3:
        w0, w1, w2 = (1.0 if comp == 0 else 0.0), (1.0 if comp == 1 else 0.0), (1.0 if comp == 2 else 0.0)
        h = vel0 if comp == 0 else (vel1 if comp == 1 else vel2)
    elif comp == 3:
        vg = max(math.hypot(vel0, vel1), 1e-3)
        w0, w1, w2 = vel0 / vg, vel1 / vg, 0.0
        h = vg
    else:
        vg2 = max(vel0 * vel0 + vel1 * vel1, 1e-6)
        w0, w1, w2 = -vel1 / vg2, vel0 / vg2, 0.0
        h = math.atan2(vel1, vel0)
    r0 = w0 * R_nb[0, 0] + w1 * R_nb[1, 0] + w2 * R_nb[2, 0]
    r1 = w0 * R_nb[0, 1] + w1 * R_nb[1, 1] + w2 * R_nb[2, 1]
    r2 = w0 * R_nb[0, 2] + w1 * R_nb[1, 2] + w2 * R_nb[2, 2]
    H[I_V], H[I_V + 1], H[I_V + 2] = r0, r1, r2
    for j in range(3):
        # column j of [V]x W_euler is V x W_euler[:, j]
        c0 = v * W_euler[2, j] - w * W_euler[1, j]
        c1 = w * W_euler[0, j] - u * W_euler[2, j]
        c2 = u * W_euler[1, j] - v * W_euler[0, j]
        H[I_TH + j] = -(r0 * c0 + r1 * c1 + r2 * c2)
    return h


@njit(cache=True, inline="always")
def h_zero_velocity(x, comp, R_nb, S_euler, W_euler, H):
    """Zero NED-velocity pseudo-measurement of logs without GPS (docs/direct.md, 'Missing sensors'): the NED
    velocity component ``comp`` (0..2) [m/s], as :func:`h_gps_velocity`."""
    return h_gps_velocity(x, comp, R_nb, S_euler, W_euler, H)


@njit(cache=True, inline="always")
def h_body_vector(x, ref_ned, comp, bias_first, R_nb, S_euler, W_euler, H):
    """A known NED vector seen in the body, component ``comp``: ``h = (R_nb^T r_n)[comp] (+ b_m[comp])``.

    Magnetometer (``ref_ned`` the unit earth field, ``bias_first`` the first hard-iron bias state) or sun
    direction (unit vector, ``bias_first = -1``). ``d(R_nb^T r_n)/dTheta = [b]x W_euler`` with
    ``b = R_nb^T r_n``: ``H_Theta`` is row ``comp`` of it; ``H_bm = e_comp^T`` with the bias.
    """
    _zero(H)
    euler_matrices(x[I_TH], x[I_TH + 1], x[I_TH + 2], R_nb, S_euler, W_euler)
    f0, f1, f2 = ref_ned[0], ref_ned[1], ref_ned[2]
    b0 = R_nb[0, 0] * f0 + R_nb[1, 0] * f1 + R_nb[2, 0] * f2
    b1 = R_nb[0, 1] * f0 + R_nb[1, 1] * f1 + R_nb[2, 1] * f2
    b2 = R_nb[0, 2] * f0 + R_nb[1, 2] * f1 + R_nb[2, 2] * f2
    # row comp of [b]x
    if comp == 0:
        x0, x1, x2, h = 0.0, -b2, b1, b0
    elif comp == 1:
        x0, x1, x2, h = b2, 0.0, -b0, b1
    else:
        x0, x1, x2, h = -b1, b0, 0.0, b2
    for j in range(3):
        H[I_TH + j] = x0 * W_euler[0, j] + x1 * W_euler[1, j] + x2 * W_euler[2, j]
    if bias_first >= 0:
        H[bias_first + comp] = 1.0
        h += x[bias_first + comp]
    return h


@njit(cache=True)
def mag_heading(x, values, variances, field, bias_first, R_nb, S_euler, W_euler, H):
    """Magnetometer heading update (:func:`estimators.core.full_state.mag_heading_innovation`): returns
    ``(nu, r_var)`` and fills ``H``: 1 on the yaw (a rotation about NED down changes the ZYX yaw by the same
    angle), the bias gradient on ``b_m`` (``bias_first`` its first state, < 0: none), 0 on roll and pitch."""
    _zero(H)
    euler_matrices(x[I_TH], x[I_TH + 1], x[I_TH + 2], R_nb, S_euler, W_euler)
    if bias_first >= 0:
        b0, b1, b2 = x[bias_first], x[bias_first + 1], x[bias_first + 2]
        grad = H[bias_first:bias_first + 3]
    else:
        b0, b1, b2 = 0.0, 0.0, 0.0
        grad = H[I_P:I_P + 3]  # scratch, cleared below
    nu, r_var = mag_heading_innovation(R_nb, values[0] - b0, values[1] - b1, values[2] - b2, variances, field, grad)
    if bias_first < 0:
        _zero(H)
    H[I_TH + 2] = 1.0
    return nu, r_var


@njit(cache=True)
def measurement(x, kind, comp, values, field, layout, R_nb, S_euler, W_euler, H):
    """Predicted scalar measurement ``h`` and its Jacobian row ``H`` (filled, length n) of component ``comp`` of
    an event of kind ``kind`` (:mod:`estimators.inputs.records` codes).

    GPS_VEL components 3/4 are ground speed and course (paper mode); SUN components 0..2 the body-frame axes
    (the kernel projects them on the tangent plane); ``values`` is the event's value row (SUN: the NED sun
    vector in 3..5); ``field`` the unit earth field NED.
    """
    if kind == BARO:
        return h_baro(x, layout, H)
    if kind == GPS_POS:
        return h_gps_position(x, comp, H)
    if kind == AIRSPEED:
        return h_airspeed(x, layout, R_nb, S_euler, W_euler, H)
    if kind == SIDESLIP:
        return h_sideslip(x, layout, R_nb, S_euler, W_euler, H)
    if kind == GPS_VEL:
        return h_gps_velocity(x, comp, R_nb, S_euler, W_euler, H)
    if kind == ZERO_VELOCITY:
        return h_zero_velocity(x, comp, R_nb, S_euler, W_euler, H)
    if kind == MAG:
        return h_body_vector(x, field, comp, layout[L_BM], R_nb, S_euler, W_euler, H)
    return h_body_vector(x, values[3:6], comp, -1, R_nb, S_euler, W_euler, H)
