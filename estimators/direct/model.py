"""Model of the full-state direct filter: state layout, process model ``f``, its Jacobian ``A``, process noise ``Q``
and the RK4 state propagation (paper section 3.2 with the corrected eqs 36-37, docs/direct.md, 'Process model').

State vector ``x`` (the named table of :func:`state_table`; optional blocks are present only when they help,
docs/direct.md, 'State vector'):

=========  ======  ===============================================================================
name       unit    meaning
=========  ======  ===============================================================================
pn pe pd   m       position NED relative to the origin (down = -(alt - alt0))
u v w      m/s     ground velocity in body FRD axes
roll ...   rad     ZYX Euler angles phi, theta, psi (R_nb = Rz(psi) Ry(theta) Rx(phi))
bgx ...    rad/s   gyro bias (gyro = omega + b_g + noise)
bax ...    m/s^2   accelerometer bias (optional, ``accel_bias_states``)
wn we      m/s     wind north/east, velocity of the air mass (only with an airspeed sensor)
bmx ...    -       magnetometer hard-iron bias in units of the field strength (only with the magnetometer)
bb         m       barometer offset against GPS height (only with barometer and GPS)
=========  ======  ===============================================================================

Process model (corrected eq 36, docs/direct.md, 'Corrections to the paper'), inputs ``omega_hat = gyro - b_g``,
``f_hat = accel - b_a``: ``p_dot = R_nb V``, ``V_dot = V x omega_hat + f_hat + R_nb^T g_n``,
``Theta_dot = S_euler(Theta) omega_hat``; biases and wind are random walks. Jacobian ``A`` (eq 37) and noise
``Qc = G_g N_g^2 G_g^T + G_a N_a^2 G_a^T + diag(random walks)``, ``G_g = [0; -[V]x; -S_euler; 0]``,
``G_a = [0; -I; 0; 0]``. ``W_euler = S_euler^-1`` maps Euler-angle rates to body rates (``omega = W_euler
Theta_dot``).

Every function below the state table is a small ``numba`` leaf working on preallocated arrays; the scratch
matrices ``R_nb``, ``S_euler``, ``W_euler`` (3, 3) are filled by :func:`euler_matrices`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from estimators.config import EstimatorConfig
from estimators.core import rotations
from estimators.core.state_table import StateSpec

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
# model leaf functions (numba)


@njit(cache=True)
def euler_matrices(phi, theta, psi, R_nb, S_euler, W_euler):
    """Fill ``R_nb`` (body -> NED), ``S_euler`` (``Theta_dot = S_euler omega``) and ``W_euler = S_euler^-1``
    for the ZYX Euler angles ``phi, theta, psi`` [rad] (docs/direct.md, 'State vector')."""
    cph, sph = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    cps, sps = math.cos(psi), math.sin(psi)
    R_nb[0, 0] = cth * cps
    R_nb[0, 1] = sph * sth * cps - cph * sps
    R_nb[0, 2] = cph * sth * cps + sph * sps
    R_nb[1, 0] = cth * sps
    R_nb[1, 1] = sph * sth * sps + cph * cps
    R_nb[1, 2] = cph * sth * sps - sph * cps
    R_nb[2, 0] = -sth
    R_nb[2, 1] = sph * cth
    R_nb[2, 2] = cph * cth
    tth = sth / cth
    S_euler[0, 0] = 1.0
    S_euler[0, 1] = sph * tth
    S_euler[0, 2] = cph * tth
    S_euler[1, 0] = 0.0
    S_euler[1, 1] = cph
    S_euler[1, 2] = -sph
    S_euler[2, 0] = 0.0
    S_euler[2, 1] = sph / cth
    S_euler[2, 2] = cph / cth
    W_euler[0, 0] = 1.0
    W_euler[0, 1] = 0.0
    W_euler[0, 2] = -sth
    W_euler[1, 0] = 0.0
    W_euler[1, 1] = cph
    W_euler[1, 2] = sph * cth
    W_euler[2, 0] = 0.0
    W_euler[2, 1] = -sph
    W_euler[2, 2] = cph * cth


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
    return gyro[0] - x[I_BG], gyro[1] - x[I_BG + 1], gyro[2] - x[I_BG + 2], f0, f1, f2


@njit(cache=True)
def dynamics(x, om0, om1, om2, f0, f1, f2, g, R_nb, S_euler, W_euler, xdot):
    """Derivatives of the :data:`N_DYNAMIC` states with dynamics (position, body velocity, Euler angles) for
    the bias-corrected inputs (:func:`corrected_inputs`); reads ``x[:9]``, writes ``xdot[:9]`` only."""
    euler_matrices(x[6], x[7], x[8], R_nb, S_euler, W_euler)
    u, v, w = x[3], x[4], x[5]
    for i in range(3):
        xdot[i] = R_nb[i, 0] * u + R_nb[i, 1] * v + R_nb[i, 2] * w
    xdot[3] = v * om2 - w * om1 + f0 + g * R_nb[2, 0]
    xdot[4] = w * om0 - u * om2 + f1 + g * R_nb[2, 1]
    xdot[5] = u * om1 - v * om0 + f2 + g * R_nb[2, 2]
    for i in range(3):
        xdot[6 + i] = S_euler[i, 0] * om0 + S_euler[i, 1] * om1 + S_euler[i, 2] * om2


@njit(cache=True)
def derivative(x, gyro, accel, g, layout, R_nb, S_euler, W_euler, xdot):
    """Continuous dynamics ``xdot = f(x, u)`` (corrected eq 36) for held IMU inputs ``gyro`` [rad/s],
    ``accel`` [m/s^2] (body FRD); the bias, wind and offset states are random walks (zero derivative)."""
    for i in range(x.shape[0]):
        xdot[i] = 0.0
    om0, om1, om2, f0, f1, f2 = corrected_inputs(x, gyro, accel, layout)
    dynamics(x, om0, om1, om2, f0, f1, f2, g, R_nb, S_euler, W_euler, xdot)


@njit(cache=True)
def jacobian(x, gyro, g, layout, R_nb, S_euler, W_euler, A):
    """Continuous Jacobian ``A = df/dx`` (eq 37 corrected, docs/direct.md, 'Process model') at ``x`` with gyro
    input ``gyro``.

    Only the rows of position, velocity and attitude are written (the bias, wind and offset states have no
    dynamics): ``A`` must be zero elsewhere (allocate it with ``np.zeros`` and reuse it).
    """
    euler_matrices(x[6], x[7], x[8], R_nb, S_euler, W_euler)
    p, q, r = gyro[0] - x[I_BG], gyro[1] - x[I_BG + 1], gyro[2] - x[I_BG + 2]
    u, v, w = x[3], x[4], x[5]
    # dp/dV = R_nb; dp/dTheta = -R_nb [V]x W_euler
    for i in range(3):
        for j in range(3):
            A[i, 3 + j] = R_nb[i, j]
    # [V]x W_euler: column j = V x W_euler[:, j]
    for j in range(3):
        c0 = v * W_euler[2, j] - w * W_euler[1, j]
        c1 = w * W_euler[0, j] - u * W_euler[2, j]
        c2 = u * W_euler[1, j] - v * W_euler[0, j]
        for i in range(3):
            A[i, 6 + j] = -(R_nb[i, 0] * c0 + R_nb[i, 1] * c1 + R_nb[i, 2] * c2)
    # dV/dV = -[omega]x
    A[3, 4] = r
    A[3, 5] = -q
    A[4, 3] = -r
    A[4, 5] = p
    A[5, 3] = q
    A[5, 4] = -p
    # dV/dTheta = [R_nb^T g_n]x W_euler, R_nb^T g_n = g R_nb[2, :]
    a0, a1, a2 = g * R_nb[2, 0], g * R_nb[2, 1], g * R_nb[2, 2]
    for j in range(3):
        A[3, 6 + j] = a1 * W_euler[2, j] - a2 * W_euler[1, j]
        A[4, 6 + j] = a2 * W_euler[0, j] - a0 * W_euler[2, j]
        A[5, 6 + j] = a0 * W_euler[1, j] - a1 * W_euler[0, j]
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
    # dTheta/dTheta (eq 37), dTheta/db_g = -S_euler
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
            A[6 + i, 9 + j] = -S_euler[i, j]


@njit(cache=True)
def process_noise(x, gyro_psd, accel_psd, walk_psd, dt, R_nb, S_euler, W_euler, Qd):
    """Discrete process noise ``Qd = (G_g N_g^2 G_g^T + G_a N_a^2 G_a^T + diag(walk_psd)) dt`` (white-noise
    densities, variance ``density^2 dt``; docs/direct.md, 'Process model').

    ``gyro_psd``, ``accel_psd``: the IMU noise densities squared; ``walk_psd`` (n,) the squared random-walk
    densities of the bias and wind states (0 elsewhere). Only the diagonal and the velocity/attitude block are
    written: ``Qd`` must be zero elsewhere (allocate it with ``np.zeros`` and reuse it).
    """
    n = x.shape[0]
    euler_matrices(x[6], x[7], x[8], R_nb, S_euler, W_euler)
    for i in range(n):
        Qd[i, i] = walk_psd[i] * dt
    u, v, w = x[3], x[4], x[5]
    vv2 = u * u + v * v + w * w
    for i in range(3):
        vi = x[3 + i]
        for j in range(3):
            # [V]x [V]x^T = |V|^2 I - V V^T; column j of [V]x S_euler^T = V x S_euler[j, :]
            vv = (vv2 if i == j else 0.0) - vi * x[3 + j]
            if i == 0:
                vt = v * S_euler[j, 2] - w * S_euler[j, 1]
            elif i == 1:
                vt = w * S_euler[j, 0] - u * S_euler[j, 2]
            else:
                vt = u * S_euler[j, 1] - v * S_euler[j, 0]
            tt = S_euler[i, 0] * S_euler[j, 0] + S_euler[i, 1] * S_euler[j, 1] + S_euler[i, 2] * S_euler[j, 2]
            Qd[3 + i, 3 + j] = (gyro_psd * vv + (accel_psd if i == j else 0.0)
                                + (walk_psd[3 + i] if i == j else 0.0)) * dt
            Qd[3 + i, 6 + j] = gyro_psd * vt * dt
            Qd[6 + j, 3 + i] = gyro_psd * vt * dt
            Qd[6 + i, 6 + j] = (gyro_psd * tt + (walk_psd[6 + i] if i == j else 0.0)) * dt


@njit(cache=True)
def propagate_state(x, gyro, accel, dt, g, layout, R_nb, S_euler, W_euler, k1, k2, k3, k4, xt):
    """RK4 step of the state over ``dt`` [s] with the IMU input held; roll and yaw wrapped to [-pi, pi).

    Only the :data:`N_DYNAMIC` states with dynamics are integrated (the others have zero derivative, so RK4
    leaves them unchanged exactly) and the bias-corrected input is formed once: the biases are constant over the
    step. ``k1`` .. ``k4``, ``xt`` (n,) scratch."""
    om0, om1, om2, f0, f1, f2 = corrected_inputs(x, gyro, accel, layout)
    dynamics(x, om0, om1, om2, f0, f1, f2, g, R_nb, S_euler, W_euler, k1)
    for i in range(N_DYNAMIC):
        xt[i] = x[i] + 0.5 * dt * k1[i]
    dynamics(xt, om0, om1, om2, f0, f1, f2, g, R_nb, S_euler, W_euler, k2)
    for i in range(N_DYNAMIC):
        xt[i] = x[i] + 0.5 * dt * k2[i]
    dynamics(xt, om0, om1, om2, f0, f1, f2, g, R_nb, S_euler, W_euler, k3)
    for i in range(N_DYNAMIC):
        xt[i] = x[i] + dt * k3[i]
    dynamics(xt, om0, om1, om2, f0, f1, f2, g, R_nb, S_euler, W_euler, k4)
    for i in range(N_DYNAMIC):
        x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    x[6] = rotations.wrap_pi(x[6])
    x[8] = rotations.wrap_pi(x[8])
