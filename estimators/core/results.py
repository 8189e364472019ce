"""What an estimator run returns, and the builders every estimator uses to produce it (one output contract).

The output contract (issue 4, "Interfaces"): ``states`` has exactly the columns :data:`STATE_COLUMNS` (NaN where an
estimator has no such quantity) plus optional ``<column>_std`` columns and ``pos_n_m_std`` / ``pos_e_m_std``
(horizontal position standard deviation [m]); ``time_s`` is the log clock, yaw in [-180, 180), altitude above MSL,
lat/lon WGS-84. ``diagnostics`` has one row per scalar measurement update with the columns
:data:`DIAGNOSTIC_COLUMNS`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from estimators import environment
from estimators.core.recorder import (
    C_DIAG_DROPPED,
    C_GPS_RESETS,
    C_REPAIRS,
    C_RESETS,
    C_UPDATES,
    C_WIND_INITS,
)
from estimators.inputs.records import COMPONENT_NAMES, SENSOR_NAMES, Origin, ReplayInputs

#: Columns of the states table, in order.
STATE_COLUMNS = ("estimator", "time_s", "roll_deg", "pitch_deg", "yaw_deg", "lat_deg", "lon_deg", "alt_m",
                 "vn_m_s", "ve_m_s", "vd_m_s", "wind_n_m_s", "wind_e_m_s")
#: Optional standard-deviation columns (same units as their quantity; horizontal position in metres).
STD_COLUMNS = ("roll_deg_std", "pitch_deg_std", "yaw_deg_std", "pos_n_m_std", "pos_e_m_std", "alt_m_std",
               "vn_m_s_std", "ve_m_s_std", "vd_m_s_std", "wind_n_m_s_std", "wind_e_m_s_std")
#: Columns of the diagnostics table, in order.
DIAGNOSTIC_COLUMNS = ("estimator", "time_s", "sensor", "component", "innovation", "innovation_var", "nis",
                      "accepted")
#: Diagnostics sensor codes beyond the measurement event kinds of :mod:`estimators.inputs.build`: the three-stage
#: filter's stage-1 accelerometer update and its wind-triangle pseudo-measurement.
ACCEL = len(SENSOR_NAMES)
WIND = ACCEL + 1
#: Sensor name per diagnostics code (the ``sensor`` column): the event kinds, then ``accel`` and ``wind``.
DIAGNOSTIC_SENSOR_NAMES = (*SENSOR_NAMES, "accel", "wind")
#: Component names per diagnostics code (the ``component`` column), indexed by the kernels' component id.
DIAGNOSTIC_COMPONENT_NAMES = (*COMPONENT_NAMES, ("x", "y", "z"), ("n", "e"))


@dataclass(frozen=True)
class EstimatorReport:
    """What one estimator did on one log.

    Attributes
    ----------
    estimator : str
        Registry name.
    used : tuple of str
        Sensors fused (diagnostics sensor names).
    skipped : dict of str -> str
        Sensor -> reason it was not used.
    degradations : tuple of str
        Degraded modes applied (docs/estimators.md, 'Sensor plan').
    resets : int
        Divergence resets (non-finite state or covariance -> last healthy state, initial covariance).
    gps_resets : int
        Position/velocity resets to GPS after a long rejection or outage (docs/estimators.md, 'GPS re-acquisition').
    covariance_repairs : int
        Covariance matrices that failed the positive-definiteness test and were repaired.
    n_imu_samples : int
        IMU rows processed.
    n_updates : int
        Scalar measurement updates attempted (accepted + rejected).
    timings_s : dict of str -> float
        Wall times [s]: ``prepare`` (events), ``kernel`` (compiled loop), ``total``.
    warnings : tuple of str
        Everything noteworthy, in words.
    details : dict
        Estimator-specific facts (alignment, final bias estimates ...), JSON-serialisable values.
    """

    estimator: str
    used: tuple[str, ...]
    skipped: dict[str, str]
    degradations: tuple[str, ...]
    resets: int = 0
    gps_resets: int = 0
    covariance_repairs: int = 0
    n_imu_samples: int = 0
    n_updates: int = 0
    timings_s: dict[str, float] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    details: dict = field(default_factory=dict)


@dataclass(frozen=True)
class EstimatorRun:
    """One estimator's result on one log.

    Attributes
    ----------
    states : pandas.DataFrame
        :data:`STATE_COLUMNS` without ``estimator`` (plus optional std columns), one row per output epoch.
    diagnostics : pandas.DataFrame
        :data:`DIAGNOSTIC_COLUMNS` without ``estimator``, one row per scalar update.
    report : EstimatorReport
    """

    states: pd.DataFrame
    diagnostics: pd.DataFrame
    report: EstimatorReport


def replay_details(inputs: ReplayInputs) -> dict:
    """The facts of the replay inputs every report's ``details`` carries (JSON-serialisable): initial alignment
    sources, GPS delay and time rule, barometer offset, magnetic-field source and the NED origin."""
    align, origin = inputs.alignment, inputs.origin
    return {
        "alignment": {"tilt_source": align.tilt_source, "yaw_source": align.yaw_source,
                      "still_window_s": align.still_window_s},
        "gps_delay_s": inputs.gps_delay_s,
        "gps_time_rule": inputs.gps_time_rule,
        "baro_offset_m": inputs.baro_offset_m,
        "mag_field_source": inputs.mag_field_source,
        "origin": {"lat_deg": origin.lat_deg, "lon_deg": origin.lon_deg, "alt_m": origin.alt_m,
                   "source": origin.source},
    }


def kernel_report(name: str, inputs: ReplayInputs, counters: np.ndarray, *, timings_s: dict[str, float],
                  details: dict, warnings=(), diverged: str = "filter", used=None, skipped=None,
                  degradations=None) -> EstimatorReport:
    """The report of a compiled run from its counter array (the shared slots of :mod:`estimators.core.linalg`).

    Parameters
    ----------
    name : str
        Registry name.
    inputs : ReplayInputs
        The run's inputs (sensor plan, warnings, IMU rows).
    counters : ndarray of int64
        The kernel's counters.
    timings_s, details
        As :class:`EstimatorReport`.
    warnings : iterable of str
        The estimator's own warnings, listed after the inputs' warnings and the divergence warning.
    diverged : str
        What diverged, in the divergence warning (``"filter"``, ``"a stage"``).
    used, skipped, degradations : optional
        Override the sensor plan's.
    """
    plan = inputs.plan
    notes = list(inputs.warnings)
    if counters[C_RESETS]:
        notes.append(f"{diverged} diverged and was reset {counters[C_RESETS]} times")
    if counters[C_WIND_INITS] > 1:
        again = counters[C_WIND_INITS] - 1
        notes.append(f"wind re-initialised {'once' if again == 1 else f'{again} times'} from the airspeed along "
                     "the heading (the estimated air flowed backwards through the airframe)")
    notes += list(warnings)
    if counters[C_DIAG_DROPPED]:
        notes.append(f"{counters[C_DIAG_DROPPED]} diagnostics rows dropped")
    return EstimatorReport(estimator=name, used=tuple(plan.used if used is None else used),
                           skipped=dict(plan.skipped if skipped is None else skipped),
                           degradations=tuple(plan.degradations if degradations is None else degradations),
                           resets=int(counters[C_RESETS]), gps_resets=int(counters[C_GPS_RESETS]),
                           covariance_repairs=int(counters[C_REPAIRS]), n_imu_samples=len(inputs.imu.time_s),
                           n_updates=int(counters[C_UPDATES]), timings_s=timings_s, warnings=tuple(notes),
                           details=details)


def states_frame(time_s, roll_rad, pitch_rad, yaw_rad, position_ned_m, velocity_ned_m_s, wind_ne_m_s,
                 origin: Origin, *, std: dict[str, np.ndarray] | None = None, navigation: bool = True,
                 wind: bool = True, height: bool = True) -> pd.DataFrame:
    """The states table of one estimator (without the ``estimator`` column); columns passed through unchanged are
    views of the given arrays, not copies.

    Parameters
    ----------
    time_s : ndarray (k,)
        Output epochs [s], log clock.
    roll_rad, pitch_rad, yaw_rad : ndarray (k,)
        ZYX Euler angles [rad]; yaw is wrapped to [-180, 180) deg.
    position_ned_m : ndarray (k, 3)
        Position relative to ``origin`` [m]; down = -(alt - origin alt).
    velocity_ned_m_s : ndarray (k, 3)
        Ground velocity NED [m/s].
    wind_ne_m_s : ndarray (k, 2) or None
        Wind north/east [m/s]; None -> NaN columns.
    origin : Origin
        NED origin; without a geodetic origin, lat/lon are NaN.
    std : dict, optional
        ``{column: values}`` for any of :data:`STD_COLUMNS` (degrees for the angles).
    navigation : bool
        False (no GPS): lat/lon and velocities are NaN (altitude is kept).
    wind : bool
        False: wind columns are NaN.
    height : bool
        False (neither barometer nor GPS): altitude is NaN.
    """
    time_s = np.asarray(time_s, dtype=float)
    k = len(time_s)
    position = np.asarray(position_ned_m, dtype=float).reshape(k, 3)
    velocity = np.asarray(velocity_ned_m_s, dtype=float).reshape(k, 3)
    if navigation and origin.source == "gps":
        lat, lon, alt = environment.ned_to_geodetic(position[:, 0], position[:, 1], position[:, 2],
                                                    origin.lat_deg, origin.lon_deg, origin.alt_m)
    else:
        lat, lon, alt = _missing(k), _missing(k), origin.alt_m - position[:, 2]
    frame = {
        "time_s": time_s,
        "roll_deg": np.degrees(roll_rad),
        "pitch_deg": np.degrees(pitch_rad),
        "yaw_deg": (np.degrees(yaw_rad) + 180.0) % 360.0 - 180.0,
        "lat_deg": np.asarray(lat, dtype=float).reshape(k),
        "lon_deg": np.asarray(lon, dtype=float).reshape(k),
        "alt_m": np.asarray(alt, dtype=float).reshape(k) if height else _missing(k),
        "vn_m_s": velocity[:, 0] if navigation else _missing(k),
        "ve_m_s": velocity[:, 1] if navigation else _missing(k),
        "vd_m_s": velocity[:, 2] if navigation else _missing(k),
        "wind_n_m_s": np.asarray(wind_ne_m_s)[:, 0] if wind and wind_ne_m_s is not None else _missing(k),
        "wind_e_m_s": np.asarray(wind_ne_m_s)[:, 1] if wind and wind_ne_m_s is not None else _missing(k),
    }
    for name, values in (std or {}).items():
        if name not in STD_COLUMNS:
            raise ValueError(f"unknown std column {name!r}")
        blank = ((not navigation and name[:2] in ("po", "vn", "ve", "vd")) or (not wind and name.startswith("wind"))
                 or (not height and name.startswith("alt")))
        frame[name] = _missing(k) if blank else np.asarray(values, dtype=float).reshape(k)
    # a yaw that wrapped to exactly 180.0 by rounding
    frame["yaw_deg"] = np.where(frame["yaw_deg"] >= 180.0, frame["yaw_deg"] - 360.0, frame["yaw_deg"])
    return pd.DataFrame(frame, copy=False)


def _missing(k: int) -> np.ndarray:
    """A NaN column of length k (its own array: the tables wrap their columns without copying them)."""
    return np.full(k, np.nan)


def diagnostics_frame(diag_f: np.ndarray, diag_i: np.ndarray, count: int) -> pd.DataFrame:
    """The diagnostics table from the kernels' recorder arrays (see :mod:`estimators.core.linalg`).

    ``sensor`` and ``component`` become categorical names (:data:`DIAGNOSTIC_SENSOR_NAMES`,
    :data:`DIAGNOSTIC_COMPONENT_NAMES`; the same categories for every estimator), ``accepted`` a bool. The float
    columns are views of ``diag_f`` (no copy: :func:`estimators.api.run_estimators` copies each column once when it
    stacks the estimators).
    """
    diag_f, diag_i = diag_f[:count], diag_i[:count]
    sensor_codes = diag_i[:, 0]
    return pd.DataFrame({
        "time_s": diag_f[:, 0],
        "sensor": pd.Categorical.from_codes(sensor_codes, categories=DIAGNOSTIC_SENSOR_NAMES),
        "component": pd.Categorical.from_codes(_COMPONENT_CODES[sensor_codes, diag_i[:, 1]],
                                               categories=COMPONENT_CATEGORIES),
        "innovation": diag_f[:, 1],
        "innovation_var": diag_f[:, 2],
        "nis": diag_f[:, 3],
        "accepted": diag_i[:, 2].astype(bool),
    }, copy=False)


#: Every component name, the categories of the diagnostics' ``component`` column.
COMPONENT_CATEGORIES = tuple(dict.fromkeys(name for names in DIAGNOSTIC_COMPONENT_NAMES for name in names))
_COMPONENT_CODES = np.array([[COMPONENT_CATEGORIES.index(names[c]) if c < len(names) else -1
                              for c in range(max(len(n) for n in DIAGNOSTIC_COMPONENT_NAMES))]
                             for names in DIAGNOSTIC_COMPONENT_NAMES])
