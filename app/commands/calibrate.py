"""``solarnav calibrate LOG [--sun SUN.csv [--device DEV.json]] [--start-s A --end-s B | --segment auto] [--cutoff-hz F]
[--numtaps N] [--tau X|auto] [--tau-method likelihood|nis] [--noise sigma|eta] [--tune [--tune-budget N]
[--estimators a,b,c]] -o CALIB.json [--px4-params OUT.params] [--ardupilot-parm OUT.parm] [--px4-replay-params
replay_params.txt] [--ardupilot-replay-params OUT.param]``: sensor noise, biases, Allan figures, R and tau from a
flight log, the filter figures they give (each with its source), optionally the noise identified per estimator from
the flight's own innovations, written as CALIB.json (and optionally as PX4 EKF2 and ArduPilot EKF3 noise parameters).

``--tau auto`` replays the three-stage estimator (whose stage 1 fuses the accelerometer) once per candidate tau
with the calibrated noise, and keeps the tau that maximises the likelihood of its body-y accelerometer innovations
(or brings their mean NIS to 1). With GPS, the error-state filter is replayed once with the calibrated noise and its
final gyro and accelerometer bias states become the in-flight bias (the three-stage estimator, which has no bias
states, gets them removed from its inputs). ``--tune`` maximises each estimator's innovation log-likelihood over its
noise figures (docs/calibration.md, 'Noise identification'). Before the first replay of a filter whose numba
cache is cold, "compiling the estimators (first run only) ..." goes to stderr."""

from __future__ import annotations

import argparse
import sys

import numpy as np

from app.commands.sun_options import add_sun_arguments, load_log_with_sun
from calib.calibration import IMU_SENSORS, NOISE_CHOICES, Calibration, FirSettings
from calib.segments import user_segment
from calib.tables import table4
from calib.tau import DEFAULT_TAU, TAU_METHODS, TauSelection, user_tau
from estimators.api import DEFAULT_ESTIMATORS, parse_estimator_names
from estimators.tuning import DEFAULT_BUDGET
from ingest.errors import InputError
from workflows.calibration import calibrate_log
from workflows.exports import write_calibration_files


def add_parser(subparsers) -> None:
    """Register the ``calibrate`` sub-parser."""
    parser = subparsers.add_parser("calibrate", help="calibrate sensor noise and bias from a flight log",
                                   description=__doc__)
    parser.add_argument("log", metavar="LOG", help="PX4 ULog file")
    add_sun_arguments(parser)
    parser.add_argument("--start-s", type=float, metavar="A", help="segment start on the log clock [s]")
    parser.add_argument("--end-s", type=float, metavar="B", help="segment end on the log clock [s]")
    parser.add_argument("--segment", choices=["auto"],
                        help="find stationary / steady segments per sensor (the default without --start-s/--end-s)")
    parser.add_argument("--cutoff-hz", type=float, metavar="F",
                        help="FIR cutoff for the IMU [Hz] (default 5 fixed-wing, 15 otherwise; other sensors use "
                             "defaults for their rate)")
    parser.add_argument("--numtaps", type=int, metavar="N", help="odd FIR length for the IMU (default from the rate)")
    parser.add_argument("--tau", metavar="X|auto",
                        help="eq 52 penalty on the accelerometer's y variance: a number, or 'auto' (chosen by "
                             "replaying the estimator; default 1)")
    parser.add_argument("--tau-method", choices=TAU_METHODS, default="likelihood",
                        help="criterion of --tau auto: innovation likelihood (default) or mean NIS = 1")
    parser.add_argument("--noise", choices=NOISE_CHOICES, default="sigma",
                        help="figure R is built from: residual sigma (default) or the paper's eq 50 eta")
    parser.add_argument("--tune", action="store_true",
                        help="identify each estimator's noise from the flight's innovations (maximum likelihood)")
    parser.add_argument("--tune-budget", type=int, default=DEFAULT_BUDGET, metavar="N",
                        help=f"filter replays per estimator for --tune (default {DEFAULT_BUDGET})")
    parser.add_argument("--estimators", default=",".join(DEFAULT_ESTIMATORS), metavar="A,B,C",
                        help="estimators --tune identifies noise for (default: all)")
    parser.add_argument("-o", "--output", required=True, metavar="CALIB.json", help="calibration file to write")
    parser.add_argument("--px4-params", metavar="OUT.params", help="also write EKF2 noise parameters (QGC format)")
    parser.add_argument("--ardupilot-parm", metavar="OUT.parm",
                        help="also write ArduPilot EKF3 noise parameters (.parm, 'NAME VALUE' lines)")
    parser.add_argument("--px4-replay-params", metavar="replay_params.txt",
                        help="also write the EKF2 noise as PX4 ekf2 replay's override file ('NAME value' lines)")
    parser.add_argument("--ardupilot-replay-params", metavar="OUT.param",
                        help="also write the EKF3 noise as ArduPilot Replay's --param-file ('NAME,VALUE' lines)")


