"""The bias states of an error-state run that the other filters and the calibration may take as biases
(docs/calibration.md, 'From calibration to filter settings'; docs/three_stage.md, 'Pre-processing')."""

from __future__ import annotations

import math
from dataclasses import dataclass

from estimators.consistency import MIN_UPDATES, NIS_WARNING_RANGE, channel_consistency
from estimators.core.results import EstimatorRun

Vector3 = tuple[float, float, float]


@dataclass(frozen=True)
class BiasStates:
    """Final bias states of an error-state run and their posterior standard deviations (body FRD).

    Attributes
    ----------
    end_s : float
        Time of the final state on the log clock [s].
    gyro_bias_rad_s, gyro_bias_std_rad_s : tuple of 3 float
        Gyro bias [rad/s].
    accel_bias_m_s2, accel_bias_std_m_s2 : tuple of 3 float
        Accelerometer bias [m/s^2].
    """

    end_s: float
    gyro_bias_rad_s: Vector3
    gyro_bias_std_rad_s: Vector3
    accel_bias_m_s2: Vector3
    accel_bias_std_m_s2: Vector3


def trusted_bias_states(run: EstimatorRun) -> BiasStates | None:
    """The final gyro and accelerometer bias states of an error-state run (None when the filter reset or diverged,
    or when its GPS channels are inconsistent).

    The accelerometer bias is observed through the GPS velocity and position; a GPS channel whose mean NIS is
    above the warning limit means the filter explained a model error (a tilt pulled by a disturbed
    magnetometer, say) with its bias states, while their covariance still says "converged"."""
    final, std = run.report.details["final_state"], run.report.details["final_state_std"]
    if run.report.resets or not all(math.isfinite(final[f"b{k}{a}"]) for k in "ga" for a in "xyz"):
        return None
    if any(c.channel.startswith("gps_") and c.n_updates >= MIN_UPDATES and c.mean_nis > NIS_WARNING_RANGE[1]
           for c in channel_consistency(run.diagnostics)):
        return None
    return BiasStates(end_s=float(run.states["time_s"].iloc[-1]),
                      gyro_bias_rad_s=tuple(final[f"bg{a}"] for a in "xyz"),
                      gyro_bias_std_rad_s=tuple(std.get(f"dbg{a}", math.nan) for a in "xyz"),
                      accel_bias_m_s2=tuple(final[f"ba{a}"] for a in "xyz"),
                      accel_bias_std_m_s2=tuple(std.get(f"dba{a}", math.nan) for a in "xyz"))
