"""The penalty factor tau of paper eq 52 on the accelerometer's body-y variance, and how to choose it
(docs/calibration.md, 'Penalty factor tau (eq 52)').

R_accel = diag(R_x0, tau R_y0, R_z0). tau is either set by the user or chosen from filter replays: the caller
injects ``replay(tau) -> Innovations`` (the y-axis accelerometer innovations of a full filter run with that tau;
calib never imports the estimators). Two criteria, both searched over log10 tau in [-1, 2]:

* ``"likelihood"``: tau* = argmin sum_k [ln(2 pi S_k) + nu_k^2 / S_k] / 2 (scipy.optimize.minimize_scalar, bounded);
* ``"nis"``: the root of mean(nu_k^2 / S_k) = 1 (scipy.optimize.brentq; mean NIS falls with tau).

Both also evaluate the criterion on a grid for display, and report the lag-1 autocorrelation of nu / sqrt(S):
above 0.5 the innovations are coloured and the chi-square band of the NIS test is too narrow.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from calib.figures import mean_nis_band
from ingest.errors import InputError
from ingest.threads import thread_map

#: Search interval of log10 tau (docs/calibration.md, 'Penalty factor tau (eq 52)').
LOG10_TAU_BOUNDS = (-1.0, 2.0)
TAU_METHODS = ("likelihood", "nis")
#: Lag-1 autocorrelation of the normalised innovations above which they are called coloured.
COLOURED_LAG1 = 0.5


@dataclass(frozen=True)
class Innovations:
    """Scalar innovations of one measurement channel from a filter replay.

    Attributes
    ----------
    innovation : numpy.ndarray
        nu_k = z_k - h(x_k^-) [measurement unit], shape (n,).
    innovation_var : numpy.ndarray
        S_k = H P H^T + R [unit^2], shape (n,), > 0.
    """

    innovation: np.ndarray
    innovation_var: np.ndarray


@dataclass(frozen=True)
class TauSelection:
    """The tau in use and, when chosen automatically, the evidence.

    Attributes
    ----------
    tau : float
        Multiplier of the accelerometer's body-y variance [-].
    method : str
        ``"default"`` (1, no penalty), ``"user"``, ``"likelihood"`` or ``"nis"``.
    log10_tau_grid : tuple of float
        Grid the criteria were evaluated on (empty unless automatic).
    neg_log_likelihood : tuple of float
        Mean negative log-likelihood per innovation on the grid [-].
    mean_nis : tuple of float
        Mean NIS on the grid [-].
    n_innovations : int
        Innovations per replay at the chosen tau (0 unless automatic).
    nis_at_tau : float
        Mean NIS at the chosen tau (NaN unless automatic).
    nis_band : tuple of 2 float
        95 % chi-square band of the mean NIS for ``n_innovations`` white innovations ((nan, nan) unless automatic).
    lag1_autocorrelation : float
        Lag-1 autocorrelation of nu / sqrt(S) at the chosen tau (NaN unless automatic).
    note : str
        What to keep in mind (unbracketed root, coloured innovations), or "".
    """

    tau: float
    method: str
    log10_tau_grid: tuple[float, ...] = ()
    neg_log_likelihood: tuple[float, ...] = ()
    mean_nis: tuple[float, ...] = ()
    n_innovations: int = 0
    nis_at_tau: float = float("nan")
    nis_band: tuple[float, float] = (float("nan"), float("nan"))
    lag1_autocorrelation: float = float("nan")
    note: str = ""


DEFAULT_TAU = TauSelection(tau=1.0, method="default")


def user_tau(tau: float) -> TauSelection:
    """A tau set by the user; must be finite and > 0."""
    if not (math.isfinite(tau) and tau > 0):
        raise InputError(f"tau must be a positive number, got {tau!r}", field="tau")
    return TauSelection(tau=float(tau), method="user")


def neg_log_likelihood(innovations: Innovations) -> float:
    """Mean Gaussian negative log-likelihood per innovation, (ln(2 pi S) + nu^2 / S) / 2 [-]."""
    nu, s = _checked(innovations)
    return float(np.mean(np.log(2 * np.pi * s) + nu**2 / s) / 2)


def mean_nis(innovations: Innovations) -> float:
    """Mean normalised innovation squared, mean(nu^2 / S) [-] (1 for a consistent scalar channel)."""
    nu, s = _checked(innovations)
    return float(np.mean(nu**2 / s))


#: Points of the display grid of :func:`choose_tau` (replayed first, side by side).
TAU_GRID_POINTS = 13


def choose_tau(replay: Callable[[float], Innovations], method: str = "likelihood", grid_points: int = TAU_GRID_POINTS,
               xatol: float = 0.01) -> TauSelection:
    """Choose tau by replaying the filter (``replay(tau)``) and maximising the likelihood or matching the NIS.

    Parameters
    ----------
    replay : callable
        tau -> :class:`Innovations` of the accelerometer y channel of a full replay with that tau; called from
        several threads at once for the grid (one per CPU; a compiled filter that releases the GIL runs them side
        by side).
    method : {"likelihood", "nis"}
        Criterion (module docstring).
    grid_points : int
        Points of the display grid over log10 tau in [-1, 2] (>= 2).
    xatol : float
        Absolute tolerance on log10 tau of the search.

    Returns
    -------
    TauSelection
        With the grid curves; when the NIS root is not bracketed by the bounds, the grid point with the mean NIS
        closest to 1 and a note.
    """
    if method not in TAU_METHODS:
        raise InputError(f"tau method must be one of {TAU_METHODS}, got {method!r}", field="tau")
    if grid_points < 2:
        raise InputError(f"grid needs >= 2 points, got {grid_points}", field="tau")
    cache: dict[float, Innovations] = {}

    def run(log10_tau: float) -> Innovations:
        if log10_tau not in cache:
            cache[log10_tau] = replay(10.0**log10_tau)
        return cache[log10_tau]

    lo, hi = LOG10_TAU_BOUNDS
    grid = np.linspace(lo, hi, grid_points)
    # the grid's replays side by side
    cache.update(zip(map(float, grid), thread_map(lambda g: replay(10.0 ** float(g)), grid), strict=True))
    nll_grid = [neg_log_likelihood(run(float(g))) for g in grid]
    nis_grid = [mean_nis(run(float(g))) for g in grid]
    note = ""
    if method == "likelihood":
        result = optimize.minimize_scalar(lambda g: neg_log_likelihood(run(float(g))), bounds=(lo, hi),
                                          method="bounded", options={"xatol": xatol})
        best = float(result.x)
    else:
        excess_lo, excess_hi = mean_nis(run(lo)) - 1.0, mean_nis(run(hi)) - 1.0
        if excess_lo * excess_hi <= 0:
            best = float(optimize.brentq(lambda g: mean_nis(run(float(g))) - 1.0, lo, hi, xtol=xatol))
        else:
            best = float(grid[int(np.argmin(np.abs(np.array(nis_grid) - 1.0)))])
            note = (f"mean NIS - 1 has the same sign at tau = 10^{lo:g} and 10^{hi:g}: no root in the bounds, "
                    f"the grid point with the mean NIS closest to 1 is used")

    innovations = run(best)
    nu, s = _checked(innovations)
    n = len(nu)
    normalised = nu / np.sqrt(s)
    lag1 = float(np.corrcoef(normalised[:-1], normalised[1:])[0, 1]) if n > 2 else float("nan")
    if lag1 > COLOURED_LAG1:
        note = "; ".join(filter(None, [note, f"innovations are coloured (lag-1 autocorrelation {lag1:.2f} > "
                                             f"{COLOURED_LAG1}): the NIS chi-square band is too narrow"]))
    band = mean_nis_band(n)
    return TauSelection(tau=10.0**best, method=method, log10_tau_grid=tuple(float(g) for g in grid),
                        neg_log_likelihood=tuple(nll_grid), mean_nis=tuple(nis_grid), n_innovations=n,
                        nis_at_tau=mean_nis(innovations), nis_band=band, lag1_autocorrelation=lag1, note=note)


def _checked(innovations: Innovations) -> tuple[np.ndarray, np.ndarray]:
    nu = np.asarray(innovations.innovation, dtype=float)
    s = np.asarray(innovations.innovation_var, dtype=float)
    if nu.ndim != 1 or nu.shape != s.shape or len(nu) == 0:
        raise InputError(f"innovations and their variances must be equal-length 1-D arrays, got shapes {nu.shape} "
                         f"and {s.shape}", field="innovations")
    if not np.all(s > 0):
        raise InputError("innovation variances must be > 0", field="innovations")
    return nu, s
