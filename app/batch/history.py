"""Per-vehicle calibration history of a fleet: which vehicle flew each log, each sensor's noise and tau over that
vehicle's logs, and a change flag when a sensor's noise departs from the vehicle's own history (a gyro whose noise
doubled: a loose mount or a failing IMU). docs/batch.md, 'Vehicles and noise history'.
"""

from __future__ import annotations

import fnmatch
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from app.batch.task import OK, TAU_COLUMN, noise_column
from calib.calibration import SENSORS
from ingest.errors import InputError

#: A sensor's noise is flagged when its ratio to the median of the vehicle's earlier logs exceeds this (or is
#: below its inverse): noise that grew by 60 % is far outside the log-to-log scatter of one airframe (a few
#: percent on the simulator, ~10-20 % between real flights of one vehicle) and well short of the doubling a loose
#: mount gives.
RATIO_LIMIT = 1.6
#: Sensors whose noise is flagged. The airspeed and GPS figures are tracked but not flagged: they are dominated by
#: the day (the wind over the pitot at rest, the satellite geometry), not by the sensor; the airspeed noise of the
#: simulated flights of one airframe varies by a factor of 4 from flight to flight.
FLAGGED_SENSORS = ("accelerometer", "gyroscope", "magnetometer", "barometer")
#: Earlier logs of a vehicle needed before its logs are judged.
MIN_HISTORY = 2
#: Columns of :func:`noise_history`.
HISTORY_COLUMNS = ("vehicle", "sha256", "name", "utc_start", "order", "figure", "value", "baseline", "ratio",
                   "flagged")


@dataclass(frozen=True)
class VehicleMap:
    """User-supplied vehicle identities: vehicle name -> patterns. A pattern matches a log when it equals the log's
    ``sys_uuid`` or matches (``fnmatch``) its file name or full path.

    Read from a JSON object ``{"vehicle name": ["pattern", ...], ...}`` (:func:`read_vehicle_map`).
    """

    patterns: dict[str, tuple[str, ...]]

    def vehicle(self, file: str, sys_uuid: str | None) -> str | None:
        """The first vehicle one of whose patterns matches, else None."""
        for name, patterns in self.patterns.items():
            for pattern in patterns:
                if pattern == sys_uuid or fnmatch.fnmatch(Path(file).name, pattern) or fnmatch.fnmatch(file, pattern):
                    return name
        return None


def read_vehicle_map(path: str | Path) -> VehicleMap:
    """Read a vehicle mapping file (see :class:`VehicleMap`).

    Raises
    ------
    InputError
        The file cannot be read, is not JSON, or is not an object of lists of strings.
    """
    try:
        data = json.loads(Path(path).read_text())
    except OSError as exc:
        raise InputError(f"cannot read the file ({exc.strerror})", source=str(path)) from exc
    except ValueError as exc:
        raise InputError(f"not JSON ({exc})", source=str(path)) from exc
    if not isinstance(data, dict) or not all(
            isinstance(v, list) and all(isinstance(p, str) for p in v) for v in data.values()):
        raise InputError('expected an object {"vehicle name": ["file pattern or sys_uuid", ...]}', source=str(path))
    return VehicleMap({str(name): tuple(patterns) for name, patterns in data.items()})


def vehicle_names(fleet: pd.DataFrame, vehicles: VehicleMap | None = None) -> pd.Series:
    """The vehicle of every summary row: from ``vehicles``, else the log's ``sys_uuid``, else
    ``"<hardware> (no sys_uuid)"``; empty for a log that could not be read."""
    def name(file: str, sys_uuid, hardware, status: str) -> str:
        mapped = vehicles.vehicle(file, sys_uuid if isinstance(sys_uuid, str) else None) if vehicles else None
        if mapped is not None:
            return mapped
        if isinstance(sys_uuid, str) and sys_uuid:
            return sys_uuid
        return f"{hardware} (no sys_uuid)" if isinstance(hardware, str) and status == OK else ""

    columns = [fleet.get(c, pd.Series(None, index=fleet.index)) for c in ("file", "sys_uuid", "hardware", "status")]
    return pd.Series([name(*values) for values in zip(*columns, strict=True)], index=fleet.index, dtype=object)


def noise_history(fleet: pd.DataFrame, ratio_limit: float = RATIO_LIMIT,
                  min_history: int = MIN_HISTORY) -> pd.DataFrame:
    """Each vehicle's noise figures and tau log after log, with the change flags.

    Parameters
    ----------
    fleet : pandas.DataFrame
        The batch summary (:func:`app.batch.summary.fleet_table`, with ``vehicle``).
    ratio_limit : float
        A sensor is flagged when ``value / baseline`` > ``ratio_limit`` or < ``1 / ratio_limit``.
    min_history : int
        Earlier logs with the figure needed for a baseline.

    Returns
    -------
    pandas.DataFrame
        :data:`HISTORY_COLUMNS`, one row per calibrated log and figure (a sensor of :data:`calib.calibration.SENSORS`
        - its noise sigma as RMS over the axes, in the unit of :func:`app.batch.task.noise_column` - or ``tau``).
        Logs of a vehicle are in order of their UTC start, then file name (``order`` counts them from 0);
        ``baseline`` is the median of the figure over the vehicle's earlier logs (NaN with fewer than
        ``min_history``), ``ratio`` = value / baseline; only :data:`FLAGGED_SENSORS` are flagged.
    """
    figures = {sensor: noise_column(sensor) for sensor in SENSORS if noise_column(sensor) in fleet}
    if TAU_COLUMN in fleet:
        figures[TAU_COLUMN] = TAU_COLUMN
    if not figures or fleet.empty:
        return pd.DataFrame(columns=list(HISTORY_COLUMNS))
    logs = fleet[(fleet["status"] == OK) & (fleet["vehicle"] != "")].drop_duplicates("sha256")
    logs = logs.assign(_utc=pd.to_datetime(logs["utc_start"], utc=True, errors="coerce")).sort_values(
        ["vehicle", "_utc", "name"], na_position="last", kind="stable")
    rows = []
    for vehicle, group in logs.groupby("vehicle", sort=True):
        for figure, column in figures.items():
            values = group[column].to_numpy(dtype=float)
            for k, value in enumerate(values):
                earlier = values[:k][np.isfinite(values[:k])]
                baseline = float(np.median(earlier)) if len(earlier) >= min_history else np.nan
                ratio = value / baseline if np.isfinite(baseline) and baseline > 0 else np.nan
                flagged = bool(figure in FLAGGED_SENSORS and np.isfinite(ratio)
                               and (ratio > ratio_limit or ratio < 1.0 / ratio_limit))
                row = group.iloc[k]
                rows.append((vehicle, row["sha256"], row["name"], row["utc_start"], k, figure, value, baseline,
                             ratio, flagged))
    return pd.DataFrame(rows, columns=list(HISTORY_COLUMNS))


def flagged_sensors(history: pd.DataFrame) -> dict[str, str]:
    """Log SHA-256 -> the comma-separated sensors flagged in it (logs without a flag left out)."""
    if history.empty:
        return {}
    flagged = history[history["flagged"]]
    return {str(sha): ",".join(group["figure"]) for sha, group in flagged.groupby("sha256", sort=False)}
