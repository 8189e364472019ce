"""Control of the three-stage kernel (numba): when each sensor is fused, and when a stage is started, reset or
re-initialised instead (PX4 EKF2's ``*_control.cpp``); the fusion itself (innovation, H, update) is in
:mod:`estimators.three_stage.stages`.

Per sensor, called by :func:`estimators.three_stage.kernel.run_kernel` at its events:

* :func:`accel_control` (``PERIODIC``): whether the stage-1 accelerometer update runs (inputs summed over the
  update interval, :func:`attitude_update_allowed`: not at the Euler singularity) and with which acceleration;
* :func:`heading_control` (magnetometer, sun): after the stage-2 update (when :func:`attitude_update_allowed`), the
  heading re-acquisition by the shared rejection rule of :mod:`estimators.core.reacquisition`;
* :func:`gps_position_control`, :func:`gps_velocity_control`, :func:`wind_pseudo_due`: the start of stage 3 at
  the first GPS epoch (:func:`stage3_start`), the GPS re-acquisition
  (:func:`estimators.core.reacquisition.gps_control`), else the GPS updates and the wind pseudo-measurement;
* :func:`airspeed_input`, :func:`height_input`, :func:`gps_velocity_input`: the low-passed inputs the stages
  read (:class:`HeldInputs`, scalars passed by value).

Arguments: ``prm`` :class:`~estimators.three_stage.kernel.KernelParams`, ``gps`` the held GPS data
(:class:`~estimators.three_stage.kernel.GpsWork`), ``held`` the held inputs. The controls are small compiled
functions (not ``inline="always"``, which compiles the callee again at every call site) that take the values they
decide on: every array a numba call receives costs a reference-count pair per call, so they do not wrap the fusion
(a control level around the fusion of the frequent events cost 0.1 us per IMU sample); the loop calls the fusion
with the arrays it holds.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from numba import njit

from estimators.core import linalg, reacquisition
from estimators.core.recorder import N_SHARED_COUNTERS
from estimators.inputs.records import GPS_POS, GPS_VEL
from estimators.three_stage.stages import stage3_init_velocity

# kernel counters: the shared slots of estimators.core.recorder (C_DIAG .. C_OUTPUTS), then this filter's
C_PITCH_GUARD = N_SHARED_COUNTERS  # attitude updates skipped at the Euler singularity
C_HEADING_RESETS = N_SHARED_COUNTERS + 1  # stage-2 heading re-acquisitions
N_COUNTERS = N_SHARED_COUNTERS + 2

# actions of gps_velocity_control
GPS_NONE = 0  # stage 3 not running, not started
GPS_START = 1  # start stage 3
GPS_RESET = 2  # re-acquisition: velocity to the GPS
GPS_FUSE = 3  # velocity update

#: Attitude updates are skipped beyond this pitch (Euler singularity) [rad].
PITCH_GUARD_RAD = math.radians(85.0)
#: An airspeed or GPS value older than this is stale: no centripetal term, no wind pseudo, no GPS acceleration [s].
STALE_AFTER_S = 1.0

class HeldInputs(NamedTuple):
    """The low-passed inputs the stages read and the times [s] of the last samples: scalars, passed by value (an
    input step returns a new one), so that the loop passes no array for them."""

    va_m_s: float  # low-passed true airspeed
    va_t: float
    height_m: float  # low-passed barometric (or GPS) height above the origin (NaN: no height source)
    height_t: float
    vertical_speed_m_s: float  # low-passed rate of the height
    gps_vel_t: float
    gps_pos_t: float


@njit(cache=True)
def held_inputs(initial_height_m):
    """The held inputs before the first sample: no airspeed, the height ``initial_height_m`` [m] (NaN: no height
    source, and no vertical speed), no GPS."""
    return HeldInputs(0.0, -math.inf, initial_height_m, -math.inf,
                      0.0 if math.isfinite(initial_height_m) else math.nan, -math.inf, -math.inf)


@njit(cache=True)
def _lowpass(value, sample, dt, tau):
    """One step of a first-order low-pass with time constant ``tau`` over ``dt`` (exact for a held sample)."""
    return value + (1.0 - math.exp(-dt / tau)) * (sample - value)


# ----------------------------------------------------------------------------------------------------------------
# inputs


@njit(cache=True)
def airspeed_input(t, airspeed_m_s, lpf_s, held):
    """An airspeed sample at ``t`` [s]: low-passed with the time constant ``lpf_s`` [s] (restarted after a stale
    gap). Returns the new :class:`HeldInputs`."""
    va = airspeed_m_s if t - held.va_t > STALE_AFTER_S else _lowpass(held.va_m_s, airspeed_m_s, t - held.va_t, lpf_s)
    return HeldInputs(va, t, held.height_m, held.height_t, held.vertical_speed_m_s, held.gps_vel_t, held.gps_pos_t)


@njit(cache=True)
def height_input(t, sample_m, lpf_s, rate_lpf_s, held):
    """A height sample [m] above the origin at ``t`` [s] (barometer, or GPS without one): the low-passed height
    (time constant ``lpf_s`` [s]) and vertical speed (``rate_lpf_s`` [s]) of the output. Returns the new
    :class:`HeldInputs`."""
    height, height_t = held.height_m, held.height_t
    if height_t == -math.inf:  # first sample
        height, vertical_speed = sample_m, 0.0
    else:
        rate = (sample_m - height) / lpf_s  # rate of the first-order filter
        height = _lowpass(height, sample_m, t - height_t, lpf_s)
        vertical_speed = _lowpass(held.vertical_speed_m_s, rate, t - height_t, rate_lpf_s)
    return HeldInputs(held.va_m_s, held.va_t, height, t, vertical_speed, held.gps_vel_t, held.gps_pos_t)


@njit(cache=True)
def gps_velocity_input(t, values, lpf_s, held, gps_vel, gps_acc):
    """A GPS velocity (NED [m/s]) at ``t`` [s]: the NED acceleration ``gps_acc`` [m/s^2] of stage 1's
    acceleration form, low-passed with the time constant ``lpf_s`` [s] (zero after a stale gap), and the held
    velocity ``gps_vel``. Returns the new :class:`HeldInputs`."""
    dt_gps = t - held.gps_vel_t
    if 0.0 < dt_gps < STALE_AFTER_S:
        for i in range(3):
            gps_acc[i] = _lowpass(gps_acc[i], (values[i] - gps_vel[i]) / dt_gps, dt_gps, lpf_s)
    else:
        gps_acc[:] = 0.0
    linalg.copy_into(gps_vel, values)
    return HeldInputs(held.va_m_s, held.va_t, held.height_m, held.height_t, held.vertical_speed_m_s, t,
                      held.gps_pos_t)


# ----------------------------------------------------------------------------------------------------------------
# stage 1 and 2 (decisions: the loop calls the fusion, so that these frequent events pass their arrays once)


@njit(cache=True)
def attitude_update_allowed(pitch_rad, counters):
    """Attitude-dependent updates (accelerometer, heading) run below :data:`PITCH_GUARD_RAD` of the stage-1 pitch
    ``pitch_rad``; a skipped one is counted (``C_PITCH_GUARD``)."""
    if abs(pitch_rad) > PITCH_GUARD_RAD:
        counters[C_PITCH_GUARD] += 1
        return False
    return True


@njit(cache=True)
def accel_control(t, gps_acceleration, held, acc_meas, pitch_rad, mean, counters):
    """Stage 1 at the accelerometer update rate (``PERIODIC``): an update when inputs were summed over the interval
    (``acc_meas``, then cleared) and the pitch allows it, with their means in ``mean`` (8,); the acceleration form
    (``gps_acceleration``) uses the NED acceleration from GPS while it is fresh, else zero.

    Returns (fuse with :func:`~estimators.three_stage.stages.stage1_update`, use the GPS acceleration)."""
    if not acc_meas[0] > 0.0:
        return False, False
    fuse = attitude_update_allowed(pitch_rad, counters)
    if fuse:
        for i in range(8):
            mean[i] = acc_meas[i] / acc_meas[0]
    acc_meas[:] = 0.0
    return fuse, gps_acceleration and t - held.gps_vel_t < STALE_AFTER_S


@njit(cache=True)
def heading_control(t, gated, heading, rejected_since, reject_s):
    """Heading re-acquisition after a stage-2 update at ``t`` [s] (``gated``: the vector passed the gate;
    ``heading`` [rad]: the one the measured vector implies).

    The rejection rule of the GPS (docs/estimators.md, 'GPS re-acquisition'; the same
    :func:`~estimators.core.reacquisition.rejection_streak` and
    :func:`~estimators.core.reacquisition.rejected_too_long`, ``reject_s`` = ``T_rej``): every vector rejected for
    ``T_rej`` means the heading, not the sensor, is wrong, and the heading restarts from ``heading``
    (:func:`restart_heading`). ``rejected_since`` [s]: start of the current rejection streak (inf: none).
    Returns (its new value, restart now)."""
    restart = not gated and reacquisition.rejected_too_long(rejected_since, t, reject_s) and math.isfinite(heading)
    rejected_since = reacquisition.rejection_streak(rejected_since, t, gated)
    return (math.inf if restart else rejected_since), restart


@njit(cache=True)
def restart_heading(heading, heading_var, x2, P2, counters):
    """Heading re-initialisation: the heading ``heading`` [rad] with the variance ``heading_var`` [rad^2] (the
    alignment's), counted in ``C_HEADING_RESETS``."""
    x2[0] = heading
    P2[0, 0] = heading_var
    counters[C_HEADING_RESETS] += 1


# ----------------------------------------------------------------------------------------------------------------
# stage 3 (GPS epochs)


@njit(cache=True)
def stage3_start(values, variances, prm, x3, P3, gps, x3_safe, acc3):
    """Start of stage 3 at a GPS epoch: position from its ``GPS_POS`` event (``gps.pos_ne``, ``gps.pos_var``),
    velocity from this ``GPS_VEL`` event, the other states and covariances initial (``prm.p3_0``); the last
    healthy state ``x3_safe`` is the start, the input sums ``acc3`` of its covariance start empty."""
    x3[:] = 0.0
    linalg.copy_rows_into(P3, prm.p3_0, P3.shape[0])
    for i in range(2):
        x3[i] = gps.pos_ne[i]
        P3[i, i] = max(P3[i, i], gps.pos_var[i])
    stage3_init_velocity(values, variances, prm, x3, P3)
    linalg.copy_into(x3_safe, x3)
    acc3[:] = 0.0


@njit(cache=True)
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


@njit(cache=True)
def gps_position_control(t, values, variances, stage3_on, reject_s, outage_s, held, gps, x3, P3, counters):
    """A GPS position (NED [m]) at ``t`` [s]: held for the start of stage 3; once it runs, the re-acquisition
    (:func:`~estimators.core.reacquisition.gps_control` with ``T_rej = reject_s``, ``T_out = outage_s`` [s])
    resets the position instead of fusing it. Returns (fuse it with
    :func:`~estimators.three_stage.stages.stage3_gps_position`, the new :class:`HeldInputs`)."""
    held = HeldInputs(held.va_m_s, held.va_t, held.height_m, held.height_t, held.vertical_speed_m_s, held.gps_vel_t, t)
    linalg.copy_into(gps.pos_ne, values)
    linalg.copy_into(gps.pos_var, variances)
    if not stage3_on:
        return False, held
    if reacquisition.gps_control(gps.monitor, int(GPS_POS), t, reject_s, outage_s, counters):
        _reset_position(values, variances, x3, P3)
        return False, held
    return True, held


@njit(cache=True)
def wind_pseudo_due(fixed_wing_nav, t, held):
    """The fixed-wing wind-triangle pseudo-measurement goes with a fused GPS position while the airspeed is fresh
    (:func:`~estimators.three_stage.stages.stage3_fw_wind`)."""
    return fixed_wing_nav and t - held.va_t < STALE_AFTER_S


@njit(cache=True)
def gps_velocity_control(t, speed_m_s, stage3_on, min_ground_speed_m_s, fixed_wing_nav, reject_s, outage_s, held,
                         monitor, counters):
    """A GPS velocity (horizontal speed ``speed_m_s`` [m/s]) at ``t`` [s]: the start of stage 3
    (:func:`stage3_start`) at a GPS epoch with a position (fixed wing: above ``min_ground_speed_m_s``), which arms
    the re-acquisition ``monitor``; once stage 3 runs, the re-acquisition
    (:func:`~estimators.core.reacquisition.gps_control`) resets the velocity
    (:func:`~estimators.three_stage.stages.stage3_init_velocity`) instead of fusing it
    (:func:`~estimators.three_stage.stages.stage3_gps_velocity`). Returns the action, ``GPS_*``."""
    if not stage3_on:
        if held.gps_pos_t == t and (speed_m_s > min_ground_speed_m_s or not fixed_wing_nav):
            reacquisition.gps_acquired(monitor, t)
            return GPS_START
        return GPS_NONE
    if reacquisition.gps_control(monitor, int(GPS_VEL), t, reject_s, outage_s, counters):
        return GPS_RESET
    return GPS_FUSE
