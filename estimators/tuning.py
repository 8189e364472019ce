"""Noise identified from the flight itself: per estimator, the noise figures that maximise the innovation
log-likelihood of its replay (docs/calibration.md, 'Noise identification').

For each estimator a small vector of figures (:data:`KNOBS`: measurement noise per fused sensor, IMU densities,
bias and wind random walks) starts at the values the calibration gives it (:func:`estimators.config.config_from_figures`
of the calibration's figures, so the start IS the ``--calib`` replay) and is searched in log10 space within bounds:

1. one covariance-matching step on the measurement figures: each sigma times ``sqrt(mean NIS)`` of its channel
   (clipped to a factor of 5), kept when the likelihood rises;
2. a coordinate pattern search: each figure up and down by a step (half a decade, then a quarter, then an
   eighth), kept when the likelihood rises, until the replay budget is spent. Every candidate must stay
   consistent: no channel's mean NIS above 3 or below 0.2 (or beyond its start value when that was already
   outside), no more resets, and on a fixed wing no more epochs with the estimated air flowing backwards through
   the airframe than at the start (at most 5 %).

The likelihood is :func:`estimators.consistency.log_likelihood` (normalised innovations clipped at 5 sigma).
Each evaluation rebuilds the replay inputs (0.1 s for 15 minutes of flight: measurement variances live in the
event table) and runs the compiled kernel, which releases the GIL, so the estimators are identified in parallel
threads.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from calib.calibration import Calibration
from calib.figures import (
    FIGURES,
    RULE_AXES_PER_STRENGTH,
    RULE_FACTOR,
    RULE_NOISE,
    RULE_NOISE_PER_STRENGTH,
    RULE_VALUE,
    SOURCE_TUNED,
    Figure,
    FigureRow,
    FigureSetting,
    TuneResult,
    rms,
)
from calib.filter_figures import calibration_figures
from estimators.api import DEFAULT_ESTIMATORS, estimator_function, parse_estimator_names
from estimators.config import EstimatorConfig, config_from_figures, noise_default
from estimators.consistency import (
    MIN_UPDATES,
    NIS_WARNING_RANGE,
    REVERSED_AIRFLOW_LIMIT,
    channel_consistency,
    log_likelihood,
    reversed_airflow_fraction,
)
from estimators.core.results import EstimatorRun
from estimators.inputs.build import build_replay_inputs
from estimators.inputs.records import AUTO_HEADING, SensorPlan
from estimators.three_stage.run import ThreeStageOptions
from ingest.flightlog import FlightLog

#: Replays per estimator (the start and the covariance-matching step included).
DEFAULT_BUDGET = 60
#: Output rate of the identification replays [Hz] (only the innovations matter).
TUNE_OUTPUT_RATE_HZ = 1.0
#: Pattern-search steps in decades.
STEPS_DECADES = (0.5, 0.25, 0.125)
#: Largest factor of the covariance-matching step.
MATCH_FACTOR_LIMIT = 5.0
#: Covariance-matching steps at most.
MATCH_ITERATIONS = 3
#: A channel that starts outside the NIS warning range may drift this factor further out (its mean NIS moves a
#: little with every other figure; without the slack no candidate would pass).
NIS_START_TOLERANCE = 1.25


#: The search vector: every figure of :data:`calib.figures.FIGURES` with an :class:`~calib.figures.Identification`
#: (its bounds, NIS channel, estimators and sensor needs), in the table's order, which the pattern search follows.
KNOBS: tuple[FigureRow, ...] = tuple(row for row in FIGURES.values() if row.identification is not None)
#: Start of a figure whose setting the configuration leaves to the estimator (None there): the estimator's default.
_UNSET_STARTS = {FIGURES.accel_stage1_floor.name: ThreeStageOptions().accel_sigma_floor_m_s2}
#: Rules whose figure is in gauss, its setting in units of the field strength.
_PER_STRENGTH = (RULE_NOISE_PER_STRENGTH, RULE_AXES_PER_STRENGTH)


def start_values(config: EstimatorConfig, strength_gauss: float) -> dict[str, float]:
    """The value of every knob's figure in ``config`` (the filter setting it stands for, its table rule inverted;
    ``strength_gauss`` the field strength the magnetometer settings are in units of)."""
    return {row.name: _figure_value(row, config, strength_gauss) for row in KNOBS}


def _figure_value(row: FigureRow, config: EstimatorConfig, strength_gauss: float) -> float:
    setting = row.setting
    if setting.rule == RULE_NOISE:
        return noise_default(config.noise, setting)
    if setting.rule == RULE_NOISE_PER_STRENGTH:
        return noise_default(config.noise, setting) * strength_gauss
    if setting.rule == RULE_AXES_PER_STRENGTH:
        return rms(_noise_axes(config, setting)) * strength_gauss
    if setting.rule == RULE_FACTOR:
        return 1.0  # the settings it multiplies hold the factor already
    if setting.rule == RULE_VALUE:
        value = getattr(config.calibrated, setting.fields[0])
        return _UNSET_STARTS[row.name] if value is None else value
    raise ValueError(f"figure {row.name!r}: no inverse of rule {setting.rule!r} to start an identification from")


def _noise_axes(config: EstimatorConfig, setting: FigureSetting) -> tuple[float, ...]:
    """The per-axis setting of a per-axis rule in ``config`` (its default on every axis when not set)."""
    return getattr(config.noise, setting.fields[0]) or (noise_default(config.noise, setting),) * 3


def knobs_for(estimator: str, plan: SensorPlan) -> tuple[FigureRow, ...]:
    """The knobs ``estimator`` uses on a log with sensor plan ``plan``."""
    return tuple(k for k in KNOBS if estimator in k.identification.estimators
                 and (k.identification.needs is None or getattr(plan, k.identification.needs)))


def tuned_figures(base: dict[str, Figure], values: dict[str, float], start: EstimatorConfig,
                  strength_gauss: float) -> dict[str, Figure]:
    """``base`` with every knob value as a tuned figure (the axes of a per-axis figure scaled together, keeping
    their ratio in ``start``, the configuration the search started from; the field strength recorded so the
    figures convert back exactly)."""
    figures = dict(base)
    for name, value in values.items():
        setting, axes = FIGURES[name].setting, ()
        if setting.rule == RULE_AXES_PER_STRENGTH:
            start_axes = _noise_axes(start, setting)
            ratio = value / (rms(start_axes) * strength_gauss)
            axes = tuple(a * strength_gauss * ratio for a in start_axes)
        figures[name] = Figure(name, value, SOURCE_TUNED, axes=axes)
    if any(FIGURES[name].setting.rule in _PER_STRENGTH for name in values):
        strength = FIGURES.mag_field_strength.name
        figures[strength] = Figure(strength, strength_gauss, SOURCE_TUNED,
                                   note="median |m| of the log (the replay's normalisation)")
    return figures


@dataclass(frozen=True)
class _Candidate:
    """A set of knob values, its replay and its log-likelihood (-inf for a replay that is not
    :meth:`_Identification.trusted`)."""

    values: dict[str, float]
    run: EstimatorRun
    log_likelihood: float

    def beats(self, other: _Candidate) -> bool:
        """A higher likelihood."""
        return self.log_likelihood > other.log_likelihood


#: ``progress(estimator, replays_done, budget)``: called after every replay of an identification (from its thread).
TuneProgress = Callable[[str, int, int], None]


class _Identification:
    """One estimator's identification problem on one log: the start, the replay of a candidate, the trust checks
    and the replay budget (see the module docstring)."""

    def __init__(self, log: FlightLog, cal: Calibration, estimator: str, budget: int, heading: str,
                 sun_observations, progress: TuneProgress | None = None):
        self.log, self.estimator, self.budget, self.progress = log, estimator, budget, progress
        self.heading, self.sun_observations = heading, sun_observations
        self.run_function = estimator_function(estimator)
        self.base_figures = calibration_figures(cal)
        self.start_config = config_from_figures(self.base_figures)
        inputs = build_replay_inputs(log, self.start_config, rate_hz=TUNE_OUTPUT_RATE_HZ, heading=heading,
                                     sun_observations=sun_observations)
        self.strength = inputs.mag_strength_gauss if math.isfinite(inputs.mag_strength_gauss) else 1.0
        self.knobs = knobs_for(estimator, inputs.plan)
        values = start_values(self.start_config, self.strength)
        self.start = {k.name: min(max(values[k.name], k.identification.lower), k.identification.upper)
                      for k in self.knobs}
        self.spent, self.trace, self.notes = 0, [], []
        self.check_airflow = inputs.plan.fixed_wing and inputs.plan.has_airspeed
        first = self._replay(self.start)
        self.nis_before = channel_consistency(first.diagnostics)
        # A channel may not leave the warning range further than it started: above it the filter trusts a sensor
        # too much (or diverges), below it the sensor is in effect ignored (its figure inflated until the others
        # explain everything: a magnetometer at 0.3 gauss leaves the heading to drift).
        self.limits = {c.channel: (min(NIS_WARNING_RANGE[0], c.mean_nis / NIS_START_TOLERANCE),
                                   max(NIS_WARNING_RANGE[1], c.mean_nis * NIS_START_TOLERANCE))
                       for c in self.nis_before}
        self.start_resets = first.report.resets + first.report.gps_resets
        self.airflow_limit = (max(REVERSED_AIRFLOW_LIMIT, _reversed_share(first)) if self.check_airflow
                              else math.inf)
        self.first = self._scored(self.start, first, judged=False)
        self.trace.append(self.first.log_likelihood)

    def figures_of(self, values: dict[str, float]) -> dict[str, Figure]:
        return tuned_figures(self.base_figures, values, self.start_config, self.strength)

    def _replay(self, values: dict[str, float]) -> EstimatorRun:
        config = config_from_figures(self.figures_of(values))
        inputs = build_replay_inputs(self.log, config, rate_hz=TUNE_OUTPUT_RATE_HZ, heading=self.heading,
                                     sun_observations=self.sun_observations)
        run = self.run_function(self.log, inputs, config)
        self.spent += 1
        if self.progress is not None:
            self.progress(self.estimator, self.spent, self.budget)
        return run

    def _scored(self, values: dict[str, float], run: EstimatorRun, *, judged: bool = True) -> _Candidate:
        """``run`` of ``values`` scored (the start replay is not ``judged``: it sets the limits)."""
        if judged and not self.trusted(run):
            return _Candidate(values, run, -math.inf)
        return _Candidate(values, run, log_likelihood(run.diagnostics))

    def evaluate(self, values: dict[str, float]) -> _Candidate:
        """Replay ``values`` (one replay of the budget) and score it."""
        return self._scored(values, self._replay(values))

    @property
    def exhausted(self) -> bool:
        return self.spent >= self.budget

    def trusted(self, run: EstimatorRun) -> bool:
        """No channel more inconsistent than the warning limit (or than at the start), no more resets and no
        mirrored wind (air flowing backwards through the airframe fits the airspeed and GPS innovations as well
        as the true wind: the likelihood cannot see it); the clipped likelihood alone would also let a diverging
        channel pay only a fixed price per update."""
        if run.report.resets + run.report.gps_resets > self.start_resets:
            return False
        if self.check_airflow and _reversed_share(run) > self.airflow_limit:
            return False
        for c in channel_consistency(run.diagnostics):
            low, high = self.limits.get(c.channel, NIS_WARNING_RANGE)
            if c.n_updates >= MIN_UPDATES and not low <= c.mean_nis <= high:
                return False
        return True

    def keep(self, best: _Candidate, candidate: _Candidate) -> _Candidate:
        """The better of the two (``candidate`` only when it :meth:`~_Candidate.beats` ``best``), traced."""
        kept = candidate if candidate.beats(best) else best
        self.trace.append(kept.log_likelihood)
        return kept


def _match_covariances(problem: _Identification, best: _Candidate) -> _Candidate:
    """Up to :data:`MATCH_ITERATIONS` covariance-matching steps on the measurement figures: each sigma times
    ``sqrt(mean NIS)`` of its channel (clipped to :data:`MATCH_FACTOR_LIMIT`), while that pays."""
    for _ in range(MATCH_ITERATIONS):
        if problem.exhausted:
            break
        matched = dict(best.values)
        for k in problem.knobs:
            search = k.identification
            nis = _mean_nis(best.run, search.channel) if search.channel else math.nan
            if math.isfinite(nis):
                factor = min(max(math.sqrt(nis), 1.0 / MATCH_FACTOR_LIMIT), MATCH_FACTOR_LIMIT)
                matched[k.name] = min(max(best.values[k.name] * factor, search.lower), search.upper)
        if matched == best.values:
            break
        kept = problem.keep(best, problem.evaluate(matched))
        if kept is best:
            break
        best = kept
    return best


def _pattern_search(problem: _Identification, best: _Candidate) -> _Candidate:
    """Coordinate pattern search in log10: each figure up and down by a step of :data:`STEPS_DECADES`, continuing
    in a direction while it pays, until the budget is spent."""
    for step in STEPS_DECADES:
        for k in problem.knobs:
            search = k.identification
            moved = False
            for direction in (+1.0, -1.0):
                while not problem.exhausted:  # keep going while the candidate beats the best
                    candidate = dict(best.values)
                    candidate[k.name] = min(max(best.values[k.name] * 10.0 ** (direction * step), search.lower),
                                            search.upper)
                    if candidate[k.name] == best.values[k.name]:
                        break
                    kept = problem.keep(best, problem.evaluate(candidate))
                    if kept is best:
                        break
                    best, moved = kept, True
                if moved:
                    break
        if problem.exhausted:
            problem.notes.append(f"replay budget of {problem.budget} spent at a step of {step:g} decade")
            break
    return best


def tune_estimator(log: FlightLog, cal: Calibration, estimator: str, *, budget: int = DEFAULT_BUDGET,
                   heading: str = AUTO_HEADING, sun_observations=None,
                   progress: TuneProgress | None = None) -> TuneResult:
    """Identify the noise figures of one estimator on ``log``, starting from ``cal``'s (see the module docstring).

    Parameters
    ----------
    log : FlightLog
        The flight.
    cal : Calibration
        Its calibration (the start; its tuning section is ignored).
    estimator : str
        Registry name.
    budget : int
        Replays to spend (>= 2).
    heading, sun_observations
        As :func:`estimators.api.run_estimators`.
    progress : TuneProgress, optional
        Told after every replay (the search may stop before the budget is spent).
    """
    started = time.perf_counter()
    problem = _Identification(log, cal, estimator, budget, heading, sun_observations, progress)
    best = _pattern_search(problem, _match_covariances(problem, problem.first))
    bounds = {k.name: (k.identification.lower, k.identification.upper) for k in problem.knobs}
    for name, (lower, upper) in bounds.items():
        if best.values[name] in (lower, upper):
            problem.notes.append(f"{name} at its {'lower' if best.values[name] == lower else 'upper'} bound "
                                 f"{best.values[name]:.3g}")
    return TuneResult(estimator=estimator, figures=problem.figures_of(best.values), start=problem.start,
                      bounds=bounds, log_likelihood_trace=tuple(problem.trace), n_replays=problem.spent,
                      nis_before=problem.nis_before, nis_after=channel_consistency(best.run.diagnostics),
                      wall_s=time.perf_counter() - started, notes=tuple(problem.notes))


def tune_calibration(log: FlightLog, cal: Calibration, estimators: str | Sequence[str] = DEFAULT_ESTIMATORS, *,
                     budget: int = DEFAULT_BUDGET, heading: str = AUTO_HEADING, sun_observations=None,
                     threads: int = 2, progress: TuneProgress | None = None) -> Calibration:
    """``cal`` with ``tuning`` filled for every estimator (identified concurrently in ``threads`` threads;
    ``progress`` as :func:`tune_estimator`)."""
    names = parse_estimator_names(estimators)
    with ThreadPoolExecutor(max_workers=max(1, threads)) as pool:
        futures = {name: pool.submit(tune_estimator, log, cal, name, budget=budget, heading=heading,
                                     sun_observations=sun_observations, progress=progress) for name in names}
        results = {name: future.result() for name, future in futures.items()}
    return dataclasses.replace(cal, tuning={**cal.tuning, **results})


def _mean_nis(run: EstimatorRun, channel: str) -> float:
    """Mean NIS of a channel (``"sensor"`` or ``"sensor.components"``) of a run's diagnostics (NaN if none)."""
    sensor, _, components = channel.partition(".")
    diagnostics = run.diagnostics
    rows = diagnostics["sensor"] == sensor
    if components:
        rows &= diagnostics["component"].isin(list(components))
    nis = diagnostics.loc[rows, "nis"].to_numpy(dtype=float)
    nis = nis[np.isfinite(nis)]
    return float(nis.mean()) if len(nis) else math.nan


def _reversed_share(run: EstimatorRun) -> float:
    """:func:`estimators.consistency.reversed_airflow_fraction` of a run, 0 where it is undefined."""
    share = reversed_airflow_fraction(run.states)
    return share if math.isfinite(share) else 0.0
