"""Full-state indirect filter: error-state (multiplicative quaternion) EKF (paper section 3.3; math note section 5).

The paper's indirect filter as printed (additive error in the direct filter's coordinates, eqs 44-49) equals the
direct filter (math note 5.1; ``full_state_direct.run(mode="paper_indirect")`` shows it). This is the useful
error-state filter the paper's motivation points to (Sola 2017, PX4 EKF2): a nominal state integrated by the
kinematics at the IMU rate and a small error state estimated by the EKF, injected into the nominal and reset to
zero after each sensor's group of scalar updates.

Nominal state (:mod:`estimators.indirect.model`): position NED, ground velocity NED, attitude quaternion (body FRD ->
NED), gyro bias, accelerometer bias, wind (north, east), magnetometer hard-iron bias, barometer offset, the z
accelerometer's cross-axis sensitivities to x and y (``accel_cross_axis_states``, with GPS).
Error state: the table :func:`error_state_table` (name, unit, initial sigma, process sigma), from which P0 and the
random walks are built; a block is present only when it helps, exactly as in the direct filter (same sensor plan
from :mod:`estimators.inputs.build`): accelerometer bias with ``accel_bias_states``; wind only with an airspeed sensor
(math note 7.1: absent states are removed from P, not frozen); magnetometer bias only with a fused magnetometer;
barometer offset only with barometer and GPS.

Propagation (math note 5.3): ``q <- q (x) Exp(omega dt)`` (exact exponential map), mid-interval attitude for the
specific force; the covariance with the exact discrete transition ``F`` of that step and
``Q = F_bg N_g^2/dt F_bg^T + F_ba N_a^2/dt F_ba^T + diag(K^2) dt`` at ``timing.covariance_rate_hz`` and before
every update, with the inputs averaged over the interval (output epochs report the last propagated covariance,
at most one covariance interval old).

Updates (math note 5.4, sequential scalar, Joseph form and gating of :func:`estimators.core.linalg.scalar_update`):
baro ``h = -p_d + b_b``; GPS position ``h = p + R l_b`` and velocity ``h = v + R (omega x l_b)`` with the antenna
lever arm ``l_b`` from ``EKF2_GPS_POS_X/Y/Z`` (or ground speed and course in ``gps_velocity_mode="paper"``);
airspeed ``h = |v - w|``; zero sideslip ``h = e2^T R^T (v - w)`` (fixed-wing only, pseudo, ungated); magnetometer
``h = R^T m_n + b_m``; sun ``h = R^T s_n`` on the tangent plane of ``h`` (2 scalars); no-GPS logs add a zero
NED-velocity pseudo-measurement (math note 7.3). Within a group the error estimate accumulates with the
linearised innovation ``z - h(x_hat) - H dx`` (eq 49 corrected); then ``x_hat <- x_hat (+) dx``,
``P <- G P G^T`` with ``G_thth = I - [dtheta/2]x`` and ``dx <- 0`` (``inject="scalar"``: after every scalar).

Filter quantities (kernel arrays): ``x`` (NX,) nominal state, ``P`` (n, n) error covariance over the active error
states (prior before, posterior after an update), ``nu`` innovation, ``S`` innovation variance, ``K = P H^T / S``,
``NIS = nu^2 / S``; every scalar update is recorded (:mod:`estimators.core.linalg`). Outputs: Euler angles from the
quaternion (:func:`ingest.frames.quat_to_euler`), their standard deviations ``S(Theta) P_thth S(Theta)^T``.
"""

from __future__ import annotations

import math
import time

import numpy as np
from numba import njit

