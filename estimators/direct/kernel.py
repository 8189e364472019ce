"""Full-state direct EKF (paper section 3.2; math note section 4 with the corrected eqs 34-43).

State vector ``x`` (the named table :data:`STATE_TABLE`; optional blocks are present only when they help, see
:func:`state_table`):

=========  ======  ===============================================================================
name       unit    meaning
=========  ======  ===============================================================================
pn pe pd   m       position NED relative to the origin (down = -(alt - alt0), math note 1.5)
u v w      m/s     ground velocity in body FRD axes
roll ...   rad     ZYX Euler angles phi, theta, psi (R_nb = Rz(psi) Ry(theta) Rx(phi))
bgx ...    rad/s   gyro bias (gyro = omega + b_g + noise)
bax ...    m/s^2   accelerometer bias (optional, ``accel_bias_states``)
wn we      m/s     wind north/east, velocity of the air mass (only with an airspeed sensor, math note 7.1)
bmx ...    -       magnetometer hard-iron bias in units of the field strength (only with the magnetometer)
bb         m       barometer offset against GPS height (only with barometer and GPS)
=========  ======  ===============================================================================

Process model (corrected eq 36), inputs omega_hat = gyro - b_g, f_hat = accel - b_a:
``p_dot = R V``, ``V_dot = V x omega_hat + f_hat + R^T g_n``, ``Theta_dot = S(Theta) omega_hat``, biases and wind
random walks. Jacobian ``A`` (eq 37 with the blocks of math note 4) and noise ``Qc = G_g N_g^2 G_g^T +
G_a N_a^2 G_a^T + diag(random walks)``, ``G_g = [0; -[V]x; -S; 0]``, ``G_a = [0; -I; 0; 0]``; the state is
integrated with RK4 at the IMU rate (input held over the interval) and split at every event time; the
covariance with ``F = I + A dt + (A dt)^2/2``, ``Qd = Qc dt`` at the fixed ``timing.covariance_rate_hz`` (A at
the state that started the interval, with the mean IMU input over it), as PX4 EKF2 does: an update between two
covariance steps uses the covariance of the last step (at most one covariance interval old).

Measurements (sequential scalar updates in Joseph form, re-linearised after each scalar; gates per sensor):
B1 baro ``h = -pd + bb``; B2 airspeed ``h = |V - R^T wbar|``; B3 zero sideslip ``h = e2^T (V - R^T wbar)``
(fixed-wing only, pseudo, ungated); B4 GPS position ``h = p``; B5 GPS velocity ``h = R V`` (or ground speed and
course in ``gps_velocity_mode="paper"``, eqs 42-43 corrected); B6 magnetometer ``h = R^T m_n + b_m`` (unit
earth field from the WMM); B7 sun ``h = R^T s_n`` projected on the tangent plane of ``h`` (2 scalars); no-GPS
logs add a zero NED-velocity pseudo-measurement (math note 7.3).

Filter quantities (kernel arrays): ``x`` (n,) state, ``P`` (n, n) covariance (prior before, posterior after an
update), ``nu`` innovation, ``S`` innovation variance, ``K = P H^T / S`` gain, ``NIS = nu^2 / S``; every scalar
update is recorded (:mod:`estimators.core.linalg`).

``mode="paper_indirect"`` runs the paper's indirect filter literally (eqs 44-49 corrected, math note 5.1): an
additive error state in the same coordinates, propagated with the same ``A`` (it stays zero between updates),
estimated over each sensor's group of scalar updates with ``H`` and ``h`` at the uncorrected prior, and injected
(reset) after the group. It equals the direct filter exactly for linear measurement models and to second order
otherwise.

``backend="numpy"`` runs :mod:`estimators.direct.reference`, the plain-NumPy twin of the kernel.
"""


from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from estimators.config import EstimatorConfig
from estimators.core import linalg, reacquisition, recorder, rotations
from estimators.core.full_state import (
    EIG_FLOOR,
    MIN_VARIANCE,
    P_COV_DT,
    P_FIELD,
    P_G,
    P_GPS_OUTAGE_S,
    P_GPS_REJECT_S,
    P_NA2,
    P_NG2,
    P_PAPER_VEL,
    P_VMIN,
    PD_CHECK_EVERY,
    accel_bias_degradations,
    component_range,
    diagnostics_capacity,
    gates_per_kind,
    scalar_innovation,
    shared_params,
)
from estimators.core.recorder import C_DIAG, C_GPS_RESETS, C_OUTPUTS, C_REPAIRS, C_RESETS, C_UPDATES, N_SHARED_COUNTERS
from estimators.core.results import EstimatorRun, diagnostics_frame, kernel_report, replay_details, states_frame
from estimators.core.state_table import StateSpec, initial_covariance, random_walk_psd
from estimators.inputs import records
from estimators.inputs.records import (
    AIRSPEED,
    BARO,
    GPS_POS,
    GPS_VEL,
    MAG,
    OUTPUT,
    SIDESLIP,
    SUN,
    ZERO_VELOCITY,
    ReplayInputs,
)
from estimators.sun.measurement import sun_tangent_basis, tangent_projection
from ingest.flightlog import FlightLog
from ingest.frames import euler_to_matrix

NAME = "full_state_direct"

# fixed state slots
I_P = 0
I_V = 3
I_TH = 6
I_BG = 9
#: States with dynamics (position, body velocity, Euler angles) come first; the rest are random walks.
N_DYNAMIC = 9
# layout array slots: index of the first state of each optional block, -1 when absent
L_BA = 0
L_W = 1
L_BM = 2
L_BB = 3
N_LAYOUT = 4
P_PAPER_INDIRECT = 11  # 1: paper-literal indirect (group error state, reset after the group)
N_PARAMS = 12

