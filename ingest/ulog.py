"""PX4 ULog -> canonical :class:`~ingest.flightlog.FlightLog`.

:func:`read_ulog` takes a path, bytes or a binary file object (a Streamlit upload), parses only the topics
listed in :mod:`ingest.px4_topics` with pyulog, and hands the result to :func:`flightlog_from_ulog`, which
maps PX4 names and units to the canonical ones and cleans the time axis. Everything it works around is written
to ``FlightLog.meta.warnings``.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import struct
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pandas as pd
from pyulog import ULog
from pyulog.exceptions import ULogException

from ingest.errors import FileTooLargeError, InputError
from ingest.flightlog import (
    FIXED_WING_MAV_TYPES,
    OPTIONAL_COLUMNS,
    STREAM_COLUMNS,
    FlightLog,
    LogMetadata,
    stream_info,
)
from ingest.frames import quat_to_euler, wrap_angle_deg
from ingest.px4_topics import ALL_TOPICS, RELATIVE_TIMESTAMP_INVALID, STREAM_TOPICS, US_TO_S, TopicSpec
from ingest.sources import source_name

#: GPS fix_type below this has no position (0-1: no fix).
MIN_POSITION_FIX_TYPE = 2

#: Measurement streams whose absence is worth a warning (references and truth are often absent).
SENSOR_STREAMS = ("mag", "baro", "gps", "airspeed")

ULogSource = str | os.PathLike | bytes | bytearray | memoryview | BinaryIO


def read_ulog(source: ULogSource, *, name: str | None = None, max_bytes: int | None = None) -> FlightLog:
    """Read a PX4 ULog file into a :class:`FlightLog`.

    Parameters
    ----------
    source : path, bytes or binary file object
        The ``.ulg`` file or its content.
    name : str, optional
        Name shown in messages and stored as ``meta.source``; default the file's base name (``"<upload>"`` for
        nameless bytes).
    max_bytes : int, optional
        Refuse files larger than this [bytes] with :class:`~ingest.errors.FileTooLargeError`.

    Returns
    -------
    FlightLog
        Canonical streams (SI, NED, body FRD, ``time_s`` index) and metadata with the file's SHA-256.

    Raises
    ------
    InputError
        The file cannot be read, is not a ULog, or has no IMU (``sensor_combined``) data.
    """
    content, name = _read_content(source, name, max_bytes)
    ulog = _parse(content, name)
    return flightlog_from_ulog(ulog, source=name, sha256=hashlib.sha256(content).hexdigest())


def flightlog_from_ulog(ulog: ULog, *, source: str, sha256: str = "") -> FlightLog:
    """Map a parsed pyulog :class:`~pyulog.core.ULog` to a :class:`FlightLog` (the ULog is not modified).

    Parameters
    ----------
    ulog : pyulog.ULog
        Parsed log.
    source : str
        File name for messages and ``meta.source``.
    sha256 : str, optional
        Hex digest of the file content.

    Returns
    -------
    FlightLog

    Raises
    ------
    InputError
        The log has no usable IMU stream.
    """
    warnings: list[str] = []
    streams: dict[str, pd.DataFrame] = {}
    topics: dict[str, str] = {}
    vehicle_type = ulog.initial_parameters.get("MAV_TYPE")
    vehicle_type = None if vehicle_type is None else int(vehicle_type)
    for stream, specs in STREAM_TOPICS.items():
        frame, topic_or_reasons = _first_usable_topic(ulog, specs, warnings)
        if frame is None:
            if stream in SENSOR_STREAMS and (stream != "airspeed" or vehicle_type in FIXED_WING_MAV_TYPES):
                warnings.append(f"no {stream} stream ({topic_or_reasons})")
            continue
        topics[stream] = topic_or_reasons
        fix = _POSTPROCESS.get(stream)
        if fix is not None:
            frame = fix(frame, topics[stream], warnings)
        streams[stream] = frame[[c for c in (*STREAM_COLUMNS[stream], *OPTIONAL_COLUMNS.get(stream, ()))
                                 if c in frame.columns]]
    if "imu" not in streams or len(streams["imu"]) < 2:
        raise InputError("no IMU data: the log needs at least two sensor_combined samples with finite "
                         "gyro_rad and accelerometer_m_s2", source=source, field="sensor_combined")

    imu_time_s = streams["imu"].index.to_numpy()
    warnings.extend(_logging_warnings(ulog))
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
        parameters={key: float(value) for key, value in ulog.initial_parameters.items()},
        streams={stream: stream_info(topics[stream], frame.index.to_numpy())
                 for stream, frame in streams.items()},
        warnings=warnings,
    )
    return FlightLog(streams=streams, meta=meta)


def firmware_version(ulog: ULog) -> str | None:
    """Firmware as ``"v1.14.0"`` (tagged release), ``"v1.15.0 dev (cb09dde6)"`` or the bare git hash."""
    release = ulog.get_version_info_str()
    if release is not None:
        return release
    git_hash = str(ulog.msg_info_dict.get("ver_sw", ""))[:8]
    version = ulog.get_version_info()
    if version is None:
        return git_hash or None
    return f"v{version[0]}.{version[1]}.{version[2]} dev" + (f" ({git_hash})" if git_hash else "")


def _read_content(source: ULogSource, name: str | None, max_bytes: int | None) -> tuple[bytes, str]:
    """The file's bytes and its display name."""
    name = name or source_name(source)
    if isinstance(source, (bytes, bytearray, memoryview)):
        content = bytes(source)
    elif isinstance(source, (str, os.PathLike)):
        path = Path(source)
        try:
            size_bytes = path.stat().st_size
            if max_bytes is not None and size_bytes > max_bytes:
                raise FileTooLargeError(f"file is {size_bytes} bytes, the limit is {max_bytes}", source=name)
            content = path.read_bytes()
        except OSError as exc:
            raise InputError(f"cannot read the file ({exc.strerror or exc})", source=str(path)) from exc
    else:
        content = source.read() if max_bytes is None else source.read(max_bytes + 1)
    if max_bytes is not None and len(content) > max_bytes:
        raise FileTooLargeError(f"file is larger than the limit of {max_bytes} bytes", source=name)
    return content, name


