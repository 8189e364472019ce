"""The work of ``solarnav batch`` on one log, run on a Dask worker: read the files, calibrate and replay with the
code paths of ``solarnav calibrate`` / ``replay``, write the outputs beside each other atomically, and return the
log's summary rows (small dicts; only they travel back to the client). docs/batch.md, 'One task per log'.

A log whose outputs exist for the same content SHA-256 and settings hash is not processed again: its stored rows
come back with ``resumed`` set. Bad input (:class:`~ingest.errors.InputError`) gives one error row; any other
exception propagates, so that Dask retries the task once and the client then records the error.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import time
from pathlib import Path

import numpy as np
import pandas as pd

from app.batch.plan import BatchSettings, LogInput, log_output_dir
from app.loading import load_log
from calib.calibration import SENSORS, Calibration
from calib.export import read_calibration
from calib.tables import noise_table
from estimators.api import ReplayResult
from estimators.evaluation import REFERENCE_STREAMS, evaluate
from ingest.errors import InputError
from ingest.files import atomic_write_text
from ingest.flightlog import FlightLog
from ingest.sources import read_content
from workflows.calibration import calibrate_log
from workflows.exports import write_calibration
from workflows.replay import replay_log, write_table

#: Files of a log's output directory; :data:`ROWS_FILE` is written last and marks the log as done.
CALIB_FILE, STATES_FILE, DIAGNOSTICS_FILE, PARAMS_FILE, ROWS_FILE = (
    "calib.json", "states.parquet", "diagnostics.parquet", "params.json", "rows.json")
OK, ERROR = "ok", "error"
#: Summary column of the calibration's eq 52 penalty factor.
TAU_COLUMN = "tau"


def process_log(item: LogInput, settings: BatchSettings, outdir: str) -> list[dict]:
    """Process one log (or return its stored rows) and return one summary row per estimator (one row without
    ``settings.replay``).

    Parameters
    ----------
    item : LogInput
        The log and its sun-device companions (paths the worker can open).
    settings : BatchSettings
        What to do.
    outdir : str
        The batch's output directory (``logs/`` below it must exist); the log's directory is
        :func:`app.batch.plan.log_output_dir`.

    Returns
    -------
    list of dict
        Summary rows (:mod:`app.batch.summary` lists the columns): status :data:`OK` (with a message when the
        log could not be calibrated: no segment found; the replay then uses the default noise, as ``replay``
        without ``--calib``), or one row with status :data:`ERROR` and the one-line message of the
        :class:`~ingest.errors.InputError`.
    """
    started = time.perf_counter()
    settings_hash, sha256, base = settings.digest(), None, {}
    try:
        content, name = read_content(item.path)
        sha256 = hashlib.sha256(content).hexdigest()
        directory = log_output_dir(outdir, sha256, item.path)
        stored = _stored_rows(directory / ROWS_FILE, sha256, settings_hash)
        if stored is not None:
            return stored
        log = load_log(content, item.sun_csv, item.device_json, name=name)
        directory.mkdir(exist_ok=True)
        base = {**_identity(item, sha256, settings_hash, directory, outdir), **log_columns(log)}
        atomic_write_text(directory / PARAMS_FILE, json.dumps(log.meta.parameters, sort_keys=True, indent=1))
        calibration, message = None, ""
        if settings.calibrate:
            try:
                cal = calibrate_log(log, tune=settings.estimators if settings.tune else (),
                                    tune_budget=settings.tune_budget)
            except InputError as exc:  # (no segment to calibrate on): the replay still runs, as `replay` would
                message = f"not calibrated{' (replayed with the default noise)' if settings.replay else ''}: " \
                    + one_line(exc)
            else:
                write_calibration(cal, directory / CALIB_FILE)
                calibration = read_calibration(directory / CALIB_FILE)  # what `replay --calib` would read
                base.update(calibration_columns(calibration))
        rows = [base]
        if settings.replay:
            result = replay_log(log, estimators=settings.estimators, calibration=calibration,
                                heading=settings.heading, rate_hz=settings.rate_hz, allow_untrusted=settings.force)
            write_table(result.states, directory / STATES_FILE)
            write_table(result.diagnostics, directory / DIAGNOSTICS_FILE)
            rms = reference_rms(result.states, log)
            rows = [{**base, **estimator_columns(name, result, rms.get(name, {}))} for name in result.reports]
        wall_s = time.perf_counter() - started
        rows = [{**row, "status": OK, "message": message, "wall_s": wall_s, "worker": _worker()} for row in rows]
        atomic_write_text(directory / ROWS_FILE, json.dumps(
            {"sha256": sha256, "settings_hash": settings_hash, "rows": rows}, indent=1))
        return [{**row, "resumed": False} for row in rows]
    except InputError as exc:  # (with what is known of the log when it was read)
        return [{**base, **error_row(item, one_line(exc), sha256=sha256, settings_hash=settings_hash,
                                     wall_s=time.perf_counter() - started)}]


def error_row(item: LogInput, message: str, *, sha256: str | None = None, settings_hash: str = "",
              wall_s: float = float("nan")) -> dict:
    """The one summary row of a log that failed."""
    return {"file": item.path, "name": Path(item.path).name, "sha256": sha256, "settings_hash": settings_hash,
            "status": ERROR, "message": message, "wall_s": wall_s, "worker": _worker(), "resumed": False}


def one_line(exc: BaseException) -> str:
    """The exception's message on one line (an InputError's text, else ``Type: text``)."""
    text = " ".join(str(exc).split())
    return text if isinstance(exc, InputError) else f"{type(exc).__name__}: {text}".rstrip(": ")


def log_columns(log: FlightLog) -> dict:
    """Vehicle, firmware, UTC start, duration, streams and the reader's warnings of a log."""
    meta = log.meta
    return {"sys_uuid": meta.sys_uuid, "hardware": meta.hardware, "mav_type": meta.vehicle_type,
            "firmware": meta.px4_version,
            "utc_start": log.utc(meta.start_time_s)[0].isoformat() if meta.utc_offset_s is not None else None,
            "duration_s": meta.duration_s, "streams": ",".join(sorted(log.streams)),
            "log_warnings": " | ".join(meta.warnings), "n_log_warnings": len(meta.warnings)}


