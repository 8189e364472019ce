"""The canonical flight log every other layer works on.

Conventions (see ``docs/nomenclature.md``):

* time: ``time_s`` = the log clock, i.e. PX4 ``timestamp`` [us] (int64) / 1e6, seconds since autopilot boot.
  Every stream DataFrame is indexed by ``time_s`` (float64, strictly increasing after ingest).
* earth frame: local NED (north, east, down); body frame: FRD (forward, right, down).
* quaternions: Hamilton, scalar first (w, x, y, z), rotating body FRD vectors into NED (as PX4's
  ``vehicle_attitude.q``).
* units: SI, with the unit in every column name (``gyro_x_rad_s``, ``alt_m``), except the magnetometer which
  stays in gauss (``mag_x_gauss``) as PX4 logs it, and angles for display which are in degrees (``roll_deg``).

A stream a log lacks is absent from :attr:`FlightLog.streams`; it is never filled with zeros.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ingest.sun_device import SunDevice

#: Canonical columns of every stream (the index is always ``time_s``). Optional columns may be missing.
STREAM_COLUMNS: dict[str, tuple[str, ...]] = {
    # IMU: gyro [rad/s] and specific force [m/s^2] in body FRD; about (0, 0, -9.81) m/s^2 at rest.
    "imu": ("gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s", "accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"),
    # Magnetometer [gauss], body FRD, calibrated as logged.
    "mag": ("mag_x_gauss", "mag_y_gauss", "mag_z_gauss"),
    # Barometer: altitude above MSL from the ISA model [m], static pressure [Pa], temperature [degC]
    # (pressure and temperature may be NaN).
    "baro": ("alt_m", "pressure_pa", "temp_c"),
    # GPS receiver: WGS-84 lat/lon [deg], altitude above MSL [m], NED velocity [m/s], accuracies [m],
    # fix type, and ``time_utc_s`` (UTC, unix seconds; NaN when the receiver gave none).
    "gps": ("lat_deg", "lon_deg", "alt_m", "vn_m_s", "ve_m_s", "vd_m_s", "eph_m", "epv_m", "fix_type",
            "time_utc_s"),
    # Airspeed: indicated and true airspeed [m/s].
    "airspeed": ("ias_m_s", "tas_m_s"),
    # Autopilot's own estimates (reference, never a measurement).
    "onboard_attitude": ("qw", "qx", "qy", "qz", "roll_deg", "pitch_deg", "yaw_deg"),
    "onboard_local_position": ("x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s"),
    "onboard_global_position": ("lat_deg", "lon_deg", "alt_m"),
    "onboard_wind": ("wind_n_m_s", "wind_e_m_s"),
    # Ground truth (SITL / simulator logs).
    "truth_attitude": ("qw", "qx", "qy", "qz", "roll_deg", "pitch_deg", "yaw_deg"),
    "truth_local_position": ("x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s"),
    "truth_global_position": ("lat_deg", "lon_deg", "alt_m"),
    "truth_wind": ("wind_n_m_s", "wind_e_m_s"),
    # Sun-device photocell currents [A], on the log clock (attached from the sun-device CSV).
    "sun": ("i1_a", "i2_a", "i3_a", "i4_a", "i5_a", "i6_a", "i7_a"),
}

#: Optional extra columns some streams carry when the log has them.
OPTIONAL_COLUMNS: dict[str, tuple[str, ...]] = {
    # ``sample_time_s``: the sensor's own sample time (PX4 ``timestamp_sample``) on the log clock, when
    # logged.
    "imu": ("dt_s",),
    "gps": ("sample_time_s", "speed_accuracy_m_s", "satellites_used"),
    "onboard_wind": ("wind_n_var_m2_s2", "wind_e_var_m2_s2"),
    "mag": ("sample_time_s",),
    "baro": ("sample_time_s",),
    "airspeed": ("sample_time_s",),
}

#: MAV_TYPE values of fixed-wing (or VTOL in fixed-wing flight) vehicles (MAVLink MAV_TYPE enum).
FIXED_WING_MAV_TYPES = frozenset({1, 16, 19, 20, 21, 22, 23, 24, 25})


@dataclass(frozen=True)
class StreamInfo:
    """Where a stream came from and how regular it is.

    Attributes
    ----------
    topic : str
        Source topic (``"sensor_combined"``, ``"vehicle_gps_position[1]"`` ...) or file.
    n_samples : int
        Number of rows after cleaning.
    rate_hz : float
        Median sample rate [Hz] (NaN with fewer than two samples).
    gaps : tuple of (float, float)
        ``(start_time_s, length_s)`` of every interval longer than 5 median periods (and > 0.1 s).
    """

    topic: str
    n_samples: int
    rate_hz: float
    gaps: tuple[tuple[float, float], ...] = ()


@dataclass
class LogMetadata:
    """Log-level facts.

    Attributes
    ----------
    source : str
        File name (or upload name) the log came from.
    sha256 : str
        Hex digest of the file content (cache and workspace key).
    vehicle_type : int or None
        MAVLink MAV_TYPE (1 fixed wing, 2 quadrotor, 22 VTOL ...), from the ``MAV_TYPE`` parameter.
    hardware : str or None
        ``ver_hw`` of the log.
    sys_uuid : str or None
        ``sys_uuid`` of the log: the autopilot board's unique id (identifies a vehicle across its logs).
    px4_version : str or None
        Release tag (``ver_sw_release`` decoded) or git hash of the firmware.
    ver_data_format : int or None
        ``ver_data_format`` info field (2 from PX4 1.14 on: float64 GPS latitude/longitude).
    start_time_s, end_time_s : float
        First and last IMU sample on the log clock [s].
    duration_s : float
        True data duration (from the sensor streams, not the header) [s].
    utc_offset_s : float or None
        UTC unix time = ``time_s + utc_offset_s`` (from GPS ``time_utc_usec``); None without GPS time.
    parameters : dict
        The log's parameters (initial values).
    streams : dict
        Stream name -> :class:`StreamInfo`.
    warnings : list of str
        Everything the reader noticed and worked around (missing sensors, fixed timestamps, corruption).
    sun_device : SunDevice or None
        Geometry of the sun device whose currents are the ``sun`` stream (set with that stream).
    """

    source: str
    sha256: str = ""
    vehicle_type: int | None = None
    hardware: str | None = None
    sys_uuid: str | None = None
    px4_version: str | None = None
    ver_data_format: int | None = None
    start_time_s: float = float("nan")
    end_time_s: float = float("nan")
    duration_s: float = 0.0
    utc_offset_s: float | None = None
    parameters: dict[str, float] = field(default_factory=dict)
    streams: dict[str, StreamInfo] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    sun_device: SunDevice | None = None

    @property
    def is_fixed_wing(self) -> bool:
        """True when MAV_TYPE says fixed-wing (airspeed-based models apply)."""
        return self.vehicle_type in FIXED_WING_MAV_TYPES


@dataclass
class FlightLog:
    """One flight: a DataFrame per sensor stream plus metadata.

    Attributes
    ----------
    streams : dict of str -> pandas.DataFrame
        Keys from :data:`STREAM_COLUMNS`; each frame indexed by ``time_s`` [s, log clock], columns as listed
        there.
    meta : LogMetadata
        Log-level facts and the per-stream :class:`StreamInfo`.
    """

    streams: dict[str, pd.DataFrame]
    meta: LogMetadata

    def has(self, name: str) -> bool:
        """True when the log has a non-empty stream ``name``."""
        frame = self.streams.get(name)
        return frame is not None and len(frame) > 0

    def __getitem__(self, name: str) -> pd.DataFrame:
        try:
            return self.streams[name]
        except KeyError:
            raise KeyError(f"log {self.meta.source!r} has no {name!r} stream "
                           f"(has: {', '.join(sorted(self.streams))})") from None

    def utc(self, time_s: np.ndarray | float) -> pd.DatetimeIndex:
        """UTC time stamps for log-clock times ``time_s`` [s]; ValueError when the log has no GPS time."""
        if self.meta.utc_offset_s is None:
            raise ValueError(f"log {self.meta.source!r} has no GPS UTC time")
        seconds = np.atleast_1d(np.asarray(time_s, dtype=float)) + self.meta.utc_offset_s
        return pd.to_datetime(seconds, unit="s", utc=True)


def stream_info(topic: str, time_s: np.ndarray) -> StreamInfo:
    """Sample count, median rate [Hz] and gaps of a stream with strictly increasing times ``time_s`` [s]."""
    n = len(time_s)
    if n < 2:
        return StreamInfo(topic=topic, n_samples=n, rate_hz=float("nan"))
    dt = np.diff(time_s)
    median_dt = float(np.median(dt))
    is_gap = dt > max(5.0 * median_dt, 0.1)
    gaps = tuple((float(time_s[i]), float(dt[i])) for i in np.flatnonzero(is_gap))
    return StreamInfo(topic=topic, n_samples=n, rate_hz=1.0 / median_dt if median_dt > 0 else float("nan"),
                      gaps=gaps)


def utc_offset_s(gps: pd.DataFrame | None) -> float | None:
    """UTC unix time minus log time [s] of a canonical ``gps`` stream: median over the rows that carry UTC; None
    without any.

    The receiver's UTC stamps the measurement, so it is paired with the sample time when logged (the publication
    time lags it by the receiver latency, ~0.1 s).
    """
    if gps is None:
        return None
    log_time_s = gps["sample_time_s"].to_numpy() if "sample_time_s" in gps else gps.index.to_numpy()
    offset_s = gps["time_utc_s"].to_numpy() - log_time_s
    offset_s = offset_s[np.isfinite(offset_s)]
    return float(np.median(offset_s)) if len(offset_s) else None
