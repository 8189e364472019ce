"""Pieces shared by the two full-state filters (docs/estimators.md, 'Full-state filters'): the shared kernel
parameter slots, variance limits, measurement component ranges and innovations, gates per event kind, the
diagnostics capacity and the accelerometer-bias degradations.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from estimators.config import EstimatorConfig
from estimators.core import rotations
from estimators.inputs import records
from estimators.inputs.records import (
    AIRSPEED,
    BARO,
    GPS_POS,
    GPS_VEL,
    MAG,
    SIDESLIP,
    SUN,
    ReplayInputs,
)

#: Variance floor of every state (keeps P positive definite).
MIN_VARIANCE = 1e-12
#: Smallest eigenvalue kept by a covariance repair.
EIG_FLOOR = 1e-12
#: The full positive-definiteness test (Cholesky) runs every this many covariance propagations; the variance
#: limits every time.
PD_CHECK_EVERY = 10
#: Component id of the magnetometer heading (``mag.psi`` in the diagnostics; docs/estimators.md, 'Magnetometer
#: heading fusion').
MAG_HEADING = 3
#: Smallest horizontal component of the unit field (measured or reference) for a heading [-]: 0.05, an inclination
#: of 87 deg, where one field-unit of noise is 20 rad of heading.
MIN_HORIZONTAL_FIELD = 0.05
#: The wind random walk runs only while an airspeed or sideslip event (airborne, docs/estimators.md, 'Wind on the
#: ground') came within this time [s]; on the ground the wind is unobservable and held, not left to drift.
WIND_HOLD_S = 1.0


@njit(cache=True)
def component_range(kind, values, paper_vel, vmin, mag_heading):
    """First and last+1 component of an event (GPS velocity in paper mode: ground speed and course, none when
    the GPS ground speed is below ``vmin``; the magnetometer as its heading, :data:`MAG_HEADING`, with
    ``mag_heading``, else its three axes)."""
    if kind in (BARO, AIRSPEED, SIDESLIP):
        return 0, 1
    if kind == MAG and mag_heading:
        return MAG_HEADING, MAG_HEADING + 1
    if kind == SUN:
        return 0, 2
    if kind == GPS_VEL and paper_vel:
        if math.hypot(values[0], values[1]) < vmin:
            return 3, 3
        return 3, 5
    return 0, 3


@njit(cache=True)
def measured_value(kind, comp, values, variances):
    """Measured value ``z`` and variance ``R`` of a scalar component (paper-mode ground speed/course derived
    from the NED velocity, eq 9 corrected: sigma_chi = sigma_V / V_g)."""
    if kind == GPS_VEL and comp >= 3:
        vg = math.hypot(values[0], values[1])
        if comp == 3:
            return vg, variances[0]
        return math.atan2(values[1], values[0]), variances[0] / (vg * vg)
    return values[comp], variances[comp]


@njit(cache=True)
def scalar_innovation(kind, comp, values, variances, h):
    """Innovation ``nu = z - h`` (the course wrapped to [-pi, pi)) and variance ``R`` of a scalar component
    whose prediction is ``h`` (both full-state filters)."""
    z, r_var = measured_value(kind, comp, values, variances)
    nu = z - h
    if kind == GPS_VEL and comp == 4:
        nu = rotations.wrap_pi(nu)
    return nu, r_var


@njit(cache=True)
def mag_heading_innovation(R_nb, m0, m1, m2, variances, field_ned, grad_bias):
    """Heading innovation of a magnetometer sample (docs/estimators.md, 'Magnetometer heading fusion').

    ``(m0, m1, m2)`` the bias-corrected body field [field units], rotated into NED with the estimate's attitude
    ``R_nb`` (body to NED); the innovation is minus the angle, about the NED down axis, from the reference field's
    horizontal part ``field_ned[:2]`` to the rotated measurement's: the measured heading minus the estimated one. It
    depends on the yaw with slope -1 (H on yaw +1) and on the bias through ``grad_bias`` (3,), written here as the
    H row of the bias ``d angle / d b_m``; the estimated roll and pitch only rotate the measurement into the
    horizontal plane and are not corrected by it. Variance: the mean per-axis variance of ``variances[:3]`` over the
    squared horizontal field. Returns ``(nu, r_var)``; NaN for a field too steep for a heading
    (:data:`MIN_HORIZONTAL_FIELD`)."""
    cn = R_nb[0, 0] * m0 + R_nb[0, 1] * m1 + R_nb[0, 2] * m2
    ce = R_nb[1, 0] * m0 + R_nb[1, 1] * m1 + R_nb[1, 2] * m2
    an, ae = field_ned[0], field_ned[1]
    c2 = cn * cn + ce * ce
    if c2 < MIN_HORIZONTAL_FIELD ** 2 or an * an + ae * ae < MIN_HORIZONTAL_FIELD ** 2:
        return math.nan, math.nan
    angle = math.atan2(an * ce - ae * cn, an * cn + ae * ce)
    for j in range(3):  # d atan2(ce, cn) / d(cn, ce) = (-ce, cn) / c2, d(cn, ce) / d b = -R_nb[:2, j]
        grad_bias[j] = (ce * R_nb[0, j] - cn * R_nb[1, j]) / c2
    return -angle, (variances[0] + variances[1] + variances[2]) / 3.0 / c2


@njit(cache=True)
def wind_observed(kind, t, last_t):
    """Time of the last event that observes the wind (airspeed or sideslip: airborne) after event ``kind`` at
    ``t`` [s], given the previous one ``last_t``."""
    return t if kind in (AIRSPEED, SIDESLIP) else last_t


@njit(cache=True)
def current_walk(walk_psd, held_walk, t, t_wind_observed):
    """The random-walk densities in force at ``t`` [s]: ``walk_psd`` while the last airspeed or sideslip event
    (:func:`wind_observed`) is at most :data:`WIND_HOLD_S` old, else ``held_walk`` (:func:`held_wind_walk`)."""
    return walk_psd if t - t_wind_observed <= WIND_HOLD_S else held_walk


#: Adaptive wind random walk (docs/estimators.md, 'Wind that follows gusts'). A wind estimate that lags the air
#: mass leaves innovations of one sign for seconds: their lag-1 correlation (normalised innovations of consecutive
#: airspeed, and of consecutive sideslip, updates) rises, whatever R is (the NIS alone cannot tell a too small walk
#: from a too large R). Time constant [s] of its moving mean; the correlation the walk is held at (a white sequence
#: has 0; slow sensor errors give some); the time [s] in which a correlation of 0.5 above it multiplies the walk's
#: density by e; the largest factor on the wind's squared random-walk density (1600: a walk 40 times the configured
#: one, 0.05 -> 2 m/s/sqrt(s), about the turbulence of a gusty day); the largest product one pair adds; and the
#: longest gap [s] between two updates of one channel that still pairs them.
WIND_CORR_TIME_S = 10.0
WIND_CORR_TARGET = 0.25
WIND_WALK_RATE_S = 5.0
WIND_WALK_MAX_SCALE = 1600.0
WIND_PAIR_CAP = 9.0
WIND_PAIR_GAP_S = 1.0
#: Slots of the adaptation state (:func:`wind_adaptation`).
_CORR, _T, _LOG_SCALE, _PREV_Z, _PREV_T = 0, 1, 2, 3, 5


@njit(cache=True)
def wind_adaptation():
    """The state of :func:`adapt_wind_walk`: moving mean lag-1 correlation (0 at the start), its time [s], the
    natural log of the factor on the wind's squared walk density (0: the configured walk), the last normalised
    innovation of the airspeed and of the sideslip channel and their times [s]."""
    return np.array([0.0, -math.inf, 0.0, 0.0, 0.0, -math.inf, -math.inf])


@njit(cache=True)
def adapt_wind_walk(state, t, diag_f, diag_i, first, last):
    """Fold the airspeed / sideslip updates recorded in ``diag_f[first:last]`` at ``t`` [s] into the moving mean
    lag-1 correlation of each channel's normalised innovations ``state[0]`` (time constant
    :data:`WIND_CORR_TIME_S`, each product capped at :data:`WIND_PAIR_CAP`) and integrate its excess over
    :data:`WIND_CORR_TARGET` into the log factor ``state[2]`` (rate :data:`WIND_WALK_RATE_S`, within 0 and log
    :data:`WIND_WALK_MAX_SCALE`): the wind walk grows while the wind estimate lags (correlated innovations, as in
    turbulence) and shrinks back to the configured walk while they are white (calm air)."""
    total, count = 0.0, 0
    for k in range(first, min(last, diag_f.shape[0])):
        nu, s_var = diag_f[k, 1], diag_f[k, 2]
        if not (math.isfinite(nu) and s_var > 0.0):
            continue
        z = nu / math.sqrt(s_var)
        channel = 0 if diag_i[k, 0] == AIRSPEED else 1
        if t - state[_PREV_T + channel] <= WIND_PAIR_GAP_S:
            total += min(max(z * state[_PREV_Z + channel], -WIND_PAIR_CAP), WIND_PAIR_CAP)
            count += 1
        state[_PREV_Z + channel] = z
        state[_PREV_T + channel] = t
    if count == 0:
        return
    if not math.isfinite(state[_T]):
        state[_T] = t
        return
    dt = max(t - state[_T], 0.0)
    state[_CORR] += (1.0 - math.exp(-dt / WIND_CORR_TIME_S)) * (total / count - state[_CORR])
    state[_T] = t
    log_scale = state[_LOG_SCALE] + dt / WIND_WALK_RATE_S * (state[_CORR] - WIND_CORR_TARGET) / 0.5
    state[_LOG_SCALE] = min(max(log_scale, 0.0), math.log(WIND_WALK_MAX_SCALE))


@njit(cache=True)
def wind_walk_scale(state):
    """The factor on the wind's squared random-walk density (:func:`adapt_wind_walk`): 1 to
    :data:`WIND_WALK_MAX_SCALE`."""
    return math.exp(state[_LOG_SCALE])


@njit(cache=True)
def scaled_wind_walk(walk_psd, wind_index, scale, out):
    """``walk_psd`` into ``out`` with the two wind states (from ``wind_index``; < 0: none) times ``scale``."""
    for i in range(out.shape[0]):
        out[i] = walk_psd[i]
    if wind_index >= 0:
        out[wind_index] *= scale
        out[wind_index + 1] *= scale
    return out


@njit(cache=True)
def held_wind_walk(walk_psd, wind_index):
    """Copy of the squared random-walk densities ``walk_psd`` with the two wind states (from ``wind_index``; < 0:
    none) at 0: the walk while the wind is held (:data:`WIND_HOLD_S`)."""
    held = walk_psd.copy()
    if wind_index >= 0:
        held[wind_index] = 0.0
        held[wind_index + 1] = 0.0
    return held


def shared_settings(inputs: ReplayInputs, config: EstimatorConfig) -> dict:
    """The kernel settings both full-state filters share, as keyword arguments of their settings NamedTuples
    (``DirectSettings``, ``IndirectSettings``): gravity [m/s^2], IMU white-noise PSDs, covariance interval [s], unit
    earth field NED [-], GPS re-acquisition times [s], minimum ground speed for course updates [m/s], the paper's
    GPS-velocity mode, the gate per event kind and the schedule (:func:`estimators.core.schedule.build_schedule`
    runs once per filter run, outside the kernel)."""
    return {
        "gravity_m_s2": float(inputs.gravity_m_s2),
        "gyro_psd": float(config.noise.gyro_noise_rad_s_sqrt_hz ** 2),
        "accel_psd": float(config.noise.accel_noise_m_s2_sqrt_hz ** 2),
        "covariance_dt_s": 1.0 / config.timing.covariance_rate_hz,
        "field_ned": np.asarray(inputs.mag_field_ned, dtype=float).copy(),
        "gps_reject_s": float(config.timing.gps_reset_after_s),
        "gps_outage_s": float(config.timing.gps_outage_reset_s),
        "min_ground_speed_m_s": float(config.timing.min_ground_speed_m_s),
        "paper_gps_velocity": config.gps_velocity_mode == "paper",
        "mag_heading": inputs.plan.mag_fusion == "heading",
        "gates": gates_per_kind(config),
    }


def gates_per_kind(config: EstimatorConfig) -> np.ndarray:
    """Scalar gate per event kind (:mod:`estimators.inputs.build` codes) from ``config.gates``; pseudo-measurements and
    outputs ungated (inf)."""
    gate_cfg = config.gates
    gates = np.full(len(records.SENSOR_NAMES), math.inf)
    gates[BARO], gates[AIRSPEED], gates[GPS_POS] = gate_cfg.baro, gate_cfg.airspeed, gate_cfg.gps_pos
    gates[GPS_VEL], gates[MAG], gates[SUN] = gate_cfg.gps_vel, gate_cfg.mag, gate_cfg.sun
    return gates


def accel_bias_degradations(plan: records.SensorPlan, estimated: bool, configured: bool) -> tuple[str, ...]:
    """The sensor plan's degradations, plus the accelerometer bias left out without GPS
    (docs/estimators.md, 'Sensor plan')."""
    extra = () if estimated or not configured else (
        "no GPS: accelerometer bias not estimated (no absolute velocity reference)",)
    return (*plan.degradations, *extra)


def diagnostics_capacity(ev: records.MeasurementEvents) -> int:
    """Upper bound of the number of scalar updates of a run."""
    per_kind = np.array([1, 1, 1, 3, 3, 3, 2, 3, 0])
    return int(per_kind[ev.kind].sum())
