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
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from calib.calibration import Calibration
from calib.figures import SOURCE_TUNED, Figure, TuneResult, rms
from calib.filter_figures import calibration_figures
from estimators.api import DEFAULT_ESTIMATORS, estimator_function, parse_estimator_names
from estimators.config import EstimatorConfig, config_from_figures
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
from estimators.inputs.records import SensorPlan
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


@dataclass(frozen=True)
class Knob:
    """One identified figure.

    Attributes
    ----------
    figure : str
        Name in :data:`calib.figures.FIGURES`.
    lower, upper : float
        Search bounds in the figure's unit.
    channel : str or None
        Diagnostics channel whose mean NIS the covariance-matching step uses (measurement figures only): a sensor
        (``"baro"``) or ``"sensor.c1c2"`` for some of its components (``"gps_pos.ne"``).
    estimators : tuple of str
        Estimators that use the figure.
    needs : str or None
        Sensor-plan attribute that must be true (``has_airspeed``, ``has_mag``, ...).
    """

    figure: str
    lower: float
    upper: float
    channel: str | None = None
    estimators: tuple[str, ...] = DEFAULT_ESTIMATORS
    needs: str | None = None


_FULL = ("full_state_direct", "full_state_indirect")
#: Every identifiable figure; bounds span the low-cost sensors of docs/calibration.md, 'Noise identification'.
#: The three-stage filter's gyro, airspeed and wind figures are not identified: there they drive stages whose
#: errors the next stage takes as exact inputs, so the summed innovation likelihood of the cascade is not a joint
#: one and rises when the error is moved into a stage with few innovations (its heading, measured: 7.7 -> 21 deg
#: in gusty air with every channel's NIS inside 0.2 .. 3).
KNOBS = (
    Knob("baro_noise", 0.02, 20.0, "baro", _FULL, "has_baro"),
    Knob("mag_noise", 2e-4, 0.3, "mag", needs="has_mag"),
    Knob("airspeed_noise", 0.02, 5.0, "airspeed", _FULL, "has_airspeed"),
    # the zero-sideslip pseudo-measurement's error is the aircraft's real sideslip (turns, gusts before the
    # weathercock settles), correlated over a turn: like the GPS position the likelihood would shrink it without
    # end, so it is floored at 0.2 m/s, about 1 deg of sideslip at 12 m/s (a well-coordinated small fixed wing)
    Knob("sideslip_noise", 0.2, 3.0, "sideslip", _FULL, "has_airspeed"),
    # GPS position error is correlated over minutes: short-term innovations would shrink its figure far below the
    # receiver's own accuracy estimate, which is the floor (the scale only inflates it, e.g. for multipath).
    Knob("gps_pos_noise_scale", 1.0, 5.0, "gps_pos.ne", needs="has_gps"),
    Knob("gps_hgt_noise_scale", 1.0, 5.0, "gps_pos.d", needs="has_gps"),
    Knob("gps_vel_noise_scale", 0.1, 10.0, "gps_vel", needs="has_gps"),
    Knob("accel_stage1_floor", 0.02, 2.0, "accel", ("three_stage",)),
    Knob("accel_tau", 0.1, 100.0, None, ("three_stage",)),
    Knob("gyro_noise_density", 1e-5, 3e-2, None, _FULL),
    Knob("accel_noise_density", 1e-4, 0.5, None, _FULL),
    Knob("gyro_bias_walk", 1e-7, 1e-2, None, _FULL),
    Knob("accel_bias_walk", 1e-5, 3e-3, None, _FULL, "has_gps"),
    Knob("accel_bias_walk_z", 1e-5, 0.1, None, _FULL, "has_gps"),
    Knob("wind_walk", 1e-3, 5.0, None, _FULL, "has_airspeed"),
    # at most ArduPilot EKF3's EK3_MAGB_P_NSE range top (0.01 gauss/s): faster, the bias follows a disturbance
    Knob("mag_bias_walk", 1e-7, 0.01, None, _FULL, "has_mag"),
    Knob("baro_bias_walk", 1e-4, 1.0, None, _FULL, "has_baro"),
)


