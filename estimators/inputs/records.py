"""What the filters' kernels read: event kinds, IMU rows, measurement events, origin, alignment, sensor plan
(docs/estimators.md, 'Inputs').

Event values per kind (unused slots are 0; variances are per component):

=============  ============================================  ============================================
kind           values                                         variances
=============  ============================================  ============================================
BARO           height above the origin [m]                    sigma_baro^2
AIRSPEED       true airspeed [m/s]                            sigma_tas^2
SIDESLIP       0 (body-y air velocity pseudo) [m/s]           sigma_beta^2
GPS_POS        NED position of the antenna [m]                (eph*scale)^2 x2, epv^2 (floored)
GPS_VEL        NED velocity [m/s]                             speed accuracy^2 x3 (floored)
MAG            field in body FRD / reference strength [-]     sigma_mag^2 x3
SUN            sun unit vector body FRD [-], then NED [-]     sigma_sun^2 (per tangent axis)
ZERO_VELOCITY  0, 0, 0 NED velocity pseudo [m/s]             sigma_zv^2 x3
OUTPUT         (none)                                         (none)
=============  ============================================  ============================================
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Measurement kinds: integer codes used by the kernels and in the diagnostics. The order is also the processing
# order of events with equal time stamps (fast group, GPS, heading, pseudo, output last; paper Alg. 2).
BARO = 0
AIRSPEED = 1
SIDESLIP = 2
GPS_POS = 3
GPS_VEL = 4
MAG = 5
SUN = 6
ZERO_VELOCITY = 7
OUTPUT = 8
#: Sensor name per kind (the ``sensor`` column of the diagnostics).
SENSOR_NAMES = ("baro", "airspeed", "sideslip", "gps_pos", "gps_vel", "mag", "sun", "zero_velocity", "output")
#: Component names per kind (the ``component`` column of the diagnostics), indexed by the kernels' component id.
COMPONENT_NAMES = (("alt",), ("tas",), ("v",), ("n", "e", "d"), ("n", "e", "d", "vg", "chi"), ("x", "y", "z", "psi"),
                   ("t1", "t2"), ("n", "e", "d"), ())
#: Width of the event value and variance arrays.
N_EVENT_VALUES = 6
#: Pseudo-measurements are never gated.
PSEUDO_KINDS = frozenset({SIDESLIP, ZERO_VELOCITY})
#: The default heading choice: the magnetometer and the sun vector for a log with sun-device data (or solved sun
#: vectors), else the magnetometer (:func:`resolve_heading`; docs/estimators.md, 'Heading source by default').
AUTO_HEADING = "auto"
#: Valid ``heading`` choices.
HEADING_SOURCES = (AUTO_HEADING, "mag", "sun", "mag+sun")


def resolve_heading(heading: str, has_sun: bool) -> str:
    """The heading source(s) ``heading`` stands for: :data:`AUTO_HEADING` is ``"mag+sun"`` when ``has_sun`` (the
    sun vector cannot be corrupted by the currents and iron that disturb a magnetometer, seed paper 003; the
    magnetometer keeps the heading where the sun is not seen), else ``"mag"``; any other choice is itself."""
    if heading != AUTO_HEADING:
        return heading
    return "mag+sun" if has_sun else "mag"


@dataclass(frozen=True)
class ImuSamples:
    """Cleaned IMU rows (body FRD).

    Attributes
    ----------
    time_s : ndarray (n,)
        Log clock [s], strictly increasing. Row k is the rate held over ``(time_s[k-1], time_s[k]]``.
    gyro_rad_s : ndarray (n, 3)
        Angular rate [rad/s].
    accel_m_s2 : ndarray (n, 3)
        Specific force [m/s^2] (about (0, 0, -g) at rest and level).
    median_dt_s : float
        Median sample interval [s].
    gaps : tuple of (float, float)
        ``(start_time_s, length_s)`` of intervals longer than ``max_imu_gap_factor`` median periods.
    n_dropped : int
        Rows removed (non-finite or non-increasing time).
    """

    time_s: np.ndarray
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    median_dt_s: float
    gaps: tuple[tuple[float, float], ...]
    n_dropped: int


@dataclass(frozen=True)
class MeasurementEvents:
    """Time-sorted measurement and output events (see the module table for values per kind).

    Attributes
    ----------
    time_s : ndarray (m,)
        Event time on the log clock [s] (sample time, GPS latency removed).
    kind : ndarray (m,) int64
        Measurement kind code (``BARO`` ... ``OUTPUT``).
    imu_index : ndarray (m,) int64
        Index k of the IMU row whose interval ``(time_s[k-1], time_s[k]]`` contains the event (0: at the start).
    values : ndarray (m, 6)
        Measurement values.
    variances : ndarray (m, 6)
        Measurement noise variances per component.
    """

    time_s: np.ndarray
    kind: np.ndarray
    imu_index: np.ndarray
    values: np.ndarray
    variances: np.ndarray

    def __len__(self) -> int:
        return len(self.time_s)

    def count(self, kind: int) -> int:
        """Number of events of one kind."""
        return int(np.count_nonzero(self.kind == kind))

    def without(self, kinds) -> MeasurementEvents:
        """A copy without the events of the given kinds (order kept)."""
        keep = ~np.isin(self.kind, np.asarray(tuple(kinds), dtype=np.int64))
        return MeasurementEvents(self.time_s[keep], self.kind[keep], self.imu_index[keep], self.values[keep],
                                 self.variances[keep])


@dataclass(frozen=True)
class Origin:
    """Local NED origin (docs/estimators.md, 'Frames and attitude identities').

    Attributes
    ----------
    lat_deg, lon_deg : float
        WGS-84 latitude/longitude [deg] (NaN without GPS).
    alt_m : float
        Altitude above MSL [m] (first good GPS fix, else the first barometer altitude, else 0).
    source : str
        ``"gps"``, ``"baro"`` or ``"none"``.
    """

    lat_deg: float
    lon_deg: float
    alt_m: float
    source: str


@dataclass(frozen=True)
class Alignment:
    """Initial state (docs/estimators.md, 'Initial alignment').

    Attributes
    ----------
    roll_rad, pitch_rad, yaw_rad : float
        Initial ZYX Euler angles [rad].
    gyro_bias_rad_s : ndarray (3,)
        Initial gyro bias [rad/s] (mean gyro of the still window, else zeros).
    velocity_ned_m_s : ndarray (3,)
        Initial NED velocity [m/s] (zero when still, else the first GPS velocity).
    position_ned_m : ndarray (3,)
        Initial NED position [m] (first GPS position, else zeros; down from the barometer when no GPS).
    still_window_s : tuple of (float, float) or None
        ``(start, end)`` of the still window used, or None for an in-air start.
    yaw_source : str
        ``"mag"``, ``"sun"`` (gravity + sun vector), ``"onboard_attitude"`` (reference borrowed from the
        autopilot), ``"gps_course"`` or ``"none"``.
    tilt_source : str
        ``"still_window"``, ``"onboard_attitude"`` or ``"accelerometer"`` (in-air levelling).
    """

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    gyro_bias_rad_s: np.ndarray
    velocity_ned_m_s: np.ndarray
    position_ned_m: np.ndarray
    still_window_s: tuple[float, float] | None
    yaw_source: str
    tilt_source: str


@dataclass(frozen=True)
class SensorPlan:
    """What a replay can use (docs/estimators.md, 'Sensor plan').

    Attributes
    ----------
    fixed_wing : bool
        MAV_TYPE says fixed-wing: airspeed-based models and the zero-sideslip pseudo-measurement apply.
    has_gps, has_baro, has_mag, has_airspeed, has_sun : bool
        Usable streams.
    used : tuple of str
        Sensors with events (names from :data:`SENSOR_NAMES`).
    skipped : dict of str -> str
        Sensor -> why it is not used.
    degradations : tuple of str
        Degraded modes applied, in words.
    mag_fusion : str
        How the full-state filters fuse the magnetometer: ``"heading"`` or ``"vector"`` (``"none"`` without one;
        docs/estimators.md, 'Magnetometer heading fusion').
    """

    fixed_wing: bool
    has_gps: bool
    has_baro: bool
    has_mag: bool
    has_airspeed: bool
    has_sun: bool
    used: tuple[str, ...]
    skipped: dict[str, str]
    degradations: tuple[str, ...]
    mag_fusion: str = "none"


@dataclass(frozen=True)
class ReplayInputs:
    """Everything a filter kernel needs from one log.

    Attributes
    ----------
    imu : ImuSamples
    events : MeasurementEvents
        Sorted events including the ``OUTPUT`` epochs.
    origin : Origin
    plan : SensorPlan
    alignment : Alignment
    mag_field_ned : ndarray (3,)
        Earth field at the origin in NED divided by :attr:`mag_strength_gauss` (a unit vector; the MAG event
        values are divided by the same strength).
    mag_strength_gauss : float
        Reference field strength [gauss]: median |m| of the log's magnetometer.
    mag_field_source : str
        ``"wmm"`` (World Magnetic Model at origin and date) or ``"declination_parameter"`` (no position: the
        log's declination parameter and the measured inclination).
    gravity_m_s2 : float
        Local normal gravity at the origin [m/s^2] (docs/estimators.md, 'Frames and attitude identities').
    gps_delay_s : float
        GPS latency [s] (:func:`gps_measurement_time_s`).
    gps_time_rule : str
        How GPS measurement times were obtained (:func:`gps_measurement_time_s`); empty without GPS.
    baro_offset_m : float
        Barometric minus GPS altitude [m] removed from the barometer (0 without GPS).
    output_time_s : ndarray
        Output epochs [s].
    source : str
        Log name, for messages.
    warnings : tuple of str
    """

    imu: ImuSamples
    events: MeasurementEvents
    origin: Origin
    plan: SensorPlan
    alignment: Alignment
    mag_field_ned: np.ndarray
    mag_strength_gauss: float
    mag_field_source: str
    gravity_m_s2: float
    gps_delay_s: float
    gps_time_rule: str
    baro_offset_m: float
    output_time_s: np.ndarray
    source: str
    warnings: tuple[str, ...] = field(default=())


@dataclass(frozen=True)
class GpsRows:
    time_s: np.ndarray  # latency-corrected sample time [s]
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    vel_ned: np.ndarray  # (n, 3)
    eph_m: np.ndarray
    epv_m: np.ndarray
    speed_sigma_m_s: np.ndarray  # NaN where not reported
    time_rule: str  # how the measurement time was obtained
