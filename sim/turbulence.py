"""Dryden turbulence and discrete 1-cosine gusts (MIL-F-8785C, MIL-HDBK-1797), seeded and twice differentiable.

See docs/evaluation.md, 'Turbulence (Dryden and discrete gusts)'. The components are those of the flight-path
axes: ``u`` along the air-relative heading, ``v`` to the right, ``w`` down (a positive ``u`` is a tail gust, a
negative ``w`` an updraft). Scale lengths ``L`` and intensities ``sigma`` follow the low-altitude formulas of the
height above ground (in ft inside the formulas, clamped to >= 10 ft), are interpolated between 1000 and 2000 ft and
constant above. Time scales are ``L / V`` with the aircraft's airspeed ``V`` (Taylor's frozen field), floored by
``min_speed_m_s`` (on the ground the mean wind carries the field past).

Generation: the Dryden shaping filters ``u = sigma sqrt(2 tau / pi) / (1 + tau s)`` and
``v, w = sigma sqrt(tau / pi) (1 + sqrt(3) tau s) / (1 + tau s)^2`` (``tau = L / V``) are written as a unit-variance
state (``a`` first-order Gauss-Markov, ``b = a / (1 + tau s)``, output ``(sqrt(3) a + (1 - sqrt(3)) b) / sqrt(2)``)
whose stationary covariance does not depend on ``tau``. Each knot step is discretised exactly (transition
``expm(A dt)``, noise covariance ``P - Phi P Phi^T``) with the frozen ``V, h`` of the step's first knot, so a slowly
varying ``V, h`` keeps the process stationary with the local spectrum; the output is scaled by the local ``sigma``.
The knots (``knot_rate_hz``) are rotated into NED with the knot's heading and joined by cubic splines, like
:mod:`sim.wind`, so the wind and its rate are exact and smooth. Discrete gusts are analytic.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

#: One foot [m].
FT_M = 0.3048
#: Lowest height of the low-altitude formulas [ft].
MIN_HEIGHT_FT = 10.0
#: Top of the low-altitude model and bottom of the medium/high-altitude one [ft].
LOW_ALTITUDE_FT, HIGH_ALTITUDE_FT = 1000.0, 2000.0
#: Scale length above 2000 ft [ft].
HIGH_ALTITUDE_LENGTH_FT = 1750.0
#: Axis names of the flight-path components and their index.
AXES = {"u": 0, "v": 1, "w": 2}
_SQRT3 = np.sqrt(3.0)


@dataclass(frozen=True)
class DiscreteGust:
    """A discrete 1-cosine gust, ``v = A/2 (1 - cos(2 pi x / length))`` for ``0 <= x <= length``, else 0.

    MIL-F-8785C's ramp ``v_m/2 (1 - cos(pi x / d_m))`` up to the peak at ``x = d_m``, followed by its mirror image
    (``length = 2 d_m``), so the gust ends. ``x`` is the distance flown through the air since ``start_s`` at the
    airspeed of the start (frozen: the gust lasts ``length / V``).

    Attributes
    ----------
    start_s : float
        Mission time the gust begins [s].
    amplitude_m_s : float
        Peak gust velocity ``A`` [m/s], signed along ``axis``.
    length_m : float
        Whole length of the gust, rise and fall [m] (``2 d_m``).
    axis : str
        ``"u"`` (along the air-relative heading at ``start_s``: negative is a head gust), ``"v"`` (to the right) or
        ``"w"`` (down: negative is an updraft); the direction stays fixed in NED.
    """

    start_s: float
    amplitude_m_s: float
    length_m: float
    axis: str = "u"

    def __post_init__(self):
        if self.axis not in AXES or self.length_m <= 0:
            raise ValueError(f"gust needs axis in {tuple(AXES)} and length_m > 0, got {self.axis!r}, {self.length_m}")


@dataclass(frozen=True)
class TurbulenceConfig:
    """Dryden turbulence and discrete gusts added to the wind (see the module docstring).

    Attributes
    ----------
    w20_m_s : float
        Wind speed at 20 ft [m/s] setting the intensity ``sigma_w = 0.1 W20`` (MIL-F-8785C: light 15 kt = 7.7 m/s,
        moderate 30 kt = 15.4 m/s, severe 45 kt = 23.2 m/s).
    sigma_m_s : tuple of 3 float, optional
        Intensities (u, v, w) [m/s] overriding the height formulas.
    length_scale_m : float or tuple of 3 float, optional
        Scale lengths (u, v, w) [m] overriding the height formulas (e.g. 40 m for a convective boundary layer).
    knot_rate_hz : float
        Rate of the spline knots [Hz].
    min_speed_m_s : float
        Floor of the speed turning scale lengths into time scales [m/s].
    gusts : tuple of DiscreteGust
        Discrete gusts.
    """

    w20_m_s: float = 0.0
    sigma_m_s: tuple[float, float, float] | None = None
    length_scale_m: float | tuple[float, float, float] | None = None
    knot_rate_hz: float = 20.0
    min_speed_m_s: float = 5.0
    gusts: tuple[DiscreteGust, ...] = ()


def dryden_scales(height_m, w20_m_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Scale lengths and intensities of MIL-F-8785C / MIL-HDBK-1797 at heights ``height_m`` above ground.

    Below 1000 ft ``L_w = h``, ``L_u = L_v = h / (0.177 + 0.000823 h)^1.2``, ``sigma_w = 0.1 W20``,
    ``sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h)^0.4`` (h in ft, clamped to >= 10 ft); above 2000 ft
    ``L = 1750 ft`` and ``sigma_u = sigma_v = sigma_w`` (the handbook's medium/high-altitude intensity comes from an
    exceedance chart, taken here as 0.1 W20, its value at 1000 ft); linear in h between.

    Parameters
    ----------
    height_m : array-like, shape (N,)
        Height above ground [m].
    w20_m_s : float
        Wind speed at 20 ft [m/s].

    Returns
    -------
    length_m : numpy.ndarray, shape (N, 3)
        ``L_u, L_v, L_w`` [m].
    sigma_m_s : numpy.ndarray, shape (N, 3)
        ``sigma_u, sigma_v, sigma_w`` [m/s].
    """
    h_ft = np.maximum(np.atleast_1d(np.asarray(height_m, dtype=float)) / FT_M, MIN_HEIGHT_FT)
    low = np.minimum(h_ft, LOW_ALTITUDE_FT)
    base = 0.177 + 0.000823 * low
    length_ft = np.column_stack([low / base**1.2, low / base**1.2, low])
    ratio = 1.0 / base**0.4
    sigma_w = 0.1 * w20_m_s
    sigma = np.column_stack([ratio, ratio, np.ones_like(ratio)]) * sigma_w
    frac = (np.clip(h_ft, LOW_ALTITUDE_FT, HIGH_ALTITUDE_FT) - LOW_ALTITUDE_FT) / (HIGH_ALTITUDE_FT - LOW_ALTITUDE_FT)
    length_ft = length_ft + frac[:, None] * (HIGH_ALTITUDE_LENGTH_FT - length_ft)
    sigma = sigma + frac[:, None] * (sigma_w - sigma)
    return length_ft * FT_M, sigma


