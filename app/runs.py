"""Estimator runs as the app stores them: settings, a replay with progress reports, and the workspace entry.

No Streamlit here: the Estimators page and the ``dashboard`` command (which prepares the bundled samples' runs on
first start) share it.
"""

from __future__ import annotations

import dataclasses
import json
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import pandas as pd

from app.workspace import Workspace
from calib.calibration import Calibration
from estimators.api import DEFAULT_ESTIMATORS
from estimators.inputs.records import AUTO_HEADING, resolve_heading
from estimators.warmup import COMPILE_MESSAGE, SUN_SOLVER, cache_state, prepare_compile
from ingest.flightlog import FlightLog
from workflows.replay import replay_log

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
        Absolute heading aid: ``"auto"`` (``"mag+sun"`` for a log with sun-device data, else ``"mag"``; a stored run
        holds the one it used), ``"mag"``, ``"sun"`` or ``"mag+sun"``.
    noise : str
        :data:`DEFAULT_NOISE`, :data:`AUTO_CALIBRATION`, or the id of a calibration saved in the workspace.
    rate_hz : float
        Output rate [Hz].
    allow_untrusted : bool
        Replay a log whose inputs the estimators refuse (``run_estimators(..., allow_untrusted=True)``); its
        reports then lead with the refusal.
    """

    estimators: tuple[str, ...] = DEFAULT_ESTIMATORS
    heading: str = AUTO_HEADING
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
    duration is measured until the next one starts (or :meth:`finish`). Stages run one after the other; within a
    stage, *lanes* (the estimators running side by side) are timed on their own. Thread-safe: the estimators report
    from their threads.

    Parameters
    ----------
    progress : callable or None
        ``progress(fraction, text)``; the fraction counts the steps (stages started and :meth:`note` calls) out of
        ``steps``.
    steps : int
        Steps expected in all (the bar's denominator; :func:`run_steps`).
    """

    def __init__(self, progress: Progress | None, steps: int):
        self.progress, self.steps, self.started = progress, max(1, steps), 0
        #: (stage, duration [s]) of every finished stage, in order.
        self.measured: list[tuple[str, float]] = []
        #: stage -> {lane: duration [s]} of the lanes timed within it.
        self.lanes: dict[str, dict[str, float]] = {}
        self._current: tuple[str, float] | None = None
        self._lane_started: dict[str, float] = {}
        self._lane_order: tuple[str, ...] = ()
        self._lock = threading.RLock()

    def order_lanes(self, lanes: Sequence[str]) -> None:
        """Show the lanes in the order of ``lanes`` (e.g. the selected estimators) rather than the order in which
        they end, which varies from run to run when they run side by side; lanes not named follow."""
        self._lane_order = tuple(lanes)

    def start(self, stage: str, text: str) -> None:
        """Finish the stage under way and start ``stage``, showing ``text``."""
        with self._lock:
            self.finish()
            self._current = (stage, time.perf_counter())
            self.note(text)

    def note(self, text: str) -> None:
        """One more step within the stage under way, showing ``text``."""
        with self._lock:
            if self.progress is not None:
                self.progress(min(self.started / self.steps, 1.0), text)
            self.started += 1

    def lane_start(self, lane: str) -> None:
        """``lane`` (an estimator) starts within the stage under way."""
        with self._lock:
            self._lane_started[lane] = time.perf_counter()

    def lane_end(self, lane: str) -> None:
        """``lane`` ended: its duration is kept under the stage under way."""
        with self._lock:
            if self._current is not None and lane in self._lane_started:
                seconds = time.perf_counter() - self._lane_started.pop(lane)
                self.lanes.setdefault(self._current[0], {})[lane] = seconds

    def finish(self) -> None:
        """Record the duration of the stage under way, if any."""
        with self._lock:
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
        """``"4.2 s: preparing inputs 0.3 s, running the filters 2.1 s (three_stage 1.1 s, ...), ..."``: the total
        and every stage (stages of the same name added up, in order of first appearance), with its lanes."""
        totals: dict[str, float] = {}
        for stage, seconds in self.measured:
            totals[stage] = totals.get(stage, 0.0) + seconds

        def lanes(stage: str) -> str:
            timed = self.lanes.get(stage)
            if not timed:
                return ""
            rank = {lane: index for index, lane in enumerate(self._lane_order)}
            ordered = sorted(timed.items(), key=lambda item: rank.get(item[0], len(rank)))
            return f" ({', '.join(f'{lane} {seconds:.1f} s' for lane, seconds in ordered)})"

        parts = ", ".join(f"{stage} {seconds:.1f} s{lanes(stage)}" for stage, seconds in totals.items())
        return f"{sum(totals.values()):.1f} s: {parts}"


def run_steps(n_estimators: int, store: bool = True, calibrate: bool = False) -> int:
    """Steps of a :class:`StageClock` for a run of ``n_estimators``: checking the inputs, per estimator preparing
    its inputs, its filter starting and ending, then the diagnostics and stacking; plus saving (``store``) and a
    calibration before (``calibrate``)."""
    return 1 + STAGES_PER_ESTIMATOR * n_estimators + 2 + int(store) + int(calibrate)


