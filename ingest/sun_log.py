"""Sun-device logs: the photocell-current CSV, the device geometry JSON, and attaching both to a flight log.

CSV format: a header row, then one row per sample, comma separated:

* a time column, strictly increasing: ``unix_time_s`` [s], UTC unix time, or ``time_utc``, an ISO-8601 time
  (``2024-03-18T14:49:11.250Z``; without a zone it is taken as UTC);
* ``i1_mA`` .. ``i7_mA``, photocell currents [mA], or ``i1_A`` .. ``i7_A`` [A]; ``i1`` is the top cell, ``i2`` ..
  ``i7`` the side cells at device azimuths 0, 60, ..., 300 deg (see :class:`~ingest.sun_device.SunDevice`).

Other columns are ignored. Times go onto the flight log's clock with ``time_s = unix_time_s - offset``, where
``offset`` [s] is the UTC unix time of log time 0: the log's GPS-derived ``meta.utc_offset_s`` or, for logs
without GPS time, an explicit ``time_offset_s`` (which wins when both are given).

Device JSON: an object with any of ``tilt_deg`` (number), ``azimuths_deg`` (6 numbers) and ``mount_rpy_deg``
(3 numbers); missing keys keep the defaults of :class:`~ingest.sun_device.SunDevice`.

Robustness: both readers raise :class:`~ingest.errors.InputError` (file, column or key, what was expected) for
anything they cannot use, never another exception, and never return NaN. The CSV must be UTF-8 (a byte order
mark is fine); blank lines are skipped and line numbers in messages count every line. A CSV that does not end
with a line break may have been cut off in its last number, so its last line is dropped with a warning
(``DataFrame.attrs["warnings"]``, copied into ``FlightLog.meta.warnings`` by :func:`attach_sun`). A time or
current column named twice, unix times outside 1970 .. 2100, and non-finite JSON numbers are refused.
"""

from __future__ import annotations

import dataclasses
import io
import json
import re
from typing import NoReturn

import numpy as np
import pandas as pd

from ingest.errors import InputError
from ingest.flightlog import STREAM_COLUMNS, FlightLog, stream_info
from ingest.sources import Source, read_content, source_name
from ingest.sun_device import N_CELLS, SunDevice

#: Accepted time columns: UTC unix time [s], ISO-8601 UTC time.
TIME_COLUMNS = ("unix_time_s", "time_utc")
#: Current columns per accepted unit, in cell order (``i1`` is the top cell), with the factor to amperes.
CURRENT_COLUMNS = {"mA": (tuple(f"i{cell}_mA" for cell in range(1, N_CELLS + 1)), 1e-3),
                   "A": (tuple(f"i{cell}_A" for cell in range(1, N_CELLS + 1)), 1.0)}
#: Currents below this are not noise around zero [A] (a dark cell reads about 0).
MIN_CURRENT_A = -1e-3
#: Currents above this are not a photocell's [A].
MAX_CURRENT_A = 10.0
#: Accepted UTC unix times [s]: 1970-01-01 .. 2100-01-01 (a time beyond is a corrupt cell, not a flight).
MIN_UNIX_TIME_S = 0.0
MAX_UNIX_TIME_S = 4_102_444_800.0
#: Default size limit of the sun-device CSV [bytes]: about 26 h of 10 Hz samples.
MAX_SUN_CSV_BYTES = 64 * 2**20
#: Default size limit of the device JSON [bytes] (the geometry takes a few hundred).
MAX_DEVICE_JSON_BYTES = 2**20
#: Key of the warnings list in the ``attrs`` of the frame :func:`load_sun_log` returns.
WARNINGS_ATTR = "warnings"


