"""Control of the three-stage kernel (numba): when each sensor is fused, and when a stage is started, reset or
re-initialised instead (PX4 EKF2's ``*_control.cpp``); the fusion itself (innovation, H, update) is in
:mod:`estimators.three_stage.stages`.

Per sensor, called by :func:`estimators.three_stage.kernel.run_kernel` at its events:

* :func:`accel_control` (``PERIODIC``): the stage-1 accelerometer update with the inputs averaged over the
  update interval, skipped at the Euler singularity;
* :func:`heading_control` (magnetometer, sun): the stage-2 update, and the heading re-acquisition by the shared
  rejection rule of :mod:`estimators.core.reacquisition`;
* :func:`gps_position_control`, :func:`gps_velocity_control`: the start of stage 3 at the first GPS epoch
  (:func:`stage3_start`), the GPS re-acquisition (:func:`estimators.core.reacquisition.gps_control`), else the
  wind pseudo-measurement and the GPS updates;
* :func:`airspeed_input`, :func:`height_input`, :func:`gps_velocity_input`: the low-passed inputs the stages
  read (held in the slots ``HELD_*`` of one float64 array, :func:`held_inputs`).

Arguments: ``prm`` :class:`~estimators.three_stage.kernel.KernelParams`, ``st`` the stage states
(:class:`~estimators.three_stage.kernel.StageStates`), ``w`` the run's work arrays
(:class:`~estimators.three_stage.kernel.KernelWork`), ``rec`` the recorder arrays
(:class:`~estimators.core.recorder.Recorder`). Every function here has one call site and is ``inline="always"``:
the loop pays no call (a numba call keeps a reference-count pair per array argument) and compiles the same code.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from estimators.core import reacquisition
from estimators.core.recorder import N_SHARED_COUNTERS
from estimators.inputs.records import GPS_POS, GPS_VEL
from estimators.three_stage.stages import (
    repair,
    stage1_update,
    stage2_update,
    stage3_fw_wind,
    stage3_gps_position,
    stage3_gps_velocity,
    stage3_init_velocity,
)

# kernel counters: the shared slots of estimators.core.recorder (C_DIAG .. C_OUTPUTS), then this filter's
C_PITCH_GUARD = N_SHARED_COUNTERS  # attitude updates skipped at the Euler singularity
C_HEADING_RESETS = N_SHARED_COUNTERS + 1  # stage-2 heading re-acquisitions
N_COUNTERS = N_SHARED_COUNTERS + 2

#: Attitude updates are skipped beyond this pitch (Euler singularity) [rad].
PITCH_GUARD_RAD = math.radians(85.0)
#: An airspeed or GPS value older than this is stale: no centripetal term, no wind pseudo, no GPS acceleration [s].
STALE_AFTER_S = 1.0

# slots of the held-input array: low-passed true airspeed [m/s], barometric (or GPS) height above the origin [m]
# and its rate [m/s], and the times [s] of the last airspeed, height, GPS velocity and GPS position samples
HELD_VA = 0
HELD_VA_T = 1
HELD_HEIGHT = 2
HELD_HEIGHT_T = 3
HELD_VERTICAL_SPEED = 4
HELD_GPS_VEL_T = 5
HELD_GPS_POS_T = 6
N_HELD = 7


@njit(cache=True)
def held_inputs(initial_height_m):
    """The held inputs before the first sample: no airspeed, the height ``initial_height_m`` [m] (NaN: no height
    source, and no vertical speed), no GPS."""
    held = np.full(N_HELD, -math.inf)
    held[HELD_VA] = 0.0
    held[HELD_HEIGHT] = initial_height_m
    held[HELD_VERTICAL_SPEED] = 0.0 if math.isfinite(initial_height_m) else math.nan
    return held


@njit(cache=True)
def _lowpass(value, sample, dt, tau):
    """One step of a first-order low-pass with time constant ``tau`` over ``dt`` (exact for a held sample)."""
    return value + (1.0 - math.exp(-dt / tau)) * (sample - value)


@njit(cache=True, inline="always")
def fresh_airspeed(t, held):
    """The held true airspeed [m/s] at ``t`` [s], 0 when stale (no centripetal term)."""
    return held[HELD_VA] if t - held[HELD_VA_T] < STALE_AFTER_S else 0.0


# ----------------------------------------------------------------------------------------------------------------
# inputs


@njit(cache=True, inline="always")
def airspeed_input(t, airspeed_m_s, prm, held):
    """An airspeed sample at ``t`` [s]: low-passed (restarted after a stale gap)."""
    va, va_t = held[HELD_VA], held[HELD_VA_T]
    held[HELD_VA] = airspeed_m_s if t - va_t > STALE_AFTER_S else _lowpass(va, airspeed_m_s, t - va_t,
                                                                           prm.airspeed_lpf_s)
    held[HELD_VA_T] = t


@njit(cache=True, inline="always")
def height_input(t, sample_m, prm, held):
    """A height sample [m] above the origin at ``t`` [s] (barometer, or GPS without one): the low-passed height
    and vertical speed of the output."""
    height, height_t = held[HELD_HEIGHT], held[HELD_HEIGHT_T]
    if height_t == -math.inf:  # first sample
        held[HELD_HEIGHT], held[HELD_VERTICAL_SPEED] = sample_m, 0.0
    else:
        rate = (sample_m - height) / prm.baro_lpf_s  # rate of the first-order filter
        held[HELD_HEIGHT] = _lowpass(height, sample_m, t - height_t, prm.baro_lpf_s)
        held[HELD_VERTICAL_SPEED] = _lowpass(held[HELD_VERTICAL_SPEED], rate, t - height_t,
                                             prm.vertical_speed_lpf_s)
    held[HELD_HEIGHT_T] = t


@njit(cache=True, inline="always")
def gps_velocity_input(t, values, prm, held, w):
    """A GPS velocity (NED [m/s]) at ``t`` [s]: the low-passed NED acceleration ``w.gps_acc`` of stage 1's
    acceleration form (zero after a stale gap) and the held velocity ``w.gps_vel``."""
    gps_vel, gps_acc = w.gps_vel, w.gps_acc
    dt_gps = t - held[HELD_GPS_VEL_T]
    if 0.0 < dt_gps < STALE_AFTER_S:
        for i in range(3):
            gps_acc[i] = _lowpass(gps_acc[i], (values[i] - gps_vel[i]) / dt_gps, dt_gps, prm.gps_acceleration_lpf_s)
    else:
        gps_acc[:] = 0.0
    gps_vel[:] = values[:3]
    held[HELD_GPS_VEL_T] = t


# ----------------------------------------------------------------------------------------------------------------
# stage 1 and 2


@njit(cache=True, inline="always")
def accel_control(t, prm, st, held, w, rec):
    """Stage 1 at the accelerometer update rate (``PERIODIC``) with the inputs averaged over the interval (none
    summed: no update); the NED acceleration from GPS while it is fresh (acceleration form), else zero. Skipped
    beyond :data:`PITCH_GUARD_RAD`."""
    acc_meas, mw = w.acc_meas, w.mw
    if acc_meas[0] > 0.0:
        if abs(st.x1[1]) > PITCH_GUARD_RAD:
            rec.counters[C_PITCH_GUARD] += 1
        else:
            use_gps_acc = prm.gps_acceleration and t - held[HELD_GPS_VEL_T] < STALE_AFTER_S
            accel_n = w.gps_acc if use_gps_acc else mw.no_accel
            mean = mw.mean
            for i in range(8):
                mean[i] = acc_meas[i] / acc_meas[0]
            stage1_update(t, mean[4:7], mean[1:4], mean[7], accel_n, prm, st.x1, st.P1, st.x2, w.w1, mw,
                          rec.diag_f, rec.diag_i, rec.counters)
            repair(st.P1, prm.max_var1, w.w1, rec.counters)
        acc_meas[:] = 0.0


@njit(cache=True, inline="always")
def heading_control(t, kind, values, variances, prm, st, heading_var_reset, rejected_since, w, rec):
    """A heading vector (magnetometer, sun) at ``t`` [s]: the stage-2 update, skipped beyond
    :data:`PITCH_GUARD_RAD`, then the heading re-acquisition.

    Re-acquisition: the rejection rule of the GPS (docs/estimators.md, 'GPS re-acquisition'; the same
    :func:`~estimators.core.reacquisition.rejection_streak` and
    :func:`~estimators.core.reacquisition.rejected_too_long`, with ``T_rej``): every vector rejected for ``T_rej``
    means the heading, not the sensor, is wrong; the heading restarts from the one the measured vector implies,
    with the variance ``heading_var_reset`` [rad^2] (the alignment's). ``rejected_since`` [s]: start of the
    current rejection streak (inf: none); returns its new value."""
    x2, P2 = st.x2, st.P2
    if abs(st.x1[1]) > PITCH_GUARD_RAD:
        rec.counters[C_PITCH_GUARD] += 1
        return rejected_since
    gated, heading = stage2_update(t, kind, values, variances, prm, st.x1, st.P1, x2, P2, w.w2, w.mw, rec.diag_f,
                                   rec.diag_i, rec.counters)
    reacquire = (not gated and reacquisition.rejected_too_long(rejected_since, t, prm.gps_reset_after_s)
                 and math.isfinite(heading))
    rejected_since = reacquisition.rejection_streak(rejected_since, t, gated)
    if reacquire:
        x2[0] = heading
        P2[0, 0] = heading_var_reset
        rejected_since = math.inf
        rec.counters[C_HEADING_RESETS] += 1
    repair(P2, prm.max_var2, w.w2, rec.counters)
    return rejected_since


# ----------------------------------------------------------------------------------------------------------------
# stage 3 (GPS epochs)


@njit(cache=True, inline="always")
def stage3_start(values, variances, prm, st, w):
    """Start of stage 3 at a GPS epoch: position from its ``GPS_POS`` event (``w.gps_pos``, ``w.gps_pos_var``),
    velocity from this ``GPS_VEL`` event, the other states and covariances initial (``prm.p3_0``)."""
    x3, P3 = st.x3, st.P3
    x3[:] = 0.0
    P3[:, :] = prm.p3_0
    for i in range(2):
        x3[i] = w.gps_pos[i]
        P3[i, i] = max(P3[i, i], w.gps_pos_var[i])
    stage3_init_velocity(values, variances, prm, x3, P3)
    w.x3_safe[:] = x3
    w.acc3[:] = 0.0


@njit(cache=True, inline="always")
def _reset_position(values, variances, x3, P3):
    """GPS re-acquisition of the position: north and east to the GPS, variances to R, cross-covariances zeroed
    (docs/estimators.md, 'GPS re-acquisition'; the velocity follows at its event)."""
    n3 = x3.shape[0]
    for i in range(2):
        x3[i] = values[i]
        for j in range(n3):
            P3[i, j] = 0.0
            P3[j, i] = 0.0
        P3[i, i] = variances[i]


@njit(cache=True, inline="always")
def gps_position_control(t, values, variances, prm, st, stage3_on, held, w, rec):
    """A GPS position (NED [m]) at ``t`` [s]: held for the start of stage 3; once it runs, the re-acquisition
    reset, else the fixed-wing wind pseudo-measurement (while the airspeed is fresh) and the position update."""
    held[HELD_GPS_POS_T] = t
    w.gps_pos[:] = values[:2]
    w.gps_pos_var[:] = variances[:2]
    if not stage3_on:
        return
    if reacquisition.gps_control(w.gps_mon, GPS_POS, t, prm.gps_reset_after_s, prm.gps_outage_reset_s,
                                 rec.counters):
        _reset_position(values, variances, st.x3, st.P3)
        return
    if prm.fixed_wing_nav and t - held[HELD_VA_T] < STALE_AFTER_S:
        stage3_fw_wind(t, held[HELD_VA], w.gps_vel[2], prm, st.x2, st.P2, st.x3, st.P3, w.w3, w.mw, rec.diag_f,
                       rec.diag_i, rec.counters)
    stage3_gps_position(t, values, variances, prm, st.x3, st.P3, w.w3, w.gps_mon, rec.diag_f, rec.diag_i,
                        rec.counters)
    repair(st.P3, prm.max_var3, w.w3, rec.counters)


@njit(cache=True, inline="always")
def gps_velocity_control(t, values, variances, prm, st, stage3_on, held, w, rec):
    """A GPS velocity (NED [m/s]) at ``t`` [s] after :func:`gps_velocity_input`: the start of stage 3 at a GPS
    epoch with a position (fixed wing: above the minimum ground speed); once it runs, the re-acquisition reset of
    the velocity, else the velocity update. Returns whether stage 3 runs."""
    if not stage3_on:
        fast = math.hypot(values[0], values[1]) > prm.min_ground_speed_m_s
        if held[HELD_GPS_POS_T] == t and (fast or not prm.fixed_wing_nav):
            stage3_start(values, variances, prm, st, w)
            reacquisition.gps_acquired(w.gps_mon, t)
            return True
        return False
    if reacquisition.gps_control(w.gps_mon, GPS_VEL, t, prm.gps_reset_after_s, prm.gps_outage_reset_s,
                                 rec.counters):
        stage3_init_velocity(values, variances, prm, st.x3, st.P3)
    else:
        stage3_gps_velocity(t, values, variances, prm, st.x3, st.P3, w.w3, w.gps_mon, rec.diag_f, rec.diag_i,
                            rec.counters)
        repair(st.P3, prm.max_var3, w.w3, rec.counters)
    return True
