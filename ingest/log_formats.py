"""The flight-log formats solarnav reads, and :func:`load_flight_log`, which picks one by the file's content.

Each :class:`LogFormat` pairs a recogniser (a test on the content: for these its first bytes) with its reader;
:data:`FORMATS` lists them, so reading another format is one more entry there and a reader module that imports
neither this module nor another reader (docs/ingest.md, 'Formats').
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from ingest.dataflash_reader import DATAFLASH_MAGIC, flightlog_from_dataflash, is_dataflash
from ingest.errors import InputError
from ingest.flightlog import FlightLog
from ingest.sources import Source, read_content
from ingest.ulog_reader import ULOG_MAGIC, flightlog_from_ulog_content, is_ulog


@dataclass(frozen=True)
class LogFormat:
    """One flight-log format.

    Attributes
    ----------
    name : str
        What the format is called in messages ("PX4 ULog", "ArduPilot DataFlash").
    signature : str
        How its content is recognised, for the message on a file no format recognises.
    recognises : callable
        ``recognises(content)``: True when the whole file ``content`` (bytes) is of this format.
    read : callable
        ``read(content, source=name)``: the :class:`FlightLog` of ``content``; raises
        :class:`~ingest.errors.InputError` naming ``source`` when it cannot.
    """

    name: str
    signature: str
    recognises: Callable[[bytes], bool]
    read: Callable[..., FlightLog]


#: The formats :func:`load_flight_log` reads, tried in this order (their signatures exclude each other).
FORMATS = (
    LogFormat("PX4 ULog", f"starts with the bytes {ULOG_MAGIC.hex(' ')}", is_ulog,
              flightlog_from_ulog_content),
    LogFormat("ArduPilot DataFlash", f"starts with the bytes {DATAFLASH_MAGIC.hex(' ')}", is_dataflash,
              flightlog_from_dataflash),
)


def load_flight_log(path_or_bytes: Source, *, max_bytes: int | None = None, name: str | None = None) -> FlightLog:
    """Read a flight log of any of :data:`FORMATS` (PX4 ULog, ArduPilot DataFlash ``.bin``), recognised by its
    content, not its name, into a :class:`FlightLog`.

    Parameters
    ----------
    path_or_bytes : path, bytes or binary file object
        The ``.ulg`` / ``.bin`` file or its content (a Streamlit upload is a binary file object).
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
        The file cannot be read, is empty, is of none of :data:`FORMATS` (the message lists each with its
        signature), or its reader refuses it: damaged beyond what the reader can skip (docs/robustness.md, 'ULog
        reader guard'), or without usable IMU data.
    FileTooLargeError
        The file is larger than ``max_bytes``.
    """
    content, name = read_content(path_or_bytes, name=name, max_bytes=max_bytes)
    for log_format in FORMATS:
        if log_format.recognises(content):
            return log_format.read(content, source=name)
    expected = "; ".join(f"{log_format.name} ({log_format.signature})" for log_format in FORMATS)
    raise InputError(f"not a flight log solarnav reads: expected one of the formats: {expected}", source=name)
