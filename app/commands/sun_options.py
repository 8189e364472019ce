"""The ``--sun SUN.csv`` and ``--device DEV.json`` options of the commands that replay a log (``calibrate``,
``replay``, ``report``): their arguments, their check and the log with its sun-device data attached."""

from __future__ import annotations

import argparse

from ingest.errors import InputError
from ingest.flightlog import FlightLog
from ingest.log_formats import load_flight_log
from ingest.sun_log import load_sun_device, with_sun


def add_sun_arguments(parser: argparse.ArgumentParser) -> None:
    """Register ``--sun`` and ``--device``."""
    parser.add_argument("--sun", metavar="SUN.csv", help="sun-device CSV (photocell currents) to attach")
    parser.add_argument("--device", metavar="DEV.json", help="sun-device geometry (tilt, azimuths, mounting)")


def check_sun_arguments(args: argparse.Namespace) -> None:
    """Refuse ``--device`` without ``--sun`` (before any file is read)."""
    if args.device is not None and args.sun is None:
        raise InputError("--device describes the sun-device log: give --sun too")


def load_log_with_sun(args: argparse.Namespace) -> FlightLog:
    """``args.log``, with ``--sun`` (and ``--device``) attached when given."""
    check_sun_arguments(args)
    log = load_flight_log(args.log)
    if args.sun is None:
        return log
    return with_sun(log, args.sun, device=load_sun_device(args.device) if args.device is not None else None)