#: Columns of the kernel's per-epoch output array.
OUT_COLUMNS = ("time_s", "roll", "pitch", "yaw", "pn", "pe", "pd", "vn", "ve", "vd", "wn", "we",
               "roll_std", "pitch_std", "yaw_std", "pn_std", "pe_std", "pd_std", "vn_std", "ve_std", "vd_std",
               "wn_std", "we_std")
# counters: the shared slots of ekf_core (C_DIAG .. C_OUTPUTS), then this filter's
C_PITCH_GUARD = N_SHARED_COUNTERS
C_FLUSHES = N_SHARED_COUNTERS + 1
N_COUNTERS = N_SHARED_COUNTERS + 2

#: Euler-angle filters stop attitude-dependent updates above this pitch (math note 7.6) [rad].
PITCH_GUARD_RAD = math.radians(85.0)


def state_table(config: EstimatorConfig, *, accel_bias: bool, wind: bool, mag_bias: bool, baro_bias: bool,
                absolute_yaw: bool) -> tuple[StateSpec, ...]:
    """The state table for a run; x0, P0 and the random-walk densities are built from it.

    Parameters
    ----------
    config : EstimatorConfig
    accel_bias, wind, mag_bias, baro_bias : bool
        Optional blocks present.
    absolute_yaw : bool
        An absolute heading source exists (initial yaw sigma ``initial.yaw_deg``, else ``yaw_unaided_deg``).
    """
    ini, noise = config.initial, config.noise
    rad = math.radians
    yaw_sigma = rad(ini.yaw_deg if absolute_yaw else ini.yaw_unaided_deg)
    rows = [StateSpec(n, "m", ini.position_m, 0.0) for n in ("pn", "pe", "pd")]
    rows += [StateSpec(n, "m/s", ini.velocity_m_s, 0.0) for n in ("u", "v", "w")]
    rows += [StateSpec("roll", "rad", rad(ini.roll_pitch_deg), 0.0),
             StateSpec("pitch", "rad", rad(ini.roll_pitch_deg), 0.0), StateSpec("yaw", "rad", yaw_sigma, 0.0)]
    rows += [StateSpec(n, "rad/s", rad(ini.gyro_bias_deg_s), noise.gyro_bias_rw_rad_s2_sqrt_hz)
             for n in ("bgx", "bgy", "bgz")]
    if accel_bias:
        rw_z = noise.accel_bias_rw_z_m_s3_sqrt_hz
        rows += [StateSpec(n, "m/s^2", ini.accel_bias_m_s2, noise.accel_bias_rw_m_s3_sqrt_hz) for n in ("bax", "bay")]
        rows.append(StateSpec("baz", "m/s^2", ini.accel_bias_m_s2,
                              noise.accel_bias_rw_m_s3_sqrt_hz if rw_z is None else rw_z))
    if wind:
        rows += [StateSpec(n, "m/s", ini.wind_m_s, noise.wind_rw_m_s_sqrt_s) for n in ("wn", "we")]
    if mag_bias:
        rows += [StateSpec(n, "-", ini.mag_bias, noise.mag_bias_rw_sqrt_s) for n in ("bmx", "bmy", "bmz")]
    if baro_bias:
        rows.append(StateSpec("bb", "m", ini.baro_bias_m, noise.baro_bias_rw_m_sqrt_s))
    return tuple(rows)


def layout_of(table: tuple[StateSpec, ...]) -> np.ndarray:
    """Kernel layout array: first index of the optional blocks (``L_BA``, ``L_W``, ``L_BM``, ``L_BB``), -1 absent."""
    names = [s.name for s in table]
    first = {"bax": L_BA, "wn": L_W, "bmx": L_BM, "bb": L_BB}
    layout = np.full(N_LAYOUT, -1, dtype=np.int64)
    for name, slot in first.items():
        if name in names:
            layout[slot] = names.index(name)
    return layout


# ----------------------------------------------------------------------------------------------------------------
# model leaf functions (numba). Scratch: R, S, W (3, 3).


@njit(cache=True)
def euler_matrices(phi, theta, psi, R, S, W):
    """Fill ``R = R_nb`` (body -> NED), ``S`` (Theta_dot = S omega) and ``W = S^-1`` (math note 1.1)."""
    cph, sph = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    cps, sps = math.cos(psi), math.sin(psi)
    R[0, 0] = cth * cps
    R[0, 1] = sph * sth * cps - cph * sps
    R[0, 2] = cph * sth * cps + sph * sps
    R[1, 0] = cth * sps
    R[1, 1] = sph * sth * sps + cph * cps
    R[1, 2] = cph * sth * sps - sph * cps
    R[2, 0] = -sth
    R[2, 1] = sph * cth
    R[2, 2] = cph * cth
    tth = sth / cth
    S[0, 0] = 1.0
    S[0, 1] = sph * tth
    S[0, 2] = cph * tth
    S[1, 0] = 0.0
    S[1, 1] = cph
    S[1, 2] = -sph
    S[2, 0] = 0.0
    S[2, 1] = sph / cth
    S[2, 2] = cph / cth
    W[0, 0] = 1.0
    W[0, 1] = 0.0
    W[0, 2] = -sth
    W[1, 0] = 0.0
    W[1, 1] = cph
    W[1, 2] = sph * cth
    W[2, 0] = 0.0
    W[2, 1] = -sph
    W[2, 2] = cph * cth


@njit(cache=True)
def corrected_inputs(x, gyro, accel, layout):
    """Bias-corrected IMU input ``(omega_hat, f_hat)`` as six floats: ``gyro - b_g`` [rad/s], ``accel - b_a``
    [m/s^2] (body FRD; ``b_a = 0`` without accelerometer-bias states)."""
    f0, f1, f2 = accel[0], accel[1], accel[2]
    iba = layout[L_BA]
    if iba >= 0:
        f0 -= x[iba]
        f1 -= x[iba + 1]
        f2 -= x[iba + 2]
    return gyro[0] - x[9], gyro[1] - x[10], gyro[2] - x[11], f0, f1, f2


