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
    HELD_HEIGHT,
    HELD_VERTICAL_SPEED,
    accel_control,
    airspeed_input,
    fresh_airspeed,
    gps_position_control,
    gps_velocity_control,
    gps_velocity_input,
    heading_control,
    height_input,
    held_inputs,
)
from estimators.three_stage.model import I_DEVIATION, corrected_heading
from estimators.three_stage.stages import accumulate, check_health, flush_stage1, flush_stage3, propagate_states

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


class KernelWork(NamedTuple):
    """Preallocated arrays of one run besides the stage states: the kernel loop allocates nothing per sample."""

    w1: StageWork
    w2: StageWork
    w3: StageWork
    mw: MeasurementWork
    x1_safe: np.ndarray  # (2,) last healthy states (divergence check)
    x2_safe: np.ndarray  # (1,)
    x3_safe: np.ndarray  # (n3,)
    rates: np.ndarray  # (3,) bias-corrected gyro of the IMU row [rad/s]
    f_b: np.ndarray  # (3,) specific force of the IMU row [m/s^2]
    variances: np.ndarray  # (n_values,) event variances raised to the model-error floor
    # input sums (dt, omega dt, f dt, V_a dt) of the accelerometer update interval and of the deferred stage-1
    # and stage-3 covariance propagations, with the states and attitude at the start of those intervals
    acc_meas: np.ndarray  # (8,)
    acc1: np.ndarray  # (8,)
    acc3: np.ndarray  # (8,)
    x1_start: np.ndarray  # (2,)
    x3_start: np.ndarray  # (n3,)
    attitude_start: np.ndarray  # (3,) roll, pitch, stage-2 heading [rad]
    gps_vel: np.ndarray  # (3,) last GPS velocity NED [m/s]
    gps_acc: np.ndarray  # (3,) low-passed NED acceleration from the GPS velocity [m/s^2]
    gps_pos: np.ndarray  # (2,) last GPS north, east [m] (start of stage 3)
    gps_pos_var: np.ndarray  # (2,) their variances [m^2]
    gps_mon: np.ndarray  # GPS re-acquisition monitor (estimators.core.reacquisition), armed when stage 3 starts
    row: np.ndarray  # (len(OUT_COLUMNS),) output row scratch


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
def _kernel_work(x1, x2, x3, n_values, n_columns):
    """Work arrays of a run with the initial stage states ``x1, x2, x3``, ``n_values`` event values and
    ``n_columns`` output columns."""
    n3 = x3.shape[0]
    return KernelWork(_stage_work(2, 3, 3), _stage_work(1, 3, 3), _stage_work(n3, 2, 6), _measurement_work(),
                      x1.copy(), x2.copy(), x3.copy(), np.empty(3), np.empty(3), np.empty(n_values), np.zeros(8),
                      np.zeros(8), np.zeros(8), x1.copy(), x3.copy(), np.zeros(3), np.zeros(3), np.zeros(3),
                      np.zeros(2), np.zeros(2), reacquisition.gps_monitor(), np.empty(n_columns))


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


@njit(cache=True, inline="always")
def _propagate(dt, imu_gyro, imu_accel, k, va, prm, st, stage3_on, w):
    """``PROPAGATE``: the states over ``dt`` [s] with IMU row ``k`` (gyro [rad/s], accelerometer [m/s^2]) and
    the airspeed ``va`` [m/s] held; the inputs summed for the accelerometer update and the deferred covariances
    (their start states kept when an interval begins)."""
    rates, f_b = w.rates, w.f_b
    for i in range(3):
        rates[i] = imu_gyro[k, i] - prm.gyro_bias_rad_s[i]
        f_b[i] = imu_accel[k, i]
    if w.acc1[0] == 0.0:
        w.x1_start[:] = st.x1
    if stage3_on and w.acc3[0] == 0.0:
        w.x3_start[:] = st.x3
        w.attitude_start[0], w.attitude_start[1], w.attitude_start[2] = st.x1[0], st.x1[1], st.x2[0]
    propagate_states(dt, rates, f_b, va, prm, st.x1, st.x2, st.P2, st.x3, stage3_on)
    accumulate(w.acc_meas, dt, rates, f_b, va)
    accumulate(w.acc1, dt, rates, f_b, va)
    if stage3_on:
        accumulate(w.acc3, dt, rates, f_b, va)


