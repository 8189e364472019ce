"""``solarnav replay LOG.ulg [--sun SUN.csv] [--device DEV.json] [--calib CALIB.json] [--estimators a,b,c]
[--rate-hz 50] [--heading auto|mag|sun|mag+sun] [--force] [--float32] [--details] -o OUT.parquet|OUT.csv
[--diagnostics DIAG.parquet|DIAG.csv]``:
re-run the estimators on a log and write their states (one row per estimator per output epoch).

A log whose inputs cannot give a trustworthy estimate (IMU too slow or with long gaps, clipping accelerometer) is
refused with the reason (exit status 2) unless ``--force`` is given; then, and for every flagged finding, the
summary and each report carry the warning. When the selected filters are not in numba's cache yet, "compiling the
estimators (first run only) ..." goes to stderr before the replay (:func:`estimators.warmup.prepare_compile`)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from app.commands.sun_options import add_sun_arguments, check_sun_arguments, load_log_with_sun
from estimators.api import DEFAULT_ESTIMATORS, ESTIMATORS, ReplayResult, parse_estimator_names, quality_warnings
from estimators.consistency import turbulence_intensity_m_s
from estimators.inputs.records import AUTO_HEADING, HEADING_SOURCES, resolve_heading
from estimators.warmup import SUN_SOLVER, compile_side_by_side, prepare_compile
from ingest.errors import InputError
from workflows.replay import TABLE_FORMATS, as_float32, replay_log, write_table


def add_parser(subparsers) -> None:
    """Register the ``replay`` sub-parser."""
    parser = subparsers.add_parser("replay", help="re-run the estimators on a log and write their states",
                                   description=__doc__)
    parser.add_argument("log", metavar="LOG.ulg", help="PX4 ULog file")
    add_sun_arguments(parser)
    parser.add_argument("--calib", metavar="CALIB.json", help="noise settings from `solarnav calibrate`")
    parser.add_argument("--estimators", default=",".join(DEFAULT_ESTIMATORS), metavar="A,B,C",
                        help=f"comma-separated subset of {', '.join(ESTIMATORS)} (default: all)")
    parser.add_argument("--rate-hz", type=float, default=50.0, metavar="HZ", help="output rate (default 50 Hz)")
    parser.add_argument("--heading", choices=HEADING_SOURCES, default=AUTO_HEADING,
                        help="absolute heading source (default auto: mag+sun with --sun, else mag; sun needs --sun)")
    parser.add_argument("--force", action="store_true",
                        help="replay even a log whose inputs are refused (every report carries the warning)")
    parser.add_argument("--float32", action="store_true",
                        help="write the states and diagnostics as float32 (about half the file; time_s, lat_deg and "
                             "lon_deg stay float64: float32 would round them to ms and metres)")
    parser.add_argument("--details", action="store_true",
                        help="print every measurement channel behind each estimator's consistency verdict")
    parser.add_argument("-o", "--output", required=True, metavar="OUT.parquet|OUT.csv", help="states file")
    parser.add_argument("--diagnostics", metavar="DIAG.parquet|DIAG.csv",
                        help="also write one row per measurement update (innovation, variance, NIS, accepted)")


def run(args: argparse.Namespace) -> int:
    """Read the inputs, run the estimators, write the files atomically and print a summary; 0 on success."""
    names = parse_estimator_names(args.estimators)
    outputs = [checked_table_path(args.output, "--output")]
    if args.diagnostics is not None:
        outputs.append(checked_table_path(args.diagnostics, "--diagnostics"))
    check_sun_arguments(args)
    calibration = None
    if args.calib is not None:
        from calib.export import read_calibration  # deferred: the calibration stack is slow to import

        calibration = read_calibration(args.calib)
    log = load_log_with_sun(args)
    announce_compile([*names, *([SUN_SOLVER] if "sun" in resolve_heading(args.heading, log.has("sun")) else [])])
    result = replay_log(log, estimators=names, calibration=calibration, heading=args.heading, rate_hz=args.rate_hz,
                        allow_untrusted=args.force)
    narrow = as_float32 if args.float32 else (lambda frame: frame)
    write_table(narrow(result.states), outputs[0])
    if args.diagnostics is not None:
        write_table(narrow(result.diagnostics), outputs[1])
    print(format_summary(result, outputs, details=args.details))
    return 0


def announce_compile(estimators) -> None:
    """Print "compiling the estimators (first run only) ..." to stderr when the filters ``estimators`` would be
    compiled (their numba cache is cold or stale; a stale one is dropped first), then compile them in two processes
    when that is faster (:func:`estimators.warmup.compile_side_by_side`)."""
    message = prepare_compile(estimators)
    if message is not None:
        print(f"{message} ...", file=sys.stderr, flush=True)
        compile_side_by_side(estimators)


def checked_table_path(path: str, option: str) -> Path:
    """``path`` as a table output of ``option``: a known suffix (:data:`workflows.replay.TABLE_FORMATS`) in an
    existing directory, else InputError."""
    out = Path(path)
    if out.suffix.lower() not in TABLE_FORMATS:
        raise InputError(f"must end in {' or '.join(TABLE_FORMATS)}, got {path!r}", field=option)
    if not out.parent.exists():
        raise InputError(f"directory {str(out.parent)!r} does not exist", field=option)
    return out


def format_summary(result: ReplayResult, outputs: list[Path], *, details: bool = False) -> str:
    """The input quality findings first (a refused one replayed with ``--force`` as ``UNTRUSTED INPUT``), then per
    estimator one line (epochs, sensors used, resets, kernel time, turbulence intensity), its consistency verdict
    (with every channel behind it when ``details``), its degradations, the calibrated figures it used or ignored,
    its other warnings and the files written."""
    shown = quality_warnings(result.input_quality)  # once at the top, not again under each estimator
    lines = [f"WARNING: {warning}" for warning in shown]
    for name, report in result.reports.items():
        states = result.states[result.states["estimator"] == name]
        skipped = ", ".join(f"{k} ({v})" for k, v in report.skipped.items()) or "none"
        turbulence = turbulence_intensity_m_s(states)
        lines.append(f"{name}: {len(states)} epochs, used {', '.join(report.used) or 'none'}; skipped {skipped}; "
                     f"{report.resets} resets; {report.timings_s.get('kernel', float('nan')):.2f} s"
                     + (f"; turbulence intensity {turbulence:.2f} m/s" if math.isfinite(turbulence) else ""))
        verdict = report.details["verdict"]
        lines.append(f"  verdict: {verdict['summary']}")
        if details:
            lines += [f"    {c['channel']:<16} {c['verdict']:<20} mean NIS {c['mean_nis']:8.3f} over "
                      f"{c['n_updates']:6d} (lag-1 {c['lag1_autocorrelation']:5.2f}, {c['n_effective']:7.0f} "
                      f"independent; accepted {c['accepted'][0]:.2f}..{c['accepted'][1]:.2f}): {c['reason']}"
                      for c in verdict["channels"]]
        lines += [f"  degraded: {d}" for d in report.degradations]
        lines += [f"  calibration: {item['figure']} [{item['source']}]: {item['use']}"
                  for item in report.details.get("calibration", [])]
        verdict_warning = f"{name}: {verdict['summary']}"
        lines += [f"  WARNING: {w}" for w in report.warnings if w not in shown and w != verdict_warning]
    lines += [f"wrote {p}" for p in outputs]
    return "\n".join(lines)
