"""``solarnav sun LOG.ulg --sun SUN.csv [--device DEV.json] [--sun-time-offset-s SECONDS] -o OUT.parquet|OUT.csv``:
solve the photocell sun vector of every sample and compare it with the sun the attitude references predict."""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import pandas as pd

from app.commands.replay import checked_table_path
from estimators.sun.prediction import ATTITUDE_STREAMS, sun_vector_table, usable_sun
from ingest.log_formats import load_flight_log
from ingest.sun_log import load_sun_device, with_sun
from workflows.replay import write_table


def add_parser(subparsers) -> None:
    """Register the ``sun`` sub-parser."""
    parser = subparsers.add_parser("sun", help="solve the photocell sun vector and compare it with the attitude",
                                   description=__doc__)
    parser.add_argument("log", metavar="LOG.ulg", help="PX4 ULog file")
    parser.add_argument("--sun", required=True, metavar="SUN.csv", help="sun-device CSV (photocell currents)")
    parser.add_argument("--device", metavar="DEV.json", help="sun-device geometry (tilt, azimuths, mounting)")
    parser.add_argument("--sun-time-offset-s", type=float, metavar="SECONDS",
                        help="UTC unix time of log time 0, for logs without GPS time (log time = unix time - "
                             "offset); also dates the ephemeris of such logs")
    parser.add_argument("-o", "--output", required=True, metavar="OUT.parquet|OUT.csv",
                        help="one row per photocell sample: solved and predicted sun vectors")


def run(args: argparse.Namespace) -> int:
    """Solve, compare, write the table atomically and print a summary; 0 on success."""
    output = checked_table_path(args.output, "--output")
    log = load_flight_log(args.log)
    if log.meta.utc_offset_s is None and args.sun_time_offset_s is not None:
        log = dataclasses.replace(log, meta=dataclasses.replace(log.meta, utc_offset_s=args.sun_time_offset_s))
    device = load_sun_device(args.device) if args.device is not None else None
    log = with_sun(log, args.sun, device=device, time_offset_s=args.sun_time_offset_s)
    table = sun_vector_table(log)
    write_table(table, output)
    for warning in log.meta.warnings:  # e.g. a sun CSV whose cut-off last line was dropped
        print(f"WARNING: {warning}")
    print(format_summary(table, output))
    return 0


def format_summary(table: pd.DataFrame, output) -> str:
    """Samples solved, cells found faulty, the solver's up-vector reference and the angle to each prediction."""
    n = len(table)
    solved = table["status"].to_numpy() == "ok"
    usable = usable_sun(table)
    faulty = table["faulty_cells"].to_numpy(dtype=np.int64)
    lines = [f"{n} photocell samples: {int(solved.sum())} solved ({100.0 * solved.mean() if n else 0.0:.1f} %), "
             f"{int(usable.sum())} with the sun above the estimators' elevation limit",
             f"faulty cells excluded in {int((faulty > 0).sum())} samples"
             + (f" (cells {', '.join(str(c + 1) for c in range(7) if np.any(faulty & (1 << c)))})"
                if np.any(faulty) else ""),
             f"sky-light model up vector: {table.attrs.get('up_reference', 'level')} attitude"]
    for name in ATTITUDE_STREAMS:
        angle = table[f"angle_{name}_deg"].to_numpy(dtype=float)[usable]
        angle = angle[np.isfinite(angle)]
        if len(angle):
            p50, p95 = np.percentile(angle, [50, 95])
            lines.append(f"angle to the sun predicted from the {name} attitude: median {p50:.2f} deg, "
                         f"95 % {p95:.2f} deg ({len(angle)} samples)")
        else:
            lines.append(f"no prediction from the {name} attitude (no such attitude, UTC time or GPS fix)")
    lines.append(f"wrote {output}")
    return "\n".join(lines)