#: Steps of each estimator in :func:`run_steps` (preparing its inputs, its filter started, ended).
STAGES_PER_ESTIMATOR = 3
SAVING = "saving"
#: The stage in which the estimators run side by side (each one's time is a lane of it).
RUNNING = "running the filters"


def replay(log: FlightLog, settings: RunSettings, calibration: Calibration | None = None,
           progress: Progress | None = None, clock: StageClock | None = None
           ) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """Run the selected estimators, side by side (:func:`estimators.api.run_estimators` with one thread per
    estimator), reporting every stage as it starts.

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
        ``progress(fraction, text)`` at every step: ``"Checking the inputs ..."``, ``"Preparing the inputs of
        <name> ..."`` per estimator, ``"Running the filters: <name> running, <name> done, ..."`` whenever one
        starts or ends, ``"Computing the diagnostics ..."``, ``"Stacking the tables ..."``, and ``"Done"`` at the
        end (by the caller when it passes its ``clock``). Until an estimator whose numba kernels are not in the
        cache yet (:func:`estimators.warmup.cache_state`) is done (it compiles when it starts), every text starts with
        :data:`~estimators.warmup.COMPILE_MESSAGE` (capitalised) ``for <names>: ``. Ignored when
        ``clock`` is given (its own ``progress`` is used). Called from the estimators' threads too.
    clock : StageClock, optional
        Measures the stages (its ``measured`` durations tell where the time went, its ``lanes`` each estimator's
        time in :data:`RUNNING`); a new one without.

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
    names = settings.estimators
    clock = StageClock(progress, run_steps(len(names), store=False)) if own_clock else clock
    clock.order_lanes(names)
    cold: set[str] = set()
    solver = (SUN_SOLVER,) if "sun" in resolve_heading(settings.heading, log.has("sun")) else ()
    if prepare_compile((*names, *solver)) is not None:  # (after dropping a stale cache numba would load)
        cold = {name for name in names if not cache_state((name, *solver)).warm}
    status = dict.fromkeys(names, "waiting")

    def say(text: str) -> str:  # a cold filter compiles in its first call: named until it is done
        compiling = [name for name in names if name in cold and status[name] != "done"]
        if not compiling:
            return text
        return f"{COMPILE_MESSAGE.capitalize()} for {', '.join(compiling)}: {text[0].lower()}{text[1:]}"

    def running_text() -> str:
        return say("Running the filters: " + ", ".join(f"{name} {state}" for name, state in status.items()))

    def stage(event: str, name: str) -> None:  # run_estimators' progress, from this thread and the estimators'
        if event == "prepare":
            clock.start("preparing inputs", say(f"Preparing the inputs of {name} ..."))
        elif event == "run":
            first = all(state == "waiting" for state in status.values())
            status[name] = "running"
            if first:
                clock.start(RUNNING, running_text())
            else:
                clock.note(running_text())
            clock.lane_start(name)
        elif event == "done":
            status[name] = "done"
            clock.lane_end(name)
            clock.note(running_text())
        else:  # "report"
            clock.start("computing diagnostics", "Computing the diagnostics ...")

    clock.start("checking inputs", say("Checking the inputs ..."))
    result = replay_log(log, estimators=names, calibration=calibration, heading=settings.heading,
                        rate_hz=settings.rate_hz, allow_untrusted=settings.allow_untrusted, progress=stage)
    clock.start("stacking the tables", "Stacking the tables ...")
    report = {name: dataclasses.asdict(result.reports[name]) for name in names}
    if own_clock:
        clock.done()
    return result.states, result.diagnostics, report


def replay_and_store(workspace: Workspace, sha256: str, log: FlightLog, settings: RunSettings,
                     calibration: Calibration | None = None, progress: Progress | None = None,
                     clock: StageClock | None = None) -> str:
    """:func:`replay`, then store the run in the workspace (atomically, stage :data:`SAVING`); returns its id.
    ``clock`` (else a new one on ``progress``) measures every stage. The run is stored with the heading source it
    used (``"auto"`` resolved for this log: :func:`estimators.inputs.records.resolve_heading`)."""
    settings = dataclasses.replace(settings, heading=resolve_heading(settings.heading, log.has("sun")))
    clock = clock if clock is not None else StageClock(progress, run_steps(len(settings.estimators)))
    states, diagnostics, report = replay(log, settings, calibration, clock=clock)
    clock.start(SAVING, "Saving the run in the workspace ...")
    run_id = workspace.add_run(sha256, settings.to_dict(), states, diagnostics, report)
    clock.done()
    return run_id


def find_run(workspace: Workspace, sha256: str, settings: RunSettings) -> str | None:
    """Id of the newest stored run of the log made with exactly ``settings`` (``"auto"`` heading as
    :func:`replay_and_store` resolves it for this log), or None."""
    entry = workspace.get_log(sha256)
    settings = dataclasses.replace(settings, heading=resolve_heading(settings.heading, bool(entry and entry.has_sun)))
    runs = workspace.list_runs(sha256)
    for run_id, text in zip(runs["run_id"], runs["settings_json"], strict=True):
        if RunSettings.from_json_dict(json.loads(text)) == settings:
            return str(run_id)
    return None