@njit(cache=True)
def dynamics(x, om0, om1, om2, f0, f1, f2, g, R, S, W, xdot):
    """Derivatives of the :data:`N_DYNAMIC` states with dynamics (position, body velocity, Euler angles) for
    the bias-corrected inputs (:func:`corrected_inputs`); reads ``x[:9]``, writes ``xdot[:9]`` only."""
    euler_matrices(x[6], x[7], x[8], R, S, W)
    u, v, w = x[3], x[4], x[5]
    for i in range(3):
        xdot[i] = R[i, 0] * u + R[i, 1] * v + R[i, 2] * w
    xdot[3] = v * om2 - w * om1 + f0 + g * R[2, 0]
    xdot[4] = w * om0 - u * om2 + f1 + g * R[2, 1]
    xdot[5] = u * om1 - v * om0 + f2 + g * R[2, 2]
    for i in range(3):
        xdot[6 + i] = S[i, 0] * om0 + S[i, 1] * om1 + S[i, 2] * om2


@njit(cache=True)
def derivative(x, gyro, accel, g, layout, R, S, W, xdot):
    """Continuous dynamics ``xdot = f(x, u)`` (corrected eq 36) for held IMU inputs ``gyro`` [rad/s],
    ``accel`` [m/s^2] (body FRD); the bias, wind and offset states are random walks (zero derivative)."""
    for i in range(x.shape[0]):
        xdot[i] = 0.0
    om0, om1, om2, f0, f1, f2 = corrected_inputs(x, gyro, accel, layout)
    dynamics(x, om0, om1, om2, f0, f1, f2, g, R, S, W, xdot)


@njit(cache=True)
def jacobian(x, gyro, g, layout, R, S, W, A):
    """Continuous Jacobian ``A = df/dx`` (eq 37 / math note 4 blocks) at ``x`` with gyro input ``gyro``.

    Only the rows of position, velocity and attitude are written (the bias, wind and offset states have no
    dynamics): ``A`` must be zero elsewhere (allocate it with ``np.zeros`` and reuse it).
    """
    euler_matrices(x[6], x[7], x[8], R, S, W)
    p, q, r = gyro[0] - x[9], gyro[1] - x[10], gyro[2] - x[11]
    u, v, w = x[3], x[4], x[5]
    # dp/dV = R; dp/dTheta = -R [V]x W
    for i in range(3):
        for j in range(3):
            A[i, 3 + j] = R[i, j]
    # [V]x W: column j = V x W[:, j]
    for j in range(3):
        c0 = v * W[2, j] - w * W[1, j]
        c1 = w * W[0, j] - u * W[2, j]
        c2 = u * W[1, j] - v * W[0, j]
        for i in range(3):
            A[i, 6 + j] = -(R[i, 0] * c0 + R[i, 1] * c1 + R[i, 2] * c2)
    # dV/dV = -[omega]x
    A[3, 4] = r
    A[3, 5] = -q
    A[4, 3] = -r
    A[4, 5] = p
    A[5, 3] = q
    A[5, 4] = -p
    # dV/dTheta = [R^T g_n]x W, R^T g_n = g R[2, :]
    a0, a1, a2 = g * R[2, 0], g * R[2, 1], g * R[2, 2]
    for j in range(3):
        A[3, 6 + j] = a1 * W[2, j] - a2 * W[1, j]
        A[4, 6 + j] = a2 * W[0, j] - a0 * W[2, j]
        A[5, 6 + j] = a0 * W[1, j] - a1 * W[0, j]
    # dV/db_g = -[V]x
    A[3, 10] = w
    A[3, 11] = -v
    A[4, 9] = -w
    A[4, 11] = u
    A[5, 9] = v
    A[5, 10] = -u
    iba = layout[L_BA]
    if iba >= 0:
        for i in range(3):
            A[3 + i, iba + i] = -1.0
    # dTheta/dTheta (eq 37), dTheta/db_g = -S
    cph, sph = math.cos(x[6]), math.sin(x[6])
    cth, sth = math.cos(x[7]), math.sin(x[7])
    a = q * cph - r * sph
    b = q * sph + r * cph
    A[6, 6] = a * sth / cth
    A[6, 7] = b / (cth * cth)
    A[7, 6] = -b
    A[8, 6] = a / cth
    A[8, 7] = b * sth / (cth * cth)
    for i in range(3):
        for j in range(3):
            A[6 + i, 9 + j] = -S[i, j]


@njit(cache=True)
def process_noise(x, ng2, na2, rw_var, dt, R, S, W, Qd):
    """Discrete process noise ``Qd = (G_g N_g^2 G_g^T + G_a N_a^2 G_a^T + diag(rw_var)) dt`` (math note 2.2
    option i: white-noise densities, variance ``density^2 dt``).

    ``rw_var`` (n,) holds the squared random-walk densities of the bias and wind states (0 elsewhere). Only the
    diagonal and the velocity/attitude block are written: ``Qd`` must be zero elsewhere (allocate it with
    ``np.zeros`` and reuse it).
    """
    n = x.shape[0]
    euler_matrices(x[6], x[7], x[8], R, S, W)
    for i in range(n):
        Qd[i, i] = rw_var[i] * dt
    u, v, w = x[3], x[4], x[5]
    vv2 = u * u + v * v + w * w
    for i in range(3):
        vi = x[3 + i]
        for j in range(3):
            # [V]x [V]x^T = |V|^2 I - V V^T; column j of [V]x S^T = V x S[j, :]
            vv = (vv2 if i == j else 0.0) - vi * x[3 + j]
            if i == 0:
                vt = v * S[j, 2] - w * S[j, 1]
            elif i == 1:
                vt = w * S[j, 0] - u * S[j, 2]
            else:
                vt = u * S[j, 1] - v * S[j, 0]
            tt = S[i, 0] * S[j, 0] + S[i, 1] * S[j, 1] + S[i, 2] * S[j, 2]
            Qd[3 + i, 3 + j] = (ng2 * vv + (na2 if i == j else 0.0) + (rw_var[3 + i] if i == j else 0.0)) * dt
            Qd[3 + i, 6 + j] = ng2 * vt * dt
            Qd[6 + j, 3 + i] = ng2 * vt * dt
            Qd[6 + i, 6 + j] = (ng2 * tt + (rw_var[6 + i] if i == j else 0.0)) * dt


