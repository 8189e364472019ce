"""Full-state indirect filter: the compiled error-state (multiplicative quaternion) EKF loop (paper section 3.3;
docs/indirect.md).

The paper's indirect filter as printed (additive error in the direct filter's coordinates, eqs 44-49) equals the
direct filter (docs/indirect.md, 'Corrections to the paper'). This is the useful error-state filter the paper's
motivation points to (Sola 2017, PX4 EKF2): a nominal state integrated by the kinematics at the IMU rate and a small
error state estimated by the EKF, injected into the nominal and reset to zero after each sensor's group of scalar
updates.

:func:`run_kernel` executes the schedule of :func:`estimators.core.schedule.build_schedule` (docs/estimators.md,
'Scheduling rule'), built once per run by :func:`estimators.indirect.run.run`:

* ``PROPAGATE``: the nominal over the step with the exact exponential map ``q <- q (x) Exp(omega dt)`` and the
  mid-interval attitude for the specific force (:func:`estimators.indirect.model.propagate_nominal`); the inputs
  accumulate for the covariance.
* ``COVARIANCE``: the covariance over the accumulated interval with the exact discrete transition ``F`` of that
  interval and ``Q = F_bg N_g^2/dt F_bg^T + F_ba N_a^2/dt F_ba^T + diag(K^2) dt``, the inputs averaged over the
  interval (docs/indirect.md, 'Process model'); the schedule emits one every ``1 / timing.covariance_rate_hz`` and
  before every measurement update (outputs report the last propagated covariance, at most one covariance interval
  old). Then the divergence check: a non-finite nominal or covariance returns to the last output's nominal state
  and the initial covariance.
* ``EVENT``: an output epoch or a measurement (docs/indirect.md, 'Measurement models'; sequential scalar updates,
  Joseph form and gating of :func:`estimators.core.linalg.scalar_update`; the models in
  :mod:`estimators.indirect.measurements`). Within a group the error estimate accumulates with the linearised
  innovation ``z - h(x_hat) - H dx`` (eq 49 corrected); then ``x_hat <- x_hat (+) dx``, ``P <- G P G^T`` with
  ``G_thth = I - [dtheta/2]x`` and ``dx <- 0`` (docs/indirect.md, 'Injection and reset'; ``inject_scalar``: after
  every scalar). Control apart from fusion (docs/indirect.md, 'Control and fusion'): the GPS (re)acquisition
  rule (:func:`estimators.core.reacquisition.gps_control`, docs/estimators.md, 'GPS re-acquisition') and
  :func:`wind_control` decide whether an event resets the position or velocity (:func:`reset_to_gps`) or
  (re)starts the wind (:func:`initialise_wind`) instead of the fusion :func:`_fuse`.

Filter quantities (kernel arrays): ``x`` (NX,) nominal state, ``P`` (n, n) error covariance over the active error
states ``sel`` (prior before, posterior after an update), ``nu`` innovation, ``S`` innovation variance,
``K = P H^T / S``, ``NIS = nu^2 / S``; every scalar update is recorded (:mod:`estimators.core.recorder`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from estimators.core import linalg, reacquisition, recorder
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
from estimators.indirect import model as m
from estimators.indirect.measurements import mag_heading, measurement
from estimators.inputs.records import AIRSPEED, GPS_POS, GPS_VEL, MAG, OUTPUT, SIDESLIP, SUN
from estimators.sun.measurement import sun_tangent_basis, tangent_projection

# counters: the shared slots of estimators.core.recorder (C_DIAG .. C_OUTPUTS), then this filter's
C_FLUSHES = N_SHARED_COUNTERS  # covariance propagations
N_COUNTERS = N_SHARED_COUNTERS + 1

#: Columns of the kernel's per-epoch output (then the error-state std of the active states and the attitude
#: error covariances xy, xz, yz).
OUT_COLUMNS = ("time_s", *(f"x{i}" for i in range(m.NX)))


class IndirectSettings(NamedTuple):
    """Scalars and small arrays of one run, read by :func:`run_kernel` (built by
    :func:`estimators.indirect.run.kernel_settings`; the first ten fields are
    :func:`estimators.core.full_state.shared_settings`)."""

    gravity_m_s2: float
    gyro_psd: float  # gyro white-noise density squared [(rad/s)^2/Hz]
    accel_psd: float  # accelerometer white-noise density squared [(m/s^2)^2/Hz]
    covariance_dt_s: float  # covariance propagation interval [s] (the schedule's)
    field_ned: np.ndarray  # (3,) unit earth magnetic field NED
    gps_reject_s: float  # a GPS component rejected this long -> position/velocity reset [s]
    gps_outage_s: float  # GPS back after an outage this long -> position/velocity reset [s]
    min_ground_speed_m_s: float  # no course update below this GPS ground speed (paper GPS velocity)
    paper_gps_velocity: bool  # GPS velocity as ground speed and course
    mag_heading: bool  # the magnetometer fused as its heading (else its three axes)
    gates: np.ndarray  # (n_kinds,) scalar gate per event kind (inf: ungated)
    x0: np.ndarray  # (NX,) initial nominal state
    P0: np.ndarray  # (n, n) initial covariance of the active error states
    sel: np.ndarray  # int64 (n,) active error states (indices E_* of estimators.indirect.model), increasing
    walk_psd: np.ndarray  # (n,) squared random-walk densities of the active error states [unit^2/s]
    min_var: np.ndarray  # (n,) variance floor of the active error states
    max_var: np.ndarray  # (n,) variance cap of the active error states
    lever_arm_m: np.ndarray  # (3,) GPS antenna position in body FRD [m]
    inject_scalar: bool  # inject and reset after every scalar update (else after each sensor group)


class KernelWork(NamedTuple):
    """Preallocated work arrays of :func:`run_kernel` (``n`` active error states): the loop allocates nothing."""

    acc: np.ndarray  # (7,) accumulated dt, sum gyro dt, sum accel dt since the last covariance propagation
    x_cov: np.ndarray  # (NX,) nominal state at the start of the accumulated interval
    mean_input: np.ndarray  # (2, 3) mean gyro and accelerometer input of the interval
    imu_psd: np.ndarray  # (2, 3) squared gyro and accelerometer noise densities
    F_full: np.ndarray  # (NE, NE) transition, kept at the identity off its blocks
    F_work: np.ndarray  # scratch of estimators.indirect.model.transition
    F_values: np.ndarray  # (N_DYNAMIC, n) sparse dynamic rows (estimators.core.linalg.sparse_rows)
    F_cols: np.ndarray  # (N_DYNAMIC, n)
    F_counts: np.ndarray  # (N_DYNAMIC,)
    Q_dyn: np.ndarray  # (N_DYNAMIC, N_DYNAMIC) input noise of the dynamic states
    work: np.ndarray  # (n, n) scratch
    T: np.ndarray  # (n, n) GPS reset transform
    block3: np.ndarray  # (3, 3) GPS position reset block
    H_full: np.ndarray  # (NE,) measurement row over all error states
    H3: np.ndarray  # (3, NE) sun rows
    h3: np.ndarray  # (3,) predicted sun vector
    basis: np.ndarray  # (3, 2) placeholder of the sun tangent basis (non-sun events)
    H: np.ndarray  # (n,) measurement row over the active states
    dx: np.ndarray  # (NE,) error estimate of the current group
    dx_r: np.ndarray  # (n,) correction of one scalar update
    ph: np.ndarray  # (n,) P H^T
    zero_error: np.ndarray  # (n,) the reset error state (health check)


@njit(cache=True)
def kernel_work(settings):
    """The work arrays of one run (:class:`KernelWork`)."""
    n = settings.sel.shape[0]
    imu_psd = np.empty((2, 3))
    imu_psd[0, :] = settings.gyro_psd
    imu_psd[1, :] = settings.accel_psd
    return KernelWork(np.zeros(7), settings.x0.copy(), np.empty((2, 3)), imu_psd, m.identity_transition(),
                      m.transition_work(), np.empty((m.N_DYNAMIC, n)), np.empty((m.N_DYNAMIC, n), dtype=np.int64),
                      np.empty(m.N_DYNAMIC, dtype=np.int64), np.empty((m.N_DYNAMIC, m.N_DYNAMIC)), np.empty((n, n)),
                      np.empty((n, n)), np.empty((3, 3)), np.zeros(m.NE), np.empty((3, m.NE)), np.empty(3),
                      np.empty((3, 2)), np.empty(n), np.zeros(m.NE), np.empty(n), np.empty(n), np.zeros(n))


@njit(cache=True)
def flush_covariance(P, settings, walk_psd, w, counters):
    """Propagate P over the accumulated interval ``w.acc[0]`` with the mean inputs ``w.acc[1:7] / w.acc[0]``, from
    the nominal ``w.x_cov`` at its start (:func:`estimators.indirect.model.transition`,
    :func:`estimators.core.linalg.propagate_sparse`, then :func:`estimators.indirect.model.add_process_noise`);
    variance limits every time, the positive-definiteness repair every ``PD_CHECK_EVERY`` propagations (as the
    direct filter). Clears the accumulator."""
    acc = w.acc
    dt = acc[0]
    for i in range(3):
        w.mean_input[0, i] = acc[1 + i] / dt
        w.mean_input[1, i] = acc[4 + i] / dt
    m.transition(w.x_cov, w.mean_input[0], w.mean_input[1], dt, w.F_full, w.F_work)
    m.process_noise(w.F_full, w.imu_psd[0], w.imu_psd[1], dt, w.Q_dyn)
    linalg.sparse_rows(w.F_full, settings.sel, w.F_values, w.F_cols, w.F_counts)
    linalg.propagate_sparse(P, w.F_values, w.F_cols, w.F_counts, w.work)
    m.add_process_noise(P, w.Q_dyn, walk_psd, dt)
    counters[C_FLUSHES] += 1
    if linalg.scheduled_repair(P, settings.min_var, settings.max_var, w.work, EIG_FLOOR, counters[C_FLUSHES],
                               PD_CHECK_EVERY):
        counters[C_REPAIRS] += 1
    for i in range(7):
        acc[i] = 0.0


@njit(cache=True)
def reset_to_gps(x, P, kind, values, variances, field, lever_b, gyro, sel, move_wind, H, block, T, work):
    """GPS re-acquisition (docs/estimators.md, 'GPS re-acquisition'): the nominal position (``kind == GPS_POS``)
    or velocity so that the predicted GPS measurement (lever arm included) equals the GPS value; the error of that
    block becomes the GPS noise: covariance R, uncorrelated with the other error states. The position and velocity
    error states lead the active states ``sel`` (indices ``E_P``, ``E_V``).

    ``move_wind`` (wind states active and the last airspeed update accepted): the wind moves with the ground
    velocity, ``w += v - h_v(x_old)`` (north, east), keeping the air-relative velocity the airspeed agreed with
    (as the direct filter); then ``e' = T e + G n``, ``P <- T P T^T + G R G^T``.
    ``H`` (NE,), ``block`` (3, 3), ``T`` and ``work`` (n, n) scratch.
    """
    if kind == GPS_POS:
        for a in range(3):
            x[m.X_P + a] += values[a] - measurement(x, kind, a, values, field, lever_b, gyro, H)
            for b in range(3):
                block[a, b] = 0.0
            block[a, a] = variances[a]
        linalg.reset_covariance_block(P, int(m.E_P), block[:3, :3])  # int(), a slice: as the wind's (one compile)
        return
    n = sel.shape[0]
    aw = -1
    for a in range(n):
        if sel[a] == m.E_W:
            aw = a
    for i in range(n):
        for k in range(n):
            T[i, k] = 0.0
        T[i, i] = 1.0
    for c in range(3):
        dv = values[c] - measurement(x, kind, c, values, field, lever_b, gyro, H)
        if move_wind and c < 2:
            x[m.X_W + c] += dv
            for k in range(n):
                T[aw + c, k] -= H[sel[k]]
        x[m.X_V + c] += dv
    for c in range(3):
        for k in range(n):
            T[m.E_V + c, k] = 0.0
    linalg.transform_covariance(P, T, work)
    for c in range(3):
        P[m.E_V + c, m.E_V + c] += variances[c]
        if move_wind and c < 2:
            P[aw + c, aw + c] += variances[c]
            P[aw + c, m.E_V + c] += variances[c]
            P[m.E_V + c, aw + c] += variances[c]


@njit(cache=True)
def _body_x_ned(x):
    """The body x axis in NED, ``R(q) e_x`` (first column of the attitude rotation)."""
    qw, qx, qy, qz = x[m.X_Q], x[m.X_Q + 1], x[m.X_Q + 2], x[m.X_Q + 3]
    return 1.0 - 2.0 * (qy * qy + qz * qz), 2.0 * (qx * qy + qw * qz), 2.0 * (qx * qz - qw * qy)


@njit(cache=True)
def initialise_wind(x, P, airspeed_m_s, aw, P0, block):
    """Wind from the airspeed (docs/estimators.md, 'Wind initialisation'): the air flows along the body x axis at
    the measured true airspeed, so the nominal horizontal wind is the NED velocity minus ``airspeed * R(q) e_x``
    (north, east); its error covariance is the initial one, uncorrelated with the other error states.

    ``aw``: active index of the wind error state ``E_W``; ``block`` (2, 2) scratch.
    """
    axis_n, axis_e, _ = _body_x_ned(x)
    x[m.X_W] = x[m.X_V] - airspeed_m_s * axis_n
    x[m.X_W + 1] = x[m.X_V + 1] - airspeed_m_s * axis_e
    for c in range(2):
        for d in range(2):
            block[c, d] = P0[aw + c, aw + d]
    linalg.reset_covariance_block(P, aw, block)


@njit(cache=True)
def air_flows_backwards(x) -> bool:
    """The nominal air velocity ``v - wbar`` points backwards along the body x axis (the mirrored solution of
    airspeed magnitude and sideslip)."""
    axis_n, axis_e, axis_d = _body_x_ned(x)
    return (axis_n * (x[m.X_V] - x[m.X_W]) + axis_e * (x[m.X_V + 1] - x[m.X_W + 1])
            + axis_d * x[m.X_V + 2]) < 0.0


@njit(cache=True)
def healthy(x, P, zero_error):
    """Finite nominal state, and a finite covariance with positive variances (``linalg.is_healthy`` on the
    reset error state ``zero_error``)."""
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    return linalg.is_healthy(zero_error, P)


@njit(cache=True)
def _check_health(x, P, x_safe, P0, zero_error, counters):
    """Divergence reset when not :func:`healthy`: last healthy nominal state, initial covariance."""
    if not healthy(x, P, zero_error):
        linalg.copy_into(x, x_safe)  # the nominal (NX) is longer than the error state (P: n x n)
        linalg.copy_rows_into(P, P0, P.shape[0])
        counters[C_RESETS] += 1


@njit(cache=True)
def _write_output(out_f, out_sd, row, t, x, P):
    """Output epoch ``row``: time, nominal state, error-state standard deviations and attitude-error covariances
    xy, xz, yz (rows beyond the arrays are counted, not written)."""
    if row >= out_f.shape[0]:
        return
    n = P.shape[0]
    out_f[row, 0] = t
    for i in range(x.shape[0]):
        out_f[row, 1 + i] = x[i]
    for i in range(n):
        out_sd[row, i] = math.sqrt(max(P[i, i], 0.0))
    out_sd[row, n] = P[m.E_TH, m.E_TH + 1]
    out_sd[row, n + 1] = P[m.E_TH, m.E_TH + 2]
    out_sd[row, n + 2] = P[m.E_TH + 1, m.E_TH + 2]


# ----------------------------------------------------------------------------------------------------------------
# control: when a measurement is fused, and when states are reset or re-initialised instead (docs/indirect.md,
# 'Control and fusion'): wind_control and the shared GPS rule estimators.core.reacquisition.gps_control decide,
# the loop resets (reset_to_gps, initialise_wind) or fuses (_fuse)


@njit(cache=True)
def wind_control(x, n_wind_inits):
    """Wind (re)start at an airspeed event (wind states active): at the first airspeed of the flight
    (``n_wind_inits`` = 0), or when the wind has the aircraft flying backwards (:func:`air_flows_backwards`; no
    update can leave that mirrored solution, it fits airspeed and sideslip as well), the wind starts again from
    the airspeed (:func:`initialise_wind`) instead of fusing it."""
    return n_wind_inits == 0 or air_flows_backwards(x)


# ----------------------------------------------------------------------------------------------------------------
# fusion


@njit(cache=True)
def _fuse(x, P, t, kind, values, variances, gyro, settings, w, gps_mon, rec):
    """The sequential scalar updates of one measurement event (a group), injected after the group (or after every
    scalar with ``settings.inject_scalar``). Returns whether the last scalar was accepted."""
    s = settings
    sel = s.sel
    n = sel.shape[0]
    field, lever, H_full, H3, h3, dx = s.field_ned, s.lever_arm_m, w.H_full, w.H3, w.h3, w.dx
    is_gps = kind in (GPS_POS, GPS_VEL)
    c0, c1 = component_range(kind, values, s.paper_gps_velocity, s.min_ground_speed_m_s, s.mag_heading)
    if kind == SUN:
        for c in range(3):
            h3[c] = measurement(x, kind, c, values, field, lever, gyro, H_full)
            linalg.copy_into(H3[c], H_full)
        basis = sun_tangent_basis(h3)
    else:
        basis = w.basis  # unused
    accepted = False
    any_accepted = False
    for c in range(c0, c1):
        if kind == SUN:
            if s.inject_scalar:  # re-linearise at the injected nominal, on the prior's tangent plane
                for cc in range(3):
                    h3[cc] = measurement(x, kind, cc, values, field, lever, gyro, H_full)
                    linalg.copy_into(H3[cc], H_full)
            nu = tangent_projection(basis, c, values, h3, H3, H_full)
            r_var = variances[c]
        elif c == MAG_HEADING and kind == MAG:
            nu, r_var = mag_heading(x, values, variances, field, w.block3, H_full)
            if not math.isfinite(nu):
                continue
        else:
            h = measurement(x, kind, c, values, field, lever, gyro, H_full)
            nu, r_var = scalar_innovation(kind, c, values, variances, h)
        # innovation of the error state accumulated in this group (eq 49 corrected): z - h(x_hat) - H dx
        for i in range(m.NE):
            nu -= H_full[i] * dx[i]
        for a in range(n):
            w.H[a] = H_full[sel[a]]
        accepted, s_var, nis = linalg.scalar_update(P, w.H, nu, r_var, s.gates[kind], w.dx_r, w.ph)
        rec.counters[C_UPDATES] += 1
        recorder.record_update(rec.diag_f, rec.diag_i, rec.counters, t, kind, c, nu, s_var, nis, accepted)
        if is_gps:
            reacquisition.gps_record(gps_mon, kind == GPS_POS, c, t, accepted)
        if accepted:
            any_accepted = True
            for a in range(n):
                dx[sel[a]] += w.dx_r[a]
            if s.inject_scalar:
                m.inject(x, dx, P)
    if any_accepted and not s.inject_scalar:
        m.inject(x, dx, P)
    return accepted


@njit(cache=True, nogil=True)  # the replays of noise identification run in threads
def run_kernel(imu_gyro, imu_accel, ev_kind, ev_imu, ev_val, ev_var, op, op_dt, op_index, settings, out_f, out_sd,
               diag_f, diag_i, counters):
    """The error-state filter over a whole log: one compiled loop over the schedule (see the module docstring).

    Parameters
    ----------
    imu_gyro, imu_accel : ndarrays (N, 3)
        IMU rows (:class:`estimators.inputs.records.ImuSamples`).
    ev_kind, ev_imu, ev_val, ev_var : ndarrays
        Events (:class:`estimators.inputs.records.MeasurementEvents`).
    op, op_dt, op_index : ndarrays (S,)
        The schedule (:func:`estimators.core.schedule.build_schedule`): operation, step or time [s], IMU row or
        event index.
    settings : IndirectSettings
    out_f : (K, 1 + NX)
        Per OUTPUT event: time and nominal state (:data:`OUT_COLUMNS`).
    out_sd : (K, n + 3)
        Per OUTPUT event: error-state standard deviations, then the attitude-error covariances xy, xz, yz.
    diag_f, diag_i : diagnostics arrays; counters : int64 (N_COUNTERS,).

    Returns
    -------
    x : ndarray (NX,)
        Final nominal state.
    P : ndarray (n, n)
        Final error covariance.
    """
    s = settings
    x = s.x0.copy()
    P = s.P0.copy()
    x_safe = s.x0.copy()
    w = kernel_work(s)
    rec = Recorder(diag_f, diag_i, counters)
    acc = w.acc
    gps_mon = reacquisition.gps_monitor()
    # bool() / int(): a loop-carried variable started from a literal would compile each callee it reaches twice
    # (for the literal and for the plain type; docs/estimators.md, 'One compile per function')
    air_ok = bool(False)  # the last airspeed update was accepted (reset_to_gps)
    wind_active = bool(False)
    aw = int(-1)  # active index of the wind error state
    for a in range(s.sel.shape[0]):
        if s.sel[a] == m.E_W:
            wind_active = True
            aw = a
    held_walk = held_wind_walk(s.walk_psd, aw)
    wind_nis = wind_adaptation()  # the wind walk follows the turbulence (adapt_wind_walk)
    walk_now = np.empty_like(s.walk_psd)
    t_now = -math.inf
    t_wind_observed = -math.inf
    last_row = imu_gyro.shape[0] - 1
    n_out = int(0)
    for step in range(op.shape[0]):
        code = op[step]
        if code == PROPAGATE:
            k = op_index[step]
            if acc[0] == 0.0:
                linalg.copy_into(w.x_cov, x)
            m.propagate_nominal(x, imu_gyro[k], imu_accel[k], op_dt[step], s.gravity_m_s2)
            linalg.accumulate_inputs(acc, op_dt[step], imu_gyro[k], imu_accel[k])
        elif code == COVARIANCE:
            if acc[0] > 0.0:
                walk = current_walk(s.walk_psd, held_walk, t_now, t_wind_observed)
                flush_covariance(P, s, scaled_wind_walk(walk, aw, wind_walk_scale(wind_nis), walk_now), w, counters)
            _check_health(x, P, x_safe, s.P0, w.zero_error, counters)
        elif code == EVENT:
            j = op_index[step]
            t = op_dt[step]
            kind = ev_kind[j]
            values = ev_val[j]
            t_now = t
            t_wind_observed = wind_observed(kind, t, t_wind_observed)
            if kind == OUTPUT:
                _check_health(x, P, x_safe, s.P0, w.zero_error, counters)
                linalg.copy_into(x_safe, x)
                _write_output(out_f, out_sd, n_out, t, x, P)
                n_out += 1
                continue
            gyro = imu_gyro[min(ev_imu[j], last_row)]  # the rate of the event's IMU interval
            if kind in (GPS_POS, GPS_VEL) and reacquisition.gps_control(gps_mon, kind, t, s.gps_reject_s,
                                                                        s.gps_outage_s, counters):
                # (re)acquisition: position or velocity to the GPS, the wind moved along when the airspeed agreed
                reset_to_gps(x, P, kind, values, ev_var[j], s.field_ned, s.lever_arm_m, gyro, s.sel,
                             air_ok and wind_active, w.H_full, w.block3, w.T, w.work)
                continue
            if kind == AIRSPEED and wind_active and wind_control(x, counters[C_WIND_INITS]):
                initialise_wind(x, P, values[0], aw, s.P0, w.block3[:2, :2])
                counters[C_WIND_INITS] += 1
                air_ok = True
                continue
            first = counters[C_DIAG]
            accepted = _fuse(x, P, t, kind, values, ev_var[j], gyro, s, w, gps_mon, rec)
            if kind in (AIRSPEED, SIDESLIP):
                adapt_wind_walk(wind_nis, t, diag_f, diag_i, first, counters[C_DIAG])
            if kind == AIRSPEED:
                air_ok = accepted
    counters[C_OUTPUTS] = n_out
    return x, P
