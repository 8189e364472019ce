"""The batch summary: one row per log and estimator (``fleet.parquet`` and ``fleet.csv``) and the per-vehicle
noise history (``history.parquet`` / ``.csv``) in OUTDIR, written atomically (docs/batch.md, 'Summary table').
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from app.batch.history import VehicleMap, flagged_sensors, noise_history, vehicle_names
from ingest.errors import InputError
from workflows.replay import write_table

FLEET_FILE, FLEET_CSV, HISTORY_FILE, HISTORY_CSV = "fleet.parquet", "fleet.csv", "history.parquet", "history.csv"
#: Batch output directories of a workspace, listed by the Fleet page: ``<workspace>/batches/<name>/``.
BATCHES_DIR = "batches"
#: Columns leading the summary (the calibrated noise, tau, RMS and NIS columns follow, then the rest).
LEADING_COLUMNS = ("file", "name", "sha256", "vehicle", "sys_uuid", "hardware", "mav_type", "firmware", "utc_start",
                   "duration_s", "streams", "estimator", "status", "message", "noise_flags")
#: Prefixes of the figure columns, in their order after :data:`LEADING_COLUMNS`.
FIGURE_PREFIXES = ("noise_", "tau", "rms_", "nis_", "resets")


def fleet_table(rows: list[dict], vehicles: VehicleMap | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The summary of a batch from its tasks' rows, and the noise history.

    Parameters
    ----------
    rows : list of dict
        Rows of :func:`app.batch.task.process_log` (and the client's error rows), in input order.
    vehicles : VehicleMap, optional
        User-supplied vehicle identities.

    Returns
    -------
    fleet : pandas.DataFrame
        :data:`LEADING_COLUMNS` (``vehicle`` from :func:`app.batch.history.vehicle_names`, ``noise_flags`` the
        sensors flagged in the log), the figures, then the remaining columns (warnings, wall time, worker ...).
    history : pandas.DataFrame
        :func:`app.batch.history.noise_history` of ``fleet``.
    """
    fleet = pd.DataFrame(rows)
    fleet["vehicle"] = vehicle_names(fleet, vehicles)
    history = noise_history(fleet)
    flags = flagged_sensors(history)
    fleet["noise_flags"] = [flags.get(sha, "") if isinstance(sha, str) else "" for sha in fleet.get("sha256", [])]
    for column in LEADING_COLUMNS:
        if column not in fleet:
            fleet[column] = None
    figures = [c for prefix in FIGURE_PREFIXES for c in fleet.columns
               if c.startswith(prefix) and c not in LEADING_COLUMNS]
    rest = [c for c in fleet.columns if c not in LEADING_COLUMNS and c not in figures]
    return fleet[[*LEADING_COLUMNS, *dict.fromkeys(figures), *rest]], history


def write_summary(fleet: pd.DataFrame, history: pd.DataFrame, outdir: str | Path) -> list[Path]:
    """Write the summary and the history as Parquet and CSV into ``outdir`` (each atomically); returns the paths."""
    outdir = Path(outdir)
    return [write_table(fleet, outdir / FLEET_FILE), write_table(fleet, outdir / FLEET_CSV),
            write_table(history, outdir / HISTORY_FILE), write_table(history, outdir / HISTORY_CSV)]


def read_summary(outdir: str | Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The summary and history a batch wrote into ``outdir``.

    Raises
    ------
    InputError
        ``outdir`` holds no ``fleet.parquet`` / ``history.parquet`` (not a batch output directory).
    """
    outdir = Path(outdir)
    if not (outdir / FLEET_FILE).is_file() or not (outdir / HISTORY_FILE).is_file():
        raise InputError(f"no {FLEET_FILE} and {HISTORY_FILE} here: not the output directory of `solarnav batch`",
                         source=str(outdir))
    return pd.read_parquet(outdir / FLEET_FILE), pd.read_parquet(outdir / HISTORY_FILE)
