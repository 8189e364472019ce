"""PX4 ULog -> canonical :class:`~ingest.flightlog.FlightLog`.

:func:`flightlog_from_ulog_content` takes the content of a file that :func:`is_ulog` recognises (the dispatcher
:func:`ingest.log_formats.load_flight_log` hands it over), parses only the topics listed in
:mod:`ingest.px4_topics` with pyulog under the guards of :mod:`ingest.ulog_guard` (bounded time and memory on any
file, docs/robustness.md, 'ULog reader guard'), the data messages gathered by :mod:`ingest.ulog_fast`
(docs/robustness.md, 'Fast data section'), and hands the result to :func:`flightlog_from_ulog`, which maps PX4
names and units to the canonical ones and cleans the time axis. Everything it works around is written to
``FlightLog.meta.warnings``; damage costs only the damaged part (a parameter, a topic, some rows) where it can be
isolated.

Time axis of every topic: PX4 ``timestamp`` [us] cast to int64 before any arithmetic; rows with timestamp 0 or
timed before the log's start are dropped, so are corrupt timestamps far from the rest of the topic or from the
IMU's span (docs/robustness.md, 'Time base checks'); rows out of order are sorted (stable), and of rows with
equal times the first logged is kept, so every stream index is strictly increasing. A topic whose timestamps
are all zero (``ekf2_innovations`` in some PX4 1.6 logs) is skipped.

Multi-instance topics: instance 0 (the primary), or the instance with the most samples when instance 0 was not
logged; the stream's topic then reads ``"sensor_gps[1]"`` (``"[0]"`` when other instances exist).

Each stream's :class:`~ingest.flightlog.StreamInfo` (median rate, gaps) describes the sensor: it is computed on
the sorted sample times (``sample_time_s``) where the topic logs them, since some topics publish two samples at
once and their row spacing alone is bimodal.
"""

from __future__ import annotations

import hashlib
import numbers
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numba import njit
from pyulog import ULog

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
    utc_offset_s,
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
from ingest.threads import in_background
from ingest.ulog_fast import compile_kernels as compile_fast_kernels
from ingest.ulog_fast import read_ulog

#: GPS fix_type below this has no position (0-1: no fix).
MIN_POSITION_FIX_TYPE = 2
#: ``SENS_BARO_QNH`` default [hPa] for logs without the parameter (or with an implausible one: outside the range
#: below, which PX4 also enforces).
DEFAULT_QNH_HPA = 1013.25
QNH_RANGE_HPA = (500.0, 1500.0)
#: The first bytes of every ULog file ("ULog" 0x01 0x12 0x35), before its version byte and start timestamp.
ULOG_MAGIC = ULog.HEADER_BYTES
#: ULog file header: magic bytes, version and the 8-byte start timestamp.
ULOG_HEADER_BYTES = 16
#: A topic's rows split wherever sorted times leave a gap above max(OUTLIER_GAP_MIN_S, OUTLIER_GAP_FACTOR x the
#: median spacing); a group of at most OUTLIER_RUN_ROWS rows (and at most a tenth of the topic) cut off so is a
#: corrupt timestamp. Topics with fewer than OUTLIER_MIN_ROWS rows are not judged.
OUTLIER_GAP_MIN_S = 5.0
OUTLIER_GAP_FACTOR = 100.0
OUTLIER_RUN_ROWS = 4
OUTLIER_MIN_ROWS = 20
#: A gap longer than this [s] splits a topic into parts of which only the largest is kept; and rows of other
#: streams further than this outside the IMU's span are dropped: no logger pauses that long within one log.
TIME_BASE_SPLIT_S = 3600.0
#: A sensor sample time (``timestamp_sample``) further than this from its row time [s] is corrupt (PX4: < 1 s).
MAX_SAMPLE_LAG_S = 60.0


def is_ulog(content: bytes) -> bool:
    """True when ``content`` starts like a ULog file (:data:`ULOG_MAGIC`)."""
    return content.startswith(ULOG_MAGIC)


