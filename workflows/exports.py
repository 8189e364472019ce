"""A calibration's files: CALIB.json and the noise parameters of PX4 EKF2 (QGroundControl ``.params``) and
ArduPilot EKF3 (``.parm``), each with a header naming the flight, the prediction period and the figures not
written. One writer for the CLI, the Calibration page and the batch."""

from __future__ import annotations

import os
from pathlib import Path

from calib.calibration import Calibration
from calib.export import calibration_text, write_calibration
from calib.parameter_export import (
    DEFAULT_PREDICT_PERIOD_S,
    EKF3_TARGET_DT_S,
    EXPORT_ESTIMATOR,
    AutopilotParam,
    ardupilot_parameters,
    ardupilot_parm_text,
    export_figures,
    px4_parameters,
    px4_params_text,
    unwritten_notes,
)
from ingest.files import atomic_write_text

__all__ = ["ardupilot_parameter_set", "ardupilot_replay_text", "ardupilot_text", "calibration_text",
           "px4_parameter_set", "px4_replay_text", "px4_text", "write_calibration", "write_calibration_files"]


def _origin(cal: Calibration) -> str:
    """Which flight the figures come from, and which estimator's figures they are."""
    figures = (f"the noise identified for {EXPORT_ESTIMATOR}" if EXPORT_ESTIMATOR in cal.tuning
               else "the calibrated figures (no identification)")
    return f"calibrated by solarnav from {cal.source} (sha256 {cal.sha256}): {figures}"


def _imu_rate_hz(cal: Calibration) -> float | None:
    return cal.sensors["gyroscope"].fir.fs_hz if "gyroscope" in cal.sensors else None


def px4_parameter_set(cal: Calibration, log_parameters: dict) -> tuple[list[AutopilotParam], str]:
    """EKF2 noise parameters of ``cal`` and their file header; the prediction period is the log's
    ``EKF2_PREDICT_US`` (else PX4's default 10 ms)."""
    figures = export_figures(cal)
    predict_us = log_parameters.get("EKF2_PREDICT_US")
    period_s = predict_us / 1e6 if predict_us else DEFAULT_PREDICT_PERIOD_S
    header = "\n".join([f"EKF2 noise parameters {_origin(cal)}", f"EKF2 prediction period {period_s * 1e3:g} ms",
                        *unwritten_notes(figures, "px4")])
    return px4_parameters(figures, period_s, _imu_rate_hz(cal)), header


def px4_text(cal: Calibration, log_parameters: dict) -> str:
    """:func:`px4_parameter_set` as a QGroundControl ``.params`` text."""
    params, header = px4_parameter_set(cal, log_parameters)
    return px4_params_text(params, header=header)


def ardupilot_parameter_set(cal: Calibration, log_parameters: dict) -> tuple[list[AutopilotParam], str]:
    """EKF3 noise parameters of ``cal`` and their file header. An ArduPilot log's loop rate (``SCHED_LOOP_RATE``)
    gives EKF3's step, max(1 / loop rate, 12 ms); a PX4 log says nothing of it: EKF3's target step (12 ms; longer
    below 83 Hz loops, said in the header)."""
    figures = export_figures(cal)
    loop_hz = log_parameters.get("SCHED_LOOP_RATE", 0.0)
    period_s = max(EKF3_TARGET_DT_S, 1.0 / loop_hz) if loop_hz > 0 else EKF3_TARGET_DT_S
    period_note = (f"max(1 / SCHED_LOOP_RATE {loop_hz:g} Hz, EKF_TARGET_DT 12 ms) of the log" if loop_hz > 0
                   else "EKF_TARGET_DT; a loop slower than 83 Hz predicts at its own period: scale the per-step "
                        "values by sqrt(12 ms / period)")
    header = "\n".join([f"EKF3 noise parameters {_origin(cal)}",
                        f"EKF3 prediction period {period_s * 1e3:g} ms ({period_note})",
                        *unwritten_notes(figures, "ardupilot")])
    return ardupilot_parameters(figures, period_s, _imu_rate_hz(cal)), header


def ardupilot_text(cal: Calibration, log_parameters: dict) -> str:
    """:func:`ardupilot_parameter_set` as an ArduPilot ``.parm`` text."""
    params, header = ardupilot_parameter_set(cal, log_parameters)
    return ardupilot_parm_text(params, header=header)


def px4_replay_text(cal: Calibration, log_parameters: dict) -> str:
    """:func:`px4_parameter_set` as PX4's EKF2 replay override file ``replay_params.txt``: ``NAME value`` lines,
    ``#`` comment lines (docs/calibration.md, 'Replaying with the autopilot replay tools')."""
    params, header = px4_parameter_set(cal, log_parameters)
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    lines += ["# PX4 EKF2 replay: copy to build/px4_sitl_default_replay/rootfs/replay_params.txt"]
    lines += [f"{p.name} {p.value!r}" for p in params]
    return "\n".join(lines) + "\n"


def ardupilot_replay_text(cal: Calibration, log_parameters: dict) -> str:
    """:func:`ardupilot_parameter_set` as an ArduPilot Replay ``--param-file``: ``NAME,VALUE`` lines, ``#``
    comment lines (docs/calibration.md, 'Replaying with the autopilot replay tools')."""
    params, header = ardupilot_parameter_set(cal, log_parameters)
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    lines += ["# ArduPilot Replay: build/sitl/tool/Replay --param-file THIS_FILE LOG.bin"]
    lines += [f"{p.name},{p.value!r}" for p in params]
    return "\n".join(lines) + "\n"


def write_calibration_files(cal: Calibration, log_parameters: dict, calib_path: str | os.PathLike | None = None, *,
                            px4_path: str | os.PathLike | None = None,
                            ardupilot_path: str | os.PathLike | None = None,
                            px4_replay_path: str | os.PathLike | None = None,
                            ardupilot_replay_path: str | os.PathLike | None = None) -> list[Path]:
    """Write CALIB.json and the requested autopilot parameter files (``.params``, ``.parm`` and the replay tools'
    override files), each atomically; returns the paths written.

    Raises
    ------
    OSError
        A file cannot be written (those written before it stay complete).
    """
    written = [] if calib_path is None else [write_calibration(cal, calib_path)]
    if px4_path is not None:
        written.append(atomic_write_text(px4_path, px4_text(cal, log_parameters)))
    if ardupilot_path is not None:
        written.append(atomic_write_text(ardupilot_path, ardupilot_text(cal, log_parameters)))
    if px4_replay_path is not None:
        written.append(atomic_write_text(px4_replay_path, px4_replay_text(cal, log_parameters)))
    if ardupilot_replay_path is not None:
        written.append(atomic_write_text(ardupilot_replay_path, ardupilot_replay_text(cal, log_parameters)))
    return written
