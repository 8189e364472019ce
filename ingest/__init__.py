"""Readers that turn PX4 ULog files and sun-device CSV logs into one canonical :class:`FlightLog`."""

from ingest.errors import FileTooLargeError, InputError
from ingest.flightlog import STREAM_COLUMNS, FlightLog, LogMetadata, StreamInfo
from ingest.sun_csv import read_sun_csv, with_sun
from ingest.sun_device import SunDevice
from ingest.ulog import read_ulog

__all__ = ["STREAM_COLUMNS", "FileTooLargeError", "FlightLog", "InputError", "LogMetadata", "StreamInfo",
           "SunDevice", "read_sun_csv", "read_ulog", "with_sun"]