def flightlog_from_ulog_content(content: bytes, *, source: str) -> FlightLog:
    """Read the content of a PX4 ULog ``.ulg`` file into a :class:`FlightLog`.

    Parameters
    ----------
    content : bytes
        The whole file.
    source : str
        File name for messages and ``meta.source``.

    Returns
    -------
    FlightLog
        Canonical streams (SI, NED, body FRD, ``time_s`` index) and metadata with the SHA-256 of ``content``. A
        truncated or partly corrupt file gives what is readable, with a warning.

    Raises
    ------
    InputError
        The content is not a ULog, is damaged beyond what the reader can skip (docs/robustness.md, 'ULog reader
        guard'), or has no usable IMU (``sensor_combined``) data.
    """
    sha256 = in_background(lambda: hashlib.sha256(content).hexdigest())  # beside the parse (hashlib frees the GIL)
    ulog, notes = read_ulog(content, source, ALL_TOPICS)
    if not ulog.file_corruption:
        end = _message_walk_end(np.frombuffer(content, dtype=np.uint8), ULOG_HEADER_BYTES)
        if end != len(content):
            notes.append(f"the file is truncated: its last message is cut off at byte {len(content)}; "
                         "the complete messages before it were read")
    return flightlog_from_ulog(ulog, source=source, sha256=sha256(), notes=notes)


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
    parameters = _numeric_parameters(ulog.initial_parameters, warnings)
    vehicle_type = _vehicle_type(ulog.initial_parameters, parameters, warnings)
    info = _typed_info(ulog, warnings)
    imu_reason = ""
    for stream, specs in STREAM_TOPICS.items():
        imu = streams.get("imu")
        span_s = None if imu is None or not len(imu) else (float(imu.index[0]), float(imu.index[-1]))
        found = _first_usable_topic(ulog, specs, warnings, span_s)
        if isinstance(found, str):
            if stream == "imu":
                imu_reason = found
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
                         "gyro_rad and accelerometer_m_s2" + "".join(f"; {note}" for note in file_notes)
                         + (f" ({imu_reason})" if imu_reason else ""), source=source, field="sensor_combined")

    imu_time_s = streams["imu"].index.to_numpy()
    meta = LogMetadata(
        source=source,
        sha256=sha256,
        vehicle_type=vehicle_type,
        hardware=info.get("ver_hw"),
        sys_uuid=info.get("sys_uuid"),
        px4_version=firmware_version(ulog, info),
        ver_data_format=info.get("ver_data_format"),
        start_time_s=float(imu_time_s[0]),
        end_time_s=float(imu_time_s[-1]),
        duration_s=float(imu_time_s[-1] - imu_time_s[0]),
        utc_offset_s=utc_offset_s(streams.get("gps")),
        parameters=parameters,
        streams={stream: stream_info(topics[stream], _sample_times_s(frame)) for stream, frame in streams.items()},
        warnings=list(dict.fromkeys(warnings)),  # a topic feeding several streams reports its cleaning once
    )
    return FlightLog(streams=streams, meta=meta)


def firmware_version(ulog: ULog, info: dict | None = None) -> str | None:
    """Firmware as ``"v1.14.0"`` (tagged release), ``"v1.15.0 dev (cb09dde6)"`` or the bare git hash.

    ``info`` is the log's info with checked types (default ``ulog.msg_info_dict``).
    """
    info = ulog.msg_info_dict if info is None else info
    git_hash = str(info.get("ver_sw", ""))[:8]
    if not info.get("ver_sw_release"):
        return git_hash or None
    release = ulog.get_version_info_str()
    if release is not None:
        return release
    major, minor, patch, _ = ulog.get_version_info()
    return f"v{major}.{minor}.{patch} dev" + (f" ({git_hash})" if git_hash else "")


def compile_kernels() -> None:
    """Compile (or load from numba's cache) the reader's numba kernels with the argument types a parse passes
    (the set-up does it once, so that no first read pauses to compile)."""
    _message_walk_end(np.frombuffer(bytes(ULOG_HEADER_BYTES), dtype=np.uint8), ULOG_HEADER_BYTES)
    compile_fast_kernels()