def _parse(content: bytes, name: str) -> ULog:
    """pyulog parse of the topics we use; pyulog's console chatter about corruption is dropped (reported
    through ``file_corruption`` instead)."""
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            return ULog(io.BytesIO(content), message_name_filter_list=list(ALL_TOPICS))
    except (ULogException, struct.error, ValueError, IndexError) as exc:
        raise InputError(f"not a readable PX4 ULog file ({exc})", source=name) from exc


def _first_usable_topic(ulog: ULog, specs: tuple[TopicSpec, ...],
                        warnings: list[str]) -> tuple[pd.DataFrame | None, str]:
    """``(frame, topic label)`` from the first topic of ``specs`` with the required fields and samples, else
    ``(None, why each topic was not used)``."""
    reasons = []
    for spec in specs:
        instances = [d for d in ulog.data_list if d.name == spec.topic]
        if not instances:
            reasons.append(f"{spec.topic}: not in the log")
            continue
        dataset = min(instances, key=lambda d: d.multi_id)
        label = spec.topic if dataset.multi_id == 0 else f"{spec.topic}[{dataset.multi_id}]"
        frame = _topic_frame(dataset.data, spec, label, warnings)
        if isinstance(frame, str):
            reasons.append(f"{label}: {frame}")
        elif len(frame) == 0:
            reasons.append(f"{label}: no valid samples")
        else:
            return frame, label
    return None, "; ".join(reasons)


def _topic_frame(data: dict[str, np.ndarray], spec: TopicSpec, label: str,
                 warnings: list[str]) -> pd.DataFrame | str:
    """Canonical columns of one topic, indexed by strictly increasing ``time_s``; or, when a required field
    is missing, the reason."""
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
        values = raw.astype(np.float64) * scale
        if field.zero_is_missing:
            values[raw == 0] = np.nan
        columns[field.column] = values

    time_us = data["timestamp"].astype(np.int64)
    has_sample = np.ones(len(time_us), dtype=bool)
    if spec.time_relative is not None:
        if spec.time_relative not in data:
            return f"no field {spec.time_relative}"
        relative_us = data[spec.time_relative].astype(np.int64)
        has_sample = relative_us != RELATIVE_TIMESTAMP_INVALID
        time_us = time_us + np.where(has_sample, relative_us, 0)
    rows = _increasing_time_rows(time_us, has_sample, label, warnings,
                                 repeats_expected=spec.time_relative is not None)
    index = pd.Index(time_us[rows] * US_TO_S, name="time_s")
    return pd.DataFrame({column: values[rows] for column, values in columns.items()}, index=index)


