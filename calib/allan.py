"""Allan deviation of an IMU axis over a stationary segment and the figures read off it (docs/calibration.md, 'Allan
deviation').

Units below for a gyro axis in rad/s (accelerometer: replace rad by m/s):

* white-noise density N [rad/s/sqrt(Hz)]: fit of sigma(tau) = N / sqrt(tau) on the -1/2 slope, i.e. the value of
  the fitted line at tau = 1 s;
* bias instability B [rad/s] = min sigma(tau) / 0.664 (only a floor when the minimum is interior);
* rate random walk K [rad/s^2/sqrt(Hz)]: fit of sigma(tau) = K sqrt(tau / 3) on a +1/2 slope, when one is visible.

Conversions at a rate f_s = 1/dt: per-sample standard deviation sigma_d = N sqrt(f_s); integrated over one step
as an input, Q_d = N^2 dt; bias random walk Q_d,b = K^2 dt.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ingest.errors import InputError

#: Ratio of the Allan-deviation floor to the bias instability for flicker noise.
FLICKER_FLOOR_FACTOR = 0.664
#: Local log-log slopes within this distance of -1/2 (+1/2) count as white noise (rate random walk).
SLOPE_TOLERANCE = 0.15
#: Cluster sizes per decade and the longest cluster as a fraction of the record (longer ones are too noisy).
POINTS_PER_DECADE = 10
MAX_CLUSTER_FRACTION = 0.1
MIN_SAMPLES = 100


@dataclass(frozen=True)
class AllanCurve:
    """Overlapping Allan deviation of one axis.

    Attributes
    ----------
    taus_s : numpy.ndarray
        Cluster times [s], shape (m,).
    adev : numpy.ndarray
        Allan deviation [unit of the data], shape (m,).
    adev_err : numpy.ndarray
        allantools' 1-sigma error of ``adev``, shape (m,).
    rate_hz : float
        Sample rate of the data [Hz].
    """

    taus_s: np.ndarray
    adev: np.ndarray
    adev_err: np.ndarray
    rate_hz: float


@dataclass(frozen=True)
class AllanFigures:
    """Noise figures read off an :class:`AllanCurve` (units for data in U, e.g. rad/s).

    Attributes
    ----------
    white_density : float
        N [U/sqrt(Hz)]; NaN when no -1/2 slope is visible.
    bias_instability : float
        B = min adev / 0.664 [U].
    bias_instability_tau_s : float
        Cluster time of the minimum [s].
    floor_reached : bool
        True when the minimum lies before the last cluster time (a flicker floor is visible); False means the
        curve was still falling and B is an upper bound.
    rate_random_walk : float
        K [U sqrt(Hz)/s]; NaN when no +1/2 slope is visible.
    rate_hz : float
        Sample rate of the analysed data [Hz].
    """

    white_density: float
    bias_instability: float
    bias_instability_tau_s: float
    floor_reached: bool
    rate_random_walk: float
    rate_hz: float

    @property
    def sigma_per_sample(self) -> float:
        """White-noise standard deviation of one sample at ``rate_hz``: N sqrt(f_s) [U]."""
        return self.white_density * math.sqrt(self.rate_hz)

    @property
    def q_white_per_step(self) -> float:
        """Input-noise variance integrated over one sample step: N^2 dt [U^2 s^2 / s = U^2 s]."""
        return self.white_density**2 / self.rate_hz

    @property
    def q_bias_walk_per_step(self) -> float:
        """Bias random-walk variance added per sample step: K^2 dt [U^2]; NaN without K."""
        return self.rate_random_walk**2 / self.rate_hz


def allan_deviation(x: np.ndarray, rate_hz: float) -> AllanCurve:
    """Overlapping Allan deviation (``allantools.oadev``, frequency data) of a uniformly sampled axis ``x``.

    Cluster times are log-spaced (10 per decade) from one sample to a tenth of the record.

    Raises
    ------
    InputError
        With fewer than 100 samples or a non-positive rate.
    """
    x = np.asarray(x, dtype=float)
    if len(x) < MIN_SAMPLES or not rate_hz > 0:
        raise InputError(f"Allan deviation needs >= {MIN_SAMPLES} samples at a positive rate, got {len(x)} "
                         f"samples at {rate_hz!r} Hz", field="allan")
    max_cluster = max(2, int(MAX_CLUSTER_FRACTION * len(x)))
    n_points = max(2, round(POINTS_PER_DECADE * math.log10(max_cluster)) + 1)
    clusters = np.unique(np.round(np.logspace(0, math.log10(max_cluster), n_points)).astype(int))
    import allantools  # here, not at the top: it imports scipy.stats, seconds for every CLI command

    taus_s, adev, adev_err, _ = allantools.oadev(x, rate=rate_hz, data_type="freq", taus=clusters / rate_hz)
    return AllanCurve(taus_s=np.asarray(taus_s), adev=np.asarray(adev), adev_err=np.asarray(adev_err),
                      rate_hz=float(rate_hz))


def allan_figures(curve: AllanCurve) -> AllanFigures:
    """White-noise density, bias instability and rate random walk of an :class:`AllanCurve`."""
    log_tau = np.log10(curve.taus_s)
    log_adev = np.log10(curve.adev)
    slope = np.gradient(log_adev, log_tau)

    white = np.abs(slope + 0.5) < SLOPE_TOLERANCE
    # Fixed-slope least squares in log space: log N = mean(log adev + 0.5 log tau) over the -1/2 region.
    density = 10 ** float(np.mean(log_adev[white] + 0.5 * log_tau[white])) if white.any() else float("nan")

    i_min = int(np.argmin(curve.adev))
    walk = (np.abs(slope - 0.5) < SLOPE_TOLERANCE) & (np.arange(len(slope)) > i_min)
    # sigma = K sqrt(tau / 3)  =>  log K = mean(log adev - 0.5 log(tau / 3)) over the +1/2 region.
    random_walk = (10 ** float(np.mean(log_adev[walk] - 0.5 * np.log10(curve.taus_s[walk] / 3.0)))
                   if walk.any() else float("nan"))
    return AllanFigures(white_density=density, bias_instability=float(curve.adev[i_min] / FLICKER_FLOOR_FACTOR),
                        bias_instability_tau_s=float(curve.taus_s[i_min]), floor_reached=i_min < len(slope) - 1,
                        rate_random_walk=random_walk, rate_hz=curve.rate_hz)
