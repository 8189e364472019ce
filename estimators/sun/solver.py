"""Sun vector from the currents of the 7-photocell sun device, and its EKF measurement model.

docs/sun.md, 'Solvers' (the PV paper, seed 003, reconstructed). Frames and cells follow ``ingest.sun_device``:
device frame x forward, y right, z down; cell 1 (column ``i1_a``) is the top cell with outward normal
(0, 0, -1); cells 2..7 are the side cells n_i = (sin a cos az_i, sin a sin az_i, -cos a).

Current model (docs/sun.md, 'Current model', with the isotropic-sky view factor the note's [FLAG] mentions)::

    I_i = k max(0, n_i . s) + I_sky (1 + n_i . u) / 2 + noise

``s``: unit vector towards the sun and ``u``: unit "up" vector, both in the device frame; ``k`` [A]: current of a
cell facing the sun (irradiance x area x responsivity, common to all cells); ``I_sky`` [A]: current of a cell
facing the zenith from the diffuse (reflected) sky light. ``(1 + n_i . u) / 2`` is the fraction of the sky dome a
tilted cell sees. Both terms are linear in the unknowns ``x = k s`` and ``I_sky`` for the cells that are lit
(``n_i . s > 0``) and for the cells that are dark (sky term only), which is what the solvers use.

Solvers
-------
* :func:`solve_sun_ls` -- least squares over all seven cells (seed 003 eqs 13-14 idea: the currents are linear in
  ``k s`` through the matrix of cell normals; the sky current is solved jointly from the device geometry, note
  8.4 (1)); ``s = x / |x|``, ``k = |x|``. Right only when every cell is lit and healthy.
* :func:`solve_sun_adaptive` -- adaptive least squares (docs/sun.md, 'Solvers'), per epoch in a numba kernel
  (:func:`_solve_epoch`): a first solution from the five largest currents screens the other cells; then
  classify each cell as lit (incidence < ``max_incidence_deg``), dark (``n . s < dark_cos_max``: it carries only
  sky light, so it measures ``I_sky``) or grazing (not used); solve the joint least squares; exclude the cell
  with the largest studentised residual beyond ``kappa`` sigma (Baarda's data snooping = the leave-one-out
  test) as faulty (stuck, shaded, glint); repeat until the fit passes and its own direction gives the same
  cell classes. When a cell was found faulty, the most suspicious accepted cells are tried as the culprit
  instead and the hypothesis with the best robust (truncated-quadratic) score over all cells is kept.
  Two passes: pass 2 adds priors on ``I_sky`` and ``k`` from pass 1's log-wide estimates (weighted median and
  the spread the estimates' own errors do not explain); an epoch whose sky or k disagrees (passing cloud)
  drops that prior. The sky prior matters: with the isotropic sky the six side cells cannot separate ``I_sky``
  from the vertical component of ``k s``, so a faulty top cell is otherwise neither detectable nor avoidable
  when all side cells are lit; the k prior makes a gross error on a well-lit cell identifiable. No solution
  with fewer than 3 lit cells, no sky reference, a condition number of the lit normals above ``cond_max``, an
  inconsistent fit that cannot be repaired, or a ``k`` below ``k_min`` (clouds, night).

Quality: with ``sigma`` the per-cell current error (noise plus ``model_error_rel * k``), ``Cov(x) = sigma^2
(A^T A)^-1`` and ``Sigma_s = P Cov(x)_xx P / k^2`` with ``P = I - s s^T`` (docs/sun.md, 'Quality'); ``sigma_rad`` is the
per-axis 1-sigma angle ``sqrt(trace(Sigma_s) / 2)``.

Measurement model (docs/sun.md, 'Measurement model', numba leaf functions for the filters): ``z = s_b``, ``h = C_bn s_n
= R_nb^T s_n``,
``dh/dTheta = [h]x W(Theta)`` for ZYX Euler angles, ``dh/d(dtheta) = [h]x`` for the body-axes error angle of the
error-state filter (``R = R_hat Exp(dtheta)``); noise ``R = sigma_rad^2 I``.
"""