@njit(cache=True)
def measurement(x, kind, comp, values, field, layout, R, S, W, H):
    """Predicted scalar measurement ``h`` and its Jacobian row ``H`` (filled, length n).

    ``kind``/``comp`` as in :mod:`estimators.inputs.build`; for GPS_VEL, components 3/4 are ground speed and course
    (paper mode); for SUN, components 0..2 are the body-frame axes (the kernel projects on the tangent plane);
    ``values`` is the event's value row (SUN: the NED sun vector in 3..5); ``field`` the unit earth field NED.
    """
    n = x.shape[0]
    for i in range(n):
        H[i] = 0.0
    euler_matrices(x[6], x[7], x[8], R, S, W)
    u, v, w = x[3], x[4], x[5]
    if kind == BARO:
        H[2] = -1.0
        ibb = layout[L_BB]
        if ibb >= 0:
            H[ibb] = 1.0
            return -x[2] + x[ibb]
        return -x[2]
    if kind == GPS_POS:
        H[comp] = 1.0
        return x[comp]
    if kind in (AIRSPEED, SIDESLIP):
        iw = layout[L_W]
        # a = R^T wbar (air mass velocity in body axes), v_r = V - a
        a0 = a1 = a2 = 0.0
        if iw >= 0:
            a0 = R[0, 0] * x[iw] + R[1, 0] * x[iw + 1]
            a1 = R[0, 1] * x[iw] + R[1, 1] * x[iw + 1]
            a2 = R[0, 2] * x[iw] + R[1, 2] * x[iw + 1]
        vr0, vr1, vr2 = u - a0, v - a1, w - a2
        if kind == AIRSPEED:
            va = max(math.sqrt(vr0 * vr0 + vr1 * vr1 + vr2 * vr2), 1e-3)
            H[3], H[4], H[5] = vr0 / va, vr1 / va, vr2 / va
            # d v_r/dTheta = -[a]x W and v_r^T [a]x = (v_r x a)^T, so dVa/dTheta = -(v_r x a)^T W / Va
            c0 = vr1 * a2 - vr2 * a1
            c1 = vr2 * a0 - vr0 * a2
            c2 = vr0 * a1 - vr1 * a0
            for j in range(3):
                H[6 + j] = -(c0 * W[0, j] + c1 * W[1, j] + c2 * W[2, j]) / va
            if iw >= 0:
                H[iw] = -(vr0 * R[0, 0] + vr1 * R[0, 1] + vr2 * R[0, 2]) / va
                H[iw + 1] = -(vr0 * R[1, 0] + vr1 * R[1, 1] + vr2 * R[1, 2]) / va
            return va
        # sideslip: e2^T v_r; e2^T [a]x = (a2, 0, -a0)
        H[4] = 1.0
        for j in range(3):
            H[6 + j] = -(a2 * W[0, j] - a0 * W[2, j])
        if iw >= 0:
            H[iw] = -R[0, 1]
            H[iw + 1] = -R[1, 1]
        return vr1
    if kind in (GPS_VEL, ZERO_VELOCITY):
        # NED velocity R V; a scalar h is a weighted sum of its rows: dh/dV = sum_i w_i R[i, :],
        # dh/dTheta = -sum_i w_i (R [V]x W)[i, :]
        vel0 = R[0, 0] * u + R[0, 1] * v + R[0, 2] * w
        vel1 = R[1, 0] * u + R[1, 1] * v + R[1, 2] * w
        vel2 = R[2, 0] * u + R[2, 1] * v + R[2, 2] * w
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
        r0 = w0 * R[0, 0] + w1 * R[1, 0] + w2 * R[2, 0]
        r1 = w0 * R[0, 1] + w1 * R[1, 1] + w2 * R[2, 1]
        r2 = w0 * R[0, 2] + w1 * R[1, 2] + w2 * R[2, 2]
        H[3], H[4], H[5] = r0, r1, r2
        for j in range(3):
            # column j of [V]x W is V x W[:, j]
            c0 = v * W[2, j] - w * W[1, j]
            c1 = w * W[0, j] - u * W[2, j]
            c2 = u * W[1, j] - v * W[0, j]
            H[6 + j] = -(r0 * c0 + r1 * c1 + r2 * c2)
        return h
    # body-frame unit vectors: magnetometer (field) and sun (values[3:6]); b = R^T ref
    if kind == MAG:
        f0, f1, f2 = field[0], field[1], field[2]
    else:
        f0, f1, f2 = values[3], values[4], values[5]
    b0 = R[0, 0] * f0 + R[1, 0] * f1 + R[2, 0] * f2
    b1 = R[0, 1] * f0 + R[1, 1] * f1 + R[2, 1] * f2
    b2 = R[0, 2] * f0 + R[1, 2] * f1 + R[2, 2] * f2
    # d(R^T a)/dTheta = [b]x W: row comp of [b]x times W
    if comp == 0:
        x0, x1, x2, h = 0.0, -b2, b1, b0
    elif comp == 1:
        x0, x1, x2, h = b2, 0.0, -b0, b1
    else:
        x0, x1, x2, h = -b1, b0, 0.0, b2
    for j in range(3):
        H[6 + j] = x0 * W[0, j] + x1 * W[1, j] + x2 * W[2, j]
    if kind == MAG:
        ibm = layout[L_BM]
        if ibm >= 0:
            H[ibm + comp] = 1.0
            h += x[ibm + comp]
    return h


