"""Estimator runs as the app stores them: settings, a replay with progress reports, and the workspace entry.

No Streamlit here: the Estimators page and the ``dashboard`` command (which prepares the bundled samples' runs on
first start) share it.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from dataclasses import dataclass

import pandas as pd

from app.workspace import Workspace
from calib.calibration import Calibration
from estimators.api import DEFAULT_ESTIMATORS, run_estimators
from estimators.config import EstimatorConfig, config_from_calibration
from estimators.warmup import COMPILE_MESSAGE, SUN_SOLVER, cache_state, prepare_compile
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


class StageClock:
    """The stages of a run as they happen: each one's text goes to ``progress`` when it starts, its wall-clock
    duration is measured until the next one starts (or :meth:`finish`).

    Parameters
    ----------
    progress : callable or None
        ``progress(fraction, text)``; the fraction counts the stages started out of ``steps``.
    steps : int
        Stages expected in all (the bar's denominator).
    """

    def __init__(self, progress: Progress | None, steps: int):
        self.progress, self.steps, self.started = progress, max(1, steps), 0
        #: (stage, duration [s]) of every finished stage, in order.
        self.measured: list[tuple[str, float]] = []
        self._current: tuple[str, float] | None = None

    def start(self, stage: str, text: str) -> None:
        """Finish the stage under way and start ``stage``, showing ``text``."""
        self.finish()
        self._current = (stage, time.perf_counter())
        if self.progress is not None:
            self.progress(min(self.started / self.steps, 1.0), text)
        self.started += 1

    def finish(self) -> None:
        """Record the duration of the stage under way, if any."""
        if self._current is not None:
            stage, began = self._current
            self.measured.append((stage, time.perf_counter() - began))
            self._current = None

    def done(self) -> None:
        """Finish the stage under way and report ``"Done"`` at fraction 1."""
        self.finish()
        if self.progress is not None:
            self.progress(1.0, "Done")

    def summary(self) -> str:
        """``"4.2 s: preparing inputs 0.3 s, running three_stage 1.1 s, ..."``: the total and every stage (stages of
        the same name added up, in order of first appearance)."""
        totals: dict[str, float] = {}
        for stage, seconds in self.measured:
            totals[stage] = totals.get(stage, 0.0) + seconds
        parts = ", ".join(f"{stage} {seconds:.1f} s" for stage, seconds in totals.items())
        return f"{sum(totals.values()):.1f} s: {parts}"


#: Stages of each estimator's replay (:func:`replay`; then one for stacking the tables, and :data:`SAVING` in
#: :func:`replay_and_store`).
STAGES_PER_ESTIMATOR = 4
SAVING = "saving"


def replay(log: FlightLog, settings: RunSettings, calibration: Calibration | None = None,
           progress: Progress | None = None, clock: StageClock | None = None
           ) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """Run the selected estimators one after the other, reporting every stage of each as it starts.

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
        ``progress(fraction, text)`` at the start of each stage of each estimator: ``"Running <name> (k of n)
        ..."`` (checking the inputs), then ``"<name> (k of n): preparing inputs ..."``, ``"...: running the filter
        ..."``, ``"...: computing diagnostics ..."`` (NIS consistency, report, tables), and ``"Done"`` at the end
        (by the caller when it passes its ``clock``);
        every text of an estimator whose numba kernels are not in the cache yet
        (:func:`estimators.warmup.cache_state`) starts with :data:`~estimators.warmup.COMPILE_MESSAGE`
        (capitalised). Ignored when ``clock`` is given (its own ``progress`` is used).
    clock : StageClock, optional
        Measures the stages (its ``measured`` durations tell where the time went); a new one without.

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
    own_clock = clock is None
    clock = StageClock(progress, STAGES_PER_ESTIMATOR * len(settings.estimators) + 1) if own_clock else clock
    states, diagnostics, report = [], [], {}
    cold: set[str] = set()
    solver = (SUN_SOLVER,) if "sun" in settings.heading else ()
    if prepare_compile((*settings.estimators, *solver)) is not None:  # (after dropping a stale cache numba would load)
        cold = {name for name in settings.estimators if not cache_state((name, *solver)).warm}
    count = len(settings.estimators)
    for k, name in enumerate(settings.estimators):
        prefix = f"{COMPILE_MESSAGE.capitalize()}: " if name in cold else ""
        header = f"{name} ({k + 1} of {count})"
        clock.start("checking inputs", f"{prefix}{'r' if prefix else 'R'}unning {header} ...")
        # run_estimators names its stages as they start (from this thread: one estimator per call)
        stages = {"prepare": ("preparing inputs", f"{prefix}{header}: preparing inputs ..."),
                  "run": (f"running {name}", f"{prefix}{header}: running the filter ..."),
                  "done": ("computing diagnostics", f"{prefix}{header}: computing diagnostics ...")}
        config = (EstimatorConfig() if calibration is None
                  else config_from_calibration(calibration, estimator=name))
        result = run_estimators(log, estimators=(name,), config=config, heading=settings.heading,
                                rate_hz=settings.rate_hz, allow_untrusted=settings.allow_untrusted,
                                progress=lambda stage, _name, stages=stages: clock.start(*stages[stage]))
        states.append(result.states)
        diagnostics.append(result.diagnostics)
        report[name] = dataclasses.asdict(result.reports[name])
    clock.start("stacking the tables", "Stacking the tables ...")
    order = pd.CategoricalDtype(list(settings.estimators))
    stacked = (_stacked(states, order), _stacked(diagnostics, order), report)
    if own_clock:
        clock.done()
    return stacked


def _stacked(frames: list[pd.DataFrame], order: pd.CategoricalDtype) -> pd.DataFrame:
    # one categorical dtype for all parts (codes remapped, no round trip through strings), so concat keeps it
    return pd.concat([f.assign(estimator=f["estimator"].cat.set_categories(order.categories)) for f in frames],
                     ignore_index=True)


def replay_and_store(workspace: Workspace, sha256: str, log: FlightLog, settings: RunSettings,
                     calibration: Calibration | None = None, progress: Progress | None = None,
                     clock: StageClock | None = None) -> str:
    """:func:`replay`, then store the run in the workspace (atomically, stage :data:`SAVING`); returns its id.
    ``clock`` (else a new one on ``progress``) measures every stage."""
    clock = clock if clock is not None else StageClock(progress, STAGES_PER_ESTIMATOR * len(settings.estimators) + 2)
    states, diagnostics, report = replay(log, settings, calibration, clock=clock)
    clock.start(SAVING, "Saving the run in the workspace ...")
    run_id = workspace.add_run(sha256, settings.to_dict(), states, diagnostics, report)
    clock.done()
    return run_id


def find_run(workspace: Workspace, sha256: str, settings: RunSettings) -> str | None:
    """Id of the newest stored run of the log made with exactly ``settings``, or None."""
    runs = workspace.list_runs(sha256)
    for run_id, text in zip(runs["run_id"], runs["settings_json"], strict=True):
        if RunSettings.from_json_dict(json.loads(text)) == settings:
            return str(run_id)
    return None