from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from estimators.sun.photocells import CURRENT_COLUMNS, sky_view_factors
from estimators.sun.solver_kernel import (
    STATUS_LOW_K,
    STATUS_NAMES,
    STATUS_NO_DATA,
    STATUS_OK,
    KernelSettings,
    adaptive_kernel,
)
from ingest.errors import InputError
from ingest.sun_device import N_CELLS, SunDevice


@dataclass(frozen=True)
class SunSolverConfig:
    """Thresholds of the sun-vector solvers (docs/sun.md, 'Solvers'; reconstructed defaults, not the PV paper's
    numbers).

    Attributes
    ----------
    max_incidence_deg : float
        A cell is lit (used for the direction) when the angle between its normal and the sun is below this [deg];
        the cosine law is poor at grazing incidence.
    dark_cos_max : float
        A cell is dark (used for the sky current only) when ``n . s`` is below this [-].
    n_initial : int
        Number of largest currents for the initial solution (PV paper: five).
    kappa : float
        A used cell whose studentised residual exceeds ``kappa`` sigma is excluded as faulty [-].
    model_error_rel : float
        Model error per cell as a fraction of ``k`` (cosine law, cell mismatch), added in quadrature to the
        current noise [-].
    cond_max : float
        Largest condition number of ``N_L^T N_L`` (normals of the lit cells) [-].
    k_min_rel : float
        No solution when ``k`` is below this fraction of the median ``k`` of the log's solved epochs [-].
    k_min_snr : float
        ... or below this multiple of the current noise [-].
    k_min_a : float or None
        Absolute ``k`` threshold [A] replacing the two relative ones when given.
    max_iterations : int
        Most solve / classify / exclude rounds per epoch.
    n_alternatives : int
        When a cell is found faulty, the number of most suspicious accepted cells tried as the faulty one instead
        (0: trust the first identification).
    """

    max_incidence_deg: float = 80.0
    dark_cos_max: float = -0.1
    n_initial: int = 5
    kappa: float = 3.0
    model_error_rel: float = 0.02
    cond_max: float = 100.0
    k_min_rel: float = 0.2
    k_min_snr: float = 20.0
    k_min_a: float | None = None
    max_iterations: int = 10
    n_alternatives: int = 4

    def __post_init__(self):
        checks = {
            "max_incidence_deg": 0.0 < self.max_incidence_deg < 90.0,
            "dark_cos_max": -1.0 < self.dark_cos_max <= 0.0,
            "n_initial": 3 <= self.n_initial <= N_CELLS,
            "kappa": self.kappa > 0.0,
            "model_error_rel": 0.0 <= self.model_error_rel < 1.0,
            "cond_max": self.cond_max >= 1.0,
            "k_min_rel": 0.0 <= self.k_min_rel < 1.0,
            "k_min_snr": self.k_min_snr >= 0.0,
            "k_min_a": self.k_min_a is None or self.k_min_a >= 0.0,
            "max_iterations": self.max_iterations >= 1,
            "n_alternatives": 0 <= self.n_alternatives < N_CELLS,
        }
        for name, ok in checks.items():
            if not ok:
                raise InputError(f"invalid value {getattr(self, name)!r}", source="sun solver config", field=name)


@dataclass(frozen=True)
class SunSolution:
    """Per-epoch sun-vector solution (N epochs).

    Attributes
    ----------
    s_device : numpy.ndarray, shape (N, 3)
        Unit vector towards the sun in the device frame [-]; NaN where ``status != STATUS_OK``.
    s_body : numpy.ndarray, shape (N, 3)
        The same in body FRD (``R_bd s_device``) [-]; NaN where there is no solution.
    k_a : numpy.ndarray, shape (N,)
        Fitted current of a cell facing the sun [A]; NaN where no fit could be made (kept when the fit was made
        but rejected, e.g. for low ``k``).
    sky_a : numpy.ndarray, shape (N,)
        Fitted sky-light current of a cell facing the zenith [A].
    residual : numpy.ndarray, shape (N,)
        RMS current residual of the used cells divided by ``k_a`` [-].
    sigma_rad : numpy.ndarray, shape (N,)
        1-sigma direction error about each axis perpendicular to ``s`` [rad].
    cells_used : numpy.ndarray of bool, shape (N, 7)
        Cells in the final fit (lit ones for the direction, dark ones for the sky current); column j = cell j+1.
    faulty : numpy.ndarray of bool, shape (N, 7)
        Cells excluded as inconsistent with the others (stuck, shaded, glint).
    status : numpy.ndarray of int8, shape (N,)
        ``STATUS_*`` code (:data:`STATUS_NAMES`).
    noise_a : float
        Current noise (1 sigma per sample) the solution assumed [A].
    k_min_a : float
        ``k`` threshold applied [A] (0 for the plain least squares, which applies none).
    """

    s_device: np.ndarray
    s_body: np.ndarray
    k_a: np.ndarray
    sky_a: np.ndarray
    residual: np.ndarray
    sigma_rad: np.ndarray
    cells_used: np.ndarray
    faulty: np.ndarray
    status: np.ndarray
    noise_a: float
    k_min_a: float

    @property
    def valid(self) -> np.ndarray:
        """Epochs with a solution, bool (N,)."""
        return self.status == STATUS_OK


