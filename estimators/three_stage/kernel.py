"""The compiled loop of the three-stage series estimator (numba): kernel parameters, work arrays and
:func:`run_kernel`.

The loop executes the operations of the shared schedule (:func:`estimators.core.schedule.build_schedule`,
docs/estimators.md, 'Scheduling rule'), built once per run by :func:`estimators.three_stage.run.run`:

* ``PROPAGATE``: the three states over the step with the IMU row held
  (:func:`~estimators.three_stage.stages.propagate_states`), the inputs summed for stage 1 (and stage 3 once it
  runs) and for the accelerometer update interval;
* ``COVARIANCE``: the deferred covariance propagation of stage 1 and, once it runs, stage 3, over what they
  accumulated (the schedule emits one at the covariance interval and before every measurement update, so the
  stage-2 and GPS updates see the covariances at their own time);
* ``EVENT``: an output row (with the divergence check), a low-passed input (airspeed, barometer height), a stage-2
  heading update (magnetometer, sun) or a GPS epoch of stage 3 (start, re-acquisition, wind pseudo-measurement,
  position, velocity);
* ``PERIODIC``: the stage-1 accelerometer update at ``accel_update_rate_hz``, with the specific force and the rates
  averaged over the update interval.

The stage steps are in :mod:`estimators.three_stage.stages`. Filter quantities per stage (kernel arrays): ``x``
state, ``P`` covariance (prior before, posterior after each scalar update), innovation ``nu``, its variance ``S``,
``NIS = nu^2 / S``. Every scalar update is a diagnostics row; the innovations of whitened vector updates
(magnetometer, sun, wind) are in whitened units (R = 1).

There is no separate NumPy twin: run with ``NUMBA_DISABLE_JIT=1`` (a fresh process), the same code is the plain
Python/NumPy reference the twin test compares the compiled kernel with.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from estimators.core import linalg, reacquisition, recorder, rotations
from estimators.core.recorder import C_GPS_RESETS, C_OUTPUTS, N_SHARED_COUNTERS
from estimators.core.schedule import COVARIANCE, PERIODIC, PROPAGATE
from estimators.inputs.records import AIRSPEED, BARO, GPS_POS, GPS_VEL, MAG, OUTPUT, SUN
from estimators.three_stage.model import I_DEVIATION, corrected_heading
from estimators.three_stage.stages import (
    accumulate,
    check_health,
    flush_stage1,
    flush_stage3,
    propagate_states,
    repair,
    stage1_update,
    stage2_update,
    stage3_fw_wind,
    stage3_gps_position,
    stage3_gps_velocity,
    stage3_init_velocity,
)

#: Columns of the kernel's output array (angles [rad], positions [m], speeds [m/s]; ``*_std`` 1-sigma).
OUT_COLUMNS = ("time_s", "roll", "pitch", "yaw", "pn", "pe", "pd", "vn", "ve", "vd", "wn", "we",
               "roll_std", "pitch_std", "yaw_std", "pn_std", "pe_std", "vn_std", "ve_std", "wn_std", "we_std")
(O_TIME, O_ROLL, O_PITCH, O_YAW, O_PN, O_PE, O_PD, O_VN, O_VE, O_VD, O_WN, O_WE, O_ROLL_STD, O_PITCH_STD, O_YAW_STD,
 O_PN_STD, O_PE_STD, O_VN_STD, O_VE_STD, O_WN_STD, O_WE_STD) = range(len(OUT_COLUMNS))

# kernel counters: the shared slots of estimators.core.recorder (C_DIAG .. C_OUTPUTS), then this filter's
C_PITCH_GUARD = N_SHARED_COUNTERS  # attitude updates skipped at the Euler singularity
C_HEADING_RESETS = N_SHARED_COUNTERS + 1  # stage-2 heading re-acquisitions
N_COUNTERS = N_SHARED_COUNTERS + 2

#: Attitude updates are skipped beyond this pitch (Euler singularity) [rad].
PITCH_GUARD_RAD = math.radians(85.0)
#: An airspeed or GPS value older than this is stale: no centripetal term, no wind pseudo, no GPS acceleration [s].
STALE_AFTER_S = 1.0
#: Variance floor of the covariance repair.
MIN_VARIANCE = 1e-12


class KernelParams(NamedTuple):
    """Scalars and small arrays of one run, read by the compiled kernel (units in the names)."""

    gravity_m_s2: float
    gyro_bias_rad_s: np.ndarray  # (3,) removed from every gyro row
    gyro_psd: np.ndarray  # (3,) gyro noise density squared per axis [rad^2/s]
    accel_psd: float  # accelerometer noise density squared [m^2/s^3]
    accel_var: np.ndarray  # (3,) stage-1 R per axis at the update rate [m^2/s^4], tau on y
    variance_floor: np.ndarray  # (n_kinds,) model-error floor of each event kind's variances
    accel_gate: float
    manoeuvre_threshold_m_s2: float
    airspeed_model: bool  # stage 1 steady-flight model with airspeed (fixed-wing with airspeed)
    gps_acceleration: bool  # stage 1 acceleration form (without airspeed)
    fixed_wing_nav: bool  # stage 3 fixed-wing mode
    paper_gps_velocity: bool  # GPS velocity as ground speed and course
    height_from_gps: bool  # no barometer: height from GPS
    initial_height_m: float  # height above the origin until the first height sample (NaN: no height source)
    cascade_inflation: bool
    qc1: np.ndarray  # (2, 2) random-walk densities [rad^2/s]
    qc2: float
    qc3: np.ndarray  # (n3, n3)
    a3_multicopter: np.ndarray  # (4, 4) constant Jacobian of the multicopter navigation model
    p1_0: np.ndarray
    p2_0: np.ndarray
    p3_0: np.ndarray
    max_var1: np.ndarray
    max_var2: np.ndarray
    max_var3: np.ndarray
    mag_field_ned: np.ndarray  # (3,) unit
    mag_gate_d2: float  # chi-square threshold of the 3-component magnetometer vector
    sun_gate_d2: float  # chi-square threshold of the 2-component sun vector
    gps_pos_gate: float
    gps_vel_gate: float
    airspeed_var: float  # [m^2/s^2]
    wind_pseudo_var: float  # [m^2/s^2]
    airspeed_lpf_s: float
    baro_lpf_s: float
    vertical_speed_lpf_s: float
    gps_acceleration_lpf_s: float
    min_ground_speed_m_s: float
    gps_reset_after_s: float  # T_rej of the GPS re-acquisition rule (docs/estimators.md, 'GPS re-acquisition') [s]
    gps_outage_reset_s: float  # T_out of the same rule [s]


class StageWork(NamedTuple):
    """Preallocated work arrays of one stage with ``n`` states: the kernel loop allocates nothing per sample."""

    A: np.ndarray  # (n, n) continuous Jacobian df/dx
    G: np.ndarray  # (n, n_inputs) input-noise Jacobian df/du
    F: np.ndarray  # (n, n) transition matrix
    Q: np.ndarray  # (n, n) discrete process noise
    W: np.ndarray  # (n, n) scratch of the covariance propagation and repair
    u: np.ndarray  # (n_u,) mean inputs of a deferred covariance propagation
    input_var: np.ndarray  # (n_inputs,) variances of the inputs in G
    H: np.ndarray  # (3, n) measurement Jacobian rows (whitened in place by vector updates)
    dx: np.ndarray  # (n,) correction of a scalar update
    ph: np.ndarray  # (n,) P H^T scratch
    min_var: np.ndarray  # (n,) variance floor of the covariance repair
    values: np.ndarray  # (n, n) scratch of the sparse covariance product (linalg.propagate_covariance_into)
    cols: np.ndarray  # (n, n) int64, the same
    counts: np.ndarray  # (n,) int64, the same
    columns: np.ndarray  # (n,) int64 arange(n), the same


class MeasurementWork(NamedTuple):
    """Preallocated work arrays of the measurement models and vector updates (up to 3 components)."""

    h: np.ndarray  # (3,) predicted measurement
    jac: np.ndarray  # (3, 3) dh/d(phi, theta, psi)
    c: np.ndarray  # (3, 2) stage-1 dh/d(phi, theta) of the airspeed model
    z: np.ndarray  # (3,) measured unit vector
    tilt: np.ndarray  # (3, 2) dh/d(phi, theta) of a heading update (cascade inflation)
    nu: np.ndarray  # (3, 1) innovation (whitened in place)
    R: np.ndarray  # (3, 3) measurement noise
    L: np.ndarray  # (3, 3) Cholesky factor
    S: np.ndarray  # (3, 3) whitened innovation covariance
    y: np.ndarray  # (3, 1) S-whitened innovation
    mean: np.ndarray  # (8,) inputs averaged over the accelerometer update interval
    no_accel: np.ndarray  # (3,) zero NED acceleration (gravity-only stage-1 model)


@njit(cache=True)
def _stage_work(n, n_inputs, n_u):
    """Work arrays of a stage with ``n`` states, ``n_inputs`` noisy inputs and ``n_u`` model inputs."""
    return StageWork(np.zeros((n, n)), np.zeros((n, n_inputs)), np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n)),
                     np.zeros(n_u), np.zeros(n_inputs), np.zeros((3, n)), np.zeros(n),
                     np.zeros(n), np.full(n, MIN_VARIANCE), np.zeros((n, n)), np.zeros((n, n), dtype=np.int64),
                     np.zeros(n, dtype=np.int64), np.arange(n))


@njit(cache=True)
def _measurement_work():
    """Work arrays of the measurement updates."""
    return MeasurementWork(np.zeros(3), np.zeros((3, 3)), np.zeros((3, 2)), np.zeros(3), np.zeros((3, 2)),
                           np.zeros((3, 1)), np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 1)),
                           np.zeros(8), np.zeros(3))


@njit(cache=True)
def _lowpass(value, sample, dt, tau):
    """One step of a first-order low-pass with time constant ``tau`` over ``dt`` (exact for a held sample)."""
    return value + (1.0 - math.exp(-dt / tau)) * (sample - value)


@njit(cache=True, inline="always")
def _output_row(t, x1, P1, x2, P2, x3, P3, stage3_on, fixed_wing_nav, height, vertical_speed, row):
    row[:] = math.nan
    row[O_TIME] = t
    row[O_ROLL] = x1[0]
    row[O_PITCH] = x1[1]
    row[O_YAW] = x2[0]
    row[O_ROLL_STD] = math.sqrt(P1[0, 0])
    row[O_PITCH_STD] = math.sqrt(P1[1, 1])
    row[O_YAW_STD] = math.sqrt(P2[0, 0])
    row[O_PD] = -height
    row[O_VD] = -vertical_speed
    if not stage3_on:
        return
    row[O_PN] = x3[0]
    row[O_PE] = x3[1]
    row[O_PN_STD] = math.sqrt(P3[0, 0])
    row[O_PE_STD] = math.sqrt(P3[1, 1])
    if fixed_wing_nav:
        # heading corrected by the stage-3 deviation estimate (its correlation with stage 2 is not tracked)
        psi, _, dpsi_ddev = corrected_heading(x3, x2[0])
        row[O_YAW] = rotations.wrap_pi(psi)
        row[O_YAW_STD] = math.sqrt(P2[0, 0] + linalg.quadratic_form(dpsi_ddev, P3, I_DEVIATION))
        c, s, vg = math.cos(x3[3]), math.sin(x3[3]), x3[2]
        row[O_VN] = vg * c
        row[O_VE] = vg * s
        # first-order propagation of the (V_g, chi) covariance to (v_n, v_e)
        row[O_VN_STD] = math.sqrt(max(linalg.quadratic_form((c, -vg * s), P3, 2), 0.0))
        row[O_VE_STD] = math.sqrt(max(linalg.quadratic_form((s, vg * c), P3, 2), 0.0))
        row[O_WN] = x3[4]
        row[O_WE] = x3[5]
        row[O_WN_STD] = math.sqrt(P3[4, 4])
        row[O_WE_STD] = math.sqrt(P3[5, 5])
    else:
        row[O_VN] = x3[2]
        row[O_VE] = x3[3]
        row[O_VN_STD] = math.sqrt(P3[2, 2])
        row[O_VE_STD] = math.sqrt(P3[3, 3])


@njit(cache=True, nogil=True)  # the replays of noise identification run in threads
def run_kernel(op, op_value, op_index, imu_t, imu_gyro, imu_accel, ev_kind, ev_val, ev_var, prm, x1, P1, x2, P2,
               x3, P3, out, diag_f, diag_i, counters):
    """The three stages over a whole log (one compiled loop over the schedule; see the module docstring).

    Parameters
    ----------
    op, op_value, op_index : ndarrays (S,)
        The schedule (:func:`estimators.core.schedule.build_schedule`): operation codes, ``PROPAGATE`` step or
        operation time [s], ``PROPAGATE`` IMU row or ``EVENT`` event index.
    imu_t, imu_gyro, imu_accel : ndarrays (N,), (N, 3), (N, 3)
        IMU rows (:class:`estimators.inputs.records.ImuSamples`): row k holds over ``(imu_t[k-1], imu_t[k]]``.
    ev_kind, ev_val, ev_var : ndarrays
        Events (:class:`estimators.inputs.records.MeasurementEvents`); their times are in the schedule.
    prm : KernelParams
    x1, P1, x2, P2 : ndarrays (2,), (2, 2), (1,), (1, 1)
        Stage 1 and 2 state and covariance, initial on entry, final on return (in place).
    x3, P3 : ndarrays (n3,), (n3, n3)
        Stage 3 state and covariance (n3 = 9 fixed-wing, 4 multicopter mode); initialised at the first GPS epoch.
    out : ndarray (K, len(OUT_COLUMNS))
        One row per OUTPUT event.
    diag_f, diag_i : ndarrays
        Diagnostics recorder arrays (:mod:`estimators.core.recorder`).
    counters : int64 (N_COUNTERS,)
    """
    n3 = x3.shape[0]
    w1, w2, w3 = _stage_work(2, 3, 3), _stage_work(1, 3, 3), _stage_work(n3, 2, 6)
    mw = _measurement_work()
    x1_safe, x2_safe, x3_safe = x1.copy(), x2.copy(), x3.copy()
    row = np.empty(out.shape[1])
    rates, f_b = np.empty(3), np.empty(3)  # bias-corrected gyro and specific force of the IMU row
    variances = np.empty(ev_var.shape[1])  # event variances raised to the model-error floor
    stage3_on = False
    # input sums (dt, omega dt, f dt, V_a dt) of the accelerometer update interval and of the deferred stage-1 and
    # stage-3 covariance propagations, with the states and attitude at the start of those intervals
    acc_meas, acc1, acc3 = np.zeros(8), np.zeros(8), np.zeros(8)
    x1_start, x3_start, attitude_start = x1.copy(), x3.copy(), np.zeros(3)
    # low-passed inputs and their sample times
    va, va_t = 0.0, -math.inf
    height, height_t = prm.initial_height_m, -math.inf
    vertical_speed = 0.0 if math.isfinite(height) else math.nan
    gps_vel, gps_vel_t = np.zeros(3), -math.inf
    gps_acc = np.zeros(3)
    gps_pos, gps_pos_var = np.zeros(2), np.zeros(2)
    gps_pos_t = -math.inf
    gps_mon = reacquisition.gps_monitor()  # re-acquisition rule, armed when stage 3 starts
    heading_rejected_since = math.inf  # start of the current streak of gated-out heading vectors
    P2_reset = P2[0, 0]  # the alignment's heading variance, given to a re-acquired heading
    n_out = 0
    t = imu_t[0] if imu_t.shape[0] > 0 else 0.0
    for s in range(op.shape[0]):
        code = op[s]
        if code == PROPAGATE:
            k = op_index[s]
            dt = op_value[s]
            for i in range(3):
                rates[i] = imu_gyro[k, i] - prm.gyro_bias_rad_s[i]
                f_b[i] = imu_accel[k, i]
            va_in = va if t - va_t < STALE_AFTER_S else 0.0
            if acc1[0] == 0.0:
                x1_start[:] = x1
            if stage3_on and acc3[0] == 0.0:
                x3_start[:] = x3
                attitude_start[0], attitude_start[1], attitude_start[2] = x1[0], x1[1], x2[0]
            propagate_states(dt, rates, f_b, va_in, prm, x1, x2, P2, x3, stage3_on)
            accumulate(acc_meas, dt, rates, f_b, va_in)
            accumulate(acc1, dt, rates, f_b, va_in)
            if stage3_on:
                accumulate(acc3, dt, rates, f_b, va_in)
            # a step ends at its row's time, or at the time of the event that follows it (the EVENT sets t)
            t = imu_t[k]
            continue
        t = op_value[s]
        if code == COVARIANCE:
            flush_stage1(acc1, x1_start, P1, prm, w1.A, w1.G, w1.F, w1.Q, w1.W, w1.u,
                         w1.values, w1.cols, w1.counts, w1.columns)
            if stage3_on:
                flush_stage3(acc3, x3_start, attitude_start, P1, P2, P3, prm, w3.A, w3.G, w3.F, w3.Q, w3.W, w3.u,
                             w3.input_var, w3.values, w3.cols, w3.counts, w3.columns)
            continue
        if code == PERIODIC:
            # stage 1 at the accelerometer update rate, with the inputs averaged over the interval
            if acc_meas[0] > 0.0:
                if abs(x1[1]) > PITCH_GUARD_RAD:
                    counters[C_PITCH_GUARD] += 1
                else:
                    use_gps_acc = prm.gps_acceleration and t - gps_vel_t < STALE_AFTER_S
                    accel_n = gps_acc if use_gps_acc else mw.no_accel
                    mean = mw.mean
                    for i in range(8):
                        mean[i] = acc_meas[i] / acc_meas[0]
                    stage1_update(t, mean[4:7], mean[1:4], mean[7], accel_n, prm, x1, P1, x2, w1, mw, diag_f,
                                  diag_i, counters)
                    repair(P1, prm.max_var1, w1, counters)
                acc_meas[:] = 0.0
            continue
        # EVENT
        ie = op_index[s]
        kind = ev_kind[ie]
        values = ev_val[ie]
        for i in range(variances.shape[0]):
            variances[i] = np.maximum(ev_var[ie, i], prm.variance_floor[kind])
        if kind == OUTPUT:
            # divergence check at the output rate: never a non-finite output row (reset to the last healthy)
            check_health(x1, P1, x1_safe, prm.p1_0, counters)
            check_health(x2, P2, x2_safe, prm.p2_0, counters)
            if stage3_on:
                check_health(x3, P3, x3_safe, prm.p3_0, counters)
            _output_row(t, x1, P1, x2, P2, x3, P3, stage3_on, prm.fixed_wing_nav, height, vertical_speed, row)
            recorder.record_output(out, n_out, row)
            n_out += 1
        elif kind == AIRSPEED:
            va = values[0] if t - va_t > STALE_AFTER_S else _lowpass(va, values[0], t - va_t, prm.airspeed_lpf_s)
            va_t = t
        elif kind == BARO or (kind == GPS_POS and prm.height_from_gps):
            sample = values[0] if kind == BARO else -values[2]
            if height_t == -math.inf:  # first sample
                height, vertical_speed = sample, 0.0
            else:
                rate = (sample - height) / prm.baro_lpf_s  # rate of the first-order filter
                height = _lowpass(height, sample, t - height_t, prm.baro_lpf_s)
                vertical_speed = _lowpass(vertical_speed, rate, t - height_t, prm.vertical_speed_lpf_s)
            height_t = t
        if kind in (MAG, SUN):
            if abs(x1[1]) > PITCH_GUARD_RAD:
                counters[C_PITCH_GUARD] += 1
            else:
                gated, heading = stage2_update(t, kind, values, variances, prm, x1, P1, x2, P2, w2, mw, diag_f,
                                               diag_i, counters)
                if gated:
                    heading_rejected_since = math.inf
                elif heading_rejected_since == math.inf:
                    heading_rejected_since = t
                elif t - heading_rejected_since >= prm.gps_reset_after_s and math.isfinite(heading):
                    # heading re-acquisition, the rule of the GPS (docs/estimators.md, 'GPS re-acquisition'):
                    # every vector rejected for T_rej means the heading, not the sensor, is wrong; restart from
                    # the measured heading
                    x2[0] = heading
                    P2[0, 0] = P2_reset
                    heading_rejected_since = math.inf
                    counters[C_HEADING_RESETS] += 1
                repair(P2, prm.max_var2, w2, counters)
        elif kind == GPS_POS:
            gps_pos_t = t
            gps_pos[:] = values[:2]
            gps_pos_var[:] = variances[:2]
            reset, counted = False, False
            if stage3_on:
                reset, counted = reacquisition.gps_reset_due(gps_mon, True, t, prm.gps_reset_after_s,
                                                             prm.gps_outage_reset_s)
            if reset:
                # re-acquisition: position (and velocity, at its event) to GPS, variances to R, cross-covariances
                # zeroed (docs/estimators.md, 'GPS re-acquisition')
                for i in range(2):
                    x3[i] = values[i]
                    for j in range(n3):
                        P3[i, j] = 0.0
                        P3[j, i] = 0.0
                    P3[i, i] = variances[i]
                if counted:
                    counters[C_GPS_RESETS] += 1
            elif stage3_on:
                if prm.fixed_wing_nav and t - va_t < STALE_AFTER_S:
                    stage3_fw_wind(t, va, gps_vel[2], prm, x2, P2, x3, P3, w3, mw, diag_f, diag_i, counters)
                stage3_gps_position(t, values, variances, prm, x3, P3, w3, gps_mon, diag_f, diag_i, counters)
                repair(P3, prm.max_var3, w3, counters)
        elif kind == GPS_VEL:
            dt_gps = t - gps_vel_t
            if 0.0 < dt_gps < STALE_AFTER_S:
                for i in range(3):
                    gps_acc[i] = _lowpass(gps_acc[i], (values[i] - gps_vel[i]) / dt_gps, dt_gps,
                                          prm.gps_acceleration_lpf_s)
            else:
                gps_acc[:] = 0.0
            gps_vel[:] = values[:3]
            gps_vel_t = t
            if not stage3_on:
                fast = math.hypot(values[0], values[1]) > prm.min_ground_speed_m_s
                if gps_pos_t == t and (fast or not prm.fixed_wing_nav):
                    # start of stage 3 at this GPS epoch: position (from its GPS_POS event) and velocity
                    x3[:] = 0.0
                    P3[:, :] = prm.p3_0
                    for i in range(2):
                        x3[i] = gps_pos[i]
                        P3[i, i] = max(P3[i, i], gps_pos_var[i])
                    stage3_init_velocity(values, variances, prm, x3, P3)
                    x3_safe[:] = x3
                    acc3[:] = 0.0
                    stage3_on = True
                    reacquisition.gps_acquired(gps_mon, t)
            else:
                reset, counted = reacquisition.gps_reset_due(gps_mon, False, t, prm.gps_reset_after_s,
                                                             prm.gps_outage_reset_s)
                if reset:
                    stage3_init_velocity(values, variances, prm, x3, P3)
                    if counted:
                        counters[C_GPS_RESETS] += 1
                else:
                    stage3_gps_velocity(t, values, variances, prm, x3, P3, w3, gps_mon, diag_f, diag_i, counters)
                    repair(P3, prm.max_var3, w3, counters)
    counters[C_OUTPUTS] = n_out
