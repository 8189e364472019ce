"""``solarnav info LOG.ulg [--sun SUN.csv] [--json]``: a flight log's streams, rates, gaps and warnings."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math

from ingest.flightlog import FlightLog
from ingest.sun_csv import with_sun
from ingest.ulog import read_ulog


def add_parser(subparsers) -> None:
    """Register the ``info`` sub-parser."""
    parser = subparsers.add_parser("info", help="streams, rates, gaps and warnings of a flight log",
                                   description=__doc__)
    parser.add_argument("log", metavar="LOG.ulg", help="PX4 ULog file")
    parser.add_argument("--sun", metavar="SUN.csv", help="sun-device CSV to attach (photocell currents)")
    parser.add_argument("--json", action="store_true", help="print a JSON object instead of text")


def run(args: argparse.Namespace) -> int:
    """Read the log (and sun CSV) and print the summary; 0 on success."""
    log = read_ulog(args.log)
    if args.sun:
        log = with_sun(log, args.sun)
    print(json.dumps(info_dict(log), indent=2) if args.json else format_info(log))
    return 0


def info_dict(log: FlightLog) -> dict:
    """The log's metadata as JSON-ready data (parameters left out; NaN as None)."""
    meta = dataclasses.asdict(log.meta)
    del meta["parameters"]
    meta["is_fixed_wing"] = log.meta.is_fixed_wing
    has_utc = log.meta.utc_offset_s is not None
    meta["utc_start"] = log.utc(log.meta.start_time_s)[0].isoformat() if has_utc else None
    return _nan_to_none(meta)


def format_info(log: FlightLog) -> str:
    """Human-readable summary: header lines, one row per stream, then the warnings."""
    meta = log.meta
    vehicle = "fixed-wing" if meta.is_fixed_wing else "not fixed-wing"
    utc = ("none (no GPS time in the log)" if meta.utc_offset_s is None
           else f"{log.utc(meta.start_time_s)[0]:%Y-%m-%d %H:%M:%S} UTC at the first IMU sample (from GPS)")
    lines = [
        f"{meta.source}  sha256 {meta.sha256[:16]}",
        f"firmware  {meta.px4_version or 'unknown'} on {meta.hardware or 'unknown hardware'}"
        + (f", ULog data format {meta.ver_data_format}" if meta.ver_data_format is not None else ""),
        f"vehicle   MAV_TYPE {meta.vehicle_type if meta.vehicle_type is not None else 'unknown'} ({vehicle})",
        f"time      {meta.start_time_s:.3f} .. {meta.end_time_s:.3f} s on the log clock "
        f"({meta.duration_s:.2f} s)",
        f"start     {utc}",
        "",
        f"{'stream':<24} {'source':<36} {'samples':>8} {'rate [Hz]':>10}  gaps",
    ]
    for name, info in meta.streams.items():
        gaps = "-"
        if info.gaps:
            start_s, length_s = max(info.gaps, key=lambda gap: gap[1])
            gaps = f"{len(info.gaps)} (longest {length_s:.2f} s at {start_s:.3f} s)"
        lines.append(f"{name:<24} {info.topic:<36} {info.n_samples:>8} {info.rate_hz:>10.1f}  {gaps}")
    if meta.warnings:
        lines += ["", "warnings:", *(f"  - {warning}" for warning in meta.warnings)]
    return "\n".join(lines)


def _nan_to_none(value):
    """Recursively replace float NaN (not valid JSON) by None; tuples become lists."""
    if isinstance(value, float) and math.isnan(value):
        return None
    if isinstance(value, dict):
        return {key: _nan_to_none(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_nan_to_none(item) for item in value]
    return value
