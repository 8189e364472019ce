"""``solarnav params LOG_A LOG_B [--calib-a CALIB.json] [--calib-b CALIB.json] [--tune] [--no-noise]
[-o DIFF.csv]``: the autopilot parameters that changed, were added or removed between two flights, grouped by prefix
(EKF2_, EK3_, SENS_, CAL_, ...), then per flight the onboard estimator's noise parameters next to solarnav's values
for that flight in the same units: from ``--calib-a`` / ``--calib-b`` (e.g. written by ``calibrate --tune``), else
from a calibration of the log (``--tune`` identifies the noise too, about a minute per 15 minutes of flight)."""

from __future__ import annotations

import argparse
import math
import sys

import pandas as pd

from ingest.errors import InputError
from ingest.flightlog import FlightLog
from ingest.log_formats import load_flight_log
from workflows.calibration import calibrate_log
from workflows.params import ADDED, CHANGED, REMOVED, autopilot_of, diff_parameters, noise_parameter_table
from workflows.replay import write_table

#: The estimator whose identified noise the autopilots' error-state filters take (calib.parameter_export).
EXPORT_ESTIMATOR = ("full_state_indirect",)


def add_parser(subparsers) -> None:
    """Register the ``params`` sub-parser."""
    parser = subparsers.add_parser("params", help="parameter diff between two flights, onboard noise vs solarnav's",
                                   description=__doc__)
    parser.add_argument("log_a", metavar="LOG_A", help="first flight log (.ulg or .bin)")
    parser.add_argument("log_b", metavar="LOG_B", help="second flight log (.ulg or .bin)")
    parser.add_argument("--calib-a", metavar="CALIB.json", help="solarnav's calibration of LOG_A")
    parser.add_argument("--calib-b", metavar="CALIB.json", help="solarnav's calibration of LOG_B")
    parser.add_argument("--tune", action="store_true",
                        help="identify the noise of a log without --calib-* from its innovations")
    parser.add_argument("--no-noise", action="store_true", help="the parameter diff only")
    parser.add_argument("-o", "--output", metavar="DIFF.csv|DIFF.parquet", help="also write the diff table")


def run(args: argparse.Namespace) -> int:
    """Read both logs, print the diff (and the noise tables); 0 on success."""
    logs = [load_flight_log(args.log_a), load_flight_log(args.log_b)]
    table = diff_parameters(logs[0].meta.parameters, logs[1].meta.parameters)
    print(format_diff(table, *logs))
    if not args.no_noise:
        for log, calib_path in zip(logs, (args.calib_a, args.calib_b), strict=True):
            print()
            print(format_noise(log, *_calibration(log, calib_path, args.tune)))
    if args.output is not None:
        from app.commands.replay import checked_table_path  # the replay command's output rule

        print(f"wrote {write_table(table, checked_table_path(args.output, '--output'))}")
    return 0


def _calibration(log: FlightLog, path: str | None, tune: bool):
    """(calibration or None, how it was made or why there is none) of one log."""
    if path is not None:
        from calib.export import read_calibration

        return read_calibration(path), f"from {path}"
    try:
        cal = calibrate_log(log, tune=EXPORT_ESTIMATOR if tune else (),
                            on_compile=lambda message: print(f"{message} ...", file=sys.stderr, flush=True))
    except InputError as exc:  # no segment to calibrate on: the onboard values alone
        return None, f"not calibrated: {exc}; give its CALIB.json with --calib-a/--calib-b"
    return cal, "identified from its innovations" if tune else "calibrated (eq 50-52; --tune identifies)"


def format_diff(table: pd.DataFrame, log_a: FlightLog, log_b: FlightLog) -> str:
    """Counts, then the rows grouped by prefix: ``NAME  a -> b`` (``(absent)`` for a missing side)."""
    counts = table["change"].value_counts()
    lines = [f"parameters: {_describe(log_a)} vs {_describe(log_b)}: {counts.get(CHANGED, 0)} changed, "
             f"{counts.get(ADDED, 0)} added, {counts.get(REMOVED, 0)} removed"]
    for group, rows in table.groupby("group", sort=False):
        lines.append(f"{group}")
        lines += [f"  {name:<18} {_value(a):>12} -> {_value(b)}" + (f" ({change})" if change != CHANGED else "")
                  for name, change, a, b in zip(rows["name"], rows["change"], rows["value_a"], rows["value_b"],
                                                strict=True)]
    return "\n".join(lines)


def format_noise(log: FlightLog, cal, how: str) -> str:
    """The onboard noise parameters of ``log`` next to solarnav's values."""
    table = noise_parameter_table(log, cal)
    lines = [f"onboard {'EKF3' if autopilot_of(log) == 'ardupilot' else 'EKF2'} noise vs solarnav for "
             f"{log.meta.source} ({how}):"]
    lines += [f"  {name:<18} onboard {_value(onboard):>10}  solarnav {_value(value, '-'):>10}"
              + (f"  (x{ratio:.2g})" if math.isfinite(ratio) else "") + (f"  {source}" if source else "")
              for name, onboard, value, ratio, source in table.itertuples(index=False)]
    return "\n".join(lines)


def _describe(log: FlightLog) -> str:
    return f"{log.meta.source} ({log.meta.px4_version or 'unknown firmware'}, {len(log.meta.parameters)} parameters)"


def _value(value: float, absent: str = "(absent)") -> str:
    return absent if math.isnan(value) else f"{value:.6g}"