@njit(cache=True, inline="always")
def _flush(prm, st, stage3_on, w):
    """``COVARIANCE``: the deferred covariance propagation of stage 1 and, once it runs, stage 3."""
    w1, w3 = w.w1, w.w3
    flush_stage1(w.acc1, w.x1_start, st.P1, prm, w1.A, w1.G, w1.F, w1.Q, w1.W, w1.u, w1.values, w1.cols, w1.counts,
                 w1.columns)
    if stage3_on:
        flush_stage3(w.acc3, w.x3_start, w.attitude_start, st.P1, st.P2, st.P3, prm, w3.A, w3.G, w3.F, w3.Q, w3.W,
                     w3.u, w3.input_var, w3.values, w3.cols, w3.counts, w3.columns)


@njit(cache=True, inline="always")
def _output(t, prm, st, stage3_on, held, w, out, n_out, counters):
    """``OUTPUT`` at ``t`` [s]: the divergence check (never a non-finite output row: reset to the last healthy
    state), then output row ``n_out``."""
    check_health(st.x1, st.P1, w.x1_safe, prm.p1_0, counters)
    check_health(st.x2, st.P2, w.x2_safe, prm.p2_0, counters)
    if stage3_on:
        check_health(st.x3, st.P3, w.x3_safe, prm.p3_0, counters)
    _output_row(t, st.x1, st.P1, st.x2, st.P2, st.x3, st.P3, stage3_on, prm.fixed_wing_nav, held[HELD_HEIGHT],
                held[HELD_VERTICAL_SPEED], w.row)
    recorder.record_output(out, n_out, w.row)


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
    st = StageStates(x1, P1, x2, P2, x3, P3)
    w = _kernel_work(x1, x2, x3, ev_var.shape[1], out.shape[1])
    rec = Recorder(diag_f, diag_i, counters)
    held = held_inputs(prm.initial_height_m)
    stage3_on = False
    heading_rejected_since = math.inf  # start of the current streak of gated-out heading vectors
    heading_var_reset = P2[0, 0]  # the alignment's heading variance, given to a re-acquired heading
    n_out = 0
    t = imu_t[0] if imu_t.shape[0] > 0 else 0.0
    for s in range(op.shape[0]):
        code = op[s]
        if code == PROPAGATE:
            k = op_index[s]
            _propagate(op_value[s], imu_gyro, imu_accel, k, fresh_airspeed(t, held), prm, st, stage3_on, w)
            # a step ends at its row's time, or at the time of the event that follows it (the EVENT sets t)
            t = imu_t[k]
            continue
        t = op_value[s]
        if code == COVARIANCE:
            _flush(prm, st, stage3_on, w)
        elif code == PERIODIC:
            accel_control(t, prm, st, held, w, rec)
        else:  # EVENT
            ie = op_index[s]
            kind = ev_kind[ie]
            values = ev_val[ie]
            variances = w.variances
            for i in range(variances.shape[0]):
                variances[i] = np.maximum(ev_var[ie, i], prm.variance_floor[kind])
            if kind == OUTPUT:
                _output(t, prm, st, stage3_on, held, w, out, n_out, counters)
                n_out += 1
            elif kind == AIRSPEED:
                airspeed_input(t, values[0], prm, held)
            elif kind == BARO or (kind == GPS_POS and prm.height_from_gps):
                height_input(t, values[0] if kind == BARO else -values[2], prm, held)
            if kind in (MAG, SUN):
                heading_rejected_since = heading_control(t, kind, values, variances, prm, st, heading_var_reset,
                                                         heading_rejected_since, w, rec)
            elif kind == GPS_POS:
                gps_position_control(t, values, variances, prm, st, stage3_on, held, w, rec)
            elif kind == GPS_VEL:
                gps_velocity_input(t, values, prm, held, w)
                stage3_on = gps_velocity_control(t, values, variances, prm, st, stage3_on, held, w, rec)
    counters[C_OUTPUTS] = n_out
