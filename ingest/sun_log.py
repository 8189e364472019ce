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
"""

from __future__ import annotations

import dataclasses
import io
import json
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
#: CSV line of the first data row (the header is line 1).
FIRST_DATA_LINE = 2


def load_sun_log(path_or_bytes: Source, *, flight_log: FlightLog | None = None, time_offset_s: float | None = None,
                 name: str | None = None) -> pd.DataFrame:
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

    Returns
    -------
    pandas.DataFrame
        Columns ``i1_a`` .. ``i7_a`` [A], indexed by ``time_s`` [s, log clock], strictly increasing.

    Raises
    ------
    InputError
        Unreadable or empty file, missing time or current column, a non-numeric or empty value, a current
        below -1 mA or above 10 A, times not strictly increasing, or no way to map UTC onto the log clock.
    """
    content, name = read_content(path_or_bytes, name=name)
    offset_s = time_offset_s if time_offset_s is not None else (
        flight_log.meta.utc_offset_s if flight_log is not None else None)
    if offset_s is None:
        why = (f"the flight log {flight_log.meta.source} has no GPS UTC time" if flight_log is not None
               else "no flight log was given")
        raise InputError(f"cannot put the sun-device times on the log clock: {why}; give the time offset "
                         "(UTC unix time of log time 0) explicitly", source=name)
    try:
        raw = pd.read_csv(io.BytesIO(content), dtype=str, skipinitialspace=True, encoding="utf-8-sig")
    except (UnicodeDecodeError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        raise InputError(f"cannot read the CSV ({exc})", source=name) from exc

    time_column = next((column for column in TIME_COLUMNS if column in raw.columns), None)
    if time_column is None:
        raise InputError(f"no time column: expected {' or '.join(TIME_COLUMNS)} "
                         f"(found {', '.join(map(str, raw.columns))})", source=name)
    current_columns, to_ampere = _current_columns(raw.columns, name)
    if len(raw) == 0:
        raise InputError("the CSV has a header but no samples", source=name)

    unix_time_s = (_numeric(raw[time_column], name) if time_column == "unix_time_s"
                   else _iso_unix_time_s(raw[time_column], name))
    not_increasing = np.flatnonzero(np.diff(unix_time_s) <= 0)
    if len(not_increasing):
        line = int(not_increasing[0]) + 1 + FIRST_DATA_LINE
        raise InputError(f"line {line}: time goes backwards or repeats; times must be strictly increasing",
                         source=name, field=time_column)
    currents_a = {}
    for sun_column, csv_column in zip(STREAM_COLUMNS["sun"], current_columns, strict=True):
        currents_a[sun_column] = _numeric(raw[csv_column], name) * to_ampere
        _check_range(currents_a[sun_column], raw[csv_column], name)
    return pd.DataFrame(currents_a, index=pd.Index(unix_time_s - offset_s, name="time_s"))


def load_sun_device(path_or_bytes: Source, *, name: str | None = None) -> SunDevice:
    """Read the sun-device geometry from a JSON file (format in the module docstring).

    Raises
    ------
    InputError
        Unreadable file, invalid JSON, an unknown key, or a value of the wrong type, length or range.
    """
    content, name = read_content(path_or_bytes, name=name)
    try:
        values = json.loads(content)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"not valid JSON ({exc})", source=name) from exc
    known = [f.name for f in dataclasses.fields(SunDevice)]
    if not isinstance(values, dict):
        raise InputError(f"expected a JSON object with the keys {', '.join(known)}", source=name)
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise InputError(f"unknown key(s) {', '.join(unknown)}; expected {', '.join(known)}", source=name)
    for key, value in values.items():
        scalar = key == "tilt_deg"
        if not (_is_number(value) if scalar else isinstance(value, list) and all(map(_is_number, value))):
            raise InputError(f"expected {'a number' if scalar else 'a list of numbers'}, got {value!r}",
                             source=name, field=key)
    try:
        return SunDevice(**{key: float(value) if key == "tilt_deg" else tuple(map(float, value))
                            for key, value in values.items()})
    except ValueError as exc:
        raise InputError(str(exc), source=name) from exc


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
        Same streams plus ``sun``, ``meta.sun_device`` set; a warning when part of the currents lies outside
        the IMU time span.

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
    warnings = list(flight_log.meta.warnings)
    if not inside.all():
        warnings.append(f"{source}: {int(np.count_nonzero(~inside))} of {len(time_s)} sun-device samples lie "
                        "outside the IMU time span")
    meta = dataclasses.replace(flight_log.meta, streams={**flight_log.meta.streams,
                                                         "sun": stream_info(source, time_s)},
                               warnings=warnings, sun_device=device or SunDevice())
    return FlightLog(streams={**flight_log.streams, "sun": sun_frame[list(STREAM_COLUMNS["sun"])]}, meta=meta)


def with_sun(flight_log: FlightLog, path_or_bytes: Source, *, device: SunDevice | None = None,
             time_offset_s: float | None = None, name: str | None = None) -> FlightLog:
    """A new :class:`FlightLog` with the sun-device CSV ``path_or_bytes`` attached as its ``sun`` stream:
    :func:`load_sun_log` on the log's clock, then :func:`attach_sun` (parameters as there)."""
    name = name or source_name(path_or_bytes)
    currents = load_sun_log(path_or_bytes, flight_log=flight_log, time_offset_s=time_offset_s, name=name)
    return attach_sun(flight_log, currents, device=device, source=name)


def _is_number(value) -> bool:
    """True for a JSON number (not a boolean)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _current_columns(columns: pd.Index, name: str) -> tuple[tuple[str, ...], float]:
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
    """UTC unix time [s] of ISO-8601 text (UTC unless the text has a zone)."""
    times = pd.to_datetime(column, utc=True, format="ISO8601", errors="coerce")
    bad = np.flatnonzero(times.isna().to_numpy())
    if len(bad):
        _bad_cell(column, int(bad[0]), "an ISO-8601 time such as 2024-03-18T14:49:11.250Z", name)
    return ((times - pd.Timestamp(0, tz="UTC")) / pd.Timedelta(seconds=1)).to_numpy(dtype=float)


def _check_range(currents_a: np.ndarray, column: pd.Series, name: str) -> None:
    """InputError at the first current below the noise allowance or above a photocell's range."""
    bad = np.flatnonzero((currents_a < MIN_CURRENT_A) | (currents_a > MAX_CURRENT_A))
    if len(bad):
        _bad_cell(column, int(bad[0]), f"a current between {MIN_CURRENT_A * 1e3:g} mA (noise around zero) and "
                  f"{MAX_CURRENT_A:g} A", name)


def _bad_cell(column: pd.Series, row: int, expected: str, name: str) -> NoReturn:
    """Raise the InputError for cell ``row`` of ``column``."""
    text = column.iloc[row]
    got = "an empty cell" if pd.isna(text) else repr(text)
    raise InputError(f"line {row + FIRST_DATA_LINE}: expected {expected}, got {got}", source=name,
                     field=str(column.name))
