"""Filter noise figures: the calibrated (or identified) numbers an estimator is run with, each with its source.

A :class:`~calib.calibration.Calibration` holds what was measured (eq 50 residuals, still-segment biases, Allan
figures, eq 51 R, eq 52 tau). What a filter needs is something else: a white-noise density for the IMU, a
per-sample sigma per fused measurement axis, random walks. :data:`FIGURES` is that vocabulary, in physical units
(docs/calibration.md, 'From calibration to filter settings'); each value travels as a :class:`Figure` that says
where it came from, so a report can say which calibrated figure a run used and why, and the PX4 / ArduPilot
parameter export and CALIB.json (schema 2, section ``figures``) share one table.

Noise identification (``solarnav calibrate --tune``) returns a :class:`TuneResult` per estimator: the identified
figures (source :data:`SOURCE_TUNED`), the likelihood trace and the NIS per channel before and after.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from scipy.special import chdtri

#: name -> (unit, meaning). Densities are per sqrt(Hz) (variance per second of a white process), walks per
#: sqrt(s), measurement noises per sample (docs/nomenclature.md).
FIGURES: dict[str, tuple[str, str]] = {
    "gyro_noise_density": ("rad/s/sqrt(Hz)", "gyroscope white-noise density (angle random walk)"),
    "accel_noise_density": ("m/s^2/sqrt(Hz)", "accelerometer white-noise density (velocity random walk)"),
    "accel_axis_noise_density": ("m/s^2/sqrt(Hz)", "accelerometer white-noise density per axis x, y, z (eq 51 R "
                                                   "without tau), for the three-stage stage-1 update"),
    "accel_stage1_floor": ("m/s^2", "model-error floor of the three-stage stage-1 accelerometer sigma at its update "
                                    "rate"),
    "gyro_bias_walk": ("rad/s^2/sqrt(Hz)", "gyroscope bias random walk"),
    "accel_bias_walk": ("m/s^3/sqrt(Hz)", "accelerometer bias random walk, body x and y"),
    "accel_bias_walk_z": ("m/s^3/sqrt(Hz)", "accelerometer bias random walk, body z"),
    "gyro_bias": ("rad/s", "gyroscope bias, per axis x, y, z (body FRD)"),
    "accel_bias": ("m/s^2", "accelerometer bias, per axis x, y, z (body FRD)"),
    "accel_tau": ("-", "eq 52 penalty factor on the stage-1 body-y accelerometer variance"),
    "mag_noise": ("gauss", "magnetometer noise per sample, per axis x, y, z"),
    "mag_field_strength": ("gauss", "earth-field strength the magnetometer is normalised by"),
    "mag_bias_walk": ("gauss/sqrt(s)", "magnetometer hard-iron bias random walk"),
    "baro_noise": ("m", "barometric altitude noise per sample"),
    "baro_bias_walk": ("m/sqrt(s)", "barometer offset (to GPS height) random walk"),
    "airspeed_noise": ("m/s", "true-airspeed noise per sample"),
    "sideslip_noise": ("m/s", "zero-sideslip pseudo-measurement noise on the body-y air velocity"),
    "gps_pos_noise_scale": ("-", "factor on the GPS horizontal position sigma (receiver accuracy, floored)"),
    "gps_hgt_noise_scale": ("-", "factor on the GPS height sigma (receiver accuracy, floored)"),
    "gps_vel_noise": ("m/s", "GPS velocity noise per sample, when the receiver reports no accuracy"),
    "gps_vel_noise_scale": ("-", "factor on the GPS velocity sigma (receiver accuracy, floored)"),
    "wind_walk": ("m/s/sqrt(s)", "wind random walk (turbulence following)"),
}


def chi2_quantile(probability: float, dof: int | float) -> float:
    """``probability`` quantile of the chi-square distribution with ``dof`` degrees of freedom (``chi2.ppf``, from
    :mod:`scipy.special`: importing :mod:`scipy.stats` costs the CLI most of a second)."""
    return float(chdtri(dof, 1.0 - probability))


def mean_nis_band(n: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided ``probability`` band of the mean of ``n`` chi-square(1) values (the NIS of a consistent filter)."""
    tail = (1.0 - probability) / 2.0
    return chi2_quantile(tail, n) / n, chi2_quantile(1.0 - tail, n) / n