@njit(cache=True)
def propagate_state(x, gyro, accel, dt, g, layout, R, S, W, k1, k2, k3, k4, xt):
    """RK4 step of the state over ``dt`` [s] with the IMU input held; roll and yaw wrapped to [-pi, pi).

    Only the :data:`N_DYNAMIC` states with dynamics are integrated (the others have zero derivative, so RK4
    leaves them unchanged exactly) and the bias-corrected input is formed once: the biases are constant over the
    step."""
    om0, om1, om2, f0, f1, f2 = corrected_inputs(x, gyro, accel, layout)
    dynamics(x, om0, om1, om2, f0, f1, f2, g, R, S, W, k1)
    for i in range(N_DYNAMIC):
        xt[i] = x[i] + 0.5 * dt * k1[i]
    dynamics(xt, om0, om1, om2, f0, f1, f2, g, R, S, W, k2)
    for i in range(N_DYNAMIC):
        xt[i] = x[i] + 0.5 * dt * k2[i]
    dynamics(xt, om0, om1, om2, f0, f1, f2, g, R, S, W, k3)
    for i in range(N_DYNAMIC):
        xt[i] = x[i] + dt * k3[i]
    dynamics(xt, om0, om1, om2, f0, f1, f2, g, R, S, W, k4)
    for i in range(N_DYNAMIC):
        x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    x[6] = rotations.wrap_pi(x[6])
    x[8] = rotations.wrap_pi(x[8])


@njit(cache=True)
def _flush_covariance(P, x_cov, acc, g, params, layout, rw_var, min_var, max_var, R, S, W, A, F, Qc, work,
                      mean_gyro, columns, F_values, F_cols, F_counts, counters):
    """Propagate P over the accumulated interval ``acc[0]`` with the mean inputs ``acc[1:7] / acc[0]``.

    Scratch: ``mean_gyro`` (3,); ``columns`` = ``arange(n)`` and the sparse dynamic rows of F ``F_values``,
    ``F_cols`` (N_DYNAMIC, n), ``F_counts`` (N_DYNAMIC,) (:func:`estimators.core.linalg.sparse_rows`)."""
    n = P.shape[0]
    dt = acc[0]
    for i in range(3):
        mean_gyro[i] = acc[1 + i] / dt
    jacobian(x_cov, mean_gyro, g, layout, R, S, W, A)
    linalg.transition_matrix(A, dt, F)
    process_noise(x_cov, params[P_NG2], params[P_NA2], rw_var, dt, R, S, W, Qc)
    linalg.sparse_rows(F, columns, F_values, F_cols, F_counts)
    linalg.propagate_sparse(P, F_values, F_cols, F_counts, work)
    for i in range(n):  # + Qd (symmetric: the diagonal and the velocity/attitude block)
        for j in range(n):
            P[i, j] += Qc[i, j]
    counters[C_FLUSHES] += 1
    if linalg.scheduled_repair(P, min_var, max_var, work, EIG_FLOOR, counters[C_FLUSHES], PD_CHECK_EVERY):
        counters[C_REPAIRS] += 1
    for i in range(7):
        acc[i] = 0.0


