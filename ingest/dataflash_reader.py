"""ArduPilot DataFlash ``.bin`` -> canonical :class:`~ingest.flightlog.FlightLog` (docs/ingest.md, 'DataFlash').

:func:`ingest.log_formats.load_flight_log` hands a file that :func:`is_dataflash` recognises (it starts with the
DataFlash record header ``0xA3 0x95``) to :func:`flightlog_from_dataflash`. The records are found in one pass
and the wanted message types decoded with numpy (:mod:`ingest.dataflash_format`); no Python object is made per
message.

Mapping (ArduPilot ``libraries/AP_Logger/LogStructure.h`` units; ArduPilot's body frame is FRD and its earth
frame NED, as the canonical ones):

* ``imu`` from ``IMU`` (GyrX/Y/Z rad/s, AccX/Y/Z m/s^2), ``mag`` from ``MAG`` (mGauss -> gauss), ``baro`` from
  ``BARO`` (Press, Temp; ``Alt`` is relative to the ground calibration, so ``alt_m`` is the ISA pressure altitude
  of Press at 1013.25 hPa), ``gps`` from ``GPS`` + ``GPA`` (velocity north/east from Spd and GCrs, down from VZ;
  HAcc/VAcc/SAcc accuracies; UTC from GWk/GMS), ``airspeed`` from ``ARSP`` (Airspeed, DiffPress; an all-zero
  stream is an unfitted or uncalibrated sensor and is left out with a warning).
* Multi-instance sensors: instance 0, from the instance field ``I`` (ArduPilot >= 4.2) or the unnumbered
  message (``IMU``, not ``IMU2``/``IMU3``, before); the stream's topic then reads ``"IMU[0]"``.
* ``onboard_*`` from EKF3 (``XKF1`` attitude, velocity, position; ``XKF2`` wind; core 0, field ``C`` from 4.1
  on), else EKF2 (``NKF1``/``NKF2``), else ``ATT`` for the attitude; ``onboard_global_position`` from ``POS``.
* ``truth_*`` of SITL and simulator logs: ``SIM`` (Q1..Q4, Lat/Lng/Alt), ``SIM2`` (PN..VD) and solarnav's own
  ``SWND`` (true wind, which ArduPilot does not log; :mod:`sim.dataflash_writer`).
* Parameters: the first ``PARM`` value of each name (the values at the start of the log). Firmware, board and
  vehicle type from the ``MSG`` strings (``"ArduPlane V4.0.8 (ac9a4b9a)"``) and the frame parameters.

Time: ``TimeUS`` [us] (int64) / 1e6 on the log clock; rows with TimeUS 0 are dropped, rows out of order sorted
(stable), of rows with equal times the first kept.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Callable

import numpy as np
import pandas as pd

from ingest import dataflash_format as df
from ingest.atmosphere import (
    ISA_SEA_LEVEL_DENSITY_KG_M3,
    ISA_SEA_LEVEL_PRESSURE_PA,
    isa_density_kg_m3,
    pressure_altitude_m,
)
from ingest.errors import InputError
from ingest.flightlog import OPTIONAL_COLUMNS, STREAM_COLUMNS, FlightLog, LogMetadata, stream_info, utc_offset_s
from ingest.frames import euler_to_quat, quat_to_euler, wrap_angle_deg
from ingest.px4_topics import SENSOR_STREAMS
from ingest.threads import in_background

#: The first bytes of every DataFlash log (the header of its first record).
DATAFLASH_MAGIC = bytes((df.HEAD_1, df.HEAD_2))
US_TO_S = 1e-6
MGAUSS_TO_GAUSS = 1e-3
#: GPS time: unix time of the GPS epoch (1980-01-06) [s], seconds per week, and GPS - UTC leap seconds from the
#: date they took effect (unix time [s]); ArduPilot's own conversion uses the latest (18 s).
GPS_EPOCH_UNIX_S = 315964800.0
WEEK_S = 604800.0
LEAP_SECONDS = ((1341100800.0, 16.0), (1435708800.0, 17.0), (1483228800.0, 18.0))
#: GPS Status below this has no position (0 no GPS, 1 no fix; 2 2D, 3 3D, 4 DGPS, 5/6 RTK as PX4's fix_type).
MIN_POSITION_FIX_TYPE = 2
#: Rows of one message more than this apart [s] belong to different time bases: no logger pauses that long.
TIME_BASE_SPLIT_S = 3600.0
#: A GPA sample time (SMS [ms]) further than this from its GPS row time [s] is not a sample time.
MAX_SAMPLE_LAG_S = 60.0

#: MAV_TYPE by firmware (``MSG`` "ArduPlane V4.0.8 (...)"); Copter by FRAME_CLASS (ArduCopter
#: ``get_frame_mav_type``), Plane with Q_ENABLE a VTOL (QuadPlane ``get_mav_type``).
FIRMWARE_MAV_TYPES = {"ArduPlane": 1, "ArduCopter": 2, "ArduRover": 10, "ArduSub": 12, "Blimp": 7,
                      "AntennaTracker": 5}
COPTER_FRAME_MAV_TYPES = {1: 2, 2: 13, 3: 14, 4: 14, 5: 13, 6: 4, 7: 15, 11: 4, 12: 29, 13: 4, 14: 35}
VTOL_QUADROTOR, VTOL_TILTROTOR, VTOL_DUOROTOR = 20, 21, 19
_FIRMWARE = re.compile(r"^(?:APM:)?(Ardu\w+|Blimp|AntennaTracker|Plane|Copter|Rover|Sub)\b\s*(.*)$")
_BOARD = re.compile(r"^(\S+)(?: [0-9A-Fa-f]{8}){3}$")


def is_dataflash(content: bytes) -> bool:
    """True when ``content`` starts like a DataFlash log (the record header ``0xA3 0x95``)."""
    return content[:2] == DATAFLASH_MAGIC


def flightlog_from_dataflash(content: bytes, *, source: str) -> FlightLog:
    """Read the content of a DataFlash ``.bin`` file into a :class:`FlightLog`.

    Parameters
    ----------
    content : bytes
        The whole file.
    source : str
        File name for messages and ``meta.source``.

    Returns
    -------
    FlightLog
        Canonical streams and metadata (SHA-256 of ``content``); a truncated or partly garbled file gives its
        readable records, with a warning.

    Raises
    ------
    InputError
        The content is not a DataFlash log, has no valid ``FMT`` records, or has no usable ``IMU`` data.
    """
    if not is_dataflash(content):
        raise InputError("not an ArduPilot DataFlash log (it does not start with the bytes 0xA3 0x95)",
                         source=source)
    sha256 = in_background(lambda: hashlib.sha256(content).hexdigest())  # beside the parse (hashlib frees the GIL)
    data = np.frombuffer(content, dtype=np.uint8)
    index = df.walk_records(data)
    formats, rejected = df.read_formats(data, index)
    if not formats:
        raise InputError("no valid FMT records: not a DataFlash log, or its message definitions are damaged"
                         + "".join(f"; {reason}" for reason in rejected[:3]), source=source, field="FMT")
    log = _Records(data, index, {fmt.name: fmt for fmt in formats.values()})
    warnings = _file_warnings(index, len(content), rejected)
    parameters = _parameters(log, warnings)
    messages = _messages(log)
    streams: dict[str, pd.DataFrame] = {}
    topics: dict[str, str] = {}
    for stream, build in _STREAMS.items():
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):  # damaged values are NaN/inf, no noise
            found = build(log, _Context(warnings, parameters, streams))
        if isinstance(found, str):
            if stream in SENSOR_STREAMS:
                warnings.append(f"{SENSOR_STREAMS[stream]}: {found}")
            elif stream == "imu":
                raise InputError(f"no IMU data: {found}" + "".join(f"; {w}" for w in warnings[:3]),
                                 source=source, field="IMU")
            continue
        frame, topics[stream] = found
        optional = [c for c in OPTIONAL_COLUMNS.get(stream, ()) if c in frame.columns]
        streams[stream] = frame[[*STREAM_COLUMNS[stream], *optional]]
    if len(streams["imu"]) < 2:
        raise InputError("no IMU data: fewer than two IMU records with finite values", source=source, field="IMU")

    firmware, vehicle, board = _firmware(messages)
    imu_time_s = streams["imu"].index.to_numpy()
    meta = LogMetadata(
        source=source,
        sha256=sha256(),
        vehicle_type=_vehicle_type(vehicle, parameters, warnings),
        hardware=board,
        px4_version=firmware,
        start_time_s=float(imu_time_s[0]),
        end_time_s=float(imu_time_s[-1]),
        duration_s=float(imu_time_s[-1] - imu_time_s[0]),
        utc_offset_s=utc_offset_s(streams.get("gps")),
        parameters=parameters,
        streams={name: stream_info(topics[name], frame.index.to_numpy()) for name, frame in streams.items()},
        warnings=list(dict.fromkeys(warnings)),
    )
    return FlightLog(streams=streams, meta=meta)


class _Records:
    """The decoded records of a file, by message name (decoded once, on first use)."""

    def __init__(self, data: np.ndarray, index: df.RecordIndex, formats: dict[str, df.MessageFormat]):
        self.data, self.index, self.formats = data, index, formats
        self._cache: dict[str, np.ndarray] = {}

    def records(self, name: str) -> np.ndarray | None:
        """Every record of message ``name`` (stored values), or None when the file defines no such type."""
        fmt = self.formats.get(name)
        if fmt is None:
            return None
        if name not in self._cache:
            self._cache[name] = df.decode(self.data, self.index, fmt)
        return self._cache[name]

    def count(self, name: str) -> int:
        """Number of records of message ``name`` (0 when the file defines no such type), without decoding them."""
        fmt = self.formats.get(name)
        return 0 if fmt is None else int(np.count_nonzero(self.index.type_ids == fmt.type_id))


class _Context:
    """What a stream builder may need: the warnings list, the parameters and the streams built before it."""

    def __init__(self, warnings: list[str], parameters: dict[str, float], streams: dict[str, pd.DataFrame]):
        self.warnings, self.parameters, self.streams = warnings, parameters, streams


def _file_warnings(index: df.RecordIndex, n_bytes: int, rejected: list[str]) -> list[str]:
    """Findings about the file itself: a cut-off last record, skipped garbage, rejected definitions."""
    notes = []
    if index.end_offset < n_bytes:
        notes.append(f"the file is truncated: its last record is cut off at byte {index.end_offset} of {n_bytes}; "
                     "the complete records before it were read")
    if index.skipped_bytes:
        notes.append(f"skipped {index.skipped_bytes} bytes in {index.skipped_stretches} stretches that are not "
                     "records of a defined message type (garbage or unknown format ids)")
    notes += [f"{reason}; its records are ignored" for reason in rejected]
    return notes


def _parameters(log: _Records, warnings: list[str]) -> dict[str, float]:
    """The first value of every ``PARM`` name (the values at the start of the log); non-finite values dropped."""
    records = log.records("PARM")
    if records is None or not _typed(log.formats["PARM"], text=("Name",), numbers=("Value",)):
        return {}
    fmt = log.formats["PARM"]
    parameters: dict[str, float] = {}
    bad = []
    for name, value in zip(df.text_column(records, "Name"), df.scaled(records, fmt, "Value"), strict=True):
        if not np.isfinite(value):
            bad.append(name)
        elif name and name not in parameters:
            parameters[name] = float(value)
    if bad:
        warnings.append(f"dropped {len(bad)} PARM records whose value is not a finite number: "
                        f"{', '.join(bad[:5])}" + (", ..." if len(bad) > 5 else ""))
    return parameters


def _messages(log: _Records) -> list[str]:
    records = log.records("MSG")
    return [] if records is None or not _typed(log.formats["MSG"], text=("Message",)) else \
        df.text_column(records, "Message")


def _typed(fmt: df.MessageFormat, *, text: tuple[str, ...] = (), numbers: tuple[str, ...] = ()) -> bool:
    """True when ``fmt`` has the ``text`` fields as strings (n/N/Z) and the ``numbers`` fields as scalars."""
    codes = dict(zip(fmt.columns, fmt.format, strict=True))
    return (all(codes.get(field, "") in ("n", "N", "Z") for field in text)
            and all(codes.get(field, "n") not in "nNZa" for field in numbers))


def _firmware(messages: list[str]) -> tuple[str | None, str | None, str | None]:
    """(firmware string, vehicle firmware name, board) from the ``MSG`` lines the autopilot writes at start."""
    firmware = vehicle = board = None
    for text in messages:
        match = _FIRMWARE.match(text)
        if match and firmware is None:
            firmware, vehicle = text, match.group(1)
        board_match = _BOARD.match(text)
        if board_match and board is None:
            board = board_match.group(1)
    if vehicle is not None and not vehicle.startswith("Ardu") and vehicle not in FIRMWARE_MAV_TYPES:
        vehicle = f"Ardu{vehicle}"  # "APM:Plane" of old firmware
    return firmware, vehicle, board


def _vehicle_type(vehicle: str | None, parameters: dict[str, float], warnings: list[str]) -> int | None:
    """MAVLink MAV_TYPE from the firmware name and the frame parameters; None when the log names no firmware."""
    if vehicle is None or vehicle not in FIRMWARE_MAV_TYPES:
        warnings.append("no firmware string (MSG 'ArduPlane V...') in the log: vehicle type unknown"
                        if vehicle is None else f"firmware {vehicle} is not a known vehicle: vehicle type unknown")
        return None
    if vehicle == "ArduCopter":
        frame_class = int(parameters.get("FRAME_CLASS", 1))
        return COPTER_FRAME_MAV_TYPES.get(frame_class, FIRMWARE_MAV_TYPES[vehicle])
    if vehicle == "ArduPlane" and parameters.get("Q_ENABLE", 0) > 0:
        if parameters.get("Q_TAILSIT_ENABLE", 0) > 0:
            return VTOL_DUOROTOR
        return VTOL_TILTROTOR if parameters.get("Q_TILT_ENABLE", 0) > 0 else VTOL_QUADROTOR
    return FIRMWARE_MAV_TYPES[vehicle]


#: Messages of instances 1 and 2 before ArduPilot 4.2 where they are not ``<name>2``/``<name>3`` (SIM2 is
#: another message, not a second SIM).
_OLD_INSTANCE_NAMES = {"BARO": ("BAR2", "BAR3"), "ARSP": ("ASP2",), "SIM": ()}


def _instance(log: _Records, name: str, instance_field: str) -> tuple[np.ndarray, df.MessageFormat, str] | str:
    """Records of instance 0 of message ``name`` (the lowest instance logged when 0 is not), with the label
    (``"IMU"``, or ``"IMU[0]"`` when other instances exist), or why there are none."""
    records = log.records(name)
    if records is None:
        return f"{name}: not in the log"
    if not len(records):
        return f"{name}: no records"
    fmt = log.formats[name]
    others = any(log.count(other) for other in _OLD_INSTANCE_NAMES.get(name, (f"{name}2", f"{name}3")))
    if instance_field in fmt.columns:
        instances = records[instance_field]
        first = int(instances.min())
        others = others or bool((instances != first).any())
        records = records[instances == first]
    else:
        first = 0
    return records, fmt, f"{name}[{first}]" if others or first else name


def _frame(found: tuple[np.ndarray, df.MessageFormat, str], columns: dict[str, tuple[str, float]],
           warnings: list[str]) -> tuple[pd.DataFrame, str] | str:
    """Columns ``{canonical: (field, factor)}`` of the records (DataFlash scale times ``factor``), indexed by
    strictly increasing ``time_s``; or the reason a field or the time is missing."""
    records, fmt, label = found
    wanted = ["TimeUS", *(field for field, _ in columns.values())]
    missing = [field for field in wanted if field not in fmt.columns]
    if missing:
        return f"{label}: no field {', '.join(missing)}"
    not_numbers = [field for field in wanted if not _typed(fmt, numbers=(field,))]
    if not_numbers:
        return f"{label}: fields {', '.join(not_numbers)} are not numbers in its FMT ({fmt.format!r})"
    rows = _time_rows(records["TimeUS"].astype(np.int64), label, warnings)
    if isinstance(rows, str):
        return f"{label}: {rows}"
    if len(rows) < len(records):  # (a copy of every field otherwise)
        records = records[rows]
    index = pd.Index(records["TimeUS"].astype(np.int64) * US_TO_S, name="time_s")
    return pd.DataFrame({column: df.scaled(records, fmt, field) * factor
                         for column, (field, factor) in columns.items()}, index=index), label


def _time_rows(time_us: np.ndarray, label: str, warnings: list[str]) -> np.ndarray | str:
    """Indices of the rows giving strictly increasing times: TimeUS 0 (or past int64) dropped, rows sorted, of
    rows more than ``TIME_BASE_SPLIT_S`` apart only the largest group kept (a corrupt TimeUS lands alone, far
    away, and would stretch the log), of equal times the first kept."""
    candidates = np.flatnonzero(time_us > 0)
    if not len(candidates):
        return "every TimeUS is zero"
    if len(candidates) < len(time_us):
        warnings.append(f"{label}: dropped {len(time_us) - len(candidates)} rows with TimeUS 0 (or past int64)")
    n_unsorted = int(np.count_nonzero(np.diff(time_us[candidates]) < 0))
    if n_unsorted:
        candidates = candidates[np.argsort(time_us[candidates], kind="stable")]
        warnings.append(f"{label}: {n_unsorted} rows were out of time order and have been sorted")
    part = np.concatenate(([0], np.cumsum(np.diff(time_us[candidates]) > TIME_BASE_SPLIT_S / US_TO_S)))
    if part[-1]:
        largest = part == np.argmax(np.bincount(part))
        warnings.append(f"{label}: dropped {int(np.count_nonzero(~largest))} rows timed more than "
                        f"{TIME_BASE_SPLIT_S:.0f} s away from the rest (corrupt TimeUS)")
        candidates = candidates[largest]
    keep = np.ones(len(candidates), dtype=bool)
    keep[1:] = np.diff(time_us[candidates]) > 0
    if not keep.all():
        warnings.append(f"{label}: dropped {int(np.count_nonzero(~keep))} rows repeating an earlier TimeUS")
    return candidates[keep]


def _with(frame: pd.DataFrame, **columns) -> pd.DataFrame:
    """``frame`` with ``columns`` added or replaced, built in one go (``DataFrame.assign`` inserts them one by
    one, the reader's largest fixed cost)."""
    data = {column: frame[column].to_numpy() for column in frame.columns} | {
        column: np.asarray(values) for column, values in columns.items()}
    return pd.DataFrame(data, index=frame.index)


def _first(*attempts: Callable[[], tuple[pd.DataFrame, str] | str]) -> tuple[pd.DataFrame, str] | str:
    """The first attempt that gives a non-empty frame, else every attempt's reason."""
    reasons = []
    for attempt in attempts:
        found = attempt()
        if isinstance(found, str):
            reasons.append(found)
        elif not len(found[0]):
            reasons.append(f"{found[1]}: no valid records")
        else:
            return found
    return "; ".join(reasons)


def _sensor(log: _Records, ctx: _Context, name: str, columns: dict[str, tuple[str, float]],
            instance_field: str = "I") -> tuple[pd.DataFrame, str] | str:
    found = _instance(log, name, instance_field)
    return found if isinstance(found, str) else _frame(found, columns, ctx.warnings)


_XYZ = ("x", "y", "z")


def _imu(log: _Records, ctx: _Context):
    columns = {f"gyro_{a}_rad_s": (f"Gyr{a.upper()}", 1.0) for a in _XYZ}
    columns |= {f"accel_{a}_m_s2": (f"Acc{a.upper()}", 1.0) for a in _XYZ}
    found = _sensor(log, ctx, "IMU", columns)
    if isinstance(found, str):
        return found
    frame, label = found
    finite = np.isfinite(frame.to_numpy()).all(axis=1)
    if not finite.all():
        ctx.warnings.append(f"{label}: dropped {int(np.count_nonzero(~finite))} rows with non-finite gyro/accel "
                            "values")
    return frame[finite], label


def _mag(log: _Records, ctx: _Context):
    return _first(lambda: _sensor(log, ctx, "MAG", {f"mag_{a}_gauss": (f"Mag{a.upper()}", MGAUSS_TO_GAUSS)
                                                    for a in _XYZ}))


def _baro(log: _Records, ctx: _Context):
    found = _first(lambda: _sensor(log, ctx, "BARO", {"pressure_pa": ("Press", 1.0), "temp_c": ("Temp", 1.0)}))
    if isinstance(found, str):
        return found
    frame, label = found
    return _with(frame, alt_m=pressure_altitude_m(frame["pressure_pa"].to_numpy(), ISA_SEA_LEVEL_PRESSURE_PA)), label


def _gps(log: _Records, ctx: _Context):
    """GPS with the GPA accuracies of the same TimeUS; NaN position and velocity without a fix."""
    found = _first(lambda: _sensor(log, ctx, "GPS", {
        "lat_deg": ("Lat", 1.0), "lon_deg": ("Lng", 1.0), "alt_m": ("Alt", 1.0), "speed_m_s": ("Spd", 1.0),
        "course_deg": ("GCrs", 1.0), "vd_m_s": ("VZ", 1.0), "fix_type": ("Status", 1.0), "week": ("GWk", 1.0),
        "week_ms": ("GMS", 1.0), "satellites_used": ("NSats", 1.0)}))
    if isinstance(found, str):
        return found
    frame, label = found
    course_rad = np.radians(frame["course_deg"].to_numpy())
    gps_s = GPS_EPOCH_UNIX_S + frame["week"].to_numpy() * WEEK_S + frame["week_ms"].to_numpy() * 1e-3
    utc_s = np.where(frame["week"].to_numpy() > 0, gps_s - leap_seconds(gps_s), np.nan)
    frame = _with(frame, vn_m_s=frame["speed_m_s"] * np.cos(course_rad), ve_m_s=frame["speed_m_s"] * np.sin(course_rad),
                         time_utc_s=utc_s)
    frame = frame.join(_gpa(log, ctx, frame.index))
    no_fix = frame["fix_type"].to_numpy() < MIN_POSITION_FIX_TYPE
    if no_fix.any():
        frame.loc[no_fix, ["lat_deg", "lon_deg", "alt_m", "vn_m_s", "ve_m_s", "vd_m_s"]] = np.nan
    return frame, label + ("+GPA" if np.isfinite(frame["eph_m"]).any() else "")


def _gpa(log: _Records, ctx: _Context, gps_index: pd.Index) -> pd.DataFrame:
    """GPA accuracies and sample time at the GPS row times (ArduPilot writes both with one TimeUS); NaN where
    no GPA record matches."""
    columns = {"eph_m": ("HAcc", 1.0), "epv_m": ("VAcc", 1.0), "speed_accuracy_m_s": ("SAcc", 1.0),
               "sample_time_s": ("SMS", 1e-3)}
    found = _sensor(log, ctx, "GPA", columns)
    empty = pd.DataFrame({column: np.full(len(gps_index), np.nan) for column in columns}, index=gps_index)
    if isinstance(found, str):
        ctx.warnings.append(f"gps: no accuracies ({found}); eph/epv are NaN")
        return empty
    gpa = found[0].reindex(gps_index)
    far = np.abs(gpa["sample_time_s"].to_numpy() - gps_index.to_numpy()) > MAX_SAMPLE_LAG_S
    if far.any():
        gpa.loc[far, "sample_time_s"] = np.nan
    if gpa["sample_time_s"].isna().any():  # one unmatched row would mix two time bases: use the row times
        gpa = gpa.drop(columns="sample_time_s")
    return gpa


def leap_seconds(time_s: np.ndarray) -> np.ndarray:
    """GPS - UTC [s] at GPS or UTC unix times ``time_s`` [s] (the two differ by under 20 s; no log straddles a
    leap second closely enough for the difference to matter)."""
    starts = np.array([start for start, _ in LEAP_SECONDS])
    values = np.array([0.0, *(value for _, value in LEAP_SECONDS)])
    return values[np.searchsorted(starts, time_s, side="right")]


def _airspeed(log: _Records, ctx: _Context):
    """IAS from ARSP Airspeed, TAS with the ISA density at the barometer's pressure; an all-zero ARSP (no sensor
    fitted, or one never calibrated) is no airspeed."""
    found = _first(lambda: _sensor(log, ctx, "ARSP", {"ias_m_s": ("Airspeed", 1.0),
                                                      "differential_pressure_pa": ("DiffPress", 1.0)}))
    if isinstance(found, str):
        return found
    frame, label = found
    if not frame.to_numpy().any():
        arspd_type = ctx.parameters.get("ARSPD_TYPE")
        return (f"{label}: every Airspeed and DiffPress is zero (no sensor fitted or never calibrated"
                + (f"; ARSPD_TYPE {arspd_type:g}" if arspd_type is not None else "") + "); stream left out")
    baro = ctx.streams.get("baro")
    if baro is None:
        density_kg_m3 = np.full(len(frame), ISA_SEA_LEVEL_DENSITY_KG_M3)
        ctx.warnings.append(f"airspeed from {label}: no barometer, so TAS = IAS (sea-level density)")
    else:
        density_kg_m3 = isa_density_kg_m3(np.interp(frame.index.to_numpy(), baro.index.to_numpy(),
                                                    baro["pressure_pa"].to_numpy()))
    return _with(frame, tas_m_s=frame["ias_m_s"] * np.sqrt(ISA_SEA_LEVEL_DENSITY_KG_M3 / density_kg_m3)), label


def _ekf_messages(log: _Records) -> tuple[str, str] | None:
    """(state message, wind message) of the onboard reference: EKF3 (XKF1/XKF2), else EKF2 (NKF1/NKF2)."""
    for state, wind in (("XKF1", "XKF2"), ("NKF1", "NKF2")):
        records = log.records(state)
        if records is not None and len(records):
            return state, wind
    return None


def _attitude(log: _Records, ctx: _Context):
    ekf = _ekf_messages(log)
    angles = {"roll_deg": ("Roll", 1.0), "pitch_deg": ("Pitch", 1.0), "yaw_deg": ("Yaw", 1.0)}
    attempts = [] if ekf is None else [lambda: _sensor(log, ctx, ekf[0], angles, "C")]
    found = _first(*attempts, lambda: _sensor(log, ctx, "ATT", angles))
    if isinstance(found, str):
        return found
    frame, label = found
    # EKF2/EKF3 and DCM log their Euler angles minus the AHRS trim (the vehicle frame), the IMU the board frame:
    # adding the trim back gives the filter's own attitude of the frame the IMU and the estimators work in.
    trim_deg = {column: np.degrees(ctx.parameters.get(name, 0.0))
                for column, name in (("roll_deg", "AHRS_TRIM_X"), ("pitch_deg", "AHRS_TRIM_Y"))}
    if any(trim_deg.values()):
        frame = _with(frame, **{column: frame[column].to_numpy() + trim for column, trim in trim_deg.items()})
        ctx.warnings.append(f"onboard_attitude from {label}: AHRS_TRIM_X/Y ({trim_deg['roll_deg']:.3g}, "
                            f"{trim_deg['pitch_deg']:.3g} deg) added back to Roll/Pitch: ArduPilot logs the "
                            "vehicle-frame attitude, the IMU the autopilot board's frame")
    q = euler_to_quat(*(np.radians(frame[c].to_numpy()) for c in angles))
    return _with(frame, qw=q[:, 0], qx=q[:, 1], qy=q[:, 2], qz=q[:, 3],
                        yaw_deg=wrap_angle_deg(frame["yaw_deg"].to_numpy())), label


def _local_position(log: _Records, ctx: _Context):
    ekf = _ekf_messages(log)
    if ekf is None:
        return "no XKF1 or NKF1 records"
    return _sensor(log, ctx, ekf[0], {"x_m": ("PN", 1.0), "y_m": ("PE", 1.0), "z_m": ("PD", 1.0),
                                      "vx_m_s": ("VN", 1.0), "vy_m_s": ("VE", 1.0), "vz_m_s": ("VD", 1.0)}, "C")


def _global_position(log: _Records, ctx: _Context):
    return _sensor(log, ctx, "POS", {"lat_deg": ("Lat", 1.0), "lon_deg": ("Lng", 1.0), "alt_m": ("Alt", 1.0)})


def _wind(log: _Records, ctx: _Context):
    ekf = _ekf_messages(log)
    if ekf is None:
        return "no XKF2 or NKF2 records"
    return _sensor(log, ctx, ekf[1], {"wind_n_m_s": ("VWN", 1.0), "wind_e_m_s": ("VWE", 1.0)}, "C")


def _truth_attitude(log: _Records, ctx: _Context):
    found = _sensor(log, ctx, "SIM", {"qw": ("Q1", 1.0), "qx": ("Q2", 1.0), "qy": ("Q3", 1.0), "qz": ("Q4", 1.0)})
    if isinstance(found, str):
        return found
    frame, label = found
    roll, pitch, yaw = quat_to_euler(frame[["qw", "qx", "qy", "qz"]].to_numpy())
    return _with(frame, roll_deg=np.degrees(roll), pitch_deg=np.degrees(pitch),
                        yaw_deg=wrap_angle_deg(np.degrees(yaw))), label


def _truth_local_position(log: _Records, ctx: _Context):
    return _sensor(log, ctx, "SIM2", {"x_m": ("PN", 1.0), "y_m": ("PE", 1.0), "z_m": ("PD", 1.0),
                                      "vx_m_s": ("VN", 1.0), "vy_m_s": ("VE", 1.0), "vz_m_s": ("VD", 1.0)})


def _truth_global_position(log: _Records, ctx: _Context):
    return _sensor(log, ctx, "SIM", {"lat_deg": ("Lat", 1.0), "lon_deg": ("Lng", 1.0), "alt_m": ("Alt", 1.0)})


def _truth_wind(log: _Records, ctx: _Context):
    return _sensor(log, ctx, "SWND", {"wind_n_m_s": ("WN", 1.0), "wind_e_m_s": ("WE", 1.0)})


#: Builder of every stream, in build order (airspeed after baro: its TAS needs the static pressure).
_STREAMS: dict[str, Callable[[_Records, _Context], tuple[pd.DataFrame, str] | str]] = {
    "imu": _imu, "mag": _mag, "baro": _baro, "gps": _gps, "airspeed": _airspeed,
    "onboard_attitude": _attitude, "onboard_local_position": _local_position,
    "onboard_global_position": _global_position, "onboard_wind": _wind,
    "truth_attitude": _truth_attitude, "truth_local_position": _truth_local_position,
    "truth_global_position": _truth_global_position, "truth_wind": _truth_wind,
}


