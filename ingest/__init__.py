"""Readers that turn PX4 ULog files and sun-device CSV logs into one canonical :class:`FlightLog`."""

from ingest.errors import FileTooLargeError, InputError
from ingest.flightlog import STREAM_COLUMNS, FlightLog, LogMetadata, StreamInfo
from ingest.sun_device import SunDevice

__all__ = ["STREAM_COLUMNS", "FileTooLargeError", "FlightLog", "InputError", "LogMetadata", "StreamInfo",
           "SunDevice"]
