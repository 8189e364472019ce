"""Random processes shared by the wind and sensor models (all draws come from an injected generator)."""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter


def gauss_markov(n_samples: int, dt_s: float, tau_s: float, sigma, rng: np.random.Generator, *,
                 stationary_start: bool = True) -> np.ndarray:
    """First-order Gauss-Markov process sampled every ``dt_s`` (paper eq. 6, docs/evaluation.md, 'Table 2 set-up').

    ``v[n+1] = exp(-dt/tau) v[n] + eta[n]`` with ``Var(eta) = sigma^2 (1 - exp(-2 dt/tau))``, so the steady-state
    standard deviation is ``sigma`` whatever the sample rate.

    Parameters
    ----------
    n_samples : int
        Number of samples.
    dt_s : float
        Sample interval [s].
    tau_s : float
        Correlation time [s] (``1 / k_GPS`` of eq. 6).
    sigma : float or array-like of shape (n_axes,)
        Steady-state standard deviation per axis [unit of the process].
    rng : numpy.random.Generator
        Source of the draws.
    stationary_start : bool
        True: ``v[0] ~ N(0, sigma^2)`` (stationary process); False: ``v[0] = 0`` (Beard & McLain), whose std grows
        as ``sigma sqrt(1 - exp(-2 t/tau))``.

    Returns
    -------
    numpy.ndarray, shape (n_samples, n_axes)
    """
    sigma = np.atleast_1d(np.asarray(sigma, dtype=float))
    if tau_s <= 0 or dt_s <= 0:
        raise ValueError(f"gauss_markov needs tau_s > 0 and dt_s > 0, got tau_s={tau_s}, dt_s={dt_s}")
    decay = np.exp(-dt_s / tau_s)
    drive = rng.standard_normal((n_samples, sigma.size)) * (sigma * np.sqrt(1.0 - decay * decay))
    if n_samples:
        drive[0] = rng.standard_normal(sigma.size) * sigma if stationary_start else 0.0
    return lfilter([1.0], [1.0, -decay], drive, axis=0)


def uniform_within(limit, rng: np.random.Generator, shape=None) -> np.ndarray:
    """Draws uniform in ``[-limit, +limit]`` (a datasheet tolerance is a bound, not a standard deviation).

    Parameters
    ----------
    limit : float or array-like
        Bound(s) [any unit]; broadcast against ``shape``.
    rng : numpy.random.Generator
        Source of the draws.
    shape : tuple of int, optional
        Output shape (default: the shape of ``limit``).
    """
    limit = np.asarray(limit, dtype=float)
    shape = limit.shape if shape is None else shape
    return rng.uniform(-1.0, 1.0, size=shape) * limit
