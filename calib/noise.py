"""Noise and bias of one channel from a measured segment and its zero-phase low-pass (paper eq 50, docs/calibration.md,
'Noise and bias (eq 50)').

Two families are reported side by side:

* eq 50 literally: ``eta = (range(x_m) - range(x_f)) / 2`` and ``beta = mean(x_m) - mean(x_f)``. Kept for
  traceability with the paper's Table 4. ``eta`` is half a difference of ranges (it grows with the sample count),
  ``beta`` is ~0 for a unity-gain zero-phase filter.
* the residual standard deviation ``sigma = sqrt(var(r) / rho_h)`` with ``r = x_m - x_f`` and its robust variant
  ``1.4826 MAD(r) / sqrt(rho_h)``: the per-sample white-noise standard deviation at the stream's rate of
  everything above the cutoff.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtri

from calib.fir import FirSpec, edge_slice, zero_phase_lowpass


@dataclass(frozen=True)
class ChannelNoise:
    """Noise figures of one channel (units of the channel).

    Attributes
    ----------
    eta : float
        Paper eq 50 noise: half the difference of the measured and filtered peak-to-peak ranges.
    beta : float
        Paper eq 50 bias: mean(measured) - mean(filtered).
    sigma : float
        Residual standard deviation corrected by rho_h (per-sample, at the stream's rate).
    sigma_robust : float
        1.4826 x median absolute deviation of the residual, corrected by rho_h.
    mean : float
        Mean of the measured samples used.
    n_used : int
        Samples used (segment minus numtaps at both ends).
    """

    eta: float
    beta: float
    sigma: float
    sigma_robust: float
    mean: float
    n_used: int


def eq50(measured: np.ndarray, filtered: np.ndarray) -> tuple[float, float]:
    """Paper eq 50 on one channel: (eta, beta) = ((ptp(x_m) - ptp(x_f)) / 2, mean(x_m) - mean(x_f))."""
    measured = np.asarray(measured, dtype=float)
    filtered = np.asarray(filtered, dtype=float)
    eta = (np.ptp(measured) - np.ptp(filtered)) / 2.0
    beta = np.mean(measured) - np.mean(filtered)
    return float(eta), float(beta)


def channel_noise(x: np.ndarray, spec: FirSpec) -> ChannelNoise:
    """Eq 50, residual sigma and its robust variant of one uniformly sampled channel ``x``, shape (n,)."""
    return noise_figures(np.asarray(x, dtype=float)[:, None], spec)[0]


def noise_figures(values: np.ndarray, spec: FirSpec) -> tuple[ChannelNoise, ...]:
    """:class:`ChannelNoise` of every column of ``values``, shape (n, k), filtered in one pass.

    Raises
    ------
    InputError
        When the channels are too short for the filter (see :func:`calib.fir.zero_phase_lowpass`).
    """
    values = np.asarray(values, dtype=float)
    kept = edge_slice(len(values), spec)
    measured = values[kept]
    filtered = zero_phase_lowpass(values, spec)[kept]
    residual = measured - filtered
    sigma = np.sqrt(np.var(residual, axis=0, ddof=1) / spec.rho_h)
    # scipy.stats.median_abs_deviation(scale="normal") without importing scipy.stats (most of a second)
    mad = np.median(np.abs(residual - np.median(residual, axis=0)), axis=0)
    sigma_robust = mad / ndtri(0.75) / np.sqrt(spec.rho_h)
    out = []
    for k in range(values.shape[1]):
        eta, beta = eq50(measured[:, k], filtered[:, k])
        out.append(ChannelNoise(eta=eta, beta=beta, sigma=float(sigma[k]), sigma_robust=float(sigma_robust[k]),
                                mean=float(np.mean(measured[:, k])), n_used=len(measured)))
    return tuple(out)
