"""``solarnav calibrate LOG [--start-s A --end-s B | --segment auto] [--cutoff-hz F] [--numtaps N] [--tau X|auto]
[--tau-method likelihood|nis] [--noise sigma|eta] -o CALIB.json [--px4-params OUT.params]``: sensor noise, biases,
Allan figures, R and tau from a flight log, written as CALIB.json (and optionally as PX4 EKF2 parameters).

``--tau auto`` replays the three-stage estimator (whose stage 1 fuses the accelerometer) once per candidate tau
with the calibrated noise, and keeps the tau that maximises the likelihood of its body-y accelerometer innovations
(or brings their mean NIS to 1)."""

from __future__ import annotations

import argparse

import numpy as np

from calib.bias import local_gravity
from calib.calibration import IMU_SENSORS, NOISE_CHOICES, Calibration, FirSettings, calibrate, with_tau
from calib.export import write_calibration
from calib.px4_params import DEFAULT_PREDICT_PERIOD_S, px4_parameters, write_px4_params
from calib.segments import user_segment
from calib.tables import table4
from calib.tau import DEFAULT_TAU, TAU_METHODS, TauSelection, choose_tau, user_tau
from estimators.calibration_replay import tau_replay
from ingest.errors import InputError
from ingest.ulog_reader import load_flight_log


def add_parser(subparsers) -> None:
    """Register the ``calibrate`` sub-parser."""
    parser = subparsers.add_parser("calibrate", help="calibrate sensor noise and bias from a flight log",
                                   description=__doc__)
    parser.add_argument("log", metavar="LOG", help="PX4 ULog file")
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
    parser.add_argument("-o", "--output", required=True, metavar="CALIB.json", help="calibration file to write")
    parser.add_argument("--px4-params", metavar="OUT.params", help="also write EKF2 noise parameters (QGC format)")


def run(args: argparse.Namespace) -> int:
    """Calibrate, write the file(s) and print Table 4 with the segments; 0 on success."""
    tau = _tau(args.tau)
    _check_segment_options(args)
    log = load_flight_log(args.log)
    segment = None if args.start_s is None else user_segment(log, args.start_s, args.end_s)
    cal = calibrate(log, segment=segment, fir=_imu_filter(args), noise=args.noise, tau=tau or DEFAULT_TAU,
                    gravity=local_gravity(log))
    if tau is None:
        cal = with_tau(cal, choose_tau(tau_replay(log, cal), method=args.tau_method))
    try:
        written = [write_calibration(cal, args.output)]
        if args.px4_params:
            predict_us = log.meta.parameters.get("EKF2_PREDICT_US")
            period_s = predict_us / 1e6 if predict_us else DEFAULT_PREDICT_PERIOD_S
            header = (f"EKF2 noise parameters calibrated by solarnav from {cal.source} (sha256 {cal.sha256})\n"
                      f"EKF2 prediction period {period_s * 1e3:g} ms")
            written.append(write_px4_params(px4_parameters(cal, period_s), args.px4_params, header=header))
    except OSError as exc:
        raise InputError(f"cannot write the output ({exc.strerror})", source=exc.filename) from exc
    print(format_summary(cal))
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
