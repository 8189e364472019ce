"""Replaying the estimators on a log with a calibration, and writing their tables: what ``solarnav replay``, the
Estimators page and ``solarnav batch --replay`` run."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import pyarrow
import pyarrow.csv

from estimators.api import DEFAULT_ESTIMATORS, ReplayResult, parse_estimator_names, run_estimators
from estimators.config import EstimatorConfig, config_from_calibration
from estimators.inputs.records import AUTO_HEADING
from ingest.files import atomic_write
from ingest.flightlog import FlightLog

if TYPE_CHECKING:  # the calibration stack is slow to import: `solarnav replay` without --calib never needs it
    from calib.calibration import Calibration

#: Table formats by file suffix.
TABLE_FORMATS = (".parquet", ".csv")
#: Columns :func:`as_float32` keeps in float64: the log clock (float32 steps reach 8 ms at 1e5 s) and the geodetic
#: angles (float32 steps of 8e-6 deg are nearly a metre).
FLOAT64_COLUMNS = frozenset({"time_s", "lat_deg", "lon_deg"})


def estimator_configs(calibration: Calibration | None,
                      estimators: Sequence[str]) -> dict[str, EstimatorConfig] | None:
    """Each estimator's settings from ``calibration`` (its own identified noise where the calibration has one,
    :func:`estimators.config.config_from_calibration`); None without a calibration (the built-in noise)."""
    if calibration is None:
        return None
    return {name: config_from_calibration(calibration, estimator=name) for name in estimators}


def replay_log(log: FlightLog, *, estimators: str | Sequence[str] = DEFAULT_ESTIMATORS,
               calibration: Calibration | None = None, heading: str = AUTO_HEADING, rate_hz: float = 50.0,
               allow_untrusted: bool = False,
               progress: Callable[[str, str], None] | None = None) -> ReplayResult:
    """Run ``estimators`` on ``log`` with the noise of ``calibration`` (None: the built-in noise).

    ``heading``, ``rate_hz``, ``allow_untrusted`` and ``progress`` as :func:`estimators.api.run_estimators`.

    Raises
    ------
    InputError
        Unknown estimator or heading, or the log's inputs are refused and ``allow_untrusted`` is False.
    """
    names = parse_estimator_names(estimators)
    return run_estimators(log, estimators=names, config=EstimatorConfig(),
                          configs=estimator_configs(calibration, names), heading=heading, rate_hz=rate_hz,
                          allow_untrusted=allow_untrusted, progress=progress)


def as_float32(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with its float64 columns as float32, except :data:`FLOAT64_COLUMNS` (other columns shared, not
    copied)."""
    narrowed = {name: frame[name].astype(np.float32) for name, dtype in frame.dtypes.items()
                if dtype == np.float64 and name not in FLOAT64_COLUMNS}
    return frame.assign(**narrowed) if narrowed else frame


def write_table(frame: pd.DataFrame, path: str | Path) -> Path:
    """Write ``frame`` as Parquet or CSV (by suffix, :data:`TABLE_FORMATS`) atomically
    (:func:`ingest.files.atomic_write`).

    Parquet dictionary-encodes only the categorical columns (tried on every float column, it costs time and saves
    nothing). CSV is written by Arrow, ten times faster than pandas on long float tables: numbers in their shortest
    round-trip form (``20`` for 20.0), strings quoted, missing values empty, booleans ``true``/``false``.
    """
    path = Path(path)

    def write(temp: Path) -> None:
        if path.suffix.lower() == ".parquet":
            categorical = [name for name, dtype in frame.dtypes.items() if isinstance(dtype, pd.CategoricalDtype)]
            frame.to_parquet(temp, index=False, use_dictionary=categorical)
        else:
            pyarrow.csv.write_csv(pyarrow.Table.from_pandas(frame, preserve_index=False), temp)

    return atomic_write(path, write)
