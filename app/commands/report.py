"""``solarnav report LOG [--sun SUN.csv] [--device DEV.json] [--calib CALIB.json] [--tune] [--heading
auto|mag|sun|mag+sun] -o REPORT.html``: one self-contained HTML flight report (works offline): the flight, its
streams and input findings, the calibration (``--calib``, else calibrated from the flight; ``--tune`` identifies the
noise too), each estimator's verdict, the comparison with the truth or the onboard estimate, the track and the
exported autopilot parameters."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.commands.sun_options import add_sun_arguments, load_log_with_sun
from estimators.inputs.records import AUTO_HEADING, HEADING_SOURCES
from ingest.errors import InputError
from ingest.files import atomic_write_text


def add_parser(subparsers) -> None:
    """Register the ``report`` sub-parser."""
    parser = subparsers.add_parser("report", help="one self-contained HTML flight report", description=__doc__)
    parser.add_argument("log", metavar="LOG", help="flight log (.ulg or .bin)")
    add_sun_arguments(parser)
    parser.add_argument("--calib", metavar="CALIB.json", help="use this calibration instead of calibrating")
    parser.add_argument("--tune", action="store_true", help="identify the noise from the flight's innovations")
    parser.add_argument("--heading", choices=HEADING_SOURCES, default=AUTO_HEADING, help="absolute heading source")
    parser.add_argument("-o", "--output", required=True, metavar="REPORT.html", help="the report to write")


def run(args: argparse.Namespace) -> int:
    """Compute, render and write the report atomically; 0 on success."""
    from app.report import render_report  # plotly: only this command needs it
    from workflows.report import flight_report

    output = Path(args.output)
    if output.suffix.lower() not in (".html", ".htm"):
        raise InputError(f"must end in .html, got {args.output!r}", field="--output")
    if not output.parent.exists():
        raise InputError(f"directory {str(output.parent)!r} does not exist", field="--output")
    log = load_log_with_sun(args)
    calibration = None
    if args.calib is not None:
        from calib.export import read_calibration

        calibration = read_calibration(args.calib)
    report = flight_report(log, calibration=calibration, tune=args.tune, heading=args.heading,
                           on_compile=lambda message: print(f"{message} ...", file=sys.stderr, flush=True))
    text = render_report(report)
    atomic_write_text(output, text)
    print(f"wrote {output} ({len(text.encode()) / 1e6:.1f} MB): {report.calibration_note}"
          + (f"; estimators not run: {report.refusal}" if report.refusal else ""))
    return 0