@njit(cache=True)
def _message_walk_end(content: np.ndarray, offset: int) -> int:
    """Offset [bytes] where the chain of ULog messages (3-byte header: uint16 size, uint8 type) starting at
    ``offset`` ends; the file's length exactly when its last message is complete."""
    n_bytes = content.shape[0]
    while offset + 3 <= n_bytes:
        offset += 3 + np.int64(content[offset]) + 256 * np.int64(content[offset + 1])
    return offset


def _numeric_parameters(raw: dict, warnings: list[str]) -> dict[str, float]:
    """The parameters whose value is a finite number, as float; the others are dropped with one warning (a
    damaged parameter message must not cost the whole log)."""
    parameters, bad = {}, []
    for key, value in raw.items():
        number = float(value) if isinstance(value, numbers.Real) else float("nan")
        if np.isfinite(number):
            parameters[key] = number
        else:
            bad.append(str(key))
    if bad:
        warnings.append(f"dropped {len(bad)} parameters whose value is not a finite number (damaged "
                        f"parameter messages): {', '.join(bad[:5])}" + (", ..." if len(bad) > 5 else ""))
    return parameters


def _vehicle_type(raw: dict, parameters: dict[str, float], warnings: list[str]) -> int | None:
    """MAV_TYPE as an int; None without one or when it is not a number."""
    if "MAV_TYPE" in parameters:
        return int(parameters["MAV_TYPE"])
    if "MAV_TYPE" in raw:
        warnings.append(f"MAV_TYPE is not a number ({raw['MAV_TYPE']!r:.40}): vehicle type unknown")
    return None


#: Info fields the reader uses and the types they must have.
_INFO_TYPES: dict[str, tuple[type, ...]] = {"ver_hw": (str,), "ver_sw": (str,), "ver_sw_release": (int,),
                                            "ver_data_format": (int,), "sys_uuid": (str,)}


def _typed_info(ulog: ULog, warnings: list[str]) -> dict:
    """The info fields the reader uses that have their expected type (a damaged info message can carry any
    type); ``ver_sw_release`` must be a uint32."""
    info = {}
    for key, types in _INFO_TYPES.items():
        value = ulog.msg_info_dict.get(key)
        if value is None:
            continue
        ok = isinstance(value, types) and not isinstance(value, bool)
        if ok and key == "ver_sw_release":
            ok = 0 <= value < 2**32
        if ok:
            info[key] = value
        else:
            warnings.append(f"info {key} has an unexpected value ({value!r:.40}); ignored")
    return info


def _first_usable_topic(ulog: ULog, specs: tuple[TopicSpec, ...], warnings: list[str],
                        imu_span_s: tuple[float, float] | None = None) -> tuple[pd.DataFrame, TopicSpec, str] | str:
    """``(frame, spec, topic label)`` from the first topic of ``specs`` with the required fields and samples,
    else why each topic was not used. Rows further than ``TIME_BASE_SPLIT_S`` outside ``imu_span_s`` (first
    and last IMU time [s]) are dropped: the log's time base is the IMU's."""
    reasons = []
    for spec in specs:
        instances = {d.multi_id: d for d in ulog.data_list if d.name == spec.topic}
        if not instances:
            reasons.append(f"{spec.topic}: not in the log")
            continue
        multi_id = 0 if 0 in instances else max(instances, key=lambda i: len(instances[i].data.get("timestamp", ())))
        label = spec.topic if len(instances) == 1 and multi_id == 0 else f"{spec.topic}[{multi_id}]"
        if multi_id != 0:
            warnings.append(f"{spec.topic}: instance 0 has no data; using instance {multi_id} (most samples)")
        frame = _topic_frame(instances[multi_id].data, spec, label, ulog.start_timestamp, warnings, imu_span_s)
        if isinstance(frame, str):
            reasons.append(f"{label}: {frame}")
        elif len(frame) == 0:
            reasons.append(f"{label}: no valid samples")
        else:
            return frame, spec, label
    return "; ".join(reasons)