def load_sun_log(path_or_bytes: Source, *, flight_log: FlightLog | None = None, time_offset_s: float | None = None,
                 name: str | None = None, max_bytes: int | None = MAX_SUN_CSV_BYTES) -> pd.DataFrame:
    """Read a sun-device CSV into the canonical ``sun`` stream on the flight log's clock.

    Parameters
    ----------
    path_or_bytes : path, bytes or file object
        The CSV file or its content (format in the module docstring).
    flight_log : FlightLog, optional
        The flight the currents belong to; its ``meta.utc_offset_s`` maps UTC onto the log clock.
    time_offset_s : float, optional
        UTC unix time of log time 0 [s]: ``time_s = unix_time_s - time_offset_s``. Overrides the log's GPS
        offset; needed for logs without GPS time.
    name : str, optional
        Name used in messages; default the file's base name.
    max_bytes : int or None, optional
        Size limit of the file [bytes]; default :data:`MAX_SUN_CSV_BYTES`, ``None`` for no limit.

    Returns
    -------
    pandas.DataFrame
        Columns ``i1_a`` .. ``i7_a`` [A], indexed by ``time_s`` [s, log clock], strictly increasing, all finite.
        ``attrs["warnings"]`` lists what was dropped (a last line without line break), each message prefixed with
        the file name.

    Raises
    ------
    InputError
        Unreadable, non-UTF-8, too large or empty file, missing or repeated time or current column, a
        non-numeric, non-finite or empty value, a current below -1 mA or above 10 A, a unix time outside
        1970 .. 2100, times not strictly increasing, or no (finite) way to map UTC onto the log clock.
    """
    content, name = read_content(path_or_bytes, name=name, max_bytes=max_bytes)
    offset_s = time_offset_s if time_offset_s is not None else (
        flight_log.meta.utc_offset_s if flight_log is not None else None)
    if offset_s is None:
        why = (f"the flight log {flight_log.meta.source} has no GPS UTC time" if flight_log is not None
               else "no flight log was given")
        raise InputError(f"cannot put the sun-device times on the log clock: {why}; give the time offset "
                         "(UTC unix time of log time 0) explicitly", source=name)
    if not np.isfinite(offset_s):
        raise InputError(f"the time offset (UTC unix time of log time 0) must be a finite number of seconds, "
                         f"got {offset_s!r}", source=name, field="time offset")
    header, data, warnings = _read_table(content, name)

    time_column = next((column for column in TIME_COLUMNS if column in header), None)
    if time_column is None:
        raise InputError(f"no time column: expected {' or '.join(TIME_COLUMNS)} "
                         f"(found {', '.join(header)})", source=name)
    current_columns, to_ampere = _current_columns(header, name)
    for column in (time_column, *current_columns):
        positions = [i + 1 for i, cell in enumerate(header) if cell == column]
        if len(positions) > 1:
            raise InputError(f"the column is named {len(positions)} times (columns "
                             f"{', '.join(map(str, positions))} of the header); keep one", source=name, field=column)
    if len(data) == 0:
        raise InputError("the CSV has a header but no samples" if not warnings else
                         "no complete sample: " + warnings[0].removeprefix(f"{name}: "), source=name)

    def cells(column: str) -> pd.Series:
        return data.iloc[:, header.index(column)].rename(column)

    unix_time_s = (_numeric(cells(time_column), name) if time_column == "unix_time_s"
                   else _iso_unix_time_s(cells(time_column), name))
    bad = np.flatnonzero((unix_time_s < MIN_UNIX_TIME_S) | (unix_time_s >= MAX_UNIX_TIME_S))
    if len(bad):
        _bad_cell(cells(time_column), int(bad[0]), "a UTC time between 1970 and 2100 (unix time 0 .. "
                  f"{MAX_UNIX_TIME_S:.0f} s)", name)
    not_increasing = np.flatnonzero(np.diff(unix_time_s) <= 0)
    if len(not_increasing):
        line = int(data.index[not_increasing[0] + 1])
        raise InputError(f"line {line}: time goes backwards or repeats; times must be strictly increasing",
                         source=name, field=time_column)
    currents_a = {}
    for sun_column, csv_column in zip(STREAM_COLUMNS["sun"], current_columns, strict=True):
        currents_a[sun_column] = _numeric(cells(csv_column), name) * to_ampere
        _check_range(currents_a[sun_column], cells(csv_column), name)
    frame = pd.DataFrame(currents_a, index=pd.Index(unix_time_s - offset_s, name="time_s"))
    frame.attrs[WARNINGS_ATTR] = warnings
    return frame


