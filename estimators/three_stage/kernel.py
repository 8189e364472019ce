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

The loop only dispatches: the decisions when to fuse, start, reset or re-initialise are the per-sensor control
functions of :mod:`estimators.three_stage.control`, the fusion (stage steps) is in
:mod:`estimators.three_stage.stages` (docs/three_stage.md, 'Control and fusion'). Filter quantities per stage
(kernel arrays): ``x`` state, ``P`` covariance (prior before, posterior after each scalar update), innovation
``nu``, its variance ``S``, ``NIS = nu^2 / S``. Every scalar update is a diagnostics row; the innovations of
whitened vector updates (magnetometer, sun, wind) are in whitened units (R = 1).

There is no separate NumPy twin: run with ``NUMBA_DISABLE_JIT=1`` (a fresh process), the same code is the plain
Python/NumPy reference the twin test compares the compiled kernel with.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from estimators.core import linalg, reacquisition, recorder, rotations
from estimators.core.recorder import C_OUTPUTS, Recorder
from estimators.core.schedule import COVARIANCE, PERIODIC, PROPAGATE
from estimators.inputs.records import AIRSPEED, BARO, GPS_POS, GPS_VEL, MAG, OUTPUT, SUN
from estimators.three_stage.control import (
    GPS_FUSE,
    GPS_RESET,
    GPS_START,
    STALE_AFTER_S,
    accel_control,
    airspeed_input,
    attitude_update_allowed,
    gps_position_control,
    gps_velocity_control,
    gps_velocity_input,
    heading_control,
    height_input,
    held_inputs,
    restart_heading,
    stage3_start,
    wind_pseudo_due,
)
from estimators.three_stage.model import I_DEVIATION, corrected_heading
from estimators.three_stage.stages import (
    accumulate_intervals,
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


class StageStates(NamedTuple):
    """The states and covariances of the three stages (the kernel's in/out arrays, bundled for the loop's
    helpers)."""

    x1: np.ndarray  # (2,) roll, pitch [rad]
    P1: np.ndarray  # (2, 2)
    x2: np.ndarray  # (1,) heading [rad]
    P2: np.ndarray  # (1, 1)
    x3: np.ndarray  # (n3,) navigation states (estimators.three_stage.model)
    P3: np.ndarray  # (n3, n3)


class HealthyStates(NamedTuple):
    """The last healthy stage states (divergence check), the states a reset returns to."""

    x1: np.ndarray  # (2,)
    x2: np.ndarray  # (1,)
    x3: np.ndarray  # (n3,)


class GpsWork(NamedTuple):
    """The GPS data the three-stage control holds between events."""

    vel_ned: np.ndarray  # (3,) last GPS velocity NED [m/s]
    acc_ned: np.ndarray  # (3,) low-passed NED acceleration from the GPS velocity [m/s^2]
    pos_ne: np.ndarray  # (2,) last GPS north, east [m] (start of stage 3)
    pos_var: np.ndarray  # (2,) their variances [m^2]
    monitor: np.ndarray  # GPS re-acquisition monitor (estimators.core.reacquisition), armed when stage 3 starts


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
        row[O_YAW_STD] = math.sqrt(P2[0, 0] + linalg.quadratic_form(dpsi_ddev, P3, int(I_DEVIATION)))
        c, s, vg = math.cos(x3[3]), math.sin(x3[3]), x3[2]
        row[O_VN] = vg * c
        row[O_VE] = vg * s
        # first-order propagation of the (V_g, chi) covariance to (v_n, v_e)
        row[O_VN_STD] = math.sqrt(max(linalg.quadratic_form((c, -vg * s), P3, int(2)), 0.0))
        row[O_VE_STD] = math.sqrt(max(linalg.quadratic_form((s, vg * c), P3, int(2)), 0.0))
        row[O_WN] = x3[4]
        row[O_WE] = x3[5]
        row[O_WN_STD] = math.sqrt(P3[4, 4])
        row[O_WE_STD] = math.sqrt(P3[5, 5])
    else:
        row[O_VN] = x3[2]
        row[O_VE] = x3[3]
        row[O_VN_STD] = math.sqrt(P3[2, 2])
        row[O_VE_STD] = math.sqrt(P3[3, 3])


class Intervals(NamedTuple):
    """The IMU row being integrated and the input sums of the open intervals: the accelerometer update interval
    and the deferred stage-1 and stage-3 covariance propagations, with the states at their start."""

    rates: np.ndarray  # (3,) bias-corrected gyro of the IMU row [rad/s]
    f_b: np.ndarray  # (3,) specific force of the IMU row [m/s^2]
    acc_meas: np.ndarray  # (8,) sums (dt, omega dt, f dt, V_a dt) of the accelerometer update interval
    acc1: np.ndarray  # (8,) the same of the stage-1 covariance interval
    acc3: np.ndarray  # (8,) the same of the stage-3 covariance interval
    x1_start: np.ndarray  # (2,) stage-1 state at the start of its covariance interval
    x3_start: np.ndarray  # (n3,) stage-3 state at the start of its covariance interval
    attitude_start: np.ndarray  # (3,) roll, pitch, stage-2 heading [rad] at the same time


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
    iv = Intervals(np.empty(3), np.empty(3), np.zeros(8), np.zeros(8), np.zeros(8), x1.copy(), x3.copy(),
                   np.zeros(3))
    # int(): one compiled _stage_work for the three stages, not one per literal size
    work = (_stage_work(int(2), int(3), int(3)), _stage_work(int(1), int(3), int(3)),
            _stage_work(x3.shape[0], int(2), int(6)), _measurement_work())
    gps = GpsWork(np.zeros(3), np.zeros(3), np.zeros(2), np.zeros(2), reacquisition.gps_monitor())
    _loop(op, op_value, op_index, imu_t, imu_gyro, imu_accel, ev_kind, ev_val, ev_var, prm,
          StageStates(x1, P1, x2, P2, x3, P3), HealthyStates(x1.copy(), x2.copy(), x3.copy()), iv, gps, work, out,
          Recorder(diag_f, diag_i, counters))


@njit(cache=True, inline="always")  # compiled once, in run_kernel (a callee linked in is optimised again)
def _loop(op, op_value, op_index, imu_t, imu_gyro, imu_accel, ev_kind, ev_val, ev_var, prm, st, safe, iv, gps, work,
          out, rec):
    """The loop of :func:`run_kernel` over the schedule, with its arrays bundled (called once: the bundles are
    unpacked here, so that each operation passes its steps loose arrays, see :mod:`estimators.three_stage.control`)."""
    x1, P1, x2, P2, x3, P3 = st
    rates, f_b, acc_meas, acc1, acc3, x1_start, x3_start, attitude_start = iv
    (w1, w2, w3, mw), (diag_f, diag_i, counters), (x1_safe, x2_safe, x3_safe) = work, rec, safe
    gps_vel, gps_acc, gps_mon = gps.vel_ned, gps.acc_ned, gps.monitor
    held = held_inputs(prm.initial_height_m)
    row, variances = np.empty(out.shape[1]), np.empty(ev_var.shape[1])  # variances: raised to the model floor
    # bool() / int(): a loop-carried variable started from a literal would compile each callee it reaches twice
    # (docs/estimators.md, 'One compile per function')
    stage3_on, n_out = bool(False), int(0)
    reject_s, outage_s = prm.gps_reset_after_s, prm.gps_outage_reset_s  # T_rej, T_out of the re-acquisition rule
    heading_rejected_since = math.inf  # start of the current streak of gated-out heading vectors
    heading_var_reset = P2[0, 0]  # the alignment's heading variance, given to a re-acquired heading
    t = imu_t[0] if imu_t.shape[0] > 0 else 0.0
    for s in range(op.shape[0]):
        code = op[s]
        if code == PROPAGATE:
            k = op_index[s]
            dt = op_value[s]
            for i in range(3):
                rates[i] = imu_gyro[k, i] - prm.gyro_bias_rad_s[i]
                f_b[i] = imu_accel[k, i]
            va = held.va_m_s if t - held.va_t < STALE_AFTER_S else 0.0  # stale: no centripetal term
            if acc1[0] == 0.0:
                linalg.copy_into(x1_start, x1)
            if stage3_on and acc3[0] == 0.0:
                linalg.copy_into(x3_start, x3)
                attitude_start[0], attitude_start[1], attitude_start[2] = x1[0], x1[1], x2[0]
            propagate_states(dt, rates, f_b, va, prm, x1, x2, P2, x3, stage3_on)
            accumulate_intervals(acc_meas, acc1, acc3, stage3_on, dt, rates, f_b, va)
            # a step ends at its row's time, or at the time of the event that follows it (the EVENT sets t)
            t = imu_t[k]
            continue
        t = op_value[s]
        if code == COVARIANCE:
            flush_stage1(acc1, x1_start, P1, prm, w1.A, w1.G, w1.F, w1.Q, w1.W, w1.u, w1.values, w1.cols, w1.counts,
                         w1.columns)
            if stage3_on:
                flush_stage3(acc3, x3_start, attitude_start, P1, P2, P3, prm, w3.A, w3.G, w3.F, w3.Q, w3.W, w3.u,
                             w3.input_var, w3.values, w3.cols, w3.counts, w3.columns)
            continue
        if code == PERIODIC:
            mean = mw.mean
            fuse, use_gps_acc = accel_control(t, prm.gps_acceleration, held, acc_meas, x1[1], mean, counters)
            if fuse:
                stage1_update(t, mean[4:7], mean[1:4], mean[7], gps_acc if use_gps_acc else mw.no_accel, prm, x1,
                              P1, x2, w1, mw, diag_f, diag_i, counters)
                repair(P1, prm.max_var1, w1, counters)
            continue
        ie = op_index[s]  # EVENT
        kind, values = ev_kind[ie], ev_val[ie]
        for i in range(variances.shape[0]):
            variances[i] = np.maximum(ev_var[ie, i], prm.variance_floor[kind])
        if kind == OUTPUT:
            # divergence check at the output rate: never a non-finite output row (reset to the last healthy)
            check_health(x1, P1, x1_safe, prm.p1_0, counters)
            check_health(x2, P2, x2_safe, prm.p2_0, counters)
            if stage3_on:
                check_health(x3, P3, x3_safe, prm.p3_0, counters)
            _output_row(t, x1, P1, x2, P2, x3, P3, stage3_on, prm.fixed_wing_nav, held.height_m,
                        held.vertical_speed_m_s, row)
            recorder.record_output(out, n_out, row)
            n_out += 1
        elif kind == AIRSPEED:
            held = airspeed_input(t, values[0], prm.airspeed_lpf_s, held)
        elif kind == BARO or (kind == GPS_POS and prm.height_from_gps):
            held = height_input(t, values[0] if kind == BARO else -values[2], prm.baro_lpf_s,
                                prm.vertical_speed_lpf_s, held)
        if kind in (MAG, SUN):
            if attitude_update_allowed(x1[1], counters):
                gated, heading = stage2_update(t, kind, values, variances, prm, x1, P1, x2, P2, w2, mw, diag_f,
                                               diag_i, counters)
                heading_rejected_since, restart = heading_control(t, gated, heading, heading_rejected_since, reject_s)
                if restart:
                    restart_heading(heading, heading_var_reset, x2, P2, counters)
                repair(P2, prm.max_var2, w2, counters)
        elif kind == GPS_POS:
            fuse, held = gps_position_control(t, values, variances, stage3_on, reject_s, outage_s, held, gps, x3, P3,
                                              counters)
            if fuse:
                if wind_pseudo_due(prm.fixed_wing_nav, t, held):
                    stage3_fw_wind(t, held.va_m_s, gps_vel[2], prm, x2, P2, x3, P3, w3, mw, diag_f, diag_i, counters)
                stage3_gps_position(t, values, variances, prm, x3, P3, w3, gps_mon, diag_f, diag_i, counters)
                repair(P3, prm.max_var3, w3, counters)
        elif kind == GPS_VEL:
            held = gps_velocity_input(t, values, prm.gps_acceleration_lpf_s, held, gps_vel, gps_acc)
            action = gps_velocity_control(t, math.hypot(values[0], values[1]), stage3_on, prm.min_ground_speed_m_s,
                                          prm.fixed_wing_nav, reject_s, outage_s, held, gps_mon, counters)
            if action == GPS_START:
                stage3_start(values, variances, prm, x3, P3, gps, x3_safe, acc3)
                stage3_on = True
            elif action == GPS_RESET:
                stage3_init_velocity(values, variances, prm, x3, P3)
            elif action == GPS_FUSE:
                stage3_gps_velocity(t, values, variances, prm, x3, P3, w3, gps_mon, diag_f, diag_i, counters)
                repair(P3, prm.max_var3, w3, counters)
    counters[C_OUTPUTS] = n_out
