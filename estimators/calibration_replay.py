"""The filter replay behind an automatic tau (paper eq 52): the three-stage estimator, whose stage 1 fuses the
accelerometer, re-run on a log for a candidate tau with the noise of a calibration.

It lives in the estimators layer because it runs a filter; :func:`calib.tau.choose_tau` receives it as an injected
``tau -> Innovations`` callable, so calib itself never imports the estimators.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import replace

from calib.bias import InflightBias
from calib.calibration import Calibration
from calib.filter_figures import calibration_figures
from calib.tau import Innovations
from estimators.config import config_from_calibration
from estimators.indirect.run import run as run_indirect
from estimators.inflight_bias import trusted_bias_states
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
    """The error-state filter's final gyro and accelerometer bias states on ``log`` with the noise of ``cal``
    (:func:`estimators.inflight_bias.trusted_bias_states`; None without GPS)."""
    config = config_from_calibration(cal)
    inputs = build_replay_inputs(log, config, rate_hz=1.0)
    if not inputs.plan.has_gps:
        return None
    states = trusted_bias_states(run_indirect(log, inputs, config))
    if states is None:
        return None
    return InflightBias(source="full_state_indirect", window_s=(states.end_s, states.end_s),
                        gyro_bias_rad_s=states.gyro_bias_rad_s, gyro_bias_std_rad_s=states.gyro_bias_std_rad_s,
                        accel_bias_m_s2=states.accel_bias_m_s2, accel_bias_std_m_s2=states.accel_bias_std_m_s2)


def with_filter_figures(log: FlightLog, cal: Calibration) -> Calibration:
    """``cal`` completed for the filters: its in-flight bias (:func:`inflight_bias`, unless it has one) and its filter
    figures (:func:`calib.filter_figures.calibration_figures`) filled in, as CALIB.json stores them."""
    if cal.inflight_bias is None:
        cal = dataclasses.replace(cal, inflight_bias=inflight_bias(log, cal))
    return dataclasses.replace(cal, figures=calibration_figures(cal))