@njit(cache=True)
def run_kernel(imu_t, imu_gyro, imu_accel, ev_t, ev_kind, ev_imu, ev_val, ev_var, x0, P0, layout, params,
               gates, rw_var, min_var, max_var, out_f, out_x, out_sx, diag_f, diag_i, counters):
    """The full-state direct filter over a whole log (one compiled loop; see the module docstring).

    Parameters
    ----------
    imu_t, imu_gyro, imu_accel : ndarrays (N,), (N, 3), (N, 3)
        IMU rows (:class:`estimators.inputs.records.ImuSamples`).
    ev_t, ev_kind, ev_imu, ev_val, ev_var : ndarrays
        Events (:class:`estimators.inputs.records.MeasurementEvents`).
    x0, P0 : ndarrays (n,), (n, n)
        Initial state and covariance.
    layout : int64 (4,)
        Optional blocks (:func:`layout_of`).
    params : float64 (N_PARAMS,)
        Scalars (``P_*`` slots).
    gates : float64 (9,)
        Gate per event kind (inf: ungated).
    rw_var : float64 (n,)
        Random-walk densities squared.
    min_var, max_var : float64 (n,)
        Variance limits.
    out_f : (K, 23) output per OUTPUT event (:data:`OUT_COLUMNS`); out_x, out_sx : (K, n) state and its std.
    diag_f, diag_i : diagnostics arrays; counters : int64 (N_COUNTERS,).
    """
    n = x0.shape[0]
    x = x0.copy()
    P = P0.copy()
    x_safe = x0.copy()
    x_cov = x0.copy()
    x_err = np.zeros(n)
    R = np.empty((3, 3))
    S = np.empty((3, 3))
    W = np.empty((3, 3))
    A = np.zeros((n, n))  # jacobian() and process_noise() write their non-zero blocks only
    F = np.empty((n, n))
    Qc = np.zeros((n, n))
    work = np.empty((n, n))
    H = np.empty(n)
    H3 = np.empty((3, n))
    dx = np.empty(n)
    ph = np.empty(n)
    k1 = np.empty(n)
    k2 = np.empty(n)
    k3 = np.empty(n)
    k4 = np.empty(n)
    xt = np.empty(n)
    h3 = np.empty(3)
    out_row = np.empty(out_f.shape[1])
    acc = np.zeros(7)  # dt, sum gyro dt, sum accel dt
    mean_gyro = np.empty(3)
    columns = np.arange(n)
    F_values = np.empty((N_DYNAMIC, n))
    F_cols = np.empty((N_DYNAMIC, n), dtype=np.int64)
    F_counts = np.empty(N_DYNAMIC, dtype=np.int64)
    no_values = np.zeros(records.N_EVENT_VALUES)  # the event values the output's velocity model does not read
    g = params[P_G]
    cov_dt = params[P_COV_DT]
    field = params[P_FIELD:P_FIELD + 3].copy()
    paper_vel = params[P_PAPER_VEL] > 0.5
    paper_indirect = params[P_PAPER_INDIRECT] > 0.5
    vmin = params[P_VMIN]
    gps_mon = reacquisition.gps_monitor()
    air_ok = False  # the last airspeed update was accepted (reset_to_gps)
    n_out = 0
    t = imu_t[0]
    j = 0
    m = ev_t.shape[0]
    for k in range(imu_t.shape[0]):
        gyro = imu_gyro[k]
        accel = imu_accel[k]
        while True:
            at_event = j < m and ev_imu[j] == k
            t_next = ev_t[j] if at_event else imu_t[k]
            if t_next > t:
                if acc[0] == 0.0:
                    for i in range(n):
                        x_cov[i] = x[i]
                step = t_next - t
                propagate_state(x, gyro, accel, step, g, layout, R, S, W, k1, k2, k3, k4, xt)
                linalg.accumulate_inputs(acc, step, gyro, accel)
                t = t_next
                if acc[0] >= cov_dt * (1.0 - 1e-9):
                    _flush_covariance(P, x_cov, acc, g, params, layout, rw_var, min_var, max_var, R, S, W, A, F,
                                      Qc, work, mean_gyro, columns, F_values, F_cols, F_counts, counters)
                    if not linalg.is_healthy(x, P):
                        linalg.reset_filter(x, P, x_safe, P0)
                        counters[C_RESETS] += 1
            if not at_event:
                break
            kind = ev_kind[j]
            values = ev_val[j]
            if kind == OUTPUT:
                # P is checked at every covariance step and updates keep it finite; the state integrated since
                # then is checked here
                finite = True
                for i in range(n):
                    if not math.isfinite(x[i]):
                        finite = False
                if not finite:
                    linalg.reset_filter(x, P, x_safe, P0)
                    counters[C_RESETS] += 1
                for i in range(n):
                    x_safe[i] = x[i]
                _output_row(x, P, layout, field, no_values, R, S, W, H, t, out_row)
                recorder.record_output(out_f, n_out, out_row)
                if n_out < out_x.shape[0]:
                    for i in range(n):
                        out_x[n_out, i] = x[i]
                        out_sx[n_out, i] = math.sqrt(max(P[i, i], 0.0))
                n_out += 1
                j += 1
                continue
            if abs(x[7]) > PITCH_GUARD_RAD and kind != BARO and kind != GPS_POS:
                counters[C_PITCH_GUARD] += 1
                j += 1
                continue
            is_gps = kind in (GPS_POS, GPS_VEL)
            if is_gps:
                # (re)acquisition (math note 2.3): position and velocity to the GPS, see reset_to_gps
                reset, counted = reacquisition.gps_reset_due(gps_mon, kind == GPS_POS, t, params[P_GPS_REJECT_S],
                                                        params[P_GPS_OUTAGE_S])
                if reset:
                    reset_to_gps(x, P, kind, values, ev_var[j], layout, air_ok and layout[L_W] >= 0, R, S, W, H,
                                 F, work)
                    if counted:
                        counters[C_GPS_RESETS] += 1
                    j += 1
                    continue
            gate = gates[kind]
            c0, c1 = component_range(kind, values, paper_vel, vmin)
            if kind == SUN:
                # tangent basis of the predicted sun direction at the prior
                for c in range(3):
                    h3[c] = measurement(x, kind, c, values, field, layout, R, S, W, H)
                    for i in range(n):
                        H3[c, i] = H[i]
                basis = sun_tangent_basis(h3)
            if paper_indirect:
                for i in range(n):
                    x_err[i] = 0.0
            for c in range(c0, c1):
                if kind == SUN:
                    if not paper_indirect:
                        for cc in range(3):
                            h3[cc] = measurement(x, kind, cc, values, field, layout, R, S, W, H)
                            for i in range(n):
                                H3[cc, i] = H[i]
                    nu = tangent_projection(basis, c, values, h3, H3, H)
                    r_var = ev_var[j, c]
                else:
                    h = measurement(x, kind, c, values, field, layout, R, S, W, H)
                    nu, r_var = scalar_innovation(kind, c, values, ev_var[j], h)
                if paper_indirect:
                    # eq 49 corrected: innovation of the error state, z - h(x_hat-) - H x_err
                    for i in range(n):
                        nu -= H[i] * x_err[i]
                accepted, s_var, nis = linalg.scalar_update(P, H, nu, r_var, gate, dx, ph)
                counters[C_UPDATES] += 1
                recorder.record_update(diag_f, diag_i, counters, t, kind, c, nu, s_var, nis, accepted)
                if is_gps:
                    reacquisition.gps_record(gps_mon, kind == GPS_POS, c, t, accepted)
                elif kind == AIRSPEED:
                    air_ok = accepted
                if accepted:
                    if paper_indirect:
                        for i in range(n):
                            x_err[i] += dx[i]
                    else:
                        for i in range(n):
                            x[i] += dx[i]
                        x[6] = rotations.wrap_pi(x[6])
                        x[8] = rotations.wrap_pi(x[8])
            if paper_indirect:
                for i in range(n):
                    x[i] += x_err[i]
                x[6] = rotations.wrap_pi(x[6])
                x[8] = rotations.wrap_pi(x[8])
            j += 1
    if acc[0] > 0.0:
        _flush_covariance(P, x_cov, acc, g, params, layout, rw_var, min_var, max_var, R, S, W, A, F, Qc, work,
                          mean_gyro, columns, F_values, F_cols, F_counts, counters)
    counters[C_OUTPUTS] = n_out
    return x, P