def start_values(config: EstimatorConfig, strength_gauss: float) -> dict[str, float]:
    """The value of every knob's figure in ``config`` (the filter setting it stands for)."""
    noise, calibrated = config.noise, config.calibrated
    mag_axes = noise.mag_sigma_axes or (noise.mag_sigma,) * 3
    return {
        "baro_noise": noise.baro_sigma_m, "airspeed_noise": noise.airspeed_sigma_m_s,
        "mag_noise": rms(mag_axes) * strength_gauss, "sideslip_noise": noise.sideslip_sigma_m_s,
        "gps_pos_noise_scale": 1.0, "gps_hgt_noise_scale": 1.0, "gps_vel_noise_scale": noise.gps_vel_accuracy_scale,
        "accel_stage1_floor": (calibrated.accel_stage1_floor_m_s2 if calibrated.accel_stage1_floor_m_s2 is not None
                               else ThreeStageOptions().accel_sigma_floor_m_s2),
        "accel_tau": calibrated.accel_tau, "gyro_noise_density": noise.gyro_noise_rad_s_sqrt_hz,
        "accel_noise_density": noise.accel_noise_m_s2_sqrt_hz, "gyro_bias_walk": noise.gyro_bias_rw_rad_s2_sqrt_hz,
        "accel_bias_walk": noise.accel_bias_rw_m_s3_sqrt_hz,
        "accel_bias_walk_z": (noise.accel_bias_rw_z_m_s3_sqrt_hz if noise.accel_bias_rw_z_m_s3_sqrt_hz is not None
                              else noise.accel_bias_rw_m_s3_sqrt_hz),
        "wind_walk": noise.wind_rw_m_s_sqrt_s, "mag_bias_walk": noise.mag_bias_rw_sqrt_s * strength_gauss,
        "baro_bias_walk": noise.baro_bias_rw_m_sqrt_s,
    }


def knobs_for(estimator: str, plan: SensorPlan) -> tuple[Knob, ...]:
    """The knobs ``estimator`` uses on a log with sensor plan ``plan``."""
    return tuple(k for k in KNOBS if estimator in k.estimators and (k.needs is None or getattr(plan, k.needs)))


def tuned_figures(base: dict[str, Figure], values: dict[str, float], start_mag_axes: tuple[float, ...],
                  strength_gauss: float) -> dict[str, Figure]:
    """``base`` with every knob value as a tuned figure (magnetometer axes scaled together, keeping their ratio;
    the field strength recorded so the figures convert back exactly)."""
    figures = dict(base)
    for name, value in values.items():
        axes = ()
        if name == "mag_noise":
            ratio = value / (rms(start_mag_axes) * strength_gauss)
            axes = tuple(a * strength_gauss * ratio for a in start_mag_axes)
        figures[name] = Figure(name, value, SOURCE_TUNED, axes=axes)
    if "mag_noise" in values or "mag_bias_walk" in values:
        figures["mag_field_strength"] = Figure("mag_field_strength", strength_gauss, SOURCE_TUNED,
                                               note="median |m| of the log (the replay's normalisation)")
    return figures