def _topic_frame(data: dict[str, np.ndarray], spec: TopicSpec, label: str, start_us: int,
                 warnings: list[str], imu_span_s: tuple[float, float] | None = None) -> pd.DataFrame | str:
    """Canonical columns of one topic, indexed by strictly increasing ``time_s``; or, when a required field
    is missing, no timestamp is set or the timestamps are hopeless, the reason. ``imu_span_s``: first and
    last IMU time [s], which bound the other topics' times."""
    if "timestamp" not in data:  # only a damaged format lacks it
        warnings.append(f"{label}: no timestamp field; topic skipped")
        return "no timestamp field"
    sources: dict[str, tuple | None] = {}  # column -> (raw field, scale, zero is missing); None: all NaN
    for field in spec.fields:
        raw_and_scale = next(((data[px4], scale) for px4, scale, kinds in field.sources
                              if px4 in data and (not kinds or data[px4].dtype.kind in kinds)), None)
        if raw_and_scale is None:
            if field.required:
                return f"no field {' or '.join(dict.fromkeys(px4 for px4, _, _ in field.sources))}"
            if field.nan_if_missing:
                sources[field.column] = None
            continue
        sources[field.column] = (*raw_and_scale, field.zero_is_missing)

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
    span_us = None if imu_span_s is None else (round(imu_span_s[0] / US_TO_S), round(imu_span_s[1] / US_TO_S))
    rows = _increasing_time_rows(time_us, has_sample, start_us, label, warnings,
                                 repeats_expected=spec.time_relative is not None, span_us=span_us)
    if isinstance(rows, str):
        warnings.append(f"{label}: {rows}; topic skipped")
        return rows
    every_row = len(rows) == len(time_us) and bool(np.all(np.diff(rows) > 0))  # the rows as logged
    # One float64 block, column after column, that the DataFrame takes without a copy (no per-column arrays
    # stacked by pandas, no second gather of the kept rows).
    block = np.empty((len(sources), len(rows)))
    for out, source in zip(block, sources.values(), strict=True):
        if source is None:
            out.fill(np.nan)
            continue
        field_values, scale, zero_is_missing = source
        raw = field_values if every_row else field_values[rows]
        np.multiply(raw, scale(raw) if callable(scale) else scale, out=out, dtype=np.float64)
        if zero_is_missing:
            out[raw == 0] = np.nan
    index = pd.Index((time_us if every_row else time_us[rows]) * US_TO_S, name="time_s")
    frame = pd.DataFrame(block.T, index=index, columns=list(sources), copy=False)
    if "sample_time_s" in frame.columns:
        _drop_implausible_sample_times(frame, label, warnings)
    return frame


def _drop_implausible_sample_times(frame: pd.DataFrame, label: str, warnings: list[str]) -> None:
    """Set to NaN (in place) the sensor sample times further than ``MAX_SAMPLE_LAG_S`` from their row time."""
    sample_time_s = frame["sample_time_s"].to_numpy()
    far = np.abs(sample_time_s - frame.index.to_numpy()) > MAX_SAMPLE_LAG_S
    if far.any():
        warnings.append(f"{label}: {int(np.count_nonzero(far))} timestamp_sample values more than "
                        f"{MAX_SAMPLE_LAG_S:.0f} s from their row time (corrupt) set to NaN")
        frame.loc[far, "sample_time_s"] = np.nan