# ----------------------------------------------------------------------------------------------------------------
# Public solvers
# ----------------------------------------------------------------------------------------------------------------
def _checked_currents(currents_a) -> np.ndarray:
    currents = np.asarray(currents_a, dtype=float)
    if currents.ndim != 2 or currents.shape[1] != N_CELLS:
        raise InputError(f"expected an (N, {N_CELLS}) array of cell currents [A], got shape {currents.shape}",
                         field="currents_a")
    return currents


def _checked_noise(noise_a) -> float:
    noise = float(noise_a)
    if not np.isfinite(noise) or noise <= 0.0:
        raise InputError(f"expected a positive current noise [A], got {noise_a!r}", field="noise_a")
    return noise


def _sky_factor_per_epoch(device: SunDevice, up_device, n_epochs: int) -> np.ndarray:
    factors = sky_view_factors(device, up_device)
    if factors.shape not in ((N_CELLS,), (n_epochs, N_CELLS)):
        raise InputError(f"expected up vectors of shape (3,) or ({n_epochs}, 3), got {np.shape(up_device)}",
                         field="up_device")
    return np.ascontiguousarray(np.broadcast_to(factors, (n_epochs, N_CELLS)))


def solve_sun_ls(currents_a, device: SunDevice, noise_a: float, up_device=None,
                 config: SunSolverConfig | None = None) -> SunSolution:
    """Least-squares unit sun vector from all seven cells (no cell selection, no validity tests).

    Solves ``[N, f] (k s, I_sky) = I`` over every cell (``N``: cell normals, ``f``: sky view factors), then
    ``s = x / |x|``, ``k = |x|`` (docs/sun.md, 'Quality' with the sky current of 8.4 (1)). Exact when all cells are lit
    and
    healthy; biased when some are dark, shaded or faulty -- the baseline :func:`solve_sun_adaptive` improves on.

    Parameters
    ----------
    currents_a : array-like, shape (N, 7)
        Cell currents [A], cell 1 (top) first.
    device : SunDevice
        Cell geometry and mounting.
    noise_a : float
        Current noise, 1 sigma per sample [A] (for ``sigma_rad``).
    up_device : array-like, shape (3,) or (N, 3), optional
        Up vector in the device frame for the sky view factors; a level vehicle when omitted.
    config : SunSolverConfig, optional
        Only ``model_error_rel`` is used.

    Returns
    -------
    SunSolution
        ``status`` is ``STATUS_NO_DATA`` where a current is NaN, else ``STATUS_OK``; every cell is "used".
    """
    config = config or SunSolverConfig()
    currents = _checked_currents(currents_a)
    noise = _checked_noise(noise_a)
    n_epochs = len(currents)
    design = np.concatenate([np.broadcast_to(device.normals_device, (n_epochs, N_CELLS, 3)),
                             _sky_factor_per_epoch(device, up_device, n_epochs)[..., None]], axis=2)
    design_t = design.transpose(0, 2, 1)
    m_inv = np.linalg.inv(design_t @ design)
    solution = (m_inv @ (design_t @ currents[..., None]))[..., 0]
    k = np.linalg.norm(solution[:, :3], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        s_device = solution[:, :3] / k[:, None]
        sigma = np.sqrt(noise ** 2 + (config.model_error_rel * k) ** 2)
        m_xx = m_inv[:, :3, :3]
        along = (s_device[:, None, :] @ m_xx @ s_device[..., None])[:, 0, 0]
        spread = np.maximum(np.trace(m_xx, axis1=1, axis2=2) - along, 0.0)
        sigma_rad = sigma * np.sqrt(spread / 2.0) / k
        residuals = currents - (design @ solution[..., None])[..., 0]
        residual = np.sqrt(np.mean(residuals ** 2, axis=1)) / k
    finite = np.isfinite(currents).all(axis=1)
    return SunSolution(
        s_device=s_device, s_body=s_device @ device.body_from_device.T, k_a=k, sky_a=solution[:, 3],
        residual=residual, sigma_rad=sigma_rad, cells_used=np.repeat(finite[:, None], N_CELLS, axis=1),
        faulty=np.zeros((n_epochs, N_CELLS), dtype=bool),
        status=np.where(finite, STATUS_OK, STATUS_NO_DATA).astype(np.int8), noise_a=noise, k_min_a=0.0)


def solve_sun_adaptive(currents_a, device: SunDevice, noise_a: float, up_device=None,
                       config: SunSolverConfig | None = None) -> SunSolution:
    """Adaptive least-squares unit sun vector with lit-cell selection, sky removal and fault exclusion.

    Algorithm in the module docstring (docs/sun.md, 'Solvers'). The per-epoch numba kernel runs twice: pass 1 without
    priors,
    pass 2 with the priors on the sky current (1-sigma at least ``noise_a``) and on ``k`` (at least
    ``model_error_rel * k``) that :func:`_robust_prior` derives from pass 1. About 5 us per epoch and pass with
    a faulty cell (which triggers the alternative hypotheses), less without.

    Parameters
    ----------
    currents_a : array-like, shape (N, 7)
        Cell currents [A], cell 1 (top) first; NaN = missing (that cell is not used).
    device : SunDevice
        Cell geometry and mounting.
    noise_a : float
        Current noise, 1 sigma per sample [A] (:func:`current_noise_a` estimates it from a log).
    up_device : array-like, shape (3,) or (N, 3), optional
        Up vector in the device frame for the sky view factors (e.g. from the onboard attitude); a level vehicle
        when omitted.
    config : SunSolverConfig, optional
        Thresholds; defaults when omitted.

    Returns
    -------
    SunSolution
        With ``k_min_a`` = ``config.k_min_a`` or ``max(k_min_rel * median k of the solved epochs,
        k_min_snr * noise_a)``; epochs below it get ``STATUS_LOW_K`` (their faulty flags are cleared: a fit on
        noise says nothing about the cells).
    """
    config = config or SunSolverConfig()
    currents = np.ascontiguousarray(_checked_currents(currents_a))
    noise = _checked_noise(noise_a)
    sky_factor = _sky_factor_per_epoch(device, up_device, len(currents))
    first = _run_adaptive_kernel(currents, device, sky_factor, noise, config)
    solved = first["status"] == STATUS_OK
    if solved.any():
        sigma_a = np.hypot(noise, config.model_error_rel * np.median(first["k"][solved]))
        priors = (*_robust_prior(first["sky"][solved], sigma_a * first["sky_gain"][solved], noise),
                  *_robust_prior(first["k"][solved], sigma_a * first["k_gain"][solved],
                                 config.model_error_rel * np.median(first["k"][solved])))
        final = _run_adaptive_kernel(currents, device, sky_factor, noise, config, priors)
    else:
        final = first
    status, k = final["status"], final["k"]
    solved = status == STATUS_OK
    if config.k_min_a is not None:
        k_min = float(config.k_min_a)
    else:
        k_reference = float(np.median(k[solved])) if solved.any() else 0.0
        k_min = max(config.k_min_rel * k_reference, config.k_min_snr * noise)
    low = solved & (k < k_min)
    status[low] = STATUS_LOW_K
    for name in ("s_device", "sigma_rad"):
        final[name][low] = np.nan
    final["faulty"][low] = False
    with np.errstate(invalid="ignore", divide="ignore"):
        residual = np.sqrt(final["rss"] / final["n_fit"]) / k
    return SunSolution(s_device=final["s_device"], s_body=final["s_device"] @ device.body_from_device.T, k_a=k,
                       sky_a=final["sky"], residual=residual, sigma_rad=final["sigma_rad"],
                       cells_used=final["cells_used"], faulty=final["faulty"], status=status, noise_a=noise,
                       k_min_a=k_min)


def _robust_prior(values_a, sd_a, floor_a) -> tuple[float, float]:
    """Prior (value, 1-sigma) [A] on the sky current or on ``k`` from pass-1 estimates with 1-sigma ``sd_a``.

    Value: median weighted by ``1 / sd^2`` (the ``sd`` come from the geometry and one common current sigma, so
    the weights do not select on the estimates' own errors). Spread ``tau`` of the true quantity: the root of
    ``median(|sky - value| / sqrt(sd^2 + tau^2)) = 0.6745`` (median of a unit half-normal), i.e. the scatter the
    estimates' errors do not explain. Returned sigma: ``sqrt(tau^2 + se^2)`` with ``se`` the standard error of
    the weighted median (1.2533 / sqrt(sum of weights)), at least ``floor_a`` (the per-cell model error: pass-1
    solutions misled by a faulty cell bias the value by more than ``se``).
    """
    weight = 1.0 / sd_a ** 2
    order = np.argsort(values_a)
    cumulative = np.cumsum(weight[order])
    value = float(values_a[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])
    standard_error = 1.2533 / np.sqrt(cumulative[-1])
    deviation = np.abs(values_a - value)

    def excess(tau):
        return float(np.median(deviation / np.sqrt(sd_a ** 2 + tau ** 2))) - 0.6745

    tau = 0.0
    if excess(0.0) > 0.0:
        low, high = 0.0, float(np.max(deviation))
        for _ in range(50):
            middle = 0.5 * (low + high)
            low, high = (middle, high) if excess(middle) > 0.0 else (low, middle)
        tau = high
    return value, max(float(np.hypot(tau, standard_error)), float(floor_a))


def _run_adaptive_kernel(currents, device, sky_factor, noise, config, priors=(0.0, np.inf, 0.0, np.inf)) -> dict:
    """Allocate the outputs and run :func:`adaptive_kernel` once.

    ``priors``: (sky value, sky sigma, k value, k sigma) [A]; an infinite sigma means no prior.
    """
    n_epochs = len(currents)
    out = {
        "s_device": np.full((n_epochs, 3), np.nan),
        **{name: np.full(n_epochs, np.nan) for name in ("k", "sky", "rss", "sigma_rad", "sky_gain", "k_gain")},
        "n_fit": np.zeros(n_epochs, dtype=np.int64),
        "cells_used": np.zeros((n_epochs, N_CELLS), dtype=bool),
        "faulty": np.zeros((n_epochs, N_CELLS), dtype=bool),
        "status": np.zeros(n_epochs, dtype=np.int8),
    }
    settings = KernelSettings(
        float(noise), float(config.model_error_rel), float(config.kappa),
        float(np.cos(np.radians(config.max_incidence_deg))), float(config.dark_cos_max), float(config.cond_max),
        int(config.n_initial), int(config.max_iterations), int(config.n_alternatives), *map(float, priors))
    adaptive_kernel(currents, np.ascontiguousarray(device.normals_device), sky_factor, settings,
                     out["s_device"], out["k"], out["sky"], out["rss"], out["n_fit"], out["sigma_rad"],
                     out["sky_gain"], out["k_gain"], out["cells_used"], out["faulty"], out["status"])
    return out


def current_noise_a(currents_a) -> float:
    """Per-sample current noise [A] estimated from the log itself.

    Robust scale of the second differences of each cell's current (``1.4826 MAD / sqrt(6)``: white noise of
    sigma gives second differences of sigma sqrt(6), a smooth signal almost none), median over the cells (a stuck
    cell does not pull it to zero), floored at 0.1 % of the 99th-percentile current (ADC quantisation). Assumes
    rows in time order at a steady rate; fast attitude motion makes it conservative.

    Parameters
    ----------
    currents_a : array-like, shape (N, 7)
        Cell currents [A], N >= 3.
    """
    currents = _checked_currents(currents_a)
    if len(currents) < 3:
        raise InputError(f"need at least 3 samples to estimate the current noise, got {len(currents)}",
                         field="currents_a")
    second = np.diff(currents, n=2, axis=0)
    deviation = np.abs(second - np.nanmedian(second, axis=0))
    per_cell = 1.4826 * np.nanmedian(deviation, axis=0) / np.sqrt(6.0)
    floor = 1e-3 * np.nanpercentile(np.abs(currents), 99.0)
    noise = max(float(np.nanmedian(per_cell)), float(floor))
    if not np.isfinite(noise) or noise <= 0.0:
        raise InputError("cannot estimate the current noise: the currents are all zero or missing",
                         field="currents_a")
    return noise


def cell_bitmask(cells: np.ndarray) -> np.ndarray:
    """Integer bitmask of a bool (N, 7) cell array: bit j set = cell j+1 (``i{j+1}_a``), shape (N,) int64."""
    return (np.asarray(cells, dtype=np.int64) << np.arange(N_CELLS)).sum(axis=1)


def solve_sun_log(sun_frame: pd.DataFrame, device: SunDevice | None = None, noise_a: float | None = None,
                  up_body=None, config: SunSolverConfig | None = None) -> pd.DataFrame:
    """Adaptive least-squares sun vector of every sample of a ``sun`` stream.

    Parameters
    ----------
    sun_frame : pandas.DataFrame
        The ``sun`` stream of a FlightLog: index ``time_s`` [s] (or a ``time_s`` column) and columns
        ``i1_a`` .. ``i7_a`` [A].
    device : SunDevice, optional
        Geometry and mounting; the default device when omitted.
    noise_a : float, optional
        Current noise [A]; estimated with :func:`current_noise_a` when omitted.
    up_body : array-like, shape (3,) or (N, 3), optional
        Up unit vector in body FRD per sample for the sky view factors, ``R_nb^T (0, 0, -1)``, e.g.
        ``-ingest.frames.quat_to_matrix(q)[:, 2, :]`` from the onboard attitude interpolated to the sun samples;
        level flight when omitted.
    config : SunSolverConfig, optional
        Solver thresholds.

    Returns
    -------
    pandas.DataFrame
        One row per sample: ``time_s`` [s]; ``sun_x``, ``sun_y``, ``sun_z``: unit vector towards the sun in body
        FRD (NaN without a solution); ``cells_used``, ``faulty_cells``: bitmasks (:func:`cell_bitmask`);
        ``residual``: RMS residual / ``k_a`` [-]; ``sigma_rad``: 1-sigma direction error per axis [rad];
        ``k_a``: current of a cell facing the sun [A]; ``sky_a``: sky-light current [A]; ``status``: name from
        :data:`STATUS_NAMES`.
    """
    device = device or SunDevice()
    missing = [c for c in CURRENT_COLUMNS if c not in sun_frame.columns]
    if missing:
        raise InputError(f"missing current columns {missing} (expected {list(CURRENT_COLUMNS)})", field="sun")
    try:
        currents = sun_frame[list(CURRENT_COLUMNS)].to_numpy(dtype=float)
    except (TypeError, ValueError) as error:
        raise InputError(f"current columns must be numeric: {error}", field="sun") from None
    time_s = (sun_frame["time_s"] if "time_s" in sun_frame.columns else sun_frame.index).to_numpy(dtype=float)
    up_device = None if up_body is None else np.asarray(up_body, dtype=float) @ device.body_from_device
    if len(currents) == 0:
        solution = solve_sun_adaptive(np.empty((0, N_CELLS)), device, noise_a or 1.0, up_device, config)
    else:
        noise = current_noise_a(currents) if noise_a is None else noise_a
        solution = solve_sun_adaptive(currents, device, noise, up_device, config)
    return pd.DataFrame({
        "time_s": time_s,
        "sun_x": solution.s_body[:, 0], "sun_y": solution.s_body[:, 1], "sun_z": solution.s_body[:, 2],
        "cells_used": cell_bitmask(solution.cells_used), "faulty_cells": cell_bitmask(solution.faulty),
        "residual": solution.residual, "sigma_rad": solution.sigma_rad, "k_a": solution.k_a,
        "sky_a": solution.sky_a, "status": [STATUS_NAMES[int(code)] for code in solution.status],
    })
