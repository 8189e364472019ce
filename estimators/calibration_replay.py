"""The filter replay behind an automatic tau (paper eq 52): the three-stage estimator, whose stage 1 fuses the
accelerometer, re-run on a log for a candidate tau with the noise of a calibration.

It lives in the estimators layer because it runs a filter; :func:`calib.tau.choose_tau` receives it as an injected
``tau -> Innovations`` callable, so calib itself never imports the estimators.
"""

from __future__ import annotations

from collections.abc import Callable

from calib.calibration import Calibration
from calib.tau import Innovations
from estimators.config import config_from_calibration
from estimators.inputs.build import build_replay_inputs
from estimators.three_stage.run import ThreeStageOptions
from estimators.three_stage.run import run as run_three_stage
from ingest.errors import InputError
from ingest.flightlog import FlightLog


def tau_replay(log: FlightLog, cal: Calibration) -> Callable[[float], Innovations]:
    """``tau -> Innovations`` of the three-stage estimator's body-y accelerometer updates (every update, gated or
    not) on ``log`` with the noise of ``cal``: the replay :func:`calib.tau.choose_tau` needs.

    The replay inputs are built once; each call runs the filter with ``ThreeStageOptions(accel_tau=tau)``.

    Raises
    ------
    InputError
        (from the returned callable) when the replay made no accelerometer update, so tau cannot be chosen.
    """
    config = config_from_calibration(cal)
    inputs = build_replay_inputs(log, config)

    def replay(tau: float) -> Innovations:
        run = run_three_stage(log, inputs, config, options=ThreeStageOptions(accel_tau=tau))
        diagnostics = run.diagnostics
        rows = diagnostics[(diagnostics["sensor"] == "accel") & (diagnostics["component"] == "y")]
        if rows.empty:
            raise InputError("the three-stage replay made no accelerometer update: tau cannot be chosen "
                             "automatically; give a number", source=log.meta.source, field="--tau")
        return Innovations(rows["innovation"].to_numpy(dtype=float), rows["innovation_var"].to_numpy(dtype=float))

    return replay