def load_sun_device(path_or_bytes: Source, *, name: str | None = None,
                    max_bytes: int | None = MAX_DEVICE_JSON_BYTES) -> SunDevice:
    """Read the sun-device geometry from a JSON file (format in the module docstring).

    Parameters
    ----------
    path_or_bytes : path, bytes or file object
        The JSON file or its content.
    name : str, optional
        Name used in messages; default the file's base name.
    max_bytes : int or None, optional
        Size limit of the file [bytes]; default :data:`MAX_DEVICE_JSON_BYTES`, ``None`` for no limit.

    Returns
    -------
    SunDevice
        The geometry; angles [deg].

    Raises
    ------
    InputError
        Unreadable, too large or empty file, invalid JSON (also: nested too deeply, an integer with thousands of
        digits), not an object, an unknown or repeated key, or a value of the wrong type, length or range
        (non-finite numbers such as ``NaN``, ``Infinity`` or ``1e400`` included).
    """
    content, name = read_content(path_or_bytes, name=name, max_bytes=max_bytes)
    try:
        values = json.loads(content, object_pairs_hook=_unique_keys)
    except _RepeatedKeyError as exc:
        raise InputError("the key appears more than once; keep one", source=name, field=exc.key) from None
    except UnicodeDecodeError as exc:
        raise InputError(f"not UTF-8 text (byte {exc.object[exc.start:exc.start + 1]!r} at offset {exc.start})",
                         source=name) from None
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON ({exc})", source=name) from None
    except RecursionError:
        raise InputError("not valid JSON (nested too deeply for a device geometry)", source=name) from None
    except ValueError as exc:  # an integer literal past Python's digit limit
        raise InputError(f"not valid JSON ({exc})", source=name) from None
    known = [f.name for f in dataclasses.fields(SunDevice)]
    if not isinstance(values, dict):
        raise InputError(f"expected a JSON object with the keys {', '.join(known)}, got a JSON "
                         f"{_json_kind(values)}", source=name)
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise InputError(f"unknown key(s) {', '.join(unknown)}; expected {', '.join(known)}", source=name)
    fields = {}
    for key, value in values.items():
        scalar = key == "tilt_deg"
        if not (_is_number(value) if scalar else isinstance(value, list) and all(map(_is_number, value))):
            raise InputError(f"expected {'a number' if scalar else 'a list of numbers'}, got {_short(value)}",
                             source=name, field=key)
        numbers = [_finite_float(number, name, key) for number in ([value] if scalar else value)]
        fields[key] = numbers[0] if scalar else tuple(numbers)
    try:
        return SunDevice(**fields)
    except ValueError as exc:
        raise InputError(str(exc), source=name) from None


def attach_sun(flight_log: FlightLog, sun_frame: pd.DataFrame, *, device: SunDevice | None = None,
               source: str = "sun-device log") -> FlightLog:
    """A new :class:`FlightLog` with ``sun_frame`` as its ``sun`` stream (``flight_log`` is not modified).

    Parameters
    ----------
    flight_log : FlightLog
        The flight.
    sun_frame : pandas.DataFrame
        Currents as returned by :func:`load_sun_log` (log clock).
    device : SunDevice, optional
        Geometry of the device; default :class:`SunDevice` (45 deg faces, mounted along the body axes).
    source : str, optional
        File name for the stream's topic and messages.

    Returns
    -------
    FlightLog
        Same streams plus ``sun``, ``meta.sun_device`` set; ``meta.warnings`` gains the reader's warnings
        (``sun_frame.attrs["warnings"]``) and one when part of the currents lies outside the IMU time span.

    Raises
    ------
    InputError
        No current sample falls inside the flight's IMU time span (wrong clock or time offset).
    """
    time_s = sun_frame.index.to_numpy()
    inside = (time_s >= flight_log.meta.start_time_s) & (time_s <= flight_log.meta.end_time_s)
    if not inside.any():
        raise InputError(f"no sample inside the flight log's time span: the currents cover {time_s[0]:.3f} "
                         f".. {time_s[-1]:.3f} s, the log {flight_log.meta.start_time_s:.3f} .. "
                         f"{flight_log.meta.end_time_s:.3f} s on the log clock (check the time offset)",
                         source=source)
    warnings = [*flight_log.meta.warnings, *sun_frame.attrs.get(WARNINGS_ATTR, ())]
    if not inside.all():
        warnings.append(f"{source}: {int(np.count_nonzero(~inside))} of {len(time_s)} sun-device samples lie "
                        "outside the IMU time span")
    meta = dataclasses.replace(flight_log.meta, streams={**flight_log.meta.streams,
                                                         "sun": stream_info(source, time_s)},
                               warnings=warnings, sun_device=device or SunDevice())
    return FlightLog(streams={**flight_log.streams, "sun": sun_frame[list(STREAM_COLUMNS["sun"])]}, meta=meta)


