"""Wind: a steady horizontal vector, a slowly varying component, optional gusts and optional turbulence, all seeded.

The two random components are first-order Gauss-Markov processes drawn at knots a quarter of their correlation
time apart and joined by cubic splines, so the wind is twice continuously differentiable and its rate of change
(which enters the aircraft's acceleration, hence the accelerometer) is exact. :func:`wind_ned` is horizontal; the
optional Dryden turbulence and discrete gusts (:mod:`sim.turbulence`, three-dimensional, in the flight-path axes) are
drawn by :func:`sim.kinematics.fly` after it, because they depend on the airspeed, height and heading, and they move
the aircraft through :mod:`sim.response` (docs/evaluation.md, 'Turbulence (Dryden and discrete gusts)').
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from sim.processes import gauss_markov
from sim.turbulence import TurbulenceConfig

#: Knot spacing of a random wind component as a fraction of its correlation time.
KNOTS_PER_TAU = 4.0


@dataclass(frozen=True)
class WindConfig:
    """Wind model (velocity of the air mass, NED).

    Attributes
    ----------
    speed_m_s : float
        Steady wind speed [m/s].
    from_deg : float
        Direction the steady wind blows from [deg, clockwise from north] (meteorological convention).
    slow_sigma_m_s : float
        Standard deviation of the slowly varying component, per horizontal axis [m/s].
    slow_tau_s : float
        Correlation time of the slowly varying component [s].
    gust_sigma_m_s : float
        Standard deviation of the gust (turbulence) component, per horizontal axis [m/s]; 0 disables it.
    gust_tau_s : float
        Correlation time of the gusts [s] (length scale / airspeed).
    turbulence : TurbulenceConfig, optional
        Dryden turbulence and discrete gusts that move the aircraft; None (default) draws nothing.
    """

    speed_m_s: float = 2.5
    from_deg: float = 300.0
    slow_sigma_m_s: float = 0.3
    slow_tau_s: float = 300.0
    gust_sigma_m_s: float = 0.0
    gust_tau_s: float = 4.0
    turbulence: TurbulenceConfig | None = None

    @property
    def steady_ned_m_s(self) -> np.ndarray:
        """Steady wind vector (north, east, down) [m/s]."""
        heading_to = np.radians(self.from_deg + 180.0)
        return np.array([np.cos(heading_to), np.sin(heading_to), 0.0]) * self.speed_m_s


def _random_component(tau_rel_s: np.ndarray, sigma: float, tau_s: float, rng: np.random.Generator) -> CubicSpline:
    spacing = tau_s / KNOTS_PER_TAU
    n_knots = int(np.ceil(tau_rel_s[-1] / spacing)) + 2
    values = gauss_markov(n_knots, spacing, tau_s, (sigma, sigma), rng)
    return CubicSpline(np.arange(n_knots) * spacing, values, axis=0)


def wind_ned(config: WindConfig, tau_s: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Draw a wind realisation and evaluate it.

    Parameters
    ----------
    config : WindConfig
        Wind model.
    tau_s : numpy.ndarray, shape (N,)
        Increasing times [s] from 0.
    rng : numpy.random.Generator
        Source of the draws (slow component first, then gusts).

    Returns
    -------
    wind_ned_m_s : numpy.ndarray, shape (N, 3)
        Wind (north, east, 0) [m/s].
    wind_rate_ned_m_s2 : numpy.ndarray, shape (N, 3)
        Its time derivative [m/s^2].
    """
    wind = np.zeros((len(tau_s), 3)) + config.steady_ned_m_s
    rate = np.zeros((len(tau_s), 3))
    for sigma, tau in ((config.slow_sigma_m_s, config.slow_tau_s), (config.gust_sigma_m_s, config.gust_tau_s)):
        if sigma > 0:
            spline = _random_component(tau_s, sigma, tau, rng)
            wind[:, :2] += spline(tau_s)
            rate[:, :2] += spline(tau_s, 1)
    return wind, rate
