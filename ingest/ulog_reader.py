"""PX4 ULog -> canonical :class:`~ingest.flightlog.FlightLog`.

:func:`load_flight_log` takes a path, bytes or a binary file object (a Streamlit upload), parses only the
topics listed in :mod:`ingest.px4_topics` with pyulog, and hands the result to :func:`flightlog_from_ulog`,
which maps PX4 names and units to the canonical ones and cleans the time axis. Everything it works around is
written to ``FlightLog.meta.warnings``.

Time axis of every topic: PX4 ``timestamp`` [us] cast to int64 before any arithmetic; rows with timestamp 0 or
timed before the log's start are dropped, rows out of order are sorted (stable), and of rows with equal times
the first logged is kept, so every stream index is strictly increasing. A topic whose timestamps are all zero
(``ekf2_innovations`` in some PX4 1.6 logs) is skipped.

Multi-instance topics: instance 0 (the primary), or the instance with the most samples when instance 0 was not
logged; the stream's topic then reads ``"sensor_gps[1]"`` (``"[0]"`` when other instances exist).

Each stream's :class:`~ingest.flightlog.StreamInfo` (median rate, gaps) describes the sensor: it is computed on
the sorted sample times (``sample_time_s``) where the topic logs them, since some topics publish two samples at
once and their row spacing alone is bimodal.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numba import njit
from pyulog import ULog
from pyulog.exceptions import ULogException

from ingest.atmosphere import (
    ISA_SEA_LEVEL_DENSITY_KG_M3,
    altitude_pressure_pa,
    isa_density_kg_m3,
    pressure_altitude_m,
)
from ingest.errors import InputError
from ingest.flightlog import (
    FIXED_WING_MAV_TYPES,
    OPTIONAL_COLUMNS,
    STREAM_COLUMNS,
    FlightLog,
    LogMetadata,
    stream_info,
)
from ingest.frames import quat_to_euler, wrap_angle_deg
from ingest.px4_topics import (
    ALL_TOPICS,
    RELATIVE_TIMESTAMP_INVALID,
    SENSOR_STREAMS,
    STREAM_TOPICS,
    US_TO_S,
    TopicSpec,
)
from ingest.sources import Source, read_content

#: GPS fix_type below this has no position (0-1: no fix).
MIN_POSITION_FIX_TYPE = 2
#: ``SENS_BARO_QNH`` default [hPa] for logs without the parameter.
DEFAULT_QNH_HPA = 1013.25
#: ULog file header: magic bytes and the 8-byte start timestamp.
ULOG_HEADER_BYTES = 16


def load_flight_log(path_or_bytes: Source, *, max_bytes: int | None = None, name: str | None = None) -> FlightLog:
    """Read a PX4 ULog file into a :class:`FlightLog`.

    Parameters
    ----------
    path_or_bytes : path, bytes or binary file object
        The ``.ulg`` file or its content (a Streamlit upload is a binary file object).
    max_bytes : int, optional
        Refuse files larger than this [bytes] with :class:`~ingest.errors.FileTooLargeError`.
    name : str, optional
        Name shown in messages and stored as ``meta.source``; default the file's base name (``"<upload>"`` for
        nameless bytes).

    Returns
    -------
    FlightLog
        Canonical streams (SI, NED, body FRD, ``time_s`` index) and metadata with the file's SHA-256. A
        truncated or partly corrupt file gives what is readable, with a warning.

    Raises
    ------
    InputError
        The file cannot be read, is empty, is not a ULog, or has no IMU (``sensor_combined``) data.
    FileTooLargeError
        The file is larger than ``max_bytes``.
    """
    content, name = read_content(path_or_bytes, name=name, max_bytes=max_bytes)
    ulog = _parse(content, name)
    notes = []
    if not ulog.file_corruption:
        end = _message_walk_end(np.frombuffer(content, dtype=np.uint8), ULOG_HEADER_BYTES)
        if end != len(content):
            notes.append(f"the file is truncated: its last message is cut off at byte {len(content)}; "
                         "the complete messages before it were read")
    return flightlog_from_ulog(ulog, source=name, sha256=hashlib.sha256(content).hexdigest(), notes=notes)


def flightlog_from_ulog(ulog: ULog, *, source: str, sha256: str = "", notes: Sequence[str] = ()) -> FlightLog:
    """Map a parsed pyulog :class:`~pyulog.core.ULog` to a :class:`FlightLog` (the ULog is not modified).

    Parameters
    ----------
    ulog : pyulog.ULog
        Parsed log.
    source : str
        File name for messages and ``meta.source``.
    sha256 : str, optional
        Hex digest of the file content.
    notes : sequence of str, optional
        Findings about the file itself (truncation), put first among the warnings.

    Returns
    -------
    FlightLog

    Raises
    ------
    InputError
        The log has no usable IMU stream.
    """
    file_notes = [*notes, *_logging_warnings(ulog)]
    warnings = list(file_notes)
    streams: dict[str, pd.DataFrame] = {}
    topics: dict[str, str] = {}
    vehicle_type = ulog.initial_parameters.get("MAV_TYPE")
    vehicle_type = None if vehicle_type is None else int(vehicle_type)
    parameters = {key: float(value) for key, value in ulog.initial_parameters.items()}
    for stream, specs in STREAM_TOPICS.items():
        found = _first_usable_topic(ulog, specs, warnings)
        if isinstance(found, str):
            if stream in SENSOR_STREAMS:
                hint = (" (normal for a vehicle that is not fixed-wing)"
                        if stream == "airspeed" and vehicle_type not in FIXED_WING_MAV_TYPES else "")
                warnings.append(f"{SENSOR_STREAMS[stream]}{hint}: {found}")
            continue
        frame, spec, label = found
        if spec.note:
            warnings.append(f"{stream} from {label}: {spec.note}")
        complete = _COMPLETE.get(stream)
        if complete is not None:
            frame = complete(frame, _Context(label, warnings, parameters, streams))
        topics[stream] = label
        optional = [c for c in OPTIONAL_COLUMNS.get(stream, ()) if c in frame.columns and frame[c].notna().any()]
        streams[stream] = frame[[*STREAM_COLUMNS[stream], *optional]]
    if "imu" not in streams or len(streams["imu"]) < 2:
        raise InputError("no IMU data: the log needs at least two sensor_combined samples with finite "
                         "gyro_rad and accelerometer_m_s2" + "".join(f"; {note}" for note in file_notes),
                         source=source, field="sensor_combined")

    imu_time_s = streams["imu"].index.to_numpy()
    meta = LogMetadata(
        source=source,
        sha256=sha256,
        vehicle_type=vehicle_type,
        hardware=ulog.msg_info_dict.get("ver_hw"),
        px4_version=firmware_version(ulog),
        ver_data_format=ulog.msg_info_dict.get("ver_data_format"),
        start_time_s=float(imu_time_s[0]),
        end_time_s=float(imu_time_s[-1]),
        duration_s=float(imu_time_s[-1] - imu_time_s[0]),
        utc_offset_s=_utc_offset_s(streams.get("gps")),
        parameters=parameters,
        streams={stream: stream_info(topics[stream], _sample_times_s(frame)) for stream, frame in streams.items()},
        warnings=list(dict.fromkeys(warnings)),  # a topic feeding several streams reports its cleaning once
    )
    return FlightLog(streams=streams, meta=meta)


def firmware_version(ulog: ULog) -> str | None:
    """Firmware as ``"v1.14.0"`` (tagged release), ``"v1.15.0 dev (cb09dde6)"`` or the bare git hash."""
    git_hash = str(ulog.msg_info_dict.get("ver_sw", ""))[:8]
    if not ulog.msg_info_dict.get("ver_sw_release"):
        return git_hash or None
    release = ulog.get_version_info_str()
    if release is not None:
        return release
    major, minor, patch, _ = ulog.get_version_info()
    return f"v{major}.{minor}.{patch} dev" + (f" ({git_hash})" if git_hash else "")


def _parse(content: bytes, name: str) -> ULog:
    """pyulog parse of the topics we use; pyulog's console chatter about corruption is dropped (reported
    through ``file_corruption`` instead)."""
    if not content.startswith(ULog.HEADER_BYTES):
        raise InputError("not a PX4 ULog file: it does not start with the ULog header bytes", source=name)
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            return ULog(io.BytesIO(content), message_name_filter_list=list(ALL_TOPICS))
    except (ULogException, struct.error, ValueError, IndexError, KeyError, OverflowError, TypeError,
            UnicodeDecodeError) as exc:
        raise InputError(f"not a readable PX4 ULog file ({exc})", source=name) from exc


@njit(cache=True)
def _message_walk_end(content: np.ndarray, offset: int) -> int:
    """Offset [bytes] where the chain of ULog messages (3-byte header: uint16 size, uint8 type) starting at
    ``offset`` ends; the file's length exactly when its last message is complete."""
    n_bytes = content.shape[0]
    while offset + 3 <= n_bytes:
        offset += 3 + np.int64(content[offset]) + 256 * np.int64(content[offset + 1])
    return offset