#: Where a figure came from (the ``source`` of a :class:`Figure`).
SOURCE_DEFAULT = "default"
SOURCE_STILL = "still segment (eq 50 residual)"
SOURCE_ALLAN = "Allan deviation (still segment)"
SOURCE_INFLIGHT = "in-flight eq 50 residual"
SOURCE_INFLIGHT_BOUND = "in-flight eq 50 residual (upper bound, model-error treatment)"
SOURCE_STILL_BIAS = "still-segment bias"
SOURCE_INFLIGHT_BIAS = "in-flight bias estimate"
SOURCE_TAU = "eq 52"
SOURCE_RECEIVER = "receiver accuracy fields"
SOURCE_R = "eq 51 R (CALIB.json, hand edits honoured)"
SOURCE_TUNED = "tuned (innovation likelihood)"
SOURCE_USER = "user"
SOURCES = (SOURCE_DEFAULT, SOURCE_STILL, SOURCE_ALLAN, SOURCE_INFLIGHT, SOURCE_INFLIGHT_BOUND, SOURCE_STILL_BIAS,
           SOURCE_INFLIGHT_BIAS, SOURCE_TAU, SOURCE_RECEIVER, SOURCE_R, SOURCE_TUNED, SOURCE_USER)


@dataclass(frozen=True)
class Figure:
    """One filter figure with its provenance.

    Attributes
    ----------
    name : str
        Key of :data:`FIGURES`.
    value : float
        The figure in the unit of :data:`FIGURES` (for a per-axis figure: the RMS over its axes).
    source : str
        One of :data:`SOURCES`.
    axes : tuple of float
        Per-axis values (empty for a scalar figure).
    note : str
        Why this source, or what was done to the raw number.
    """

    name: str
    value: float
    source: str
    axes: tuple[float, ...] = ()
    note: str = ""

    def __post_init__(self):
        if self.name not in FIGURES:
            raise ValueError(f"unknown figure {self.name!r}; known: {', '.join(FIGURES)}")

    @property
    def unit(self) -> str:
        """Unit of :attr:`value` (from :data:`FIGURES`)."""
        return FIGURES[self.name][0]


@dataclass(frozen=True)
class ChannelConsistency:
    """Mean NIS of one measurement channel (sensor, component) of one replay against its chi-square band.

    Attributes
    ----------
    channel : str
        ``"<sensor>.<component>"`` as in the diagnostics table.
    n_updates : int
        Scalar updates of the channel.
    mean_nis : float
        Mean of nu^2 / S over them [-] (1 for a consistent filter).
    band : tuple of 2 float
        95 % two-sided band of the mean of ``n_updates`` chi-square(1) values.
    """

    channel: str
    n_updates: int
    mean_nis: float
    band: tuple[float, float]


@dataclass(frozen=True)
class TuneResult:
    """Noise identified for one estimator from the flight's own innovations.

    Attributes
    ----------
    estimator : str
        Registry name of the estimator.
    figures : dict of str -> Figure
        Every figure the estimator was run with after tuning (tuned ones with source :data:`SOURCE_TUNED`, the
        others as they came from the calibration).
    start : dict of str -> float
        Starting value of every tuned figure.
    bounds : dict of str -> tuple of 2 float
        Search bounds of every tuned figure.
    log_likelihood_trace : tuple of float
        Innovation log-likelihood of the best point after each replay (first entry: the start).
    n_replays : int
        Filter replays spent.
    nis_before, nis_after : tuple of ChannelConsistency
        Per channel, at the start and at the tuned figures.
    wall_s : float
        Wall time of the identification [s].
    notes : tuple of str
        What the search did (bounds reached, budget spent, parameters left out and why).
    """

    estimator: str
    figures: dict[str, Figure]
    start: dict[str, float]
    bounds: dict[str, tuple[float, float]]
    log_likelihood_trace: tuple[float, ...]
    n_replays: int
    nis_before: tuple[ChannelConsistency, ...] = ()
    nis_after: tuple[ChannelConsistency, ...] = ()
    wall_s: float = 0.0
    notes: tuple[str, ...] = field(default_factory=tuple)


def rms(values) -> float:
    """Root mean square of a non-empty sequence of numbers (the value of a per-axis figure)."""
    values = [float(v) for v in values]
    return math.sqrt(sum(v * v for v in values) / len(values))