def turbulence_scales(config: TurbulenceConfig, height_m) -> tuple[np.ndarray, np.ndarray]:
    """:func:`dryden_scales` with the config's overrides: ``(length_m, sigma_m_s)``, each shape (N, 3)."""
    length, sigma = dryden_scales(height_m, config.w20_m_s)
    if config.length_scale_m is not None:
        length = np.broadcast_to(np.asarray(config.length_scale_m, dtype=float), length.shape).copy()
    if config.sigma_m_s is not None:
        sigma = np.broadcast_to(np.asarray(config.sigma_m_s, dtype=float), sigma.shape).copy()
    return length, sigma


def dryden_psd(omega_rad_s, sigma_m_s: float, length_m: float, speed_m_s: float, axis: str) -> np.ndarray:
    """One-sided Dryden spectrum ``Phi(omega)`` [(m/s)^2 / (rad/s)], ``integral_0^inf Phi d omega = sigma^2``.

    ``u``: ``sigma^2 2 tau / pi / (1 + (tau omega)^2)``; ``v, w``: ``sigma^2 tau / pi (1 + 3 (tau omega)^2) /
    (1 + (tau omega)^2)^2`` with ``tau = L / V`` [s].
    """
    tau = length_m / speed_m_s
    x2 = (tau * np.asarray(omega_rad_s, dtype=float)) ** 2
    if axis == "u":
        return sigma_m_s**2 * 2.0 * tau / np.pi / (1.0 + x2)
    return sigma_m_s**2 * tau / np.pi * (1.0 + 3.0 * x2) / (1.0 + x2) ** 2


