"""Estimator runs as the app stores them: settings, a replay with progress reports, and the workspace entry.

No Streamlit here: the Estimators page and the ``dashboard`` command (which prepares the bundled samples' runs on
first start) share it.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from dataclasses import dataclass

import pandas as pd

from app.workspace import Workspace
from calib.calibration import Calibration
from estimators.api import DEFAULT_ESTIMATORS, run_estimators
from estimators.config import EstimatorConfig, config_from_calibration
from estimators.warmup import COMPILE_MESSAGE, cache_state, prepare_compile
from ingest import FlightLog

#: ``noise`` setting of a run with the filters' built-in noise (datasheet values).
DEFAULT_NOISE = "default"
#: ``noise`` setting of a run with R from an automatic calibration of the same log.
AUTO_CALIBRATION = "calibrated"

#: ``progress(fraction, text)`` callback.
Progress = Callable[[float, str], None]


@dataclass(frozen=True)
class RunSettings:
    """What an estimator run was made with (stored in the catalog as JSON).

    Attributes
    ----------
    estimators : tuple of str
        Estimator names, in display order.
    heading : str
        Absolute heading aid: ``"mag"``, ``"sun"`` or ``"mag+sun"``.
    noise : str
        :data:`DEFAULT_NOISE`, :data:`AUTO_CALIBRATION`, or the id of a calibration saved in the workspace.
    rate_hz : float
        Output rate [Hz].
    allow_untrusted : bool
        Replay a log whose inputs the estimators refuse (``run_estimators(..., allow_untrusted=True)``); its
        reports then lead with the refusal.
    """

    estimators: tuple[str, ...] = DEFAULT_ESTIMATORS
    heading: str = "mag"
    noise: str = DEFAULT_NOISE
    rate_hz: float = 50.0
    allow_untrusted: bool = False

    def to_dict(self) -> dict:
        """JSON-ready form (lists for tuples)."""
        return {**dataclasses.asdict(self), "estimators": list(self.estimators)}

    @classmethod
    def from_json_dict(cls, data: dict) -> RunSettings:
        """Inverse of :meth:`to_dict` (unknown keys ignored, missing ones defaulted)."""
        known = {field.name for field in dataclasses.fields(cls)}
        values = {key: value for key, value in data.items() if key in known}
        if "estimators" in values:
            values["estimators"] = tuple(values["estimators"])
        return cls(**values)


def replay(log: FlightLog, settings: RunSettings, calibration: Calibration | None = None,
           progress: Progress | None = None) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """Run the selected estimators one after the other, reporting progress between them.

    Parameters
    ----------
    log : FlightLog
        The flight.
    settings : RunSettings
        Estimators, heading aid, output rate, whether refused inputs are replayed anyway.
    calibration : Calibration, optional
        Noise for R (:func:`estimators.config.config_from_calibration`, the estimator's tuned figures when the
        calibration has them); the default noise without one.
    progress : callable, optional
        ``progress(fraction, text)`` before each estimator and at the end; the text of an estimator whose numba
        kernels are not in the cache yet (:func:`estimators.warmup.cache_state`) starts with
        :data:`~estimators.warmup.COMPILE_MESSAGE` (capitalised).

    Raises
    ------
    InputError
        The log's inputs are refused and ``settings.allow_untrusted`` is False (before any estimator runs).

    Returns
    -------
    states, diagnostics : pandas.DataFrame
        As :func:`estimators.api.run_estimators` returns them, estimators stacked in the selected order.
    report : dict
        Estimator name -> its report as a JSON-ready dict.
    """
    states, diagnostics, report = [], [], {}
    cold: set[str] = set()
    if prepare_compile(settings.estimators) is not None:  # (after dropping a stale cache numba would load)
        cold = {name for name in settings.estimators if not cache_state((name,)).warm}
    for k, name in enumerate(settings.estimators):
        if progress is not None:
            text = f"Running {name} ({k + 1} of {len(settings.estimators)}) ..."
            if name in cold:
                text = f"{COMPILE_MESSAGE.capitalize()}: {text[0].lower()}{text[1:]}"
            progress(k / len(settings.estimators), text)
        config = (EstimatorConfig() if calibration is None
                  else config_from_calibration(calibration, estimator=name))
        result = run_estimators(log, estimators=(name,), config=config, heading=settings.heading,
                                rate_hz=settings.rate_hz, allow_untrusted=settings.allow_untrusted)
        states.append(result.states)
        diagnostics.append(result.diagnostics)
        report[name] = dataclasses.asdict(result.reports[name])
    if progress is not None:
        progress(1.0, "Done")
    order = pd.CategoricalDtype(list(settings.estimators))
    return (_stacked(states, order), _stacked(diagnostics, order), report)


def _stacked(frames: list[pd.DataFrame], order: pd.CategoricalDtype) -> pd.DataFrame:
    # one categorical dtype for all parts (codes remapped, no round trip through strings), so concat keeps it
    return pd.concat([f.assign(estimator=f["estimator"].cat.set_categories(order.categories)) for f in frames],
                     ignore_index=True)


def replay_and_store(workspace: Workspace, sha256: str, log: FlightLog, settings: RunSettings,
                     calibration: Calibration | None = None, progress: Progress | None = None) -> str:
    """:func:`replay`, then store the run in the workspace (atomically); returns its id."""
    states, diagnostics, report = replay(log, settings, calibration, progress)
    return workspace.add_run(sha256, settings.to_dict(), states, diagnostics, report)


def find_run(workspace: Workspace, sha256: str, settings: RunSettings) -> str | None:
    """Id of the newest stored run of the log made with exactly ``settings``, or None."""
    runs = workspace.list_runs(sha256)
    for run_id, text in zip(runs["run_id"], runs["settings_json"], strict=True):
        if RunSettings.from_json_dict(json.loads(text)) == settings:
            return str(run_id)
    return None
