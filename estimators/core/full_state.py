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
#: The wind random walk runs only while an airspeed or sideslip event (airborne, docs/estimators.md, 'Wind on the
#: ground') came within this time [s]; on the ground the wind is unobservable and held, not left to drift.
WIND_HOLD_S = 1.0


@njit(cache=True)
def component_range(kind, values, paper_vel, vmin):
    """First and last+1 component of an event (GPS velocity in paper mode: ground speed and course, none when
    the GPS ground speed is below ``vmin``)."""
    if kind in (BARO, AIRSPEED, SIDESLIP):
        return 0, 1
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
def wind_observed(kind, t, last_t):
    """Time of the last event that observes the wind (airspeed or sideslip: airborne) after event ``kind`` at
    ``t`` [s], given the previous one ``last_t``."""
    return t if kind in (AIRSPEED, SIDESLIP) else last_t


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