def tune_estimator(log: FlightLog, cal: Calibration, estimator: str, *, budget: int = DEFAULT_BUDGET,
                   heading: str = "mag", sun_observations=None) -> TuneResult:
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
    """
    started = time.perf_counter()
    run_function = estimator_function(estimator)
    base_figures = calibration_figures(cal)
    start_config = config_from_figures(base_figures)
    inputs = build_replay_inputs(log, start_config, rate_hz=TUNE_OUTPUT_RATE_HZ, heading=heading,
                                 sun_observations=sun_observations)
    strength = inputs.mag_strength_gauss if math.isfinite(inputs.mag_strength_gauss) else 1.0
    knobs = knobs_for(estimator, inputs.plan)
    values = start_values(start_config, strength)
    start = {k.figure: values[k.figure] for k in knobs}
    start = {name: min(max(v, k.lower), k.upper) for (name, v), k in zip(start.items(), knobs, strict=True)}
    mag_axes = start_config.noise.mag_sigma_axes or (start_config.noise.mag_sigma,) * 3

    def figures_of(values):
        return tuned_figures(base_figures, values, mag_axes, strength)

    def replay(values) -> tuple[float, EstimatorRun]:
        config = config_from_figures(figures_of(values))
        run_inputs = build_replay_inputs(log, config, rate_hz=TUNE_OUTPUT_RATE_HZ, heading=heading,
                                         sun_observations=sun_observations)
        run = run_function(log, run_inputs, config)
        return log_likelihood(run.diagnostics), run

    best_ll, best_run = replay(start)
    best, trace, spent, notes = dict(start), [best_ll], 1, []
    before = channel_consistency(best_run.diagnostics)
    # A channel may not leave the warning range further than it started: above it the filter trusts a sensor
    # too much (or diverges), below it the sensor is in effect ignored (its figure inflated until the others
    # explain everything: a magnetometer at 0.3 gauss leaves the heading to drift).
    limits = {c.channel: (min(NIS_WARNING_RANGE[0], c.mean_nis / NIS_START_TOLERANCE),
                          max(NIS_WARNING_RANGE[1], c.mean_nis * NIS_START_TOLERANCE)) for c in before}
    start_resets = best_run.report.resets + best_run.report.gps_resets

    check_airflow = inputs.plan.fixed_wing and inputs.plan.has_airspeed
    airflow_limit = max(REVERSED_AIRFLOW_LIMIT, _reversed_share(best_run)) if check_airflow else math.inf

    def feasible(run) -> bool:
        """No channel more inconsistent than the warning limit (or than at the start), no more resets and no
        mirrored wind (air flowing backwards through the airframe fits the airspeed and GPS innovations as well
        as the true wind: the likelihood cannot see it); the clipped likelihood alone would also let a diverging
        channel pay only a fixed price per update."""
        if run.report.resets + run.report.gps_resets > start_resets:
            return False
        if check_airflow and _reversed_share(run) > airflow_limit:
            return False
        for c in channel_consistency(run.diagnostics):
            low, high = limits.get(c.channel, NIS_WARNING_RANGE)
            if c.n_updates >= MIN_UPDATES and not low <= c.mean_nis <= high:
                return False
        return True

    def evaluate(values):
        ll, run = replay(values)
        return (ll if feasible(run) else -math.inf), run

    # 1. covariance matching on the measurement figures (repeated while it pays)
    for _ in range(MATCH_ITERATIONS):
        if spent >= budget:
            break
        matched = dict(best)
        for k in knobs:
            nis = _mean_nis(best_run, k.channel) if k.channel else math.nan
            if math.isfinite(nis):
                factor = min(max(math.sqrt(nis), 1.0 / MATCH_FACTOR_LIMIT), MATCH_FACTOR_LIMIT)
                matched[k.figure] = min(max(best[k.figure] * factor, k.lower), k.upper)
        if matched == best:
            break
        ll, run = evaluate(matched)
        spent += 1
        if ll <= best_ll:
            trace.append(best_ll)
            break
        best_ll, best, best_run = ll, matched, run
        trace.append(best_ll)

    # 2. coordinate pattern search in log10
    for step in STEPS_DECADES:
        improved_any = False
        for k in knobs:
            for direction in (+1.0, -1.0):
                moved = False
                while spent < budget:  # keep going while the likelihood rises
                    candidate = dict(best)
                    candidate[k.figure] = min(max(best[k.figure] * 10.0 ** (direction * step), k.lower), k.upper)
                    if candidate[k.figure] == best[k.figure]:
                        break
                    ll, run = evaluate(candidate)
                    spent += 1
                    if ll <= best_ll:
                        trace.append(best_ll)
                        break
                    best_ll, best, best_run, moved = ll, candidate, run, True
                    trace.append(best_ll)
                if moved:
                    improved_any = True
                    break
        if spent >= budget:
            notes.append(f"replay budget of {budget} spent at a step of {step:g} decade")
            break
        if not improved_any:
            continue
    for k in knobs:
        if best[k.figure] in (k.lower, k.upper):
            notes.append(f"{k.figure} at its {'lower' if best[k.figure] == k.lower else 'upper'} bound "
                         f"{best[k.figure]:.3g}")
    bounds = {k.figure: (k.lower, k.upper) for k in knobs}
    return TuneResult(estimator=estimator, figures=figures_of(best), start=start, bounds=bounds,
                      log_likelihood_trace=tuple(trace), n_replays=spent, nis_before=before,
                      nis_after=channel_consistency(best_run.diagnostics), wall_s=time.perf_counter() - started,
                      notes=tuple(notes))


def tune_calibration(log: FlightLog, cal: Calibration, estimators: str | Sequence[str] = DEFAULT_ESTIMATORS, *,
                     budget: int = DEFAULT_BUDGET, heading: str = "mag", sun_observations=None,
                     threads: int = 2) -> Calibration:
    """``cal`` with ``tuning`` filled for every estimator (identified concurrently in ``threads`` threads)."""
    names = parse_estimator_names(estimators)
    with ThreadPoolExecutor(max_workers=max(1, threads)) as pool:
        futures = {name: pool.submit(tune_estimator, log, cal, name, budget=budget, heading=heading,
                                     sun_observations=sun_observations) for name in names}
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
