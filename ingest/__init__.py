"""Readers that turn PX4 ULog files and sun-device CSV logs into one canonical :class:`FlightLog`."""

from ingest.errors import FileTooLargeError, InputError
from ingest.flightlog import STREAM_COLUMNS, FlightLog, LogMetadata, StreamInfo
from ingest.sun_device import SunDevice
from ingest.sun_log import attach_sun, load_sun_device, load_sun_log, with_sun
from ingest.ulog_reader import load_flight_log

__all__ = ["STREAM_COLUMNS", "FileTooLargeError", "FlightLog", "InputError", "LogMetadata", "StreamInfo",
           "SunDevice", "attach_sun", "load_flight_log", "load_sun_device", "load_sun_log", "with_sun"]