def _increasing_time_rows(time_us: np.ndarray, has_sample: np.ndarray, start_us: int, label: str,
                          warnings: list[str], *, repeats_expected: bool,
                          span_us: tuple[int, int] | None = None) -> np.ndarray | str:
    """Indices of the rows that give strictly increasing times: rows with time 0 or before the log start
    ``start_us`` are dropped, so are rows more than ``TIME_BASE_SPLIT_S`` outside ``span_us`` (the IMU's first
    and last time [us]) and rows whose time jumps far from the rest (:func:`_time_outliers`); rows out of
    order are sorted, and of rows with equal times the first logged is kept. A topic without a consistent time
    base gives the reason instead."""
    is_zero = has_sample & (time_us == 0)
    is_early = has_sample & ~is_zero & (time_us < start_us)
    is_outside = np.zeros(len(time_us), dtype=bool)
    if span_us is not None:
        margin_us = round(TIME_BASE_SPLIT_S / US_TO_S)
        is_outside = (has_sample & ~is_zero & ~is_early
                      & ((time_us < span_us[0] - margin_us) | (time_us > span_us[1] + margin_us)))
        if is_outside.any():
            warnings.append(f"{label}: dropped {int(np.count_nonzero(is_outside))} rows timed more than "
                            f"{TIME_BASE_SPLIT_S:.0f} s outside the IMU's span (corrupt timestamps)")
    candidates = np.flatnonzero(has_sample & ~is_zero & ~is_early & ~is_outside)
    outliers = _time_outliers(time_us[candidates])
    if isinstance(outliers, str):
        return outliers
    if outliers.any():
        kept = time_us[candidates[~outliers]]
        jump_s = np.abs(time_us[candidates[outliers]] - np.clip(time_us[candidates[outliers]], kept.min(),
                                                                kept.max())).max() * US_TO_S
        warnings.append(f"{label}: dropped {int(np.count_nonzero(outliers))} rows whose timestamps jump up to "
                        f"{jump_s:.3g} s away from the rest of the topic (corrupt timestamps)")
        candidates = candidates[~outliers]
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


def _time_outliers(time_us: np.ndarray) -> np.ndarray | str:
    """Mask of the rows of one topic (``time_us`` [us] in logged order) whose time is corrupt, or why the topic
    has no consistent time base.

    On the sorted times, a group of at most ``OUTLIER_RUN_ROWS`` rows (and a tenth of the topic) cut off by
    gaps above max(``OUTLIER_GAP_MIN_S``, ``OUTLIER_GAP_FACTOR`` x the median spacing) is an outlier (a single
    corrupt timestamp lands alone, far from its neighbours); then gaps above ``TIME_BASE_SPLIT_S`` split the
    rest into parts of which the largest is kept, and a largest part with under half the rows is hopeless.
    A logger pause shifts every later row alike and leaves large groups on both sides, so it is kept.
    """
    n = len(time_us)
    outliers = np.zeros(n, dtype=bool)
    if n < OUTLIER_MIN_ROWS:
        return outliers
    gaps_us = np.diff(time_us)
    order = None if (gaps_us >= 0).all() else np.argsort(time_us, kind="stable")
    sorted_us = time_us if order is None else time_us[order]
    if order is not None:
        gaps_us = np.diff(sorted_us)
    limit_us = max(OUTLIER_GAP_MIN_S / US_TO_S, OUTLIER_GAP_FACTOR * float(np.median(gaps_us)))
    if gaps_us.max() <= min(limit_us, TIME_BASE_SPLIT_S / US_TO_S):  # the common case: nothing far away
        return outliers
    group = np.concatenate(([0], np.cumsum(gaps_us > limit_us)))
    size = np.bincount(group)[group]
    bad = (size <= OUTLIER_RUN_ROWS) & (10 * size <= n)
    rest_us = sorted_us[~bad]
    part = np.concatenate(([0], np.cumsum(np.diff(rest_us) > TIME_BASE_SPLIT_S / US_TO_S)))
    part_size = np.bincount(part)
    largest = int(np.argmax(part_size))
    if 2 * part_size[largest] < n:
        span_s = float(sorted_us[-1] - sorted_us[0]) * US_TO_S
        return (f"no consistent time base: its timestamps scatter over {span_s:.3g} s, the largest consistent "
                f"part holding {int(part_size[largest])} of {n} rows")
    bad[np.flatnonzero(~bad)[part != largest]] = True
    if order is None:
        return bad
    outliers[order] = bad
    return outliers


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
    qnh_hpa = ctx.parameters.get("SENS_BARO_QNH", DEFAULT_QNH_HPA)
    if not QNH_RANGE_HPA[0] <= qnh_hpa <= QNH_RANGE_HPA[1]:
        ctx.warnings.append(f"SENS_BARO_QNH {qnh_hpa:g} hPa is implausible; {DEFAULT_QNH_HPA} hPa used")
        qnh_hpa = DEFAULT_QNH_HPA
    qnh_pa = 100.0 * qnh_hpa
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