def _first_usable_topic(ulog: ULog, specs: tuple[TopicSpec, ...],
                        warnings: list[str]) -> tuple[pd.DataFrame, TopicSpec, str] | str:
    """``(frame, spec, topic label)`` from the first topic of ``specs`` with the required fields and samples,
    else why each topic was not used."""
    reasons = []
    for spec in specs:
        instances = {d.multi_id: d for d in ulog.data_list if d.name == spec.topic}
        if not instances:
            reasons.append(f"{spec.topic}: not in the log")
            continue
        multi_id = 0 if 0 in instances else max(instances, key=lambda i: len(instances[i].data["timestamp"]))
        label = spec.topic if len(instances) == 1 and multi_id == 0 else f"{spec.topic}[{multi_id}]"
        if multi_id != 0:
            warnings.append(f"{spec.topic}: instance 0 has no data; using instance {multi_id} (most samples)")
        frame = _topic_frame(instances[multi_id].data, spec, label, ulog.start_timestamp, warnings)
        if isinstance(frame, str):
            reasons.append(f"{label}: {frame}")
        elif len(frame) == 0:
            reasons.append(f"{label}: no valid samples")
        else:
            return frame, spec, label
    return "; ".join(reasons)


def _topic_frame(data: dict[str, np.ndarray], spec: TopicSpec, label: str, start_us: int,
                 warnings: list[str]) -> pd.DataFrame | str:
    """Canonical columns of one topic, indexed by strictly increasing ``time_s``; or, when a required field
    is missing or no timestamp is set, the reason."""
    columns: dict[str, np.ndarray] = {}
    for field in spec.fields:
        raw_and_scale = next(((data[px4], scale) for px4, scale, kinds in field.sources
                              if px4 in data and (not kinds or data[px4].dtype.kind in kinds)), None)
        if raw_and_scale is None:
            if field.required:
                return f"no field {' or '.join(dict.fromkeys(px4 for px4, _, _ in field.sources))}"
            if field.nan_if_missing:
                columns[field.column] = np.full(len(data["timestamp"]), np.nan)
            continue
        raw, scale = raw_and_scale
        values = raw.astype(np.float64) * (scale(raw) if callable(scale) else scale)
        if field.zero_is_missing:
            values[raw == 0] = np.nan
        columns[field.column] = values

    time_us = data["timestamp"].astype(np.int64)
    if not time_us.any():
        warnings.append(f"{label}: every timestamp is zero; topic skipped")
        return "every timestamp is zero"
    has_sample = np.ones(len(time_us), dtype=bool)
    if spec.time_relative is not None:
        if spec.time_relative not in data:
            return f"no field {spec.time_relative}"
        relative_us = data[spec.time_relative].astype(np.int64)
        has_sample = relative_us != RELATIVE_TIMESTAMP_INVALID
        if not has_sample.any():
            return f"no valid samples ({spec.time_relative} marks every row invalid)"
        time_us = time_us + np.where(has_sample, relative_us, 0)
    rows = _increasing_time_rows(time_us, has_sample, start_us, label, warnings,
                                 repeats_expected=spec.time_relative is not None)
    index = pd.Index(time_us[rows] * US_TO_S, name="time_s")
    return pd.DataFrame({column: values[rows] for column, values in columns.items()}, index=index)


