"""Calibrating a log: eq 50-52 noise and bias, the automatic tau, the filter figures (in-flight bias) and the noise
identified per estimator, in the order ``solarnav calibrate``, the Calibration page and ``solarnav batch
--calibrate`` all run them."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence

from calib.bias import local_gravity
from calib.calibration import Calibration, FirSettings, calibrate, with_tau
from calib.segments import Segment
from calib.tau import DEFAULT_TAU, Innovations, TauSelection, choose_tau
from estimators.api import DEFAULT_ESTIMATORS
from estimators.calibration_replay import tau_replay, with_filter_figures
from estimators.tuning import DEFAULT_BUDGET, TuneProgress, tune_calibration
from estimators.warmup import prepare_compile
from ingest.flightlog import FlightLog

#: ``on_compile(message)``: told before a replay compiles the filters (their numba cache is cold).
CompileNotice = Callable[[str], None]


def calibrate_log(log: FlightLog, *, segment: Segment | None = None, fir: dict[str, FirSettings] | None = None,
                  noise: str = "sigma", tau: TauSelection | None = DEFAULT_TAU, tau_method: str = "likelihood",
                  tune: Sequence[str] = (), tune_budget: int = DEFAULT_BUDGET,
                  on_compile: CompileNotice | None = None) -> Calibration:
    """Everything ``solarnav calibrate`` computes for one log.

    Parameters
    ----------
    log : FlightLog
        The flight.
    segment, fir, noise
        As :func:`calib.calibration.calibrate` (None: automatic segments / rate-based FIR defaults).
    tau : TauSelection or None
        The eq 52 penalty; None chooses it by replaying the three-stage estimator (:func:`choose_tau_by_replay`,
        ``--tau auto``) with ``tau_method``.
    tune : sequence of str
        Estimators whose noise is identified from the flight's innovations (``--tune``); empty for none.
    tune_budget : int
        Filter replays per identified estimator.
    on_compile : callable, optional
        Told :data:`estimators.warmup.COMPILE_MESSAGE` before the first replay when the filters it needs are not in
        numba's cache yet.

    Returns
    -------
    Calibration
        With its filter figures (and the in-flight bias with GPS) and the identification results.
    """
    cal = measure_noise(log, segment=segment, fir=fir, noise=noise, tau=tau or DEFAULT_TAU)
    replayed = (["three_stage"] if tau is None else []) + (["full_state_indirect"] if log.has("gps") else [])
    message = prepare_compile([*replayed, *tune])
    if message is not None and on_compile is not None:
        on_compile(message)
    if tau is None:
        cal = with_tau(cal, choose_tau_by_replay(log, cal, tau_method))
    cal = with_filter_figures(log, cal)
    return tune_calibration(log, cal, tune, budget=tune_budget) if tune else cal


def measure_noise(log: FlightLog, *, segment: Segment | None = None, fir: dict[str, FirSettings] | None = None,
                  noise: str = "sigma", tau: TauSelection = DEFAULT_TAU) -> Calibration:
    """The eq 50-52 calibration of ``log`` (:func:`calib.calibration.calibrate`) with the local gravity of its
    first position: noise, bias, R and Allan figures, no filter replayed."""
    return calibrate(log, segment=segment, fir=fir, noise=noise, tau=tau, gravity=local_gravity(log))


def choose_tau_by_replay(log: FlightLog, cal: Calibration, method: str = "likelihood",
                         progress: Callable[[int], None] | None = None) -> TauSelection:
    """The eq 52 tau that makes the three-stage estimator's body-y accelerometer innovations most likely
    (``method="likelihood"``) or brings their mean NIS to 1 (``"nis"``), with the evidence curves; ``progress`` is
    told the number of replays made after each (the grid's :data:`calib.tau.TAU_GRID_POINTS` first, side by side
    in threads, then the search's)."""
    replay = tau_replay(log, cal)
    if progress is None:
        return choose_tau(replay, method=method)
    replays = itertools.count(1)

    def counted(tau: float) -> Innovations:
        innovations = replay(tau)
        progress(next(replays))
        return innovations

    return choose_tau(counted, method=method)


def identify_noise(log: FlightLog, cal: Calibration, estimators: str | Sequence[str] = DEFAULT_ESTIMATORS, *,
                   budget: int = DEFAULT_BUDGET, progress: TuneProgress | None = None) -> Calibration:
    """``cal`` completed with its filter figures (the in-flight bias, unless it has one) and the noise identified per
    estimator from the flight's innovations (docs/calibration.md, 'Noise identification'); ``progress`` is told
    after every replay (:data:`estimators.tuning.TuneProgress`)."""
    return tune_calibration(log, with_filter_figures(log, cal), estimators, budget=budget, progress=progress)
