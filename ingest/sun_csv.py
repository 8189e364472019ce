"""Sun-device CSV -> the ``sun`` stream of a :class:`~ingest.flightlog.FlightLog`.

File format: a header row, then one row per sample, comma separated:

* ``i1_mA`` .. ``i7_mA``: photocell currents [mA]; ``i1`` is the top cell, ``i2`` .. ``i7`` the side cells at
  device azimuths 0, 60, ..., 300 deg (see :class:`~ingest.sun_device.SunDevice`);
* a time column, strictly increasing: either ``time_s`` [s] on the flight log's clock (PX4 ``timestamp`` /
  1e6), or ``time_utc_s`` [s], UTC unix time, mapped onto the log clock with the log's GPS-derived UTC offset.

Other columns are ignored.
"""

from __future__ import annotations

import dataclasses
import io
import os
from typing import IO

import numpy as np
import pandas as pd

from ingest.errors import InputError
from ingest.flightlog import STREAM_COLUMNS, FlightLog, stream_info
from ingest.sources import source_name
from ingest.sun_device import N_CELLS

#: Current columns of the CSV [mA], in cell order (``i1_mA`` is the top cell).
CURRENT_COLUMNS_MA = tuple(f"i{cell}_mA" for cell in range(1, N_CELLS + 1))
#: Accepted time columns, in order of preference: log clock [s], UTC unix time [s].
TIME_COLUMNS = ("time_s", "time_utc_s")
MA_TO_A = 1e-3

SunSource = str | os.PathLike | bytes | IO


def read_sun_csv(source: SunSource, *, utc_offset_s: float | None = None,
                 name: str | None = None) -> pd.DataFrame:
    """Read a sun-device CSV into the canonical ``sun`` stream.

    Parameters
    ----------
    source : path, bytes or file object
        The CSV file or its content.
    utc_offset_s : float, optional
        UTC unix time minus log time [s] (``FlightLog.meta.utc_offset_s``); needed when the file is timed by
        ``time_utc_s``.
    name : str, optional
        Name used in messages; default the file's base name.

    Returns
    -------
    pandas.DataFrame
        Columns ``i1_a`` .. ``i7_a`` [A], indexed by ``time_s`` [s, log clock], strictly increasing.

    Raises
    ------
    InputError
        Unreadable file, missing time or current column, a non-numeric or empty value, times not strictly
        increasing, or UTC times without a UTC offset.
    """
    name = name or source_name(source)
    try:
        raw = pd.read_csv(io.BytesIO(source) if isinstance(source, bytes) else source, dtype=str,
                          skipinitialspace=True)
    except (OSError, UnicodeDecodeError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        raise InputError(f"cannot read the CSV ({exc})", source=name) from exc

    time_column = next((column for column in TIME_COLUMNS if column in raw.columns), None)
    if time_column is None:
        raise InputError(f"no time column: expected {' or '.join(TIME_COLUMNS)} "
                         f"(found {', '.join(map(str, raw.columns))})", source=name)
    missing = [column for column in CURRENT_COLUMNS_MA if column not in raw.columns]
    if missing:
        raise InputError(f"missing current column(s) {', '.join(missing)} [mA]", source=name)
    if len(raw) == 0:
        raise InputError("the CSV has a header but no samples", source=name)

    values = {column: _numeric(raw[column], name) for column in (time_column, *CURRENT_COLUMNS_MA)}
    time_s = values[time_column]
    if time_column == "time_utc_s":
        if utc_offset_s is None:
            raise InputError("the file is timed in UTC but the flight log has no GPS UTC time to align it; "
                             "give time_s on the log clock instead", source=name, field="time_utc_s")
        time_s = time_s - utc_offset_s
    not_increasing = np.flatnonzero(np.diff(time_s) <= 0)
    if len(not_increasing):
        line = int(not_increasing[0]) + 3  # header is line 1, the first data row line 2
        raise InputError(f"times must be strictly increasing; line {line} is not after the line before it",
                         source=name, field=time_column)

    currents_a = {sun_column: values[csv_column] * MA_TO_A
                  for sun_column, csv_column in zip(STREAM_COLUMNS["sun"], CURRENT_COLUMNS_MA, strict=True)}
    return pd.DataFrame(currents_a, index=pd.Index(time_s, name="time_s"))


def with_sun(log: FlightLog, source: SunSource, *, name: str | None = None) -> FlightLog:
    """A copy of ``log`` with the sun-device CSV attached as its ``sun`` stream.

    Parameters
    ----------
    log : FlightLog
        The flight (its UTC offset aligns ``time_utc_s`` files; it is not modified).
    source : path, bytes or file object
        The sun-device CSV (format in the module docstring).
    name : str, optional
        Name used in messages and as the stream's source; default the file's base name.

    Returns
    -------
    FlightLog
        Same streams plus ``sun``; a warning is added when part of the CSV lies outside the IMU time span.

    Raises
    ------
    InputError
        As :func:`read_sun_csv`, or when no sample falls inside the flight's IMU time span (wrong clock).
    """
    name = name or source_name(source)
    sun = read_sun_csv(source, utc_offset_s=log.meta.utc_offset_s, name=name)
    time_s = sun.index.to_numpy()
    inside = (time_s >= log.meta.start_time_s) & (time_s <= log.meta.end_time_s)
    if not inside.any():
        raise InputError(f"no sample inside the flight log's time span: the CSV covers {time_s[0]:.3f} "
                         f".. {time_s[-1]:.3f} s, the log {log.meta.start_time_s:.3f} .. "
                         f"{log.meta.end_time_s:.3f} s on the log clock", source=name)
    warnings = list(log.meta.warnings)
    if not inside.all():
        warnings.append(f"{name}: {int(np.count_nonzero(~inside))} of {len(time_s)} sun-device samples lie "
                        "outside the IMU time span")
    meta = dataclasses.replace(log.meta, streams={**log.meta.streams, "sun": stream_info(name, time_s)},
                               warnings=warnings)
    return FlightLog(streams={**log.streams, "sun": sun}, meta=meta)


def _numeric(column: pd.Series, name: str) -> np.ndarray:
    """Float values of a text column; InputError naming the first line that is empty or not a number."""
    values = pd.to_numeric(column, errors="coerce").to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(values))
    if len(bad):
        text = column.iloc[bad[0]]
        got = "an empty cell" if pd.isna(text) else repr(text)
        raise InputError(f"line {int(bad[0]) + 2}: expected a finite number, got {got}",
                         source=name, field=str(column.name))
    return values