def _increasing_time_rows(time_us: np.ndarray, has_sample: np.ndarray, start_us: int, label: str,
                          warnings: list[str], *, repeats_expected: bool) -> np.ndarray:
    """Indices of the rows that give strictly increasing times: rows with time 0 or before the log start
    ``start_us`` are dropped, rows out of order are sorted, and of rows with equal times the first logged is
    kept."""
    is_zero = has_sample & (time_us == 0)
    is_early = has_sample & ~is_zero & (time_us < start_us)
    candidates = np.flatnonzero(has_sample & ~is_zero & ~is_early)
    n_unsorted = int(np.count_nonzero(np.diff(time_us[candidates]) < 0))
    order = candidates[np.argsort(time_us[candidates], kind="stable")] if n_unsorted else candidates
    keep = np.ones(len(order), dtype=bool)
    keep[1:] = np.diff(time_us[order]) > 0
    n_repeated = int(np.count_nonzero(~keep))
    if is_zero.any():
        warnings.append(f"{label}: dropped {int(np.count_nonzero(is_zero))} rows with timestamp 0")
    if is_early.any():
        warnings.append(f"{label}: dropped {int(np.count_nonzero(is_early))} rows timed before the log start "
                        f"({start_us * US_TO_S:.6f} s)")
    if n_unsorted:
        warnings.append(f"{label}: {n_unsorted} rows were out of time order and have been sorted")
    if n_repeated and not repeats_expected:
        warnings.append(f"{label}: dropped {n_repeated} rows repeating an earlier timestamp")
    return order[keep]


