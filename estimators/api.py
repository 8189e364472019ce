"""Replay API: run the estimators on a FlightLog and get DataFrames (the contract the CLI and the dashboard use).

>>> result = run_estimators(flight_log)                                  # doctest: +SKIP
>>> result.states.groupby("estimator").yaw_deg.describe()                # doctest: +SKIP

``states``: one row per estimator per output epoch with exactly :data:`~estimators.core.results.STATE_COLUMNS` (NaN
where an estimator has no such quantity) plus optional ``*_std`` columns; ``diagnostics``: one row per scalar
measurement update with :data:`~estimators.core.results.DIAGNOSTIC_COLUMNS`; ``reports``: what each estimator used,
skipped, degraded, reset, and how long it took.

Estimators are looked up in :data:`ESTIMATORS`, an explicit registry ``name -> run function`` (plain imports a
reader and a linter can follow).
An estimator's function has the signature ``run(flight_log, inputs, config) -> EstimatorRun`` where ``inputs``
(:class:`~estimators.inputs.records.ReplayInputs`, built once per call and shared by all estimators) carries the IMU
rows, time-sorted measurement events, origin, sensor plan and initial alignment.

Inputs that parse but cannot give a trustworthy estimate (:func:`ingest.quality.assess_input_quality`) are refused
with an :class:`~ingest.errors.InputError` naming the reason, unless ``allow_untrusted=True``; then, and for every
merely flagged finding, each report carries the finding as a warning (docs/estimators.md, 'Inputs the estimators
refuse').
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from calib.figures import FIGURES, MAX_ACCEL_BIAS_STD_M_S2, SOURCE_INFLIGHT_BIAS
from estimators.config import EstimatorConfig
from estimators.consistency import (
    REVERSED_AIRFLOW_LIMIT,
    channel_consistency,
    channel_verdicts,
    estimator_verdict,
    reversed_airflow_fraction,
)
from estimators.core.results import DIAGNOSTIC_COLUMNS, STATE_COLUMNS, EstimatorReport, EstimatorRun
from estimators.direct.run import run as run_direct
from estimators.indirect.run import NAME as INDIRECT
from estimators.indirect.run import run as run_indirect
from estimators.inflight_bias import trusted_bias_states
from estimators.inputs.build import build_replay_inputs
from estimators.inputs.records import AUTO_HEADING, HEADING_SOURCES
from estimators.three_stage.run import NAME as THREE_STAGE
from estimators.three_stage.run import run as run_three_stage
from ingest.errors import InputError
from ingest.flightlog import FlightLog
from ingest.quality import REFUSE, QualityFinding, assess_input_quality
from ingest.threads import thread_map

#: Registry: estimator name -> run function with the signature ``(flight_log, inputs, config) -> EstimatorRun``.
#: Add an estimator with one import and one line.
ESTIMATORS: dict[str, Callable[..., EstimatorRun]] = {
    "three_stage": run_three_stage,
    "full_state_direct": run_direct,
    "full_state_indirect": run_indirect,
}
#: Calibrated figures an estimator does not use, and why (the ``ignored`` of their rows of
#: :data:`calib.figures.FIGURES`); the others set what ``config.calibrated.provenance`` says.
IGNORED_FIGURES: dict[str, dict[str, str]] = {
    name: {row.name: why for row in FIGURES.values() for estimator, why in row.ignored if estimator == name}
    for name in ESTIMATORS}
#: Default estimator selection (all three, paper order).
DEFAULT_ESTIMATORS = ("three_stage", "full_state_direct", "full_state_indirect")
#: Leads the warning of a refused finding replayed on request (``allow_untrusted=True``), and of a flagged one.
UNTRUSTED_PREFIX = "UNTRUSTED INPUT (refused, replayed on request): "
FLAGGED_PREFIX = "input quality: "


@dataclass(frozen=True)
class ReplayResult:
    """Result of :func:`run_estimators`.

    Attributes
    ----------
    states : pandas.DataFrame
        :data:`~estimators.core.results.STATE_COLUMNS` (+ optional std columns), estimators stacked in the requested
        order, each sorted by ``time_s``.
    diagnostics : pandas.DataFrame
        :data:`~estimators.core.results.DIAGNOSTIC_COLUMNS`.
    reports : dict of str -> EstimatorReport
        Per estimator, in the requested order.
    input_quality : tuple of QualityFinding
        The log's quality findings (:func:`ingest.quality.assess_input_quality`), refused ones first; a refused one
        is here only when the replay was forced (``allow_untrusted=True``).
    """

    states: pd.DataFrame
    diagnostics: pd.DataFrame
    reports: dict[str, EstimatorReport]
    input_quality: tuple[QualityFinding, ...] = ()


def estimator_function(name: str) -> Callable[..., EstimatorRun]:
    """The run function registered under ``name``.

    Raises
    ------
    InputError
        Unknown name (the message lists the registered ones).
    """
    if name not in ESTIMATORS:
        raise InputError(f"unknown estimator {name!r} (available: {', '.join(ESTIMATORS)})", field="estimators")
    return ESTIMATORS[name]


def parse_estimator_names(names: str | Sequence[str]) -> tuple[str, ...]:
    """Validate a selection (``"a,b"`` or a sequence); duplicates removed, order kept."""
    items = [n.strip() for n in names.split(",")] if isinstance(names, str) else [str(n).strip() for n in names]
    items = [n for n in items if n]
    if not items:
        raise InputError("no estimator selected", field="estimators")
    unknown = [n for n in items if n not in ESTIMATORS]
    if unknown:
        raise InputError(f"unknown estimator(s) {', '.join(map(repr, unknown))} (available: {', '.join(ESTIMATORS)})",
                         field="estimators")
    return tuple(dict.fromkeys(items))


def run_estimators(flight_log: FlightLog, *, estimators: str | Sequence[str] = DEFAULT_ESTIMATORS,
                   config: EstimatorConfig | None = None, heading: str = AUTO_HEADING, rate_hz: float = 50.0,
                   sun_observations: pd.DataFrame | None = None,
                   configs: Mapping[str, EstimatorConfig] | None = None,
                   allow_untrusted: bool = False, threads: int | None = None,
                   progress: Callable[[str, str], None] | None = None) -> ReplayResult:
    """Run estimators on one log.

    Parameters
    ----------
    flight_log : FlightLog
        The canonical log (needs an ``imu`` stream).
    estimators : str or sequence of str
        Names from :data:`ESTIMATORS` (``"a,b"`` accepted).
    config : EstimatorConfig, optional
        Noise, gates, initial sigmas, timing (defaults when None).
    heading : {"auto", "mag", "sun", "mag+sun"}
        Absolute heading source(s); ``sun`` needs the log's ``sun`` stream (photocell currents) or
        ``sun_observations``; ``"auto"`` (default) is ``"mag+sun"`` with them, else ``"mag"``
        (:func:`estimators.inputs.records.resolve_heading`).
    rate_hz : float
        Output rate [Hz] (epochs ``k / rate_hz`` on the log clock).
    sun_observations : pandas.DataFrame, optional
        Pre-solved sun vectors (see :func:`estimators.inputs.build.build_replay_inputs`).
    configs : mapping of estimator name -> EstimatorConfig, optional
        Per-estimator settings overriding ``config`` (noise identified per estimator,
        :func:`estimators.config.config_from_calibration` with ``estimator=``); the replay inputs are built once per
        distinct configuration.
    allow_untrusted : bool
        Replay a log whose inputs are refused (``solarnav replay --force``); every report then leads its warnings
        with each refused finding (:data:`UNTRUSTED_PREFIX`).
    threads : int, optional
        Estimators run at the same time (default: one per estimator, even beyond the CPUs: three kernels on two
        CPUs then finish together instead of the third waiting for a free one); their compiled kernels release the
        GIL, so the threads share the one set of replay inputs without copies. Results do not depend on it.
    progress : callable, optional
        ``progress(stage, estimator)`` with ``stage`` in ``"prepare"`` (building its inputs), ``"run"`` (its filter
        started) and ``"done"`` (its run and its report, consistency checks included, are ready; called from the
        worker threads), then ``progress("report", "")`` once all are done (the stacked tables follow).

    Every report carries ``details["consistency"]`` (mean NIS per channel, :mod:`estimators.consistency`) and
    ``details["calibration"]`` (each calibrated figure behind the run's settings: its source and what this
    estimator did with it) and ``details["verdict"]`` (the estimator's consistency verdict, one warning when it is
    inconsistent).
    Every report also carries ``details["input_quality"]`` (the findings as dicts) and a warning per finding.

    Returns
    -------
    ReplayResult

    Raises
    ------
    InputError
        Unknown estimator, bad rate/heading, no IMU data, sun heading without sun data, refused inputs (without
        ``allow_untrusted``).
    """
    names = parse_estimator_names(estimators)
    if heading not in HEADING_SOURCES:
        raise InputError(f"heading must be one of {', '.join(HEADING_SOURCES)}, got {heading!r}", field="heading")
    findings = checked_input_quality(flight_log, allow_untrusted=allow_untrusted)
    config = EstimatorConfig() if config is None else config
    configs = {name: (configs or {}).get(name, config) for name in names}
    functions = {name: estimator_function(name) for name in names}
    notify = progress if progress is not None else (lambda stage, name: None)
    inputs, prepare_s, built = {}, {}, []
    for name in names:  # inputs once per distinct configuration, shared read-only by the estimators
        started = time.perf_counter()
        notify("prepare", name)
        shared = next((replay_inputs for run_config, replay_inputs in built if run_config == configs[name]), None)
        if shared is None:
            shared = build_replay_inputs(flight_log, configs[name], rate_hz=rate_hz, heading=heading,
                                         sun_observations=sun_observations)
            built.append((configs[name], shared))
        inputs[name], prepare_s[name] = shared, time.perf_counter() - started

    bias = _ThreeStageBias(flight_log, names, configs, inputs)

    def run_one(name: str) -> tuple[EstimatorRun, EstimatorReport]:
        notify("run", name)
        run_config = bias.config() if name == THREE_STAGE else configs[name]
        try:
            run = functions[name](flight_log, inputs[name], run_config)
        except BaseException as exc:
            bias.offer(name, exc)  # a waiting three-stage run fails with it instead of waiting forever
            raise
        bias.offer(name, run)
        # its consistency checks here, while the other estimators' kernels still run
        report = _checked_report(run, run_config, {"prepare": prepare_s[name], **run.report.timings_s},
                                 findings, fixed_wing=inputs[name].plan.fixed_wing)
        notify("done", name)
        return run, report

    # the error-state filter first: the three-stage filter waits for its bias states (nogil kernels: side by side)
    order = sorted(names, key=lambda name: (name != bias.source, name == THREE_STAGE))
    done = dict(zip(order, thread_map(run_one, order, len(names) if threads is None else threads), strict=True))
    finished = [done[name] for name in names]
    notify("report", "")
    runs = [run for run, _ in finished]
    reports = {name: report for name, (_, report) in zip(names, finished, strict=True)}
    state_columns = dict.fromkeys(column for run in runs for column in run.states.columns)
    extra = [column for column in state_columns if column not in STATE_COLUMNS]
    states = _stacked(names, [run.states for run in runs], (*STATE_COLUMNS[1:], *extra))
    diagnostics = _stacked(names, [run.diagnostics for run in runs], DIAGNOSTIC_COLUMNS[1:])
    return ReplayResult(states=states, diagnostics=diagnostics, reports=reports, input_quality=findings)


class _ThreeStageBias:
    """The accelerometer bias the three-stage filter (no bias states) removes from its specific force when no
    calibration gives one: the error-state filter's in-flight estimate on the same inputs and settings
    (docs/three_stage.md, 'Pre-processing'). Taken from that filter's run in this replay when it runs with
    the same settings, else from a run of its own, so the three-stage result does not depend on the selection."""

    source = INDIRECT

    def __init__(self, flight_log: FlightLog, names: tuple[str, ...], configs: Mapping[str, EstimatorConfig],
                 inputs: Mapping[str, object]) -> None:
        self._log, self._inputs = flight_log, inputs.get(THREE_STAGE)
        self._base = configs.get(THREE_STAGE)
        self.needed = (self._base is not None and self._base.calibrated.accel_bias_m_s2 is None
                       and self._inputs.plan.has_gps)
        self.shared = (self.needed and self.source in names and configs[self.source] == self._base
                       and inputs[self.source] is self._inputs)
        self._run: Future = Future()

    def offer(self, name: str, run: EstimatorRun | BaseException) -> None:
        """Keep the error-state run of this replay (or its failure) when it is the one the three-stage filter
        needs."""
        if self.shared and name == self.source:
            if isinstance(run, BaseException):
                self._run.set_exception(run)
            else:
                self._run.set_result(run)

    def config(self) -> EstimatorConfig:
        """The three-stage settings with the in-flight bias, or as given when it is not needed or not trusted
        (:func:`estimators.inflight_bias.trusted_bias_states`). Per axis: an axis whose posterior standard
        deviation is above :data:`calib.figures.MAX_ACCEL_BIAS_STD_M_S2` (not converged) is left at zero; the
        horizontal axes are what tilt the levelling, and a z bias with a random walk (which never converges as
        far) must not keep them out."""
        if not self.needed:
            return self._base
        run = self._run.result() if self.shared else run_indirect(self._log, self._inputs, self._base)
        states = trusted_bias_states(run)
        if states is None:
            return self._base
        converged = [math.isfinite(v) and v <= MAX_ACCEL_BIAS_STD_M_S2 for v in states.accel_bias_std_m_s2]
        if not any(converged):
            return self._base
        bias = tuple(b if ok else 0.0 for b, ok in zip(states.accel_bias_m_s2, converged, strict=True))
        use = "subtracted from the specific force (the error-state filter's final bias states in this replay"
        left = [f"{axis} (sigma {std:.3f} m/s^2)" for axis, ok, std in zip("xyz", converged,
                                                                        states.accel_bias_std_m_s2, strict=True)
                if not ok]
        use += f"; not converged, left at zero: {', '.join(left)})" if left else ")"
        calibrated = self._base.calibrated
        return replace(self._base, calibrated=replace(
            calibrated, accel_bias_m_s2=bias,
            provenance=(*calibrated.provenance, (FIGURES.accel_bias.name, SOURCE_INFLIGHT_BIAS, use))))


def checked_input_quality(flight_log: FlightLog, *, allow_untrusted: bool = False) -> tuple[QualityFinding, ...]:
    """The log's quality findings (:func:`ingest.quality.assess_input_quality`), after the refusal policy.

    Raises
    ------
    InputError
        A finding is refused and ``allow_untrusted`` is False: one line naming every refused finding (stream and
        figure) and the override.
    """
    findings = assess_input_quality(flight_log)
    refused = [finding.message for finding in findings if finding.severity == REFUSE]
    if refused and not allow_untrusted:
        raise InputError(f"refused: {'; '.join(refused)}; replay anyway with --force (allow_untrusted=True), "
                         "every report then carries the warning", source=flight_log.meta.source)
    return findings


def quality_warnings(findings: Sequence[QualityFinding]) -> list[str]:
    """One warning per finding: :data:`UNTRUSTED_PREFIX` for a refused (forced) one, :data:`FLAGGED_PREFIX` for a
    flagged one, refused first."""
    return [(UNTRUSTED_PREFIX if finding.severity == REFUSE else FLAGGED_PREFIX) + finding.message
            for finding in findings]


def _stacked(names: tuple[str, ...], frames: list[pd.DataFrame], columns: Sequence[str]) -> pd.DataFrame:
    """The estimators' tables one below the other, led by the categorical ``estimator`` column.

    Built column by column, so every value is copied once (no frame-wide concatenation and reordering); a column
    an estimator lacks is NaN in its rows.
    """
    lengths = [len(frame) for frame in frames]
    codes = np.repeat(np.arange(len(names), dtype=np.int8), lengths)
    table = {"estimator": pd.Categorical.from_codes(codes, categories=list(names))}
    for column in columns:
        present = [frame[column] for frame in frames if column in frame.columns]
        if all(part.dtype.kind == "f" for part in present):  # numbers: one numpy copy, NaN where missing
            table[column] = np.concatenate([frame[column].to_numpy() if column in frame.columns
                                            else np.full(len(frame), np.nan) for frame in frames])
            continue
        parts = [frame[column] if column in frame.columns else pd.Series(np.nan, index=frame.index)
                 for frame in frames]
        table[column] = pd.concat(parts, ignore_index=True)
    return pd.DataFrame(table, copy=False)


def _checked_report(run: EstimatorRun, config: EstimatorConfig, timings: dict[str, float],
                    findings: Sequence[QualityFinding] = (), *, fixed_wing: bool = False) -> EstimatorReport:
    """The run's report with its timings, the NIS consistency per channel and the estimator's verdict
    (:func:`estimators.consistency.estimator_verdict`; one warning when it is inconsistent), the calibration
    provenance, the input quality findings (leading the warnings), and for a
    fixed-wing aircraft a warning when its wind estimate has the air flowing backwards through the airframe."""
    report = run.report
    channels = channel_consistency(run.diagnostics)
    provenance = config.calibrated.provenance
    ignored = IGNORED_FIGURES.get(report.estimator, {})
    calibration = [{"figure": figure, "source": source,
                    "use": f"ignored: {ignored[figure]}" if figure in ignored else use}
                   for figure, source, use in provenance]
    warnings = [*quality_warnings(findings), *report.warnings]
    verdict = estimator_verdict(report.estimator, channel_verdicts(report.estimator, run.diagnostics, config.noise,
                                                                   channels))
    if verdict.status == "inconsistent":  # one warning for the estimator, its channels in the verdict
        warnings.append(f"{report.estimator}: {verdict.summary}")
    reversed_share = reversed_airflow_fraction(run.states) if fixed_wing else math.nan
    if reversed_share > REVERSED_AIRFLOW_LIMIT:
        warnings.append(f"{report.estimator}: wind estimate not trusted: in {100 * reversed_share:.0f} % of the "
                        "wing-borne epochs the estimated air flows backwards through the airframe (the mirrored "
                        "solution of airspeed and sideslip; wind noise set too high or a wrong heading)")
    details = {**report.details, "consistency": [dataclasses.asdict(c) for c in channels],
               "verdict": dataclasses.asdict(verdict),
               "reversed_airflow_fraction": reversed_share if math.isfinite(reversed_share) else None,
               "calibration": calibration, "input_quality": [dataclasses.asdict(f) for f in findings]}
    return replace(report, timings_s=timings, warnings=tuple(warnings), details=details)
