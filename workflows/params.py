"""Autopilot parameters between flights: what changed from one log to another (as Flight Review's parameter diff
and ArduPilot's ``mavparmdiff``), grouped by prefix, and the onboard estimator's noise parameters of a flight next
to the values solarnav calibrated or identified for the same flight (docs/workflows.md, 'Parameter diff')."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from calib.calibration import Calibration
from calib.parameter_export import MAPPING
from ingest.flightlog import FlightLog
from workflows.exports import ardupilot_parameter_set, px4_parameter_set

#: Columns of :func:`diff_parameters`.
DIFF_COLUMNS = ("group", "name", "change", "value_a", "value_b")
#: Columns of :func:`noise_parameter_table`.
NOISE_COLUMNS = ("name", "onboard", "solarnav", "ratio", "figure source")
CHANGED, ADDED, REMOVED = "changed", "added", "removed"


def parameter_group(name: str) -> str:
    """The group of a parameter: its prefix up to and with the first underscore (``EKF2_``, ``EK3_``, ``SENS_``,
    ``CAL_``, ...), the whole name without one."""
    prefix, separator, _ = name.partition("_")
    return f"{prefix}_" if separator else name


def _same(a: float, b: float) -> bool:
    # parameters are stored as float32 (PX4) or float (ArduPilot): compare at float32 precision
    return bool(np.float32(a) == np.float32(b)) or (math.isnan(a) and math.isnan(b))


def diff_parameters(a: dict[str, float], b: dict[str, float]) -> pd.DataFrame:
    """The parameters that differ between two flights: :data:`DIFF_COLUMNS`, one row per parameter that changed
    (values unequal at float32 precision), was added (only in ``b``) or removed (only in ``a``); sorted by group,
    then name. ``value_a`` / ``value_b`` NaN where the parameter is absent."""
    rows = []
    for name in sorted(set(a) | set(b)):
        if name in a and name in b:
            if _same(float(a[name]), float(b[name])):
                continue
            change = CHANGED
        else:
            change = ADDED if name in b else REMOVED
        rows.append((parameter_group(name), name, change, float(a.get(name, math.nan)), float(b.get(name, math.nan))))
    table = pd.DataFrame(rows, columns=list(DIFF_COLUMNS))
    return table.sort_values(["group", "name"], kind="stable").reset_index(drop=True)


def autopilot_of(log: FlightLog) -> str:
    """``"ardupilot"`` for a log with ArduPilot EKF parameters (``EK3_*`` / ``EK2_*``), else ``"px4"``."""
    return "ardupilot" if any(name.startswith(("EK3_", "EK2_")) for name in log.meta.parameters) else "px4"


def noise_parameter_table(log: FlightLog, cal: Calibration | None) -> pd.DataFrame:
    """The onboard estimator's noise parameters of ``log`` (its autopilot's: EKF2 for PX4, EKF3 for ArduPilot, the
    parameters of :data:`calib.parameter_export.MAPPING`) next to the values of ``cal`` in the same units and
    prediction period (:mod:`workflows.exports`): :data:`NOISE_COLUMNS`; ``solarnav`` NaN where ``cal`` gives none
    (or is None), ``ratio`` = solarnav / onboard, ``figure source`` the first comment of the exported row (the
    figure, its value and where it came from)."""
    autopilot = autopilot_of(log)
    names = dict.fromkeys(row.spec(autopilot).name for row in MAPPING if row.spec(autopilot) is not None)
    exported = {}
    if cal is not None:
        parameter_set = ardupilot_parameter_set if autopilot == "ardupilot" else px4_parameter_set
        exported = {p.name: p for p in parameter_set(cal, log.meta.parameters)[0]}
    rows = []
    for name in names:
        onboard = float(log.meta.parameters.get(name, math.nan))
        param = exported.get(name)
        value = float(param.value) if param is not None else math.nan
        ratio = value / onboard if math.isfinite(onboard) and onboard != 0 else math.nan
        rows.append((name, onboard, value, ratio, param.comments[0] if param is not None and param.comments else ""))
    return pd.DataFrame(rows, columns=list(NOISE_COLUMNS))