@njit(cache=True)
def reset_to_gps(x, P, kind, values, variances, layout, move_wind, R, S, W, H, T, work):
    """GPS re-acquisition (math note 2.3): the position (``kind == GPS_POS``) or the velocity to the GPS value.

    Position: ``p = z``, covariance ``diag(R_gps)``, no correlation with the other states.

    Velocity: the NED velocity becomes the GPS value ``v``, its error the GPS noise, uncorrelated with the other
    states; the body state is ``V = R_nb^T v``, so ``dV = R_nb^T dv + J dTheta`` with ``J = [V]x W`` (math note
    1.1; zeroing the body-axis cross-covariances instead would correlate the NED velocity with the attitude).
    ``move_wind`` (wind states present and the last airspeed update accepted, i.e. the filter's air-relative
    velocity agrees with the airspeed): the wind moves with the ground velocity, ``w += v - R_nb V_old`` (north,
    east), so the air-relative velocity is kept; otherwise the wind, fitted to the rejected velocity, would make
    the airspeed updates fail after the reset. The covariance follows the same linear map,
    ``e' = T e + G n``: ``P <- T P T^T + G R_gps G^T``.

    ``layout`` as :func:`layout_of`; ``H`` (n,), ``T`` and ``work`` (n, n) scratch.
    """
    n = x.shape[0]
    if kind == GPS_POS:
        for a in range(3):
            x[I_P + a] = values[a]
            for b in range(3):
                work[a, b] = 0.0
            work[a, a] = variances[a]
        linalg.reset_covariance_block(P, I_P, work[:3, :3].copy())
        return
    for i in range(n):
        for k in range(n):
            T[i, k] = 0.0
        T[i, i] = 1.0
    iw = layout[L_W]
    if move_wind:
        for c in range(2):
            h = measurement(x, GPS_VEL, c, values, values, layout, R, S, W, H)
            x[iw + c] += values[c] - h
            for k in range(n):
                T[iw + c, k] -= H[k]
    euler_matrices(x[6], x[7], x[8], R, S, W)
    for a in range(3):
        x[I_V + a] = R[0, a] * values[0] + R[1, a] * values[1] + R[2, a] * values[2]
    u, v, w = x[I_V], x[I_V + 1], x[I_V + 2]
    for a in range(3):
        for k in range(n):
            T[I_V + a, k] = 0.0
    for t in range(3):  # J = [V]x W
        T[I_V, I_TH + t] = -w * W[1, t] + v * W[2, t]
        T[I_V + 1, I_TH + t] = w * W[0, t] - u * W[2, t]
        T[I_V + 2, I_TH + t] = -v * W[0, t] + u * W[1, t]
    linalg.transform_covariance(P, T, work)
    # + G R_gps G^T, G = [R_nb^T on V; I (north, east) on the moved wind]
    for a in range(3):
        for b in range(3):
            P[I_V + a, I_V + b] += (R[0, a] * variances[0] * R[0, b] + R[1, a] * variances[1] * R[1, b]
                                    + R[2, a] * variances[2] * R[2, b])
        if move_wind:
            for c in range(2):
                P[I_V + a, iw + c] += R[c, a] * variances[c]
                P[iw + c, I_V + a] += R[c, a] * variances[c]
    if move_wind:
        for c in range(2):
            P[iw + c, iw + c] += variances[c]


@njit(cache=True)
def _output_row(x, P, layout, field, no_values, R, S, W, H, t, out):
    """Fill one output row (:data:`OUT_COLUMNS`); ``no_values`` (N_EVENT_VALUES,) stands for the event values
    that the NED-velocity model (GPS_VEL components 0..2) does not read."""
    out[0] = t
    for i in range(3):
        out[1 + i] = x[6 + i]
        out[4 + i] = x[i]
        out[12 + i] = math.sqrt(max(P[6 + i, 6 + i], 0.0))
        out[15 + i] = math.sqrt(max(P[i, i], 0.0))
    for c in range(3):
        out[7 + c] = measurement(x, GPS_VEL, c, no_values, field, layout, R, S, W, H)
        var = 0.0
        for i in range(I_V, I_TH + 3):  # the NED velocity depends on V and Theta only
            for jj in range(I_V, I_TH + 3):
                var += H[i] * P[i, jj] * H[jj]
        out[18 + c] = math.sqrt(max(var, 0.0))
    iw = layout[L_W]
    for c in range(2):
        if iw >= 0:
            out[10 + c] = x[iw + c]
            out[21 + c] = math.sqrt(max(P[iw + c, iw + c], 0.0))
        else:
            out[10 + c] = math.nan
            out[21 + c] = math.nan


# ----------------------------------------------------------------------------------------------------------------
# orchestration


@dataclass(frozen=True)
class KernelInputs:
    """Arrays handed to :func:`run_kernel` (and to the NumPy twin)."""

    table: tuple[StateSpec, ...]
    x0: np.ndarray
    P0: np.ndarray
    layout: np.ndarray
    params: np.ndarray
    gates: np.ndarray
    rw_var: np.ndarray
    min_var: np.ndarray
    max_var: np.ndarray


