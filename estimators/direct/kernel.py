"""Compiled loop of the full-state direct EKF (paper section 3.2): :func:`run_kernel` executes the schedule of
:func:`estimators.core.schedule.build_schedule` (docs/estimators.md, 'Scheduling rule') on the model of
:mod:`estimators.direct.model` and the measurements of :mod:`estimators.direct.measurements`.

* ``PROPAGATE``: RK4 step of the state over the step with the IMU row held; the inputs are summed for the
  covariance.
* ``COVARIANCE``: ``P <- F P F^T + Qd`` over the time summed since the last one, ``F = I + A dt + (A dt)^2/2``
  and ``Qd = Qc dt`` with ``A`` at the state that started the interval and the mean IMU input over it
  (:func:`_flush_covariance`); variance limits, the scheduled positive-definiteness repair, and the health check
  (a non-finite state or covariance resets the filter to the last output's state and ``P0``). The schedule puts
  one before every measurement update, so every update sees the covariance at its own time.
* ``EVENT``: an output row (:data:`OUT_COLUMNS`) or a measurement: sequential scalar updates in Joseph form,
  re-linearised after each scalar, gated per sensor; every scalar update is recorded
  (:mod:`estimators.core.recorder`). Attitude-dependent updates stop above :data:`PITCH_GUARD_RAD` (Euler
  singularity). Control apart from fusion (docs/direct.md, 'Control and fusion'): the GPS re-acquisition rule
  (:func:`estimators.core.reacquisition.gps_control`, docs/estimators.md, 'GPS re-acquisition') and
  :func:`wind_control` decide whether an event resets states (:func:`reset_to_gps`, :func:`initialise_wind`)
  instead of being fused by :func:`_fuse`.

Filter quantities (kernel arrays): ``x`` (n,) state, ``P`` (n, n) covariance (prior before, posterior after an
update), ``nu`` innovation, ``s_var`` innovation variance, ``K = P H^T / s_var`` gain, ``NIS = nu^2 / s_var``,
``r_var`` measurement noise variance.

``DirectSettings.paper_indirect`` runs the paper's indirect filter literally (eqs 44-49 corrected,
docs/direct.md, 'Corrections to the paper'): an additive error state in the same coordinates, propagated with
the same ``A`` (it stays zero between updates), estimated over each sensor's group of scalar updates with ``H``
and ``h`` at the uncorrected prior, and injected (reset) after the group. It equals the direct filter exactly for
linear measurement models and to second order otherwise.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from estimators.core import linalg, reacquisition, recorder, rotations
from estimators.core.full_state import (
    EIG_FLOOR,
    MAG_HEADING,
    PD_CHECK_EVERY,
    adapt_wind_walk,
    component_range,
    current_walk,
    held_wind_walk,
    scalar_innovation,
    scaled_wind_walk,
    wind_adaptation,
    wind_observed,
    wind_walk_scale,
)
from estimators.core.recorder import (
    C_DIAG,
    C_OUTPUTS,
    C_REPAIRS,
    C_RESETS,
    C_UPDATES,
    C_WIND_INITS,
    N_SHARED_COUNTERS,
    Recorder,
)
from estimators.core.schedule import COVARIANCE, EVENT, PROPAGATE
from estimators.direct import model
from estimators.direct.measurements import h_gps_velocity, mag_heading, measurement
from estimators.direct.model import I_P, I_TH, I_V, L_BM, L_W, N_DYNAMIC, euler_matrices
from estimators.inputs.records import AIRSPEED, BARO, GPS_POS, GPS_VEL, MAG, OUTPUT, SIDESLIP, SUN
from estimators.sun.measurement import sun_tangent_basis, tangent_projection

#: Columns of the kernel's per-epoch output array.
OUT_COLUMNS = ("time_s", "roll", "pitch", "yaw", "pn", "pe", "pd", "vn", "ve", "vd", "wn", "we",
               "roll_std", "pitch_std", "yaw_std", "pn_std", "pe_std", "pd_std", "vn_std", "ve_std", "vd_std",
               "wn_std", "we_std")
# counters: the shared slots of estimators.core.recorder (C_DIAG .. C_OUTPUTS), then this filter's
C_PITCH_GUARD = N_SHARED_COUNTERS
C_FLUSHES = N_SHARED_COUNTERS + 1
N_COUNTERS = N_SHARED_COUNTERS + 2

#: Euler-angle filters stop attitude-dependent updates above this pitch [rad].
PITCH_GUARD_RAD = math.radians(85.0)


class DirectSettings(NamedTuple):
    """Scalars and small arrays of one run, read by the compiled kernel (units in the names).

    The first ten fields are those both full-state filters share
    (:func:`estimators.core.full_state.shared_settings`); the rest are this filter's.
    """

    gravity_m_s2: float
    gyro_psd: float  # gyro white-noise density squared [rad^2/s]
    accel_psd: float  # accelerometer white-noise density squared [m^2/s^3]
    covariance_dt_s: float  # covariance propagation interval of the schedule [s]
    field_ned: np.ndarray  # (3,) unit earth field NED
    gps_reject_s: float  # a GPS component rejected this long -> position/velocity reset [s]
    gps_outage_s: float  # GPS back after an outage this long -> position/velocity reset [s]
    min_ground_speed_m_s: float  # no course updates below this GPS ground speed (paper mode)
    paper_gps_velocity: bool  # GPS velocity as ground speed and course
    mag_heading: bool  # the magnetometer fused as its heading (else its three axes)
    gates: np.ndarray  # (n_kinds,) scalar gate per event kind (inf: ungated)
    x0: np.ndarray  # (n,) initial state
    P0: np.ndarray  # (n, n) initial covariance (also the covariance of a divergence reset)
    layout: np.ndarray  # int64 (N_LAYOUT,) optional blocks (estimators.direct.model.layout_of)
    walk_psd: np.ndarray  # (n,) random-walk densities squared (0 for the states with dynamics)
    min_var: np.ndarray  # (n,) variance floor
    max_var: np.ndarray  # (n,) variance cap
    paper_indirect: bool  # paper-literal indirect filter (group error state, reset after the group)


@njit(cache=True)
def reset_to_gps(x, P, kind, values, variances, layout, move_wind, R_nb, S_euler, W_euler, H, T, work):
    """GPS re-acquisition (docs/estimators.md, 'GPS re-acquisition'): the position (``kind == GPS_POS``) or the
    velocity to the GPS value.

    Position: ``p = z``, covariance ``diag(R_gps)``, no correlation with the other states.

    Velocity: the NED velocity becomes the GPS value ``v``, its error the GPS noise, uncorrelated with the other
    states; the body state is ``V = R_nb^T v``, so ``dV = R_nb^T dv + J dTheta`` with ``J = [V]x W_euler``
    (zeroing the body-axis cross-covariances instead would correlate the NED velocity with the attitude).
    ``move_wind`` (wind states present and the last airspeed update accepted, i.e. the filter's air-relative
    velocity agrees with the airspeed): the wind moves with the ground velocity, ``w += v - R_nb V_old`` (north,
    east), so the air-relative velocity is kept; otherwise the wind, fitted to the rejected velocity, would make
    the airspeed updates fail after the reset. The covariance follows the same linear map,
    ``e' = T e + G n``: ``P <- T P T^T + G R_gps G^T``.

    ``layout`` as :func:`estimators.direct.model.layout_of`; ``H`` (n,), ``T`` and ``work`` (n, n) scratch.
    """
    n = x.shape[0]
    if kind == GPS_POS:
        for a in range(3):
            x[I_P + a] = values[a]
            for b in range(3):
                work[a, b] = 0.0
            work[a, a] = variances[a]
        linalg.reset_covariance_block(P, int(I_P), work[:3, :3])  # int(), a slice: as the wind's (one compile)
        return
    for i in range(n):
        for k in range(n):
            T[i, k] = 0.0
        T[i, i] = 1.0
    iw = layout[L_W]
    if move_wind:
        for c in range(2):
            h = h_gps_velocity(x, c, R_nb, S_euler, W_euler, H)
            x[iw + c] += values[c] - h
            for k in range(n):
                T[iw + c, k] -= H[k]
    euler_matrices(x[I_TH], x[I_TH + 1], x[I_TH + 2], R_nb, S_euler, W_euler)
    for a in range(3):
        x[I_V + a] = R_nb[0, a] * values[0] + R_nb[1, a] * values[1] + R_nb[2, a] * values[2]
    u, v, w = x[I_V], x[I_V + 1], x[I_V + 2]
    for a in range(3):
        for k in range(n):
            T[I_V + a, k] = 0.0
    for t in range(3):  # J = [V]x W_euler
        T[I_V, I_TH + t] = -w * W_euler[1, t] + v * W_euler[2, t]
        T[I_V + 1, I_TH + t] = w * W_euler[0, t] - u * W_euler[2, t]
        T[I_V + 2, I_TH + t] = -v * W_euler[0, t] + u * W_euler[1, t]
    linalg.transform_covariance(P, T, work)
    # + G R_gps G^T, G = [R_nb^T on V; I (north, east) on the moved wind]
    for a in range(3):
        for b in range(3):
            P[I_V + a, I_V + b] += (R_nb[0, a] * variances[0] * R_nb[0, b] + R_nb[1, a] * variances[1] * R_nb[1, b]
                                    + R_nb[2, a] * variances[2] * R_nb[2, b])
        if move_wind:
            for c in range(2):
                P[I_V + a, iw + c] += R_nb[c, a] * variances[c]
                P[iw + c, I_V + a] += R_nb[c, a] * variances[c]
    if move_wind:
        for c in range(2):
            P[iw + c, iw + c] += variances[c]


@njit(cache=True)
def initialise_wind(x, P, airspeed_m_s, layout, P0, R_nb, S_euler, W_euler, block):
    """Wind from the airspeed (docs/estimators.md, 'Wind initialisation'): the air flows along the body x axis at
    the measured true airspeed, so the horizontal wind is the NED ground velocity minus ``airspeed * R_nb e_x``
    (north, east); its covariance is the initial wind covariance, uncorrelated with the other states.

    ``layout`` as :func:`estimators.direct.model.layout_of` (wind states present); ``block`` (2, 2) scratch.
    """
    iw = layout[L_W]
    euler_matrices(x[I_TH], x[I_TH + 1], x[I_TH + 2], R_nb, S_euler, W_euler)
    for c in range(2):
        ground = R_nb[c, 0] * x[I_V] + R_nb[c, 1] * x[I_V + 1] + R_nb[c, 2] * x[I_V + 2]
        x[iw + c] = ground - airspeed_m_s * R_nb[c, 0]
        for d in range(2):
            block[c, d] = P0[iw + c, iw + d]
    linalg.reset_covariance_block(P, iw, block)


@njit(cache=True)
def air_flows_backwards(x, layout, R_nb, S_euler, W_euler) -> bool:
    """The estimated air velocity's body-x component ``(V - R_nb^T wbar)_x`` is negative (the mirrored solution of
    airspeed magnitude and sideslip)."""
    iw = layout[L_W]
    euler_matrices(x[I_TH], x[I_TH + 1], x[I_TH + 2], R_nb, S_euler, W_euler)
    return x[I_V] - (R_nb[0, 0] * x[iw] + R_nb[1, 0] * x[iw + 1]) < 0.0


@njit(cache=True)
def _output_row(x, P, layout, R_nb, S_euler, W_euler, H, t, out):
    """Fill one output row (:data:`OUT_COLUMNS`): attitude, position, NED velocity ``R_nb V`` and wind with
    their standard deviations (the velocity's from ``H P H^T`` of its model)."""
    out[0] = t
    for i in range(3):
        out[1 + i] = x[I_TH + i]
        out[4 + i] = x[I_P + i]
        out[12 + i] = math.sqrt(max(P[I_TH + i, I_TH + i], 0.0))
        out[15 + i] = math.sqrt(max(P[I_P + i, I_P + i], 0.0))
    for c in range(3):
        out[7 + c] = h_gps_velocity(x, c, R_nb, S_euler, W_euler, H)
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


@njit(cache=True)
def _flush_covariance(P, x_cov, acc, settings, walk_psd, R_nb, S_euler, W_euler, A, F, Qd, work, mean_gyro,
                      columns, F_values, F_cols, F_counts, counters):
    """Propagate P over the accumulated interval ``acc[0]`` with the mean inputs ``acc[1:7] / acc[0]`` from the
    state ``x_cov`` that started it (random walks ``walk_psd``: ``settings.walk_psd``, or its held-wind copy);
    then the variance limits and the scheduled repair.

    Scratch: ``mean_gyro`` (3,); ``columns`` = ``arange(n)`` and the sparse dynamic rows of F ``F_values``,
    ``F_cols`` (N_DYNAMIC, n), ``F_counts`` (N_DYNAMIC,) (:func:`estimators.core.linalg.sparse_rows`)."""
    n = P.shape[0]
    dt = acc[0]
    for i in range(3):
        mean_gyro[i] = acc[1 + i] / dt
    model.jacobian(x_cov, mean_gyro, settings.gravity_m_s2, settings.layout, R_nb, S_euler, W_euler, A)
    linalg.transition_matrix(A, dt, F)
    model.process_noise(x_cov, settings.gyro_psd, settings.accel_psd, walk_psd, dt, R_nb, S_euler, W_euler, Qd)
    linalg.sparse_rows(F, columns, F_values, F_cols, F_counts)
    linalg.propagate_sparse(P, F_values, F_cols, F_counts, work)
    for i in range(n):  # + Qd, where it is not zero: the diagonal and the velocity/attitude block
        P[i, i] += Qd[i, i]
    for i in range(I_V, I_TH + 3):
        for j in range(I_V, I_TH + 3):
            if i != j:
                P[i, j] += Qd[i, j]
    counters[C_FLUSHES] += 1
    if linalg.scheduled_repair(P, settings.min_var, settings.max_var, work, EIG_FLOOR,
                               counters[C_FLUSHES], PD_CHECK_EVERY):
        counters[C_REPAIRS] += 1
    for i in range(7):
        acc[i] = 0.0


class FusionWork(NamedTuple):
    """Work arrays of the measurement control and fusion (``n`` states)."""

    R_nb: np.ndarray  # (3, 3) body-to-NED rotation of the current attitude (scratch)
    S_euler: np.ndarray  # (3, 3) Euler-rate matrices of the current attitude (scratch)
    W_euler: np.ndarray  # (3, 3)
    H: np.ndarray  # (n,) measurement row
    H3: np.ndarray  # (3, n) sun rows
    h3: np.ndarray  # (3,) predicted sun vector
    dx: np.ndarray  # (n,) correction of one scalar update
    ph: np.ndarray  # (n,) P H^T
    x_err: np.ndarray  # (n,) error state of a paper-indirect group


class DirectWork(NamedTuple):
    """Preallocated work arrays of :func:`run_kernel` (``n`` states): the loop allocates nothing per sample."""

    fusion: FusionWork
    x_safe: np.ndarray  # (n,) the last output's state (divergence reset)
    x_cov: np.ndarray  # (n,) state at the start of the accumulated covariance interval
    acc: np.ndarray  # (7,) dt, sum gyro dt, sum accel dt since the last covariance propagation
    mean_gyro: np.ndarray  # (3,) mean gyro of the interval [rad/s]
    A: np.ndarray  # (n, n) continuous Jacobian; jacobian() and process_noise() write their non-zero blocks only
    F: np.ndarray  # (n, n) transition; also the GPS reset transform and the wind-reset block
    Qd: np.ndarray  # (n, n) discrete process noise
    work: np.ndarray  # (n, n) scratch
    k1: np.ndarray  # (n,) RK4 slopes and stage state
    k2: np.ndarray
    k3: np.ndarray
    k4: np.ndarray
    xt: np.ndarray
    columns: np.ndarray  # int64 (n,) arange(n), the sparse rows of F (estimators.core.linalg.sparse_rows)
    F_values: np.ndarray  # (N_DYNAMIC, n)
    F_cols: np.ndarray  # int64 (N_DYNAMIC, n)
    F_counts: np.ndarray  # int64 (N_DYNAMIC,)
    out_row: np.ndarray  # (len(OUT_COLUMNS),) output row scratch


@njit(cache=True)
def _direct_work(x0, n_columns):
    """The work arrays of a run from the initial state ``x0`` with ``n_columns`` output columns."""
    n = x0.shape[0]
    fusion = FusionWork(np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty(n), np.empty((3, n)),
                        np.empty(3), np.empty(n), np.empty(n), np.zeros(n))
    return DirectWork(fusion, x0.copy(), x0.copy(), np.zeros(7), np.empty(3), np.zeros((n, n)), np.empty((n, n)),
                      np.zeros((n, n)), np.empty((n, n)), np.empty(n), np.empty(n), np.empty(n), np.empty(n),
                      np.empty(n), np.arange(n), np.empty((N_DYNAMIC, n)), np.empty((N_DYNAMIC, n), dtype=np.int64),
                      np.empty(N_DYNAMIC, dtype=np.int64), np.empty(n_columns))


# ----------------------------------------------------------------------------------------------------------------
# control: when a measurement is fused, and when states are reset or re-initialised instead (docs/direct.md,
# 'Control and fusion'): attitude_update_allowed, wind_control and the shared GPS rule
# estimators.core.reacquisition.gps_control decide, the loop resets (reset_to_gps, initialise_wind) or fuses
# (_fuse). Every array a numba call receives (loose or in a tuple) costs a reference-count pair per call, so the
# controls take what they decide on and do not wrap the fusion; _fuse is inline="always" (one call site).


@njit(cache=True)
def attitude_update_allowed(x, kind, counters):
    """Updates that depend on the attitude (all but the barometer and the GPS position) run below
    :data:`PITCH_GUARD_RAD` of pitch (Euler singularity); a skipped one is counted (``C_PITCH_GUARD``)."""
    if abs(x[I_TH + 1]) > PITCH_GUARD_RAD and kind != BARO and kind != GPS_POS:
        counters[C_PITCH_GUARD] += 1
        return False
    return True


@njit(cache=True)
def wind_control(x, n_wind_inits, layout, R_nb, S_euler, W_euler):
    """Wind (re)start at an airspeed event (wind states present): at the first airspeed of the flight
    (``n_wind_inits`` = 0), or when the wind has the aircraft flying backwards (:func:`air_flows_backwards`; no
    update can leave that mirrored solution, it fits airspeed and sideslip as well), the wind starts again from
    the airspeed (:func:`initialise_wind`) instead of fusing it."""
    return n_wind_inits == 0 or air_flows_backwards(x, layout, R_nb, S_euler, W_euler)


# ----------------------------------------------------------------------------------------------------------------
# fusion


@njit(cache=True, inline="always")
def _fuse(x, P, kind, values, variances, t, settings, gps_mon, air_ok, w, diag_f, diag_i, counters):
    """The event's sequential scalar updates (see the module docstring), each recorded; GPS components are booked
    in the re-acquisition monitor ``gps_mon``. ``w``: :class:`FusionWork`. Returns the new ``air_ok``."""
    n = x.shape[0]
    layout = settings.layout
    R_nb, S_euler, W_euler, H, H3, h3, x_err = w.R_nb, w.S_euler, w.W_euler, w.H, w.H3, w.h3, w.x_err
    field = settings.field_ned
    paper_indirect = settings.paper_indirect
    gate = settings.gates[kind]
    is_gps = kind in (GPS_POS, GPS_VEL)
    c0, c1 = component_range(kind, values, settings.paper_gps_velocity, settings.min_ground_speed_m_s,
                             settings.mag_heading)
    if kind == SUN:
        # tangent basis of the predicted sun direction at the prior
        for c in range(3):
            h3[c] = measurement(x, kind, c, values, field, layout, R_nb, S_euler, W_euler, H)
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
                    h3[cc] = measurement(x, kind, cc, values, field, layout, R_nb, S_euler, W_euler, H)
                    for i in range(n):
                        H3[cc, i] = H[i]
            nu = tangent_projection(basis, c, values, h3, H3, H)
            r_var = variances[c]
        elif c == MAG_HEADING and kind == MAG:
            nu, r_var = mag_heading(x, values, variances, field, layout[L_BM], R_nb, S_euler, W_euler, H)
            if not math.isfinite(nu):
                continue
        else:
            h = measurement(x, kind, c, values, field, layout, R_nb, S_euler, W_euler, H)
            nu, r_var = scalar_innovation(kind, c, values, variances, h)
        if paper_indirect:
            # eq 49 corrected: innovation of the error state, z - h(x_hat-) - H x_err
            for i in range(n):
                nu -= H[i] * x_err[i]
        accepted, s_var, nis = linalg.scalar_update(P, H, nu, r_var, gate, w.dx, w.ph)
        counters[C_UPDATES] += 1
        recorder.record_update(diag_f, diag_i, counters, t, kind, c, nu, s_var, nis, accepted)
        if is_gps:
            reacquisition.gps_record(gps_mon, kind == GPS_POS, c, t, accepted)
        elif kind == AIRSPEED:
            air_ok = accepted
        if accepted:
            if paper_indirect:
                for i in range(n):
                    x_err[i] += w.dx[i]
            else:
                for i in range(n):
                    x[i] += w.dx[i]
                x[I_TH] = rotations.wrap_pi(x[I_TH])
                x[I_TH + 2] = rotations.wrap_pi(x[I_TH + 2])
    if paper_indirect:
        for i in range(n):
            x[i] += x_err[i]
        x[I_TH] = rotations.wrap_pi(x[I_TH])
        x[I_TH + 2] = rotations.wrap_pi(x[I_TH + 2])
    return air_ok


@njit(cache=True, nogil=True)  # the replays of noise identification run in threads
def run_kernel(imu_gyro, imu_accel, ev_kind, ev_val, ev_var, op, op_dt, op_index, settings, out_f, out_x, out_sx,
               diag_f, diag_i, counters):
    """The full-state direct filter over a whole log (one compiled loop; see the module docstring).

    Parameters
    ----------
    imu_gyro, imu_accel : ndarrays (N, 3)
        IMU rows (:class:`estimators.inputs.records.ImuSamples`) [rad/s], [m/s^2].
    ev_kind, ev_val, ev_var : ndarrays
        Events (:class:`estimators.inputs.records.MeasurementEvents`).
    op, op_dt, op_index : ndarrays (n_ops,)
        The schedule (:func:`estimators.core.schedule.build_schedule`): operation, step or time [s], IMU row or
        event index.
    settings : DirectSettings
    out_f : (K, 23) output per OUTPUT event (:data:`OUT_COLUMNS`); out_x, out_sx : (K, n) state and its std.
    diag_f, diag_i : diagnostics arrays; counters : int64 (N_COUNTERS,).

    Returns
    -------
    x, P : the final state and covariance.
    """
    x = settings.x0.copy()
    P = settings.P0.copy()
    _loop(imu_gyro, imu_accel, ev_kind, ev_val, ev_var, op, op_dt, op_index, settings, x, P,
          _direct_work(x, out_f.shape[1]), out_f, out_x, out_sx, Recorder(diag_f, diag_i, counters))
    return x, P


@njit(cache=True, inline="always")  # compiled once, in run_kernel (a callee linked in is optimised again)
def _loop(imu_gyro, imu_accel, ev_kind, ev_val, ev_var, op, op_dt, op_index, settings, x, P, w, out_f, out_x, out_sx,
          rec):
    """The loop of :func:`run_kernel` over the schedule from the state ``x`` and covariance ``P`` (in place), with
    its work arrays ``w`` (:class:`DirectWork`) and recorder arrays ``rec`` bundled (called once: the bundles are
    unpacked here, so that every operation passes its step the arrays it uses)."""
    P0, layout = settings.P0, settings.layout
    n = x.shape[0]
    fw, x_safe, x_cov, acc, mean_gyro = w.fusion, w.x_safe, w.x_cov, w.acc, w.mean_gyro
    A, F, Qd, work = w.A, w.F, w.Qd, w.work
    R_nb, S_euler, W_euler, H = fw.R_nb, fw.S_euler, fw.W_euler, fw.H
    k1, k2, k3, k4, xt, out_row = w.k1, w.k2, w.k3, w.k4, w.xt, w.out_row
    columns, F_values, F_cols, F_counts = w.columns, w.F_values, w.F_cols, w.F_counts
    diag_f, diag_i, counters = rec
    g = settings.gravity_m_s2
    gps_mon = reacquisition.gps_monitor()
    # bool() / int(): a loop-carried variable started from a literal would compile each callee it reaches twice
    # (docs/estimators.md, 'One compile per function')
    air_ok = bool(False)  # the last airspeed update was accepted (reset_to_gps)
    held_walk = held_wind_walk(settings.walk_psd, layout[L_W])
    wind_nis = wind_adaptation()  # the wind walk follows the turbulence (adapt_wind_walk)
    walk_now = np.empty_like(settings.walk_psd)
    t_now = -math.inf
    t_wind_observed = -math.inf
    n_out = int(0)
    for s in range(op.shape[0]):
        code = op[s]
        if code == PROPAGATE:
            k = op_index[s]
            if acc[0] == 0.0:
                for i in range(n):
                    x_cov[i] = x[i]
            model.propagate_state(x, imu_gyro[k], imu_accel[k], op_dt[s], g, layout, R_nb, S_euler, W_euler, k1, k2,
                                  k3, k4, xt)
            linalg.accumulate_inputs(acc, op_dt[s], imu_gyro[k], imu_accel[k])
        elif code == COVARIANCE:
            if acc[0] > 0.0:
                walk = scaled_wind_walk(current_walk(settings.walk_psd, held_walk, t_now, t_wind_observed),
                                        layout[L_W], wind_walk_scale(wind_nis), walk_now)
                _flush_covariance(P, x_cov, acc, settings, walk, R_nb, S_euler, W_euler, A, F, Qd, work,
                                  mean_gyro, columns, F_values, F_cols, F_counts, counters)
            if not linalg.is_healthy(x, P):
                linalg.reset_filter(x, P, x_safe, P0)
                counters[C_RESETS] += 1
        elif code == EVENT:
            t = op_dt[s]
            j = op_index[s]
            kind = ev_kind[j]
            values, variances = ev_val[j], ev_var[j]
            t_now = t
            t_wind_observed = wind_observed(kind, t, t_wind_observed)
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
                _output_row(x, P, layout, R_nb, S_euler, W_euler, H, t, out_row)
                recorder.record_output(out_f, n_out, out_row)
                if n_out < out_x.shape[0]:
                    for i in range(n):
                        out_x[n_out, i] = x[i]
                        out_sx[n_out, i] = math.sqrt(max(P[i, i], 0.0))
                n_out += 1
            elif attitude_update_allowed(x, kind, counters):
                if kind in (GPS_POS, GPS_VEL) and reacquisition.gps_control(gps_mon, kind, t, settings.gps_reject_s,
                                                                            settings.gps_outage_s, counters):
                    # (re)acquisition: position or velocity to the GPS, the wind moved along when the airspeed agreed
                    reset_to_gps(x, P, kind, values, variances, layout, air_ok and layout[L_W] >= 0, R_nb, S_euler,
                                 W_euler, H, F, work)
                elif kind == AIRSPEED and layout[L_W] >= 0 and wind_control(x, counters[C_WIND_INITS], layout, R_nb,
                                                                            S_euler, W_euler):
                    initialise_wind(x, P, values[0], layout, P0, R_nb, S_euler, W_euler, F[:2, :2])
                    counters[C_WIND_INITS] += 1
                    air_ok = True
                else:
                    first = counters[C_DIAG]
                    air_ok = _fuse(x, P, kind, values, variances, t, settings, gps_mon, air_ok, fw, diag_f, diag_i,
                                   counters)
                    if kind in (AIRSPEED, SIDESLIP):
                        adapt_wind_walk(wind_nis, t, diag_f, diag_i, first, counters[C_DIAG])
    counters[C_OUTPUTS] = n_out
