"""``solarnav info LOG.ulg [--sun SUN.csv] [--device DEV.json] [--json]``: a flight log's streams, rates, gaps,
warnings and input quality findings (what the estimators refuse or flag, docs/estimators.md, 'Inputs the
estimators refuse')."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math

from ingest.errors import InputError
from ingest.flightlog import FlightLog
from ingest.log_formats import load_flight_log
from ingest.quality import assess_input_quality
from ingest.sun_log import load_sun_device, with_sun


def add_parser(subparsers) -> None:
    """Register the ``info`` sub-parser."""
    parser = subparsers.add_parser("info", help="streams, rates, gaps and warnings of a flight log",
                                   description=__doc__)
    parser.add_argument("log", metavar="LOG.ulg", help="PX4 ULog file")
    parser.add_argument("--sun", metavar="SUN.csv", help="sun-device CSV to attach (photocell currents)")
    parser.add_argument("--device", metavar="DEV.json", help="sun-device geometry (tilt, azimuths, mounting)")
    parser.add_argument("--sun-time-offset-s", type=float, metavar="SECONDS",
                        help="UTC unix time of log time 0, for logs without GPS time (log time = unix time - "
                             "offset)")
    parser.add_argument("--json", action="store_true", help="print a JSON object instead of text")


def run(args: argparse.Namespace) -> int:
    """Read the log (and sun CSV) and print the summary; 0 on success."""
    if args.sun is None and (args.device is not None or args.sun_time_offset_s is not None):
        raise InputError("--device and --sun-time-offset-s describe the sun-device log: give --sun too")
    log = load_flight_log(args.log)
    if args.sun is not None:
        device = load_sun_device(args.device) if args.device is not None else None
        log = with_sun(log, args.sun, device=device, time_offset_s=args.sun_time_offset_s)
    print(json.dumps(info_dict(log), indent=2) if args.json else format_info(log))
    return 0


def info_dict(log: FlightLog) -> dict:
    """The log's metadata as JSON-ready data (parameters left out; NaN as None), with ``input_quality``: one dict
    per :class:`~ingest.quality.QualityFinding` (kind, severity, stream, message, value, threshold, unit)."""
    meta = log.meta
    has_utc = meta.utc_offset_s is not None
    return _nan_to_none({
        "source": meta.source,
        "sha256": meta.sha256,
        "vehicle_type": meta.vehicle_type,
        "is_fixed_wing": meta.is_fixed_wing,
        "hardware": meta.hardware,
        "px4_version": meta.px4_version,
        "ver_data_format": meta.ver_data_format,
        "start_time_s": meta.start_time_s,
        "end_time_s": meta.end_time_s,
        "duration_s": meta.duration_s,
        "utc_offset_s": meta.utc_offset_s,
        "utc_start": log.utc(meta.start_time_s)[0].isoformat() if has_utc else None,
        "streams": {name: {"topic": info.topic, "rate_hz": info.rate_hz, "n": info.n_samples,
                           "gaps": info.gaps}
                    for name, info in meta.streams.items()},
        "sun_device": dataclasses.asdict(meta.sun_device) if meta.sun_device is not None else None,
        "warnings": meta.warnings,
        "input_quality": [dataclasses.asdict(finding) for finding in assess_input_quality(log)],
    })


def format_info(log: FlightLog) -> str:
    """Human-readable summary: header lines, one row per stream, the warnings, then the input quality findings
    (``REFUSED`` ones stop a replay without ``--force``)."""
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
    if meta.sun_device is not None:
        device = meta.sun_device
        lines += ["", f"sun device  faces tilted {device.tilt_deg:g} deg, side cells at "
                  f"{', '.join(f'{az:g}' for az in device.azimuths_deg)} deg, mounted roll/pitch/yaw "
                  f"{', '.join(f'{a:g}' for a in device.mount_rpy_deg)} deg"]
    if meta.warnings:
        lines += ["", "warnings:", *(f"  - {warning}" for warning in meta.warnings)]
    findings = assess_input_quality(log)
    lines += ["", "input quality: " + ("no finding" if not findings else
                                       f"{len(findings)} finding{'s' if len(findings) > 1 else ''}")]
    lines += [f"  - {'REFUSED' if f.severity == 'refuse' else 'flagged'}: {f.message}" for f in findings]
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