def with_sun(flight_log: FlightLog, path_or_bytes: Source, *, device: SunDevice | None = None,
             time_offset_s: float | None = None, name: str | None = None,
             max_bytes: int | None = MAX_SUN_CSV_BYTES) -> FlightLog:
    """A new :class:`FlightLog` with the sun-device CSV ``path_or_bytes`` attached as its ``sun`` stream:
    :func:`load_sun_log` on the log's clock, then :func:`attach_sun` (parameters as there)."""
    name = name or source_name(path_or_bytes)
    currents = load_sun_log(path_or_bytes, flight_log=flight_log, time_offset_s=time_offset_s, name=name,
                            max_bytes=max_bytes)
    return attach_sun(flight_log, currents, device=device, source=name)


def _read_table(content: bytes, name: str) -> tuple[list[str], pd.DataFrame, list[str]]:
    """Header cells, the text cells of the data rows indexed by their line number, and the warnings.

    Every line counts (blank ones are read, then dropped), so the index is the line number a user's editor
    shows, unless a quoted cell spans lines. A last line without line break is dropped with a warning: a file
    cut off inside its last number (``9.4803`` -> ``9``) looks complete otherwise.
    """
    body = content.removeprefix(b"\xef\xbb\xbf")
    leading = re.match(rb"(?:[ \t]*(?:\r\n|\n|\r))*", body).group()  # pandas finds no columns past them
    body = body[len(leading):]
    if not body.strip():
        raise InputError("the file has no header line (only blank lines)", source=name)
    try:
        table = pd.read_csv(io.BytesIO(body), header=None, dtype=str, skipinitialspace=True, encoding="utf-8",
                            skip_blank_lines=False)
    except UnicodeDecodeError:  # pandas' offsets count from its read buffer: find the byte ourselves
        raise InputError(f"not UTF-8 text ({_first_non_utf8(content)}); save the CSV as UTF-8",
                         source=name) from None
    except pd.errors.EmptyDataError:
        raise InputError("the file has no header line (only blank lines)", source=name) from None
    except (pd.errors.ParserError, ValueError, OverflowError) as exc:  # malformed rows, quotes, field counts
        raise InputError(f"cannot read the CSV ({' '.join(str(exc).split())})", source=name) from None
    first_line = 1 + leading.count(b"\n") + leading.replace(b"\r\n", b"").count(b"\r")
    table.index = pd.RangeIndex(first_line, first_line + len(table))  # line numbers
    filled = table.notna().any(axis=1).to_numpy()
    header = ["" if pd.isna(cell) else str(cell).strip() for cell in table.iloc[0]]
    data = table.iloc[1:]
    warnings = []
    if not content.endswith((b"\n", b"\r")) and len(data) and filled[-1]:
        last_line = int(data.index[-1])
        warnings.append(f"{name}: line {last_line}, the last, does not end with a line break and may be cut off "
                        "(the file looks truncated); it was dropped")
        data = data.iloc[:-1]
    return header, data[data.notna().any(axis=1)], warnings


def _first_non_utf8(content: bytes) -> str:
    """Where the first byte that is not UTF-8 is, for messages."""
    try:
        content.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = content.count(b"\n", 0, exc.start) + 1
        return f"byte {content[exc.start:exc.start + 1]!r} on line {line}, at byte offset {exc.start}"
    return "a byte sequence that is not UTF-8"


class _RepeatedKeyError(ValueError):
    """A JSON object names a key twice (raised inside :func:`json.loads`)."""

    def __init__(self, key: str):
        super().__init__(key)
        self.key = key


def _unique_keys(pairs: list[tuple[str, object]]) -> dict:
    """``object_pairs_hook`` of :func:`json.loads` refusing a repeated key (the last would silently win)."""
    values = {}
    for key, value in pairs:
        if key in values:
            raise _RepeatedKeyError(key)
        values[key] = value
    return values


def _json_kind(value) -> str:
    """JSON type name of a decoded value, for messages."""
    return {list: "array", str: "string", bool: "boolean", type(None): "null"}.get(type(value), "number")