def _increasing_time_rows(time_us: np.ndarray, has_sample: np.ndarray, label: str, warnings: list[str], *,
                          repeats_expected: bool) -> np.ndarray:
    """Indices of the rows that give strictly increasing times: rows with time <= 0 are dropped, rows out of
    order are sorted, and of rows with equal times the first logged is kept."""
    candidates = np.flatnonzero(has_sample & (time_us > 0))
    n_nonpositive = int(np.count_nonzero(has_sample)) - len(candidates)
    n_unsorted = int(np.count_nonzero(np.diff(time_us[candidates]) < 0))
    order = candidates[np.argsort(time_us[candidates], kind="stable")]
    keep = np.ones(len(order), dtype=bool)
    keep[1:] = np.diff(time_us[order]) > 0
    n_repeated = int(np.count_nonzero(~keep))
    if n_nonpositive:
        warnings.append(f"{label}: dropped {n_nonpositive} rows with a zero or negative timestamp")
    if n_unsorted:
        warnings.append(f"{label}: {n_unsorted} rows were out of time order and have been sorted")
    if n_repeated and not repeats_expected:
        warnings.append(f"{label}: dropped {n_repeated} rows repeating an earlier timestamp")
    return order[keep]


def _finite_imu(frame: pd.DataFrame, label: str, warnings: list[str]) -> pd.DataFrame:
    """Drop IMU rows with a non-finite gyro or accelerometer value (every filter integrates them)."""
    finite = np.isfinite(frame[list(STREAM_COLUMNS["imu"])].to_numpy()).all(axis=1)
    if not finite.all():
        warnings.append(f"{label}: dropped {int(np.count_nonzero(~finite))} rows with non-finite "
                        "gyro/accel values")
    return frame[finite]


def _gps_without_fix_to_nan(frame: pd.DataFrame, label: str, warnings: list[str]) -> pd.DataFrame:
    """Position and velocity are NaN where the receiver had no fix (PX4 logs zeros there)."""
    no_fix = frame["fix_type"].to_numpy() < MIN_POSITION_FIX_TYPE
    if no_fix.any():
        frame = frame.copy()
        frame.loc[no_fix, ["lat_deg", "lon_deg", "alt_m", "vn_m_s", "ve_m_s", "vd_m_s"]] = np.nan
    return frame


def _with_euler(frame: pd.DataFrame, label: str, warnings: list[str]) -> pd.DataFrame:
    """Add ZYX Euler angles [deg] (yaw in [-180, 180)) from the quaternion columns."""
    roll, pitch, yaw = quat_to_euler(frame[["qw", "qx", "qy", "qz"]].to_numpy())
    return frame.assign(roll_deg=np.degrees(roll), pitch_deg=np.degrees(pitch),
                        yaw_deg=wrap_angle_deg(np.degrees(yaw)))


_POSTPROCESS: dict[str, Callable[[pd.DataFrame, str, list[str]], pd.DataFrame]] = {
    "imu": _finite_imu,
    "gps": _gps_without_fix_to_nan,
    "onboard_attitude": _with_euler,
    "truth_attitude": _with_euler,
}


def _utc_offset_s(gps: pd.DataFrame | None) -> float | None:
    """UTC unix time minus log time [s]: median over GPS rows that carry UTC; None without any."""
    if gps is None:
        return None
    offset_s = gps["time_utc_s"].to_numpy() - gps.index.to_numpy()
    offset_s = offset_s[np.isfinite(offset_s)]
    return float(np.median(offset_s)) if len(offset_s) else None


def _logging_warnings(ulog: ULog) -> list[str]:
    """Corruption and logger dropouts reported by pyulog."""
    notes = []
    if ulog.file_corruption:
        notes.append("the file is corrupt in places; the damaged parts were skipped")
    durations_ms = np.array([d.duration for d in ulog.dropouts], dtype=float)
    if len(durations_ms) and durations_ms.sum() > 0:
        worst = ulog.dropouts[int(np.argmax(durations_ms))]
        notes.append(f"{len(durations_ms)} logger dropouts, {durations_ms.sum():.0f} ms of data lost in "
                     f"total (longest {worst.duration} ms at {worst.timestamp * US_TO_S:.3f} s)")
    return notes