def calibration_columns(cal: Calibration) -> dict:
    """Per calibrated sensor and axis the per-sample noise sigma (``noise_<sensor>_<axis>_<unit>``), per sensor
    the RMS over its axes (``noise_<sensor>_<unit>``, what the history tracks), and tau."""
    table = noise_table(cal).reset_index()
    columns = {}
    for sensor, group in table.groupby("sensor", sort=False):
        for axis, sigma in zip(group["axis"], group["sigma"], strict=True):
            columns[noise_column(sensor, axis)] = float(sigma)
        columns[noise_column(sensor)] = float(np.sqrt(np.mean(np.square(group["sigma"].to_numpy(float)))))
    return {**columns, TAU_COLUMN: float(cal.tau.tau)}


def noise_column(sensor: str, axis: str | None = None) -> str:
    """Summary column of a sensor's noise sigma (one axis, or the RMS over its axes), named with its unit
    (``noise_gyroscope_x_rad_s``, ``noise_gyroscope_rad_s``)."""
    unit = SENSORS[sensor].unit.replace("/", "_").replace("^", "")
    return f"noise_{sensor}_{axis}_{unit}" if axis is not None else f"noise_{sensor}_{unit}"


def reference_rms(states: pd.DataFrame, log: FlightLog) -> dict[str, dict[str, float]]:
    """Per estimator, the RMS error of every Table-2 quantity against each reference the log has
    (``rms_truth_<quantity>``, ``rms_onboard_<quantity>``), by the one evaluator
    (:func:`estimators.evaluation.evaluate`, as the dashboard shows them)."""
    out: dict[str, dict[str, float]] = {}
    for source in REFERENCE_STREAMS:
        evaluation = evaluate(states, log, reference=source)
        if evaluation.reference is None:
            continue
        for name, row in evaluation.rms().iterrows():
            out.setdefault(str(name), {}).update({f"rms_{source}_{quantity}": float(value)
                                                  for quantity, value in row.items()})
    return out


def estimator_columns(name: str, result: ReplayResult, rms: dict[str, float]) -> dict:
    """One estimator's part of a summary row: RMS figures, mean NIS per channel (``nis_<sensor>.<component>``),
    resets and warnings."""
    report = result.reports[name]
    nis = {f"nis_{c['channel']}": float(c["mean_nis"]) for c in report.details.get("consistency", [])}
    return {"estimator": name, **rms, **nis, "resets": int(report.resets), "warnings": " | ".join(report.warnings),
            "n_warnings": len(report.warnings)}


def _identity(item: LogInput, sha256: str, settings_hash: str, directory: Path, outdir: str) -> dict:
    return {"file": item.path, "name": Path(item.path).name, "sha256": sha256, "settings_hash": settings_hash,
            "output_dir": str(directory.relative_to(outdir)), "sun_csv": item.sun_csv,
            "device_json": item.device_json}


def _stored_rows(path: Path, sha256: str, settings_hash: str) -> list[dict] | None:
    """The rows of a finished earlier run of the same content with the same settings, else None."""
    try:
        stored = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if stored.get("sha256") != sha256 or stored.get("settings_hash") != settings_hash:
        return None
    return [{**row, "resumed": True} for row in stored["rows"]]


def _worker() -> str:
    """``host:pid`` of the process running the task."""
    return f"{socket.gethostname()}:{os.getpid()}"