def dryden_autocorrelation(lag_s, sigma_m_s: float, length_m: float, speed_m_s: float, axis: str) -> np.ndarray:
    """Dryden autocorrelation [(m/s)^2]: ``u``: ``sigma^2 exp(-t/tau)``; ``v, w``: ``sigma^2 (1 - t/(2 tau))
    exp(-t/tau)`` with ``t = |lag_s|`` [s] and ``tau = L / V``."""
    t = np.abs(np.asarray(lag_s, dtype=float)) * speed_m_s / length_m
    shape = 1.0 if axis == "u" else 1.0 - 0.5 * t
    return sigma_m_s**2 * shape * np.exp(-t)


def dryden_knots(config: TurbulenceConfig, speed_m_s, height_m, rng: np.random.Generator) -> np.ndarray:
    """Dryden components at knots ``1 / knot_rate_hz`` apart, with the frozen ``V, h`` of each knot.

    Parameters
    ----------
    config : TurbulenceConfig
        Intensity, scale lengths and knot rate.
    speed_m_s, height_m : array-like, shape (K,)
        Airspeed [m/s] (floored by ``min_speed_m_s``) and height above ground [m] at the knots.
    rng : numpy.random.Generator
        Source of the draws: one ``(K, 5)`` block of standard normals (initial states, then the drives).

    Returns
    -------
    numpy.ndarray, shape (K, 3)
        ``u_g, v_g, w_g`` in the flight-path axes [m/s], stationary from the first knot.
    """
    speed = np.maximum(np.asarray(speed_m_s, dtype=float), config.min_speed_m_s)
    length, sigma = turbulence_scales(config, height_m)
    n = len(speed)
    r = (1.0 / config.knot_rate_hz) * speed[:, None] / length  # knot step / tau, per axis
    decay = np.exp(-r)
    e2 = decay * decay
    q11 = -np.expm1(-2.0 * r)
    q12 = 0.5 - e2 * (r + 0.5)
    q22 = 0.5 - e2 * (r * r + r + 0.5)
    c11 = np.sqrt(q11)
    c21 = q12 / c11
    c22 = np.sqrt(np.maximum(q22 - c21 * c21, 0.0))
    noise = rng.standard_normal((n, 5))  # columns: u, v (two), w (two)
    # stationary start: a ~ N(0, 1), Cov(a, b) = Var(b) = 1/2
    first = noise[0]
    out = [[first[0], first[1], 0.5 * (first[1] + first[2]), first[3], 0.5 * (first[3] + first[4])]]
    steps = np.column_stack([decay, r[:, 1:], c11, c21[:, 1:], c22[:, 1:]])[:-1].tolist()
    for (eu, ev, ew, rv, rw, su, s1v, s1w, s2v, s2w, s3v, s3w), (n0, n1, n2, n3, n4) in zip(
            steps, noise[1:].tolist(), strict=True):
        au, av, bv, aw, bw = out[-1]
        out.append([eu * au + su * n0, ev * av + s1v * n1, ev * (rv * av + bv) + s2v * n1 + s3v * n2,
                    ew * aw + s1w * n3, ew * (rw * aw + bw) + s2w * n3 + s3w * n4])
    x = np.array(out)
    shaped = np.column_stack([x[:, 0], (_SQRT3 * x[:, 1] + (1.0 - _SQRT3) * x[:, 2]) / np.sqrt(2.0),
                              (_SQRT3 * x[:, 3] + (1.0 - _SQRT3) * x[:, 4]) / np.sqrt(2.0)])
    return sigma * shaped