@dataclass(frozen=True)
class _Context:
    """What a stream's completion step may need: its topic label, the warnings list, the log's parameters and
    the streams built before it."""

    label: str
    warnings: list[str]
    parameters: dict[str, float]
    streams: dict[str, pd.DataFrame]


def _finite_imu(frame: pd.DataFrame, ctx: _Context) -> pd.DataFrame:
    """Drop IMU rows with a non-finite gyro or accelerometer value (every filter integrates them)."""
    finite = np.isfinite(frame[list(STREAM_COLUMNS["imu"])].to_numpy()).all(axis=1)
    if not finite.all():
        ctx.warnings.append(f"{ctx.label}: dropped {int(np.count_nonzero(~finite))} rows with non-finite "
                            "gyro/accel values")
    return frame[finite]


def _complete_baro(frame: pd.DataFrame, ctx: _Context) -> pd.DataFrame:
    """Fill the altitude from the pressure or the pressure from the altitude, whichever the topic lacks, with
    the ISA and the log's QNH (``SENS_BARO_QNH``), as PX4 computes ``baro_alt_meter``."""
    qnh_pa = 100.0 * ctx.parameters.get("SENS_BARO_QNH", DEFAULT_QNH_HPA)
    if "alt_m" not in frame.columns:
        return frame.assign(alt_m=pressure_altitude_m(frame["pressure_pa"].to_numpy(), qnh_pa))
    pressure_pa = frame["pressure_pa"].to_numpy()
    if np.isnan(pressure_pa).all():
        ctx.warnings.append(f"baro from {ctx.label}: pressure derived from the altitude with the ISA and "
                            f"QNH {qnh_pa / 100.0:.2f} hPa")
        return frame.assign(pressure_pa=altitude_pressure_pa(frame["alt_m"].to_numpy(), qnh_pa))
    return frame


def _complete_airspeed(frame: pd.DataFrame, ctx: _Context) -> pd.DataFrame:
    """Indicated and true airspeed from a differential pressure q [Pa], signed as PX4 does:
    IAS = sign(q) sqrt(2 |q| / rho_0), TAS = IAS sqrt(rho_0 / rho), rho the ISA density at the barometer's
    static pressure (sea level without a barometer)."""
    if "differential_pressure_pa" not in frame.columns:
        return frame
    dp_pa = frame["differential_pressure_pa"].to_numpy()
    ias_m_s = np.sign(dp_pa) * np.sqrt(2.0 * np.abs(dp_pa) / ISA_SEA_LEVEL_DENSITY_KG_M3)
    baro = ctx.streams.get("baro")
    if baro is None:
        density_kg_m3 = np.full(len(dp_pa), ISA_SEA_LEVEL_DENSITY_KG_M3)
        ctx.warnings.append(f"airspeed from {ctx.label}: no barometer, so TAS uses the sea-level density "
                            f"{ISA_SEA_LEVEL_DENSITY_KG_M3} kg/m^3 (TAS = IAS)")
    else:
        static_pa = np.interp(frame.index.to_numpy(), baro.index.to_numpy(), baro["pressure_pa"].to_numpy())
        density_kg_m3 = isa_density_kg_m3(static_pa)
        ctx.warnings.append(f"airspeed from {ctx.label}: IAS with the sea-level density "
                            f"{ISA_SEA_LEVEL_DENSITY_KG_M3} kg/m^3, TAS with the ISA density at the barometer's "
                            "static pressure")
    tas_m_s = ias_m_s * np.sqrt(ISA_SEA_LEVEL_DENSITY_KG_M3 / density_kg_m3)
    return frame.assign(ias_m_s=ias_m_s, tas_m_s=tas_m_s)