def kernel_inputs(inputs: ReplayInputs, config: EstimatorConfig, *, mode: str = "direct") -> KernelInputs:
    """State table, x0, P0 and the scalar parameters of one run."""
    if mode not in ("direct", "paper_indirect"):
        raise ValueError(f"mode must be 'direct' or 'paper_indirect', got {mode!r}")
    plan, align = inputs.plan, inputs.alignment
    # without GPS the accelerometer bias has no absolute velocity reference: not estimated (math note 7.3)
    table = state_table(config, accel_bias=config.accel_bias_states and plan.has_gps, wind=plan.has_airspeed,
                        mag_bias=plan.has_mag and config.mag_bias_states,
                        baro_bias=plan.has_baro and plan.has_gps and config.baro_bias_state,
                        absolute_yaw=align.yaw_source != "none" or plan.has_sun)
    names = [s.name for s in table]
    n = len(table)
    x0 = np.zeros(n)
    x0[I_P:I_P + 3] = align.position_ned_m
    r_nb = euler_to_matrix(align.roll_rad, align.pitch_rad, align.yaw_rad)
    x0[I_V:I_V + 3] = r_nb.T @ align.velocity_ned_m_s
    x0[I_TH:I_TH + 3] = align.roll_rad, align.pitch_rad, align.yaw_rad
    x0[I_BG:I_BG + 3] = align.gyro_bias_rad_s
    P0 = initial_covariance(table)
    rw_var = random_walk_psd(table)
    params = shared_params(inputs, config, N_PARAMS)
    params[P_PAPER_INDIRECT] = 1.0 if mode == "paper_indirect" else 0.0
    max_var = np.full(n, 1e12)
    max_var[names.index("yaw")] = math.pi ** 2  # yaw std capped at 180 deg (math note 7.2)
    return KernelInputs(table=table, x0=x0, P0=P0, layout=layout_of(table), params=params, gates=gates_per_kind(config),
                        rw_var=rw_var, min_var=np.full(n, MIN_VARIANCE), max_var=max_var)


def run(flight_log: FlightLog, inputs: ReplayInputs, config: EstimatorConfig, *, backend: str = "numba",
        mode: str = "direct") -> EstimatorRun:
    """Run the full-state direct filter on prepared inputs (the registry entry of :mod:`estimators.api`).

    Parameters
    ----------
    flight_log : FlightLog
        The log (unused beyond ``inputs``; part of the common estimator signature).
    inputs : ReplayInputs
        From :func:`estimators.inputs.build.build_replay_inputs`.
    config : EstimatorConfig
    backend : {"numba", "numpy"}
        Compiled kernel or the plain-NumPy twin (slow; tests only).
    mode : {"direct", "paper_indirect"}
        See the module docstring.
    """
    del flight_log
    started = time.perf_counter()
    k = kernel_inputs(inputs, config, mode=mode)
    ev, imu = inputs.events, inputs.imu
    n = len(k.x0)
    n_out = ev.count(OUTPUT)
    out_f = np.full((n_out, len(OUT_COLUMNS)), np.nan)
    out_x = np.full((n_out, n), np.nan)
    out_sx = np.full((n_out, n), np.nan)
    diag_f, diag_i = recorder.diagnostics_arrays(diagnostics_capacity(ev))
    counters = np.zeros(N_COUNTERS, dtype=np.int64)
    args = (imu.time_s, imu.gyro_rad_s, imu.accel_m_s2, ev.time_s, ev.kind, ev.imu_index, ev.values, ev.variances,
            k.x0, k.P0, k.layout, k.params, k.gates, k.rw_var, k.min_var, k.max_var, out_f, out_x, out_sx, diag_f,
            diag_i, counters)
    kernel_started = time.perf_counter()
    if backend == "numba":
        x_final, _ = run_kernel(*args)
    elif backend == "numpy":
        from estimators.direct.reference import run_reference

        x_final, _ = run_reference(*args)
    else:
        raise ValueError(f"backend must be 'numba' or 'numpy', got {backend!r}")
    kernel_s = time.perf_counter() - kernel_started
    return _assemble(inputs, k, out_f, out_x, out_sx, diag_f, diag_i, counters, x_final,
                     timings={"kernel": kernel_s, "total": time.perf_counter() - started}, mode=mode,
                     config_accel_bias=config.accel_bias_states)


def _assemble(inputs, k: KernelInputs, out_f, out_x, out_sx, diag_f, diag_i, counters, x_final, *, timings, mode,
              config_accel_bias):
    plan = inputs.plan
    col = {c: i for i, c in enumerate(OUT_COLUMNS)}
    o = out_f[:counters[C_OUTPUTS]]
    deg = np.degrees
    std = {"roll_deg_std": deg(o[:, col["roll_std"]]), "pitch_deg_std": deg(o[:, col["pitch_std"]]),
           "yaw_deg_std": deg(o[:, col["yaw_std"]]), "pos_n_m_std": o[:, col["pn_std"]],
           "pos_e_m_std": o[:, col["pe_std"]], "alt_m_std": o[:, col["pd_std"]],
           "vn_m_s_std": o[:, col["vn_std"]], "ve_m_s_std": o[:, col["ve_std"]], "vd_m_s_std": o[:, col["vd_std"]],
           "wind_n_m_s_std": o[:, col["wn_std"]], "wind_e_m_s_std": o[:, col["we_std"]]}
    states = states_frame(o[:, col["time_s"]], o[:, col["roll"]], o[:, col["pitch"]], o[:, col["yaw"]],
                          o[:, col["pn"]:col["pd"] + 1], o[:, col["vn"]:col["vd"] + 1],
                          o[:, col["wn"]:col["we"] + 1], inputs.origin, std=std, navigation=plan.has_gps,
                          wind=plan.has_airspeed, height=plan.has_baro or plan.has_gps)
    diagnostics = diagnostics_frame(diag_f, diag_i, int(counters[C_DIAG]))
    names = [s.name for s in k.table]
    warnings = []
    if counters[C_PITCH_GUARD]:
        warnings.append(f"{counters[C_PITCH_GUARD]} updates skipped at |pitch| > 85 deg (Euler singularity)")
    details = {
        "mode": mode,
        "states": names,
        "final_state": {name: float(x_final[i]) for i, name in enumerate(names)},
        **replay_details(inputs),
        "final_state_std": {name: float(out_sx[counters[C_OUTPUTS] - 1, i]) if counters[C_OUTPUTS] else math.nan
                            for i, name in enumerate(names)},
    }
    report = kernel_report(NAME, inputs, counters, timings_s=timings, details=details, warnings=warnings,
                           degradations=accel_bias_degradations(plan, "bax" in names, config_accel_bias))
    return EstimatorRun(states=states, diagnostics=diagnostics, report=report)