def run(args: argparse.Namespace) -> int:
    """Calibrate, write the file(s) and print Table 4 with the segments; 0 on success."""
    tau = _tau(args.tau)
    _check_segment_options(args)
    if args.tune and args.tune_budget < 2:
        raise InputError(f"must be at least 2 replays, got {args.tune_budget}", field="--tune-budget")
    log = load_log_with_sun(args)  # the sun heads the replays of tau, in-flight bias and identification
    segment = None if args.start_s is None else user_segment(log, args.start_s, args.end_s)
    cal = calibrate_log(log, segment=segment, fir=_imu_filter(args), noise=args.noise, tau=tau,
                        tau_method=args.tau_method,
                        tune=parse_estimator_names(args.estimators) if args.tune else (), tune_budget=args.tune_budget,
                        on_compile=lambda message: print(f"{message} ...", file=sys.stderr, flush=True))
    try:
        written = write_calibration_files(cal, log.meta.parameters, args.output, px4_path=args.px4_params,
                                          ardupilot_path=args.ardupilot_parm, px4_replay_path=args.px4_replay_params,
                                          ardupilot_replay_path=args.ardupilot_replay_params)
    except OSError as exc:
        raise InputError(f"cannot write the output ({exc.strerror})", source=exc.filename) from exc
    print(format_summary(cal))
    if cal.tuning:
        print(format_tuning(cal))
    for path in written:
        print(f"wrote {path}")
    return 0


def format_summary(cal: Calibration) -> str:
    """Segments per sensor, the Table-4 layout, R diagonals, bias and warnings as text."""
    lines = [f"{cal.source}: noise '{cal.noise}', tau {cal.tau.tau:.3g} ({cal.tau.method})"]
    if cal.tau.log10_tau_grid:
        lines.append(f"  tau curve over log10 tau {cal.tau.log10_tau_grid[0]:g} .. {cal.tau.log10_tau_grid[-1]:g}: "
                     f"mean NIS at tau {cal.tau.nis_at_tau:.3g} (95 % band {cal.tau.nis_band[0]:.3g} .. "
                     f"{cal.tau.nis_band[1]:.3g}), lag-1 autocorrelation {cal.tau.lag1_autocorrelation:.2f}"
                     + (f"; {cal.tau.note}" if cal.tau.note else ""))
    lines += ["", "segments:"]
    for name, s in cal.sensors.items():
        lines.append(f"  {name:<14} {s.segment.start_s:.2f} .. {s.segment.end_s:.2f} s ({s.segment.kind}), "
                     f"{s.fir.fs_hz:.1f} Hz, FIR {s.fir.cutoff_hz:.3g} Hz / {s.fir.numtaps} taps")
    reasons = dict.fromkeys(s.segment.reason for s in cal.sensors.values())
    lines += [f"  why: {reason}" for reason in reasons]
    lines += ["", "Table 4 (accelerometer m/s^2, gyroscope deg/s):", table4(cal).to_string(float_format="%.4g"),
              "", "eq 51 R diagonals:"]
    for name in cal.r:
        unit = cal.sensors[name].unit if name in cal.sensors else ""
        diagonal = ", ".join(f"{v:.3g}" for v in np.diag(cal.r_matrix(name)))
        lines.append(f"  {name:<14} [{diagonal}] ({unit})^2")
    bias = cal.stationary_bias
    if bias is not None:
        lines += ["", f"stationary gyro bias [rad/s]: {', '.join(f'{v:.3g}' for v in bias.gyro_bias_rad_s)}",
                  f"accelerometer bias along gravity: {bias.accel_bias_parallel_m_s2:.3g} m/s^2 (g = "
                  f"{bias.gravity.value_m_s2:.5f}, {bias.gravity.source}); horizontal components not identifiable "
                  "from one orientation"]
    notes = list(cal.warnings) + [f"{name}: {w}" for name, s in cal.sensors.items() for w in s.warnings]
    if notes:
        lines += ["", "warnings:", *(f"  - {note}" for note in notes)]
    return "\n".join(lines)


def format_tuning(cal: Calibration) -> str:
    """Per tuned estimator: likelihood start -> end, replays, wall time, each figure start -> tuned, and the mean
    NIS per channel before and after with its 95 % band."""
    lines = ["", "noise identified from the flight's innovations (--tune):"]
    for name, result in cal.tuning.items():
        trace = result.log_likelihood_trace
        lines.append(f"  {name}: log-likelihood {trace[0]:.6g} -> {trace[-1]:.6g} in {result.n_replays} replays, "
                     f"{result.wall_s:.1f} s")
        for figure, start in result.start.items():
            tuned = result.figures[figure]
            low, high = result.bounds[figure]
            lines.append(f"    {figure:<22} {start:10.4g} -> {tuned.value:10.4g} {tuned.unit:<16} "
                         f"(bounds {low:g}..{high:g})")
        after = {c.channel: c for c in result.nis_after}
        lines.append("    mean NIS per channel before -> after (95 % chi-square band):")
        for before in result.nis_before:
            now = after.get(before.channel)
            if now is not None:
                lines.append(f"      {before.channel:<16} {before.mean_nis:8.3f} -> {now.mean_nis:8.3f} "
                             f"({now.band[0]:.3f}..{now.band[1]:.3f}, {now.n_updates} updates)")
        lines += [f"    note: {note}" for note in result.notes]
    return "\n".join(lines)


def _check_segment_options(args: argparse.Namespace) -> None:
    """A window needs both bounds and excludes ``--segment auto``."""
    given = (args.start_s is not None, args.end_s is not None)
    if any(given) and args.segment == "auto":
        raise InputError("give either --start-s/--end-s or --segment auto, not both", field="--segment")
    if any(given) and not all(given):
        raise InputError("--start-s and --end-s go together", field="--start-s/--end-s")


def _imu_filter(args: argparse.Namespace) -> dict[str, FirSettings]:
    settings = FirSettings(cutoff_hz=args.cutoff_hz, numtaps=args.numtaps)
    return dict.fromkeys(IMU_SENSORS, settings)


def _tau(text: str | None) -> TauSelection | None:
    """The user's tau, the default (no option) or None for ``auto``."""
    if text is None:
        return DEFAULT_TAU
    if text.strip().lower() == "auto":
        return None
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"expected a positive number or 'auto', got {text!r}", field="--tau") from None
    return user_tau(value)
