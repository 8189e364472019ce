"""The filter replay behind an automatic tau (paper eq 52): the three-stage estimator, whose stage 1 fuses the
accelerometer, re-run on a log for a candidate tau with the noise of a calibration.

It lives in the estimators layer because it runs a filter; :func:`calib.tau.choose_tau` receives it as an injected
``tau -> Innovations`` callable, so calib itself never imports the estimators.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import replace

from calib.bias import InflightBias
from calib.calibration import Calibration
from calib.filter_figures import calibration_figures
from calib.tau import Innovations
from estimators.config import config_from_calibration
from estimators.consistency import MIN_UPDATES, NIS_WARNING_RANGE, channel_consistency
from estimators.indirect.run import run as run_indirect
from estimators.inputs.build import build_replay_inputs
from estimators.three_stage.run import run as run_three_stage
from ingest.errors import InputError
from ingest.flightlog import FlightLog


def tau_replay(log: FlightLog, cal: Calibration) -> Callable[[float], Innovations]:
    """``tau -> Innovations`` of the three-stage estimator's body-y accelerometer updates (every update, gated or
    not) on ``log`` with the noise of ``cal``: the replay :func:`calib.tau.choose_tau` needs.

    The replay inputs are built once; each call runs the filter with that tau in ``config.calibrated.accel_tau``.

    Raises
    ------
    InputError
        (from the returned callable) when the replay made no accelerometer update, so tau cannot be chosen.
    """
    config = config_from_calibration(cal)
    inputs = build_replay_inputs(log, config)

    def replay(tau: float) -> Innovations:
        run = run_three_stage(log, inputs, replace(config, calibrated=replace(config.calibrated, accel_tau=tau)))
        diagnostics = run.diagnostics
        rows = diagnostics[(diagnostics["sensor"] == "accel") & (diagnostics["component"] == "y")]
        if rows.empty:
            raise InputError("the three-stage replay made no accelerometer update: tau cannot be chosen "
                             "automatically; give a number", source=log.meta.source, field="--tau")
        return Innovations(rows["innovation"].to_numpy(dtype=float), rows["innovation_var"].to_numpy(dtype=float))

    return replay


def inflight_bias(log: FlightLog, cal: Calibration) -> InflightBias | None:
    """The error-state filter's final gyro and accelerometer bias states on ``log`` with the noise of ``cal`` (None
    without GPS, when the accelerometer biases are not observable, when the filter diverged, or when its GPS
    channels are inconsistent: docs/calibration.md, 'From calibration to filter settings').

    The accelerometer bias is observed through the GPS velocity and position; a GPS channel whose mean NIS is
    above the warning limit means the filter explained a model error (a tilt pulled by a disturbed
    magnetometer, say) with its bias states, while their covariance still says "converged"."""
    config = config_from_calibration(cal)
    inputs = build_replay_inputs(log, config, rate_hz=1.0)
    if not inputs.plan.has_gps:
        return None
    run = run_indirect(log, inputs, config)
    final, std = run.report.details["final_state"], run.report.details["final_state_std"]
    if run.report.resets or not all(math.isfinite(final[f"b{k}{a}"]) for k in "ga" for a in "xyz"):
        return None
    if any(c.channel.startswith("gps_") and c.n_updates >= MIN_UPDATES and c.mean_nis > NIS_WARNING_RANGE[1]
           for c in channel_consistency(run.diagnostics)):
        return None
    end_s = float(run.states["time_s"].iloc[-1])
    return InflightBias(source="full_state_indirect", window_s=(end_s, end_s),
                        gyro_bias_rad_s=tuple(final[f"bg{a}"] for a in "xyz"),
                        gyro_bias_std_rad_s=tuple(std.get(f"dbg{a}", math.nan) for a in "xyz"),
                        accel_bias_m_s2=tuple(final[f"ba{a}"] for a in "xyz"),
                        accel_bias_std_m_s2=tuple(std.get(f"dba{a}", math.nan) for a in "xyz"))


def with_filter_figures(log: FlightLog, cal: Calibration) -> Calibration:
    """``cal`` completed for the filters: its in-flight bias (:func:`inflight_bias`, unless it has one) and its filter
    figures (:func:`calib.filter_figures.calibration_figures`) filled in, as CALIB.json stores them."""
    if cal.inflight_bias is None:
        cal = dataclasses.replace(cal, inflight_bias=inflight_bias(log, cal))
    return dataclasses.replace(cal, figures=calibration_figures(cal))