def _short(value, limit: int = 60) -> str:
    """``repr`` of ``value`` cut to ``limit`` characters, for messages."""
    try:
        text = repr(value)
    except (RecursionError, ValueError):  # deeply nested JSON, an integer past Python's digit limit
        return f"a {_json_kind(value)} too large to show"
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _finite_float(number: int | float, name: str, key: str) -> float:
    """``number`` as a finite float; InputError naming ``key`` for NaN, infinities and too-large integers."""
    try:
        value = float(number)
    except OverflowError:
        value = float("inf")
    if not np.isfinite(value):
        raise InputError(f"expected finite numbers, got {_short(number)} (NaN, Infinity and numbers beyond "
                         "1.8e308 are not geometry)", source=name, field=key)
    return value


def _is_number(value) -> bool:
    """True for a JSON number (not a boolean)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _current_columns(columns: list[str], name: str) -> tuple[tuple[str, ...], float]:
    """The CSV's current columns (all in mA or all in A) and their factor to amperes."""
    present = {unit: [c for c in names if c in columns] for unit, (names, _) in CURRENT_COLUMNS.items()}
    if present["mA"] and present["A"]:
        raise InputError("current columns mix mA and A; use i1_mA .. i7_mA or i1_A .. i7_A", source=name)
    unit = "A" if present["A"] else "mA"
    names, to_ampere = CURRENT_COLUMNS[unit]
    missing = [column for column in names if column not in columns]
    if missing:
        raise InputError(f"missing current column(s) {', '.join(missing)} [{unit}]", source=name)
    return names, to_ampere


def _numeric(column: pd.Series, name: str) -> np.ndarray:
    """Float values of a text column; InputError naming the first line that is empty or not a number."""
    values = pd.to_numeric(column, errors="coerce").to_numpy(dtype=float, na_value=np.nan)
    bad = np.flatnonzero(~np.isfinite(values))
    if len(bad):
        _bad_cell(column, int(bad[0]), "a finite number", name)
    return values


def _iso_unix_time_s(column: pd.Series, name: str) -> np.ndarray:
    """UTC unix time [s] of ISO-8601 text (UTC unless the text has a zone), each between 1970 and 2100.

    Text not starting with a four-digit year is refused before parsing (pandas would read ``now`` and
    ``today`` as the time of reading); the range is checked on the timestamps, whose resolution follows the
    text, before any arithmetic that could overflow.
    """
    looks_iso = column.str.match(r"\d{4}").fillna(False).astype(bool)
    times = pd.to_datetime(column.where(looks_iso), utc=True, format="ISO8601", errors="coerce")
    bad = np.flatnonzero(times.isna().to_numpy())
    if len(bad):
        _bad_cell(column, int(bad[0]), "an ISO-8601 time such as 2024-03-18T14:49:11.250Z", name)
    start, end = (pd.Timestamp(seconds, unit="s", tz="UTC") for seconds in (MIN_UNIX_TIME_S, MAX_UNIX_TIME_S))
    bad = np.flatnonzero(((times < start) | (times >= end)).to_numpy())
    if len(bad):
        _bad_cell(column, int(bad[0]), "a UTC time between 1970 and 2100", name)
    return ((times - start) / pd.Timedelta(seconds=1)).to_numpy(dtype=float) + MIN_UNIX_TIME_S


def _check_range(currents_a: np.ndarray, column: pd.Series, name: str) -> None:
    """InputError at the first current below the noise allowance or above a photocell's range."""
    bad = np.flatnonzero((currents_a < MIN_CURRENT_A) | (currents_a > MAX_CURRENT_A))
    if len(bad):
        _bad_cell(column, int(bad[0]), f"a current between {MIN_CURRENT_A * 1e3:g} mA (noise around zero) and "
                  f"{MAX_CURRENT_A:g} A", name)


def _bad_cell(column: pd.Series, row: int, expected: str, name: str) -> NoReturn:
    """Raise the InputError for cell ``row`` (position) of ``column``, whose index holds the line numbers."""
    text = column.iloc[row]
    got = "an empty cell" if pd.isna(text) else _short(text)
    raise InputError(f"line {int(column.index[row])}: expected {expected}, got {got}", source=name,
                     field=str(column.name))