from estimators.config import EstimatorConfig
from estimators.core import linalg, reacquisition, recorder
from estimators.core.full_state import (
    EIG_FLOOR,
    MIN_VARIANCE,
    N_SHARED_PARAMS,
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
from estimators.core.state_table import StateSpec, initial_sigmas, random_walk_psd
from estimators.indirect import model as m
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
from ingest.frames import euler_to_quat, quat_to_euler

NAME = "full_state_indirect"

# parameter array slots: P_G .. P_PAPER_VEL as the direct filter (full_state_direct.shared_params), then
P_LEVER = N_SHARED_PARAMS  # 3 slots: GPS antenna position in body FRD [m]
P_INJECT_SCALAR = P_LEVER + 3  # 1: inject and reset after every scalar update (else after each sensor group)
N_PARAMS = P_INJECT_SCALAR + 1

# counters: the shared slots of ekf_core (C_DIAG .. C_OUTPUTS), then this filter's
C_FLUSHES = N_SHARED_COUNTERS
N_COUNTERS = N_SHARED_COUNTERS + 1

#: Cap of the attitude-error variances: 180 deg standard deviation (math note 7.2).
MAX_ATTITUDE_VAR_RAD2 = math.pi ** 2
#: PX4 parameters of the GPS antenna position in the body frame [m].
GPS_LEVER_ARM_PARAMETERS = ("EKF2_GPS_POS_X", "EKF2_GPS_POS_Y", "EKF2_GPS_POS_Z")
#: Columns of the kernel's per-epoch output (then the error-state std of the active states and the attitude
#: error covariances xy, xz, yz).
OUT_COLUMNS = ("time_s", *(f"x{i}" for i in range(m.NX)))
#: Lever arm of the zero-velocity pseudo-measurement (the body origin) [m]; a global, compiled in as a constant.
_NO_LEVER_M = np.zeros(3)
#: Nominal-state names (report), in the order of :mod:`estimators.indirect.model`.
NOMINAL_NAMES = ("pn", "pe", "pd", "vn", "ve", "vd", "qw", "qx", "qy", "qz", "bgx", "bgy", "bgz", "bax", "bay",
                 "baz", "wn", "we", "bmx", "bmy", "bmz", "bb", "kzx", "kzy")


def error_state_table(config: EstimatorConfig, *, absolute_yaw: bool) -> tuple[StateSpec, ...]:
    """All error states in the order of :mod:`estimators.indirect.model` (``E_*``); P0 and the walks come from here.

    Parameters
    ----------
    config : EstimatorConfig
        Initial sigmas (``initial``) and random-walk densities (``noise``).
    absolute_yaw : bool
        An absolute heading source exists (initial yaw sigma ``initial.yaw_deg``, else ``yaw_unaided_deg``).

    Notes
    -----
    The attitude rows give roll, pitch and yaw sigmas; P0's attitude block is their image under
    ``dtheta = W(Theta) dTheta`` (math note 1.1), which equals the diagonal at level attitude.
    """
    ini, noise = config.initial, config.noise
    rad = math.radians
    yaw_sigma = rad(ini.yaw_deg if absolute_yaw else ini.yaw_unaided_deg)
    rows = [StateSpec(n, "m", ini.position_m, 0.0) for n in ("dpn", "dpe", "dpd")]
    rows += [StateSpec(n, "m/s", ini.velocity_m_s, 0.0) for n in ("dvn", "dve", "dvd")]
    rows += [StateSpec("dthx", "rad", rad(ini.roll_pitch_deg), 0.0),
             StateSpec("dthy", "rad", rad(ini.roll_pitch_deg), 0.0), StateSpec("dthz", "rad", yaw_sigma, 0.0)]
    rows += [StateSpec(n, "rad/s", rad(ini.gyro_bias_deg_s), noise.gyro_bias_rw_rad_s2_sqrt_hz)
             for n in ("dbgx", "dbgy", "dbgz")]
    rw_z = noise.accel_bias_rw_z_m_s3_sqrt_hz  # z may walk faster (cross-axis coupling, as the direct filter)
    rows += [StateSpec(n, "m/s^2", ini.accel_bias_m_s2, noise.accel_bias_rw_m_s3_sqrt_hz) for n in ("dbax", "dbay")]
    rows.append(StateSpec("dbaz", "m/s^2", ini.accel_bias_m_s2,
                          noise.accel_bias_rw_m_s3_sqrt_hz if rw_z is None else rw_z))
    rows += [StateSpec(n, "m/s", ini.wind_m_s, noise.wind_rw_m_s_sqrt_s) for n in ("dwn", "dwe")]
    rows += [StateSpec(n, "-", ini.mag_bias, noise.mag_bias_rw_sqrt_s) for n in ("dbmx", "dbmy", "dbmz")]
    rows.append(StateSpec("dbb", "m", ini.baro_bias_m, noise.baro_bias_rw_m_sqrt_s))
    rows += [StateSpec(n, "-", ini.accel_cross_axis, noise.accel_cross_axis_rw_sqrt_s) for n in ("dkzx", "dkzy")]
    return tuple(rows)


def active_error_states(config: EstimatorConfig, plan: records.SensorPlan) -> np.ndarray:
    """Indices (into :func:`error_state_table`) of the error states estimated for a sensor plan."""
    active = np.zeros(m.NE, dtype=bool)
    active[:m.E_BA] = True  # dp, dv, dtheta, db_g
    # without GPS the accelerometer bias has no absolute velocity reference (math note 7.3), as the direct filter
    active[m.E_BA:m.E_BA + 3] = config.accel_bias_states and plan.has_gps
    active[m.E_W:m.E_W + 2] = plan.has_airspeed
    active[m.E_BM:m.E_BM + 3] = plan.has_mag and config.mag_bias_states
    active[m.E_BB] = plan.has_baro and plan.has_gps and config.baro_bias_state
    # z accelerometer cross-axis: k_zx (climbs, descents and accelerations change the forward specific force);
    # k_zy only off fixed-wing, whose coordinated flight keeps the lateral specific force near zero (unobservable)
    cross_axis = config.accel_bias_states and config.accel_cross_axis_states and plan.has_gps
    active[m.E_KZ] = cross_axis
    active[m.E_KZ + 1] = cross_axis and not plan.fixed_wing
    return np.flatnonzero(active).astype(np.int64)


def attitude_matrices(roll_rad, pitch_rad):
    """``S(Theta)`` (Euler rates from body rates; dTheta = S dtheta) and ``W = S^-1`` (math note 1.1), (..., 3, 3)."""
    cph, sph = np.cos(roll_rad), np.sin(roll_rad)
    cth, sth = np.cos(pitch_rad), np.sin(pitch_rad)
    zero, one = np.zeros_like(cph), np.ones_like(cph)
    S = np.moveaxis(np.array([[one, sph * sth / cth, cph * sth / cth], [zero, cph, -sph],
                              [zero, sph / cth, cph / cth]]), (0, 1), (-2, -1))
    W = np.moveaxis(np.array([[one, zero, -sth], [zero, cph, sph * cth], [zero, -sph, cph * cth]]),
                    (0, 1), (-2, -1))
    return S, W


# ----------------------------------------------------------------------------------------------------------------
# kernel


@njit(cache=True)
def measurement(x, kind, comp, values, field, lever_b, gyro, H):
    """Predicted scalar ``h`` and its row ``H`` over all NE error states (:mod:`estimators.indirect.model`).

    ``kind``/``comp`` as in :mod:`estimators.inputs.build` (GPS_VEL components 3/4: ground speed and course, paper
    mode; SUN components 0..2: body axes, projected on the tangent plane by the caller); ``values`` the event's
    value row (SUN: NED sun vector in 3..5); ``field`` the unit earth field NED; ``lever_b`` the GPS antenna
    position [m] body; ``gyro`` the current IMU rate [rad/s].
    """
    if kind == BARO:
        return m.h_baro(x, H)
    if kind == AIRSPEED:
        return m.h_airspeed(x, H)
    if kind == SIDESLIP:
        return m.h_sideslip(x, H)
    if kind == GPS_POS:
        return m.h_gps_position(x, lever_b, comp, H)
    if kind == GPS_VEL:
        if comp == 3:
            return m.h_ground_speed(x, H)
        if comp == 4:
            return m.h_course(x, H)
        return m.h_gps_velocity(x, gyro, lever_b, comp, H)
    if kind == ZERO_VELOCITY:
        return m.h_gps_velocity(x, gyro, _NO_LEVER_M, comp, H)
    if kind == MAG:
        return m.h_body_vector(x, field, comp, True, H)
    return m.h_body_vector(x, values[3:6], comp, False, H)


@njit(cache=True)
def _flush_covariance(P, x_cov, acc, imu_psd, walk_psd, sel, min_var, max_var, mean_input, F_full, F_work, F_values,
                      F_cols, F_counts, Q_dyn, work, counters):
    """Propagate P over the accumulated interval ``acc[0]`` with the mean inputs ``acc[1:7] / acc[0]``, from the
    nominal ``x_cov`` at its start (:func:`estimators.core.linalg.propagate_sparse`, then
    :func:`estimators.indirect.model.add_process_noise`); variance limits every
    time, the positive-definiteness repair every ``PD_CHECK_EVERY`` propagations (as the direct filter).
    ``imu_psd`` (2, 3): squared gyro and accelerometer noise densities; ``walk_psd`` (n,): squared random-walk
    densities of the active states; ``F_full`` the (NE, NE) transition, kept at the identity off its blocks;
    scratch: ``mean_input`` (2, 3), ``F_work`` (:func:`estimators.indirect.model.transition_work`), the sparse dynamic
    rows ``F_values``, ``F_cols``, ``F_counts`` (:func:`estimators.core.linalg.sparse_rows`), ``Q_dyn``
    (N_DYNAMIC, N_DYNAMIC) and ``work`` (n, n)."""
    dt = acc[0]
    for i in range(3):
        mean_input[0, i] = acc[1 + i] / dt
        mean_input[1, i] = acc[4 + i] / dt
    m.transition(x_cov, mean_input[0], mean_input[1], dt, F_full, F_work)
    m.process_noise(F_full, imu_psd[0], imu_psd[1], dt, Q_dyn)
    linalg.sparse_rows(F_full, sel, F_values, F_cols, F_counts)
    linalg.propagate_sparse(P, F_values, F_cols, F_counts, work)
    m.add_process_noise(P, Q_dyn, walk_psd, dt)
    counters[C_FLUSHES] += 1
    if linalg.scheduled_repair(P, min_var, max_var, work, EIG_FLOOR, counters[C_FLUSHES], PD_CHECK_EVERY):
        counters[C_REPAIRS] += 1
    for i in range(7):
        acc[i] = 0.0


@njit(cache=True)
def reset_to_gps(x, P, kind, values, variances, field, lever_b, gyro, sel, move_wind, H, block, T, work):
    """GPS re-acquisition (math note 2.3): the nominal position (``kind == GPS_POS``) or velocity so that the
    predicted GPS measurement (lever arm included) equals the GPS value; the error of that block becomes the GPS
    noise: covariance R, uncorrelated with the other error states. The position and velocity error states lead
    the active states ``sel`` (indices ``E_P``, ``E_V``).

    ``move_wind`` (wind states active and the last airspeed update accepted): the wind moves with the ground
    velocity, ``w += v - h_v(x_old)`` (north, east), keeping the air-relative velocity the airspeed agreed with
    (as :func:`estimators.direct.kernel.reset_to_gps`); then ``e' = T e + G n``, ``P <- T P T^T + G R G^T``.
    ``H`` (NE,), ``block`` (3, 3), ``T`` and ``work`` (n, n) scratch.
    """
    if kind == GPS_POS:
        for a in range(3):
            x[m.X_P + a] += values[a] - measurement(x, kind, a, values, field, lever_b, gyro, H)
            for b in range(3):
                block[a, b] = 0.0
            block[a, a] = variances[a]
        linalg.reset_covariance_block(P, m.E_P, block)
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
def _healthy(x, P, zero_error):
    """Finite nominal state, and a finite covariance with positive variances (``linalg.is_healthy`` on the
    reset error state ``zero_error``)."""
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    return linalg.is_healthy(zero_error, P)


@njit(cache=True)
def _reset(x, P, x_safe, P0, counters):
    """Divergence reset: last healthy nominal state, initial covariance."""
    x[:] = x_safe
    P[:, :] = P0
    counters[C_RESETS] += 1


@njit(cache=True)
def run_kernel(imu_t, imu_gyro, imu_accel, ev_t, ev_kind, ev_imu, ev_val, ev_var, x0, P0, sel, params, gates,
               rw_psd, min_var, max_var, out_f, out_sd, diag_f, diag_i, counters):
    """The error-state filter over a whole log (one compiled loop; see the module docstring).

    Parameters
    ----------
    imu_t, imu_gyro, imu_accel : ndarrays (N,), (N, 3), (N, 3)
        IMU rows (:class:`estimators.inputs.records.ImuSamples`).
    ev_t, ev_kind, ev_imu, ev_val, ev_var : ndarrays
        Events (:class:`estimators.inputs.records.MeasurementEvents`).
    x0 : ndarray (NX,)
        Initial nominal state.
    P0 : ndarray (n, n)
        Initial covariance of the active error states.
    sel : int64 (n,)
        Active error states (indices ``E_*`` of :mod:`estimators.indirect.model`), increasing.
    params : float64 (N_PARAMS,)
        Scalars (``P_*`` slots).
    gates : float64 (9,)
        Gate per event kind (inf: ungated).
    rw_psd : float64 (NE,)
        Squared random-walk densities of all error states.
    min_var, max_var : float64 (n,)
        Variance limits of the active error states.
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
    n = sel.shape[0]
    x = x0.copy()
    P = P0.copy()
    x_safe = x0.copy()
    x_cov = x0.copy()
    F_full = m.identity_transition()
    F_work = m.transition_work()
    F_values = np.empty((m.N_DYNAMIC, n))
    F_cols = np.empty((m.N_DYNAMIC, n), dtype=np.int64)
    F_counts = np.empty(m.N_DYNAMIC, dtype=np.int64)
    Q_dyn = np.empty((m.N_DYNAMIC, m.N_DYNAMIC))
    walk_psd = rw_psd[sel]
    T = np.empty((n, n))
    work = np.empty((n, n))
    H_full = np.zeros(m.NE)
    H3 = np.empty((3, m.NE))
    H = np.empty(n)
    dx = np.zeros(m.NE)  # error estimate of the current group (full layout)
    dx_r = np.empty(n)
    ph = np.empty(n)
    zero_error = np.zeros(n)
    h3 = np.empty(3)
    acc = np.zeros(7)  # dt, sum gyro dt, sum accel dt
    mean_input = np.empty((2, 3))
    imu_psd = np.empty((2, 3))
    imu_psd[0, :] = params[P_NG2]
    imu_psd[1, :] = params[P_NA2]
    g = params[P_G]
    cov_dt = params[P_COV_DT]
    field = params[P_FIELD:P_FIELD + 3].copy()
    lever = params[P_LEVER:P_LEVER + 3].copy()
    paper_vel = params[P_PAPER_VEL] > 0.5
    inject_scalar = params[P_INJECT_SCALAR] > 0.5
    vmin = params[P_VMIN]
    gps_mon = reacquisition.gps_monitor()
    air_ok = False  # the last airspeed update was accepted (reset_to_gps)
    wind_active = False
    for a in range(n):
        if sel[a] == m.E_W:
            wind_active = True
    block3 = np.empty((3, 3))
    n_out = 0
    t = imu_t[0]
    j = 0
    n_events = ev_t.shape[0]
    for k in range(imu_t.shape[0]):
        gyro = imu_gyro[k]
        accel = imu_accel[k]
        while True:
            at_event = j < n_events and ev_imu[j] == k
            t_next = ev_t[j] if at_event else imu_t[k]
            if t_next > t:
                if acc[0] == 0.0:
                    x_cov[:] = x
                step = t_next - t
                m.propagate_nominal(x, gyro, accel, step, g)
                linalg.accumulate_inputs(acc, step, gyro, accel)
                t = t_next
                if acc[0] >= cov_dt * (1.0 - 1e-9):
                    _flush_covariance(P, x_cov, acc, imu_psd, walk_psd, sel, min_var, max_var, mean_input, F_full,
                                      F_work, F_values, F_cols, F_counts, Q_dyn, work, counters)
                    if not _healthy(x, P, zero_error):
                        _reset(x, P, x_safe, P0, counters)
            if not at_event:
                break
            kind = ev_kind[j]
            values = ev_val[j]
            if kind == OUTPUT:
                if not _healthy(x, P, zero_error):
                    _reset(x, P, x_safe, P0, counters)
                x_safe[:] = x
                if n_out < out_f.shape[0]:
                    out_f[n_out, 0] = t
                    out_f[n_out, 1:] = x
                    for i in range(n):
                        out_sd[n_out, i] = math.sqrt(max(P[i, i], 0.0))
                    out_sd[n_out, n] = P[m.E_TH, m.E_TH + 1]
                    out_sd[n_out, n + 1] = P[m.E_TH, m.E_TH + 2]
                    out_sd[n_out, n + 2] = P[m.E_TH + 1, m.E_TH + 2]
                n_out += 1
                j += 1
                continue
            # measurements see the covariance brought up to their time (outputs report the last propagated one,
            # at most 1 / covariance_rate_hz old)
            if acc[0] > 0.0:
                _flush_covariance(P, x_cov, acc, imu_psd, walk_psd, sel, min_var, max_var, mean_input, F_full,
                                  F_work, F_values, F_cols, F_counts, Q_dyn, work, counters)
            is_gps = kind in (GPS_POS, GPS_VEL)
            if is_gps:
                # (re)acquisition (math note 2.3): position and velocity to the GPS, see reset_to_gps
                reset, counted = reacquisition.gps_reset_due(gps_mon, kind == GPS_POS, t, params[P_GPS_REJECT_S],
                                                        params[P_GPS_OUTAGE_S])
                if reset:
                    reset_to_gps(x, P, kind, values, ev_var[j], field, lever, gyro, sel, air_ok and wind_active,
                                 H_full, block3, T, work)
                    if counted:
                        counters[C_GPS_RESETS] += 1
                    j += 1
                    continue
            gate = gates[kind]
            c0, c1 = component_range(kind, values, paper_vel, vmin)
            if kind == SUN:
                for c in range(3):
                    h3[c] = measurement(x, kind, c, values, field, lever, gyro, H_full)
                    H3[c, :] = H_full
                basis = sun_tangent_basis(h3)
            any_accepted = False
            for c in range(c0, c1):
                if kind == SUN:
                    if inject_scalar:  # re-linearise at the injected nominal, on the prior's tangent plane
                        for cc in range(3):
                            h3[cc] = measurement(x, kind, cc, values, field, lever, gyro, H_full)
                            H3[cc, :] = H_full
                    nu = tangent_projection(basis, c, values, h3, H3, H_full)
                    r_var = ev_var[j, c]
                else:
                    h = measurement(x, kind, c, values, field, lever, gyro, H_full)
                    nu, r_var = scalar_innovation(kind, c, values, ev_var[j], h)
                # innovation of the error state accumulated in this group (eq 49 corrected): z - h(x_hat) - H dx
                for i in range(m.NE):
                    nu -= H_full[i] * dx[i]
                for a in range(n):
                    H[a] = H_full[sel[a]]
                accepted, s_var, nis = linalg.scalar_update(P, H, nu, r_var, gate, dx_r, ph)
                counters[C_UPDATES] += 1
                recorder.record_update(diag_f, diag_i, counters, t, kind, c, nu, s_var, nis, accepted)
                if is_gps:
                    reacquisition.gps_record(gps_mon, kind == GPS_POS, c, t, accepted)
                elif kind == AIRSPEED:
                    air_ok = accepted
                if accepted:
                    any_accepted = True
                    for a in range(n):
                        dx[sel[a]] += dx_r[a]
                    if inject_scalar:
                        m.inject(x, dx, P)
            if any_accepted and not inject_scalar:
                m.inject(x, dx, P)
            j += 1
    if acc[0] > 0.0:
        _flush_covariance(P, x_cov, acc, imu_psd, walk_psd, sel, min_var, max_var, mean_input, F_full, F_work,
                          F_values, F_cols, F_counts, Q_dyn, work, counters)
    counters[C_OUTPUTS] = n_out
    return x, P


# ----------------------------------------------------------------------------------------------------------------
# orchestration


def kernel_inputs(inputs: ReplayInputs, config: EstimatorConfig, flight_log: FlightLog, *,
                  inject: str = "group") -> dict:
    """Error-state table, x0, P0 and the scalar parameters of one run (keyword arguments of :func:`run_kernel`
    plus ``table``: the active rows of :func:`error_state_table`)."""
    if inject not in ("group", "scalar"):
        raise ValueError(f"inject must be 'group' or 'scalar', got {inject!r}")
    plan, align = inputs.plan, inputs.alignment
    full_table = error_state_table(config, absolute_yaw=align.yaw_source != "none" or plan.has_sun)
    sel = active_error_states(config, plan)
    x0 = np.zeros(m.NX)
    x0[m.X_P:m.X_P + 3] = align.position_ned_m
    x0[m.X_V:m.X_V + 3] = align.velocity_ned_m_s
    x0[m.X_Q:m.X_Q + 4] = euler_to_quat(align.roll_rad, align.pitch_rad, align.yaw_rad)
    x0[m.X_BG:m.X_BG + 3] = align.gyro_bias_rad_s
    sigma0 = initial_sigmas(full_table)
    P0_full = np.diag(sigma0 ** 2)
    _, W = attitude_matrices(align.roll_rad, align.pitch_rad)
    th = slice(m.E_TH, m.E_TH + 3)
    P0_full[th, th] = W @ np.diag(sigma0[th] ** 2) @ W.T
    params = shared_params(inputs, config, N_PARAMS)
    params[P_LEVER:P_LEVER + 3] = gps_lever_arm_m(flight_log)
    params[P_INJECT_SCALAR] = 1.0 if inject == "scalar" else 0.0
    n = len(sel)
    max_var = np.full(n, 1e12)
    max_var[(sel >= m.E_TH) & (sel < m.E_TH + 3)] = MAX_ATTITUDE_VAR_RAD2
    return {"table": tuple(full_table[i] for i in sel), "x0": x0, "P0": np.ascontiguousarray(P0_full[np.ix_(sel, sel)]),
            "sel": sel, "params": params, "gates": gates_per_kind(config),
            "rw_psd": random_walk_psd(full_table),
            "min_var": np.full(n, MIN_VARIANCE), "max_var": max_var}


def gps_lever_arm_m(flight_log: FlightLog) -> np.ndarray:
    """GPS antenna position in body FRD [m] from the log's ``EKF2_GPS_POS_X/Y/Z`` (zeros when absent)."""
    params = flight_log.meta.parameters
    values = [float(params.get(name, 0.0)) for name in GPS_LEVER_ARM_PARAMETERS]
    return np.array([v if math.isfinite(v) else 0.0 for v in values])


def run(flight_log: FlightLog, inputs: ReplayInputs, config: EstimatorConfig, *, inject: str = "group",
        backend: str = "numba") -> EstimatorRun:
    """Run the error-state filter on prepared inputs (the registry entry of :mod:`estimators.api`).

    Parameters
    ----------
    flight_log : FlightLog
        The log (its parameters give the GPS lever arm).
    inputs : ReplayInputs
        From :func:`estimators.inputs.build.build_replay_inputs`.
    config : EstimatorConfig
    inject : {"group", "scalar"}
        Inject the error estimate and reset after each sensor's group of scalar updates (default, the paper's
        Alg. 3) or after every scalar (re-linearised, math note 5.4 flag).
    backend : {"numba", "numpy"}
        Compiled kernel or the plain-NumPy twin :mod:`estimators.indirect.reference` (slow; tests only).
    """
    started = time.perf_counter()
    k = kernel_inputs(inputs, config, flight_log, inject=inject)
    ev, imu = inputs.events, inputs.imu
    n = len(k["sel"])
    n_out = ev.count(OUTPUT)
    out_f = np.full((n_out, len(OUT_COLUMNS)), np.nan)
    out_sd = np.full((n_out, n + 3), np.nan)
    diag_f, diag_i = recorder.diagnostics_arrays(diagnostics_capacity(ev))
    counters = np.zeros(N_COUNTERS, dtype=np.int64)
    args = (imu.time_s, imu.gyro_rad_s, imu.accel_m_s2, ev.time_s, ev.kind, ev.imu_index, ev.values, ev.variances,
            k["x0"], k["P0"], k["sel"], k["params"], k["gates"], k["rw_psd"], k["min_var"], k["max_var"], out_f,
            out_sd, diag_f, diag_i, counters)
    kernel_started = time.perf_counter()
    if backend == "numba":
        x_final, _ = run_kernel(*args)
    elif backend == "numpy":
        from estimators.indirect.reference import run_reference

        x_final, _ = run_reference(*args)
    else:
        raise ValueError(f"backend must be 'numba' or 'numpy', got {backend!r}")
    kernel_s = time.perf_counter() - kernel_started
    return _assemble(inputs, k, out_f, out_sd, diag_f, diag_i, counters, x_final, inject=inject,
                     timings={"kernel": kernel_s, "total": time.perf_counter() - started},
                     config_accel_bias=config.accel_bias_states)


def _assemble(inputs: ReplayInputs, k: dict, out_f, out_sd, diag_f, diag_i, counters, x_final, *, inject,
              timings, config_accel_bias) -> EstimatorRun:
    plan = inputs.plan
    count = int(counters[C_OUTPUTS])
    o, sd = out_f[:count], out_sd[:count]
    sel = list(k["sel"])
    n = len(sel)
    x = o[:, 1:]
    roll, pitch, yaw = quat_to_euler(x[:, m.X_Q:m.X_Q + 4])
    # Euler standard deviations: dTheta = S(Theta) dtheta
    col = {e: a for a, e in enumerate(sel)}
    th = [col[m.E_TH + i] for i in range(3)]
    P_th = np.zeros((count, 3, 3))
    for i in range(3):
        P_th[:, i, i] = sd[:, th[i]] ** 2
    for (i, j), c in (((0, 1), n), ((0, 2), n + 1), ((1, 2), n + 2)):
        P_th[:, i, j] = P_th[:, j, i] = sd[:, c]
    S, _ = attitude_matrices(roll, pitch)
    euler_std = np.sqrt(np.maximum(np.einsum("kij,kjl,kil->ki", S, P_th, S), 0.0))
    deg = np.degrees
    wind = plan.has_airspeed
    std = {"roll_deg_std": deg(euler_std[:, 0]), "pitch_deg_std": deg(euler_std[:, 1]),
           "yaw_deg_std": deg(euler_std[:, 2]),
           "pos_n_m_std": sd[:, col[m.E_P]], "pos_e_m_std": sd[:, col[m.E_P + 1]], "alt_m_std": sd[:, col[m.E_P + 2]],
           "vn_m_s_std": sd[:, col[m.E_V]], "ve_m_s_std": sd[:, col[m.E_V + 1]], "vd_m_s_std": sd[:, col[m.E_V + 2]]}
    if wind:
        std["wind_n_m_s_std"] = sd[:, col[m.E_W]]
        std["wind_e_m_s_std"] = sd[:, col[m.E_W + 1]]
    states = states_frame(o[:, 0], roll, pitch, yaw, x[:, m.X_P:m.X_P + 3], x[:, m.X_V:m.X_V + 3],
                          x[:, m.X_W:m.X_W + 2] if wind else None, inputs.origin, std=std,
                          navigation=plan.has_gps, wind=wind)
    diagnostics = diagnostics_frame(diag_f, diag_i, int(counters[C_DIAG]))
    table = k["table"]
    details = {
        "mode": f"error-state (multiplicative quaternion), injection per {inject}",
        "states": [s.name for s in table],
        "final_state": {name: float(x_final[i]) for i, name in enumerate(NOMINAL_NAMES)},
        "final_state_std": {s.name: float(sd[-1, a]) if count else math.nan for a, s in enumerate(table)},
        "gps_lever_arm_m": [float(v) for v in k["params"][P_LEVER:P_LEVER + 3]],
        **replay_details(inputs),
    }
    report = kernel_report(NAME, inputs, counters, timings_s=timings, details=details,
                           degradations=accel_bias_degradations(plan, m.E_BA in sel, config_accel_bias))
    return EstimatorRun(states=states, diagnostics=diagnostics, report=report)
