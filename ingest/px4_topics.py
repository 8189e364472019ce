"""Where each canonical stream comes from in a PX4 ULog, across PX4 versions (1.6 to 1.15).

This is the only place that knows PX4 topic and field names. Each canonical stream (see
:data:`ingest.flightlog.STREAM_COLUMNS`) lists the topics that can feed it, best first; each topic lists, per
canonical column, the PX4 field names it had over time with the factor that turns the raw value into SI.
The reader takes the first topic present in the log with every required field and at least one valid sample,
and, per column, the first field name present.

Version differences handled here:

* PX4 <= 1.7 logs the magnetometer and the barometer inside ``sensor_combined`` (``magnetometer_ga[3]``,
  ``baro_alt_meter``, ``baro_temp_celcius`` with ``*_timestamp_relative``); later versions have
  ``vehicle_magnetometer`` / ``vehicle_air_data``; the raw ``sensor_mag`` / ``sensor_baro`` (1-2 Hz in default
  logging) are the last resort.
* ``gyro_integral_dt``: float32 seconds before PX4 1.7, uint32 microseconds after (told apart by dtype).
* ``sensor_baro.pressure``: millibar up to PX4 1.12, pascal after (told apart by magnitude, see
  :func:`pressure_scale_to_pa`).
* GPS: int32 ``lat``/``lon`` [1e-7 deg] and ``alt`` [mm] until PX4 1.13 (``ver_data_format`` < 2), float64
  ``latitude_deg``/``longitude_deg``/``altitude_msl_m`` after.
* wind: ``wind_estimate`` (``covariance_*`` in 1.6, ``variance_*`` later), ``wind`` (1.14+), or the wind states
  22-23 of ``estimator_states`` when neither is logged.
* airspeed: the sensor topic ``airspeed``, else ``differential_pressure`` (converted by the reader), else
  ``airspeed_validated`` (possibly synthetic, so last and flagged).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: PX4 marks a ``*_timestamp_relative`` field whose sensor has no new sample with this value.
RELATIVE_TIMESTAMP_INVALID = 0x7FFFFFFF

US_TO_S = 1e-6

#: Below this a logged static pressure is in millibar (1 mbar = 100 Pa): real static pressure is above
#: 2000 Pa up to 25 km altitude, and below 2000 mbar everywhere.
MBAR_PRESSURE_LIMIT = 2000.0

#: The simulator's wind truth (not a PX4 topic): fields ``timestamp``, ``windspeed_north``,
#: ``windspeed_east`` (float32, m/s, NED).
TRUTH_WIND_TOPIC = "solarnav_wind_groundtruth"


def pressure_scale_to_pa(raw: np.ndarray) -> float:
    """Factor from a logged ``sensor_baro.pressure`` to Pa: 100 for millibar (PX4 <= 1.12), else 1."""
    return 100.0 if np.nanmedian(np.abs(raw)) < MBAR_PRESSURE_LIMIT else 1.0


Scale = float | Callable[[np.ndarray], float]


@dataclass(frozen=True)
class Field:
    """One canonical column and the PX4 fields that can fill it.

    Attributes
    ----------
    column : str
        Canonical column name.
    sources : tuple of (str, float or callable, str)
        ``(px4_field, scale, dtype_kinds)``, best first. The column is ``scale * raw``, where a callable
        scale is given the raw array (units told apart by magnitude); ``dtype_kinds`` limits a source to
        raw arrays of those numpy dtype kinds (``"iu"`` integers, ``"f"`` floats, ``""`` any), for fields
        that kept their name but changed type and unit.
    required : bool
        A required column missing from the topic makes the topic unusable; an optional one is left out
        (or, for columns the contract always carries, filled with NaN; see ``nan_if_missing``).
    zero_is_missing : bool
        The raw value 0 means "not available" (PX4 ``time_utc_usec``); it becomes NaN.
    nan_if_missing : bool
        When no source is present, the column is kept and filled with NaN (contract columns that may be NaN
        or that the reader derives from others).
    """

    column: str
    sources: tuple[tuple[str, Scale, str], ...]
    required: bool = True
    zero_is_missing: bool = False
    nan_if_missing: bool = False


@dataclass(frozen=True)
class TopicSpec:
    """A PX4 topic that feeds a canonical stream.

    Attributes
    ----------
    topic : str
        uORB topic name as logged.
    fields : tuple of Field
        Columns taken from this topic.
    time_relative : str or None
        Field holding the sample time relative to ``timestamp`` [us] (sensors embedded in the old
        ``sensor_combined``); rows marked :data:`RELATIVE_TIMESTAMP_INVALID` carry no sample of this sensor
        and repeated rows of one sample collapse to one. None: the row time is ``timestamp``.
    note : str
        Caveat reported as a warning when this topic is the one used (fallback sources).
    """

    topic: str
    fields: tuple[Field, ...]
    time_relative: str | None = None
    note: str = ""


def _f(column: str, *names: str, scale: Scale = 1.0, **flags) -> Field:
    """A field whose PX4 names all share one scale and any dtype."""
    return Field(column, tuple((name, scale, "") for name in names), **flags)


def _vector(prefix: str, px4_fields: str, scale: float = 1.0) -> tuple[Field, ...]:
    """Columns ``prefix`` formatted with x/y/z from PX4 fields ``px4_fields`` formatted with 0/1/2 (or x/y/z)."""
    return tuple(_f(prefix.format(axis), px4_fields.format(i=i, axis=axis), scale=scale)
                 for i, axis in enumerate("xyz"))


# 0 where the driver did not set it (GPS in PX4 1.15 SITL)
_SAMPLE_TIME = _f("sample_time_s", "timestamp_sample", scale=US_TO_S, required=False, zero_is_missing=True)
_QUATERNION = tuple(_f(f"q{c}", f"q[{i}]") for i, c in enumerate("wxyz"))
_LOCAL_POSITION = (_f("x_m", "x"), _f("y_m", "y"), _f("z_m", "z"),
                   _f("vx_m_s", "vx"), _f("vy_m_s", "vy"), _f("vz_m_s", "vz"))
_GLOBAL_POSITION = (_f("lat_deg", "lat"), _f("lon_deg", "lon"), _f("alt_m", "alt"))
_WIND = (_f("wind_n_m_s", "windspeed_north"), _f("wind_e_m_s", "windspeed_east"),
         # PX4 1.6 called the variances "covariance_*"
         _f("wind_n_var_m2_s2", "variance_north", "covariance_north", required=False),
         _f("wind_e_var_m2_s2", "variance_east", "covariance_east", required=False))
_GPS = (
    # PX4 >= 1.14 (ver_data_format 2): float64 degrees and metres; before: int32 1e-7 deg and int32 mm
    Field("lat_deg", (("latitude_deg", 1.0, ""), ("lat", 1e-7, "iu"))),
    Field("lon_deg", (("longitude_deg", 1.0, ""), ("lon", 1e-7, "iu"))),
    Field("alt_m", (("altitude_msl_m", 1.0, ""), ("alt", 1e-3, "iu"))),
    _f("vn_m_s", "vel_n_m_s"), _f("ve_m_s", "vel_e_m_s"), _f("vd_m_s", "vel_d_m_s"),
    _f("eph_m", "eph"), _f("epv_m", "epv"), _f("fix_type", "fix_type"),
    _f("time_utc_s", "time_utc_usec", scale=US_TO_S, required=False, zero_is_missing=True,
       nan_if_missing=True),
    _SAMPLE_TIME,
    # a standard deviation despite its name
    _f("speed_accuracy_m_s", "s_variance_m_s", required=False),
    _f("satellites_used", "satellites_used", required=False),
)
_AIR_DATA_BARO = (
    _f("alt_m", "baro_alt_meter"),
    # absent from sensor_combined: the reader derives it from alt_m and SENS_BARO_QNH
    _f("pressure_pa", "baro_pressure_pa", required=False, nan_if_missing=True),
    _f("temp_c", "ambient_temperature", "baro_temp_celcius", required=False, nan_if_missing=True),
)
_AIRSPEED = (_f("ias_m_s", "indicated_airspeed_m_s"), _f("tas_m_s", "true_airspeed_m_s"), _SAMPLE_TIME)

#: Canonical stream -> topics that can feed it, best first.
STREAM_TOPICS: dict[str, tuple[TopicSpec, ...]] = {
    "imu": (TopicSpec("sensor_combined", (
        *_vector("gyro_{}_rad_s", "gyro_rad[{i}]"),
        *_vector("accel_{}_m_s2", "accelerometer_m_s2[{i}]"),
        # uint32 microseconds since PX4 1.7; float32 seconds before
        Field("dt_s", (("gyro_integral_dt", US_TO_S, "iu"), ("gyro_integral_dt", 1.0, "f")), required=False),
    )),),
    "mag": (
        TopicSpec("vehicle_magnetometer", (*_vector("mag_{}_gauss", "magnetometer_ga[{i}]"), _SAMPLE_TIME)),
        TopicSpec("sensor_combined", _vector("mag_{}_gauss", "magnetometer_ga[{i}]"),
                  time_relative="magnetometer_timestamp_relative"),
        TopicSpec("sensor_mag", (*_vector("mag_{}_gauss", "{axis}"), _SAMPLE_TIME),
                  note="raw driver output, without the in-flight calibration"),
    ),
    "baro": (
        TopicSpec("vehicle_air_data", (*_AIR_DATA_BARO, _SAMPLE_TIME)),
        TopicSpec("sensor_combined", _AIR_DATA_BARO, time_relative="baro_timestamp_relative"),
        TopicSpec("sensor_baro", (
            _f("pressure_pa", "pressure", scale=pressure_scale_to_pa),
            _f("temp_c", "temperature", required=False, nan_if_missing=True),
            _SAMPLE_TIME,
        ), note="raw driver output; altitude from the pressure with the ISA and SENS_BARO_QNH"),
    ),
    # vehicle_gps_position is the selected (or blended) receiver, logged at the full rate
    "gps": (TopicSpec("vehicle_gps_position", _GPS), TopicSpec("sensor_gps", _GPS)),
    "airspeed": (
        TopicSpec("airspeed", _AIRSPEED),
        TopicSpec("differential_pressure", (
            # the reader turns this intermediate column into ias_m_s / tas_m_s
            _f("differential_pressure_pa", "differential_pressure_pa", "differential_pressure_raw_pa",
               "differential_pressure_filtered_pa"),
            _SAMPLE_TIME,
        ), note="converted from the differential pressure"),
        TopicSpec("airspeed_validated", _AIRSPEED,
                  note="PX4's validated airspeed, which may be synthetic or EKF-derived, not a raw measurement"),
    ),
    "onboard_attitude": (TopicSpec("vehicle_attitude", _QUATERNION),),
    "onboard_local_position": (TopicSpec("vehicle_local_position", _LOCAL_POSITION),),
    "onboard_global_position": (TopicSpec("vehicle_global_position", _GLOBAL_POSITION),),
    "onboard_wind": (
        TopicSpec("wind_estimate", _WIND),
        TopicSpec("wind", _WIND),
        # EKF2 states 22-23 are the NE wind velocity [m/s] in PX4 1.12-1.15 (24-state filter)
        TopicSpec("estimator_states", (_f("wind_n_m_s", "states[22]"), _f("wind_e_m_s", "states[23]"))),
    ),
    "truth_attitude": (TopicSpec("vehicle_attitude_groundtruth", _QUATERNION),),
    "truth_local_position": (TopicSpec("vehicle_local_position_groundtruth", _LOCAL_POSITION),),
    "truth_global_position": (TopicSpec("vehicle_global_position_groundtruth", _GLOBAL_POSITION),),
    "truth_wind": (TopicSpec(TRUTH_WIND_TOPIC, _WIND[:2]),),
}

#: Measurement streams whose absence is reported, with the words used for them.
SENSOR_STREAMS: dict[str, str] = {"mag": "no magnetometer", "baro": "no barometer", "gps": "no GPS",
                                  "airspeed": "no airspeed sensor"}

#: Every topic the reader asks pyulog for.
ALL_TOPICS: tuple[str, ...] = tuple(sorted({spec.topic for specs in STREAM_TOPICS.values()
                                             for spec in specs}))