def _gps_without_fix_to_nan(frame: pd.DataFrame, ctx: _Context) -> pd.DataFrame:
    """Position and velocity are NaN where the receiver had no fix (PX4 logs zeros there)."""
    no_fix = frame["fix_type"].to_numpy() < MIN_POSITION_FIX_TYPE
    if no_fix.any():
        frame = frame.copy()
        frame.loc[no_fix, ["lat_deg", "lon_deg", "alt_m", "vn_m_s", "ve_m_s", "vd_m_s"]] = np.nan
    return frame


def _with_euler(frame: pd.DataFrame, ctx: _Context) -> pd.DataFrame:
    """Add ZYX Euler angles [deg] (yaw in [-180, 180)) from the quaternion columns."""
    roll, pitch, yaw = quat_to_euler(frame[["qw", "qx", "qy", "qz"]].to_numpy())
    return frame.assign(roll_deg=np.degrees(roll), pitch_deg=np.degrees(pitch),
                        yaw_deg=wrap_angle_deg(np.degrees(yaw)))


#: Per stream, the step that checks or completes the mapped columns.
_COMPLETE: dict[str, Callable[[pd.DataFrame, _Context], pd.DataFrame]] = {
    "imu": _finite_imu,
    "baro": _complete_baro,
    "gps": _gps_without_fix_to_nan,
    "airspeed": _complete_airspeed,
    "onboard_attitude": _with_euler,
    "truth_attitude": _with_euler,
}


def _sample_times_s(frame: pd.DataFrame) -> np.ndarray:
    """The sensor's own sample times [s] in order when logged, else the row times: rate and gaps describe the
    sensor (some topics publish two samples at once, the second one older, which makes row spacing bimodal)."""
    if "sample_time_s" in frame.columns:
        sample_time_s = frame["sample_time_s"].to_numpy()
        if np.isfinite(sample_time_s).all():
            return np.sort(sample_time_s)
    return frame.index.to_numpy()


def _utc_offset_s(gps: pd.DataFrame | None) -> float | None:
    """UTC unix time minus log time [s]: median over GPS rows that carry UTC; None without any.

    The receiver's UTC stamps the measurement, so it is paired with the sample time when logged (the publication
    time ``timestamp`` lags it by the receiver latency, ~0.1 s).
    """
    if gps is None:
        return None
    log_time_s = gps["sample_time_s"].to_numpy() if "sample_time_s" in gps else gps.index.to_numpy()
    offset_s = gps["time_utc_s"].to_numpy() - log_time_s
    offset_s = offset_s[np.isfinite(offset_s)]
    return float(np.median(offset_s)) if len(offset_s) else None


def _logging_warnings(ulog: ULog) -> list[str]:
    """Corruption and logger dropouts reported by pyulog."""
    notes = []
    if ulog.file_corruption:
        notes.append("the file is corrupt in places; pyulog skipped the damaged messages")
    durations_ms = np.array([d.duration for d in ulog.dropouts], dtype=float)
    if len(durations_ms) and durations_ms.sum() > 0:
        worst = ulog.dropouts[int(np.argmax(durations_ms))]
        notes.append(f"{len(durations_ms)} logger dropouts, {durations_ms.sum():.0f} ms of data lost in "
                     f"total (longest {worst.duration} ms at {worst.timestamp * US_TO_S:.3f} s)")
    return notes