def gust_profile(gust: DiscreteGust, tau_s, speed_m_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Gust velocity ``A/2 (1 - cos(2 pi x / length))`` along its axis [m/s] and its exact time derivative
    [m/s^2] at mission times ``tau_s`` [s], for a frozen airspeed ``speed_m_s`` [m/s] (``x = V (t - start)``)."""
    x = speed_m_s * (np.asarray(tau_s, dtype=float) - gust.start_s)
    inside = (x >= 0.0) & (x <= gust.length_m)
    phase = 2.0 * np.pi * x / gust.length_m
    value = np.where(inside, 0.5 * gust.amplitude_m_s * (1.0 - np.cos(phase)), 0.0)
    rate = np.where(inside, 0.5 * gust.amplitude_m_s * np.sin(phase) * 2.0 * np.pi * speed_m_s / gust.length_m, 0.0)
    return value, rate


def _flight_path_to_ned(heading_rad: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """(N, 3) flight-path components (forward, right, down) at headings [rad] as NED vectors."""
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    return np.column_stack([c * fp[:, 0] - s * fp[:, 1], s * fp[:, 0] + c * fp[:, 1], fp[:, 2]])


@dataclass(frozen=True)
class TurbulenceField:
    """A drawn turbulence realisation (NED velocity of the air added to the wind).

    Attributes
    ----------
    knot_tau_s : numpy.ndarray, shape (K,)
        Knot times [s].
    dryden : scipy.interpolate.CubicSpline
        Dryden part, NED [m/s], of the mission time [s].
    gusts : tuple of (DiscreteGust, float, numpy.ndarray)
        Each gust with its frozen airspeed [m/s] and NED unit direction.
    """

    knot_tau_s: np.ndarray
    dryden: CubicSpline
    gusts: tuple[tuple[DiscreteGust, float, np.ndarray], ...]

    def ned_m_s(self, tau_s, derivative: int = 0) -> np.ndarray:
        """Turbulence velocity NED [m/s] (``derivative=1``: its exact rate [m/s^2]) at mission times [s]."""
        tau_s = np.asarray(tau_s, dtype=float)
        total = self.dryden(tau_s, derivative)
        for gust, speed, direction in self.gusts:
            total = total + np.outer(gust_profile(gust, tau_s, speed)[derivative], direction)
        return total


def turbulence_field(config: TurbulenceConfig, duration_s: float, speed_m_s: Callable, height_m: Callable,
                     heading_rad: Callable, rng: np.random.Generator) -> TurbulenceField:
    """Draw a turbulence realisation along a flight.

    Parameters
    ----------
    config : TurbulenceConfig
        Turbulence model.
    duration_s : float
        Last mission time to cover [s].
    speed_m_s, height_m, heading_rad : callable
        Airspeed [m/s], height above ground [m] and air-relative heading [rad, clockwise from north] of the mission
        time [s].
    rng : numpy.random.Generator
        Source of the draws (:func:`dryden_knots`).

    Returns
    -------
    TurbulenceField
    """
    spacing = 1.0 / config.knot_rate_hz
    knots = np.arange(int(np.ceil(duration_s / spacing)) + 2) * spacing
    fp = dryden_knots(config, speed_m_s(knots), height_m(knots), rng)
    spline = CubicSpline(knots, _flight_path_to_ned(heading_rad(knots), fp), axis=0)
    gusts = []
    for gust in config.gusts:
        unit = np.zeros((1, 3))
        unit[0, AXES[gust.axis]] = 1.0
        direction = _flight_path_to_ned(np.atleast_1d(heading_rad(gust.start_s)), unit)[0]
        gusts.append((gust, max(float(speed_m_s(gust.start_s)), config.min_speed_m_s), direction))
    return TurbulenceField(knot_tau_s=knots, dryden=spline, gusts=tuple(gusts))
