"""Sun vector from the currents of the 7-photocell sun device, and its EKF measurement model.

Design note section 8 (the PV paper, seed 003, reconstructed). Frames and cells follow ``ingest.sun_device``:
device frame x forward, y right, z down; cell 1 (column ``i1_a``) is the top cell with outward normal
(0, 0, -1); cells 2..7 are the side cells n_i = (sin a cos az_i, sin a sin az_i, -cos a).

Current model (note 8.2, with the isotropic-sky view factor the note's [FLAG] mentions)::

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
* :func:`solve_sun_adaptive` -- adaptive least squares (note 8.4), per epoch in a numba kernel
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
(A^T A)^-1`` and ``Sigma_s = P Cov(x)_xx P / k^2`` with ``P = I - s s^T`` (note 8.3); ``sigma_rad`` is the
per-axis 1-sigma angle ``sqrt(trace(Sigma_s) / 2)``.

Measurement model (note 8.5, numba leaf functions for the filters): ``z = s_b``, ``h = C_bn s_n = R_nb^T s_n``,
``dh/dTheta = [h]x W(Theta)`` for ZYX Euler angles, ``dh/d(dtheta) = [h]x`` for the body-axes error angle of the
error-state filter (``R = R_hat Exp(dtheta)``); noise ``R = sigma_rad^2 I``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import pandas as pd
from numba import njit

from estimators.ekf_core import cholesky_lower
from ingest.errors import InputError
from ingest.flightlog import STREAM_COLUMNS
from ingest.sun_device import N_CELLS, SunDevice

#: Current columns of the canonical ``sun`` stream, cell 1 (top) first.
CURRENT_COLUMNS = STREAM_COLUMNS["sun"]

#: Solver status codes (``SunSolution.status``) and their names (``status`` column of :func:`solve_sun_log`).
STATUS_OK = 0
STATUS_NO_DATA = 1
STATUS_TOO_FEW_CELLS = 2
STATUS_ILL_CONDITIONED = 3
STATUS_INCONSISTENT = 4
STATUS_LOW_K = 5
STATUS_NAMES = {
    STATUS_OK: "ok",
    STATUS_NO_DATA: "no_data",  # fewer than 3 finite currents
    STATUS_TOO_FEW_CELLS: "too_few_cells",  # < 3 lit cells or no sky reference
    STATUS_ILL_CONDITIONED: "ill_conditioned",  # lit normals (nearly) coplanar
    STATUS_INCONSISTENT: "inconsistent",  # residual too large and no cell left to exclude
    STATUS_LOW_K: "low_k",  # direct-sun current too low (clouds, night)
}

_UP_BODY = np.array([0.0, 0.0, -1.0])
#: Tolerance [-] (in cos of the incidence) of the lit/dark thresholds when checking a solution's cell classes.
_CLASS_BAND = 0.05
#: Score margin [-] (in squared standardised residuals) by which an alternative fault hypothesis must beat the
#: first one to replace it: ties go to the hypothesis that excludes fewer cells.
_ALTERNATIVE_MARGIN = 1.0
#: Most re-linearisations of the k prior row per fit.
_K_PRIOR_ITERATIONS = 5


@dataclass(frozen=True)
class SunSolverConfig:
    """Thresholds of the sun-vector solvers (note 8.4; reconstructed defaults, not the PV paper's numbers).

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
# Forward model
# ----------------------------------------------------------------------------------------------------------------
def default_up_device(device: SunDevice) -> np.ndarray:
    """Up direction in the device frame of a level vehicle, shape (3,) (``R_bd^T (0, 0, -1)``)."""
    return device.body_from_device.T @ _UP_BODY


def sky_view_factors(device: SunDevice, up_device=None) -> np.ndarray:
    """Fraction of the sky dome each cell sees, ``(1 + n_i . u) / 2``, shape (..., 7) [-].

    Parameters
    ----------
    device : SunDevice
        Cell geometry.
    up_device : array-like, shape (3,) or (N, 3), optional
        Unit up vector in the device frame; a level vehicle (:func:`default_up_device`) when omitted.
    """
    up = default_up_device(device) if up_device is None else np.asarray(up_device, dtype=float)
    up = up / np.linalg.norm(up, axis=-1, keepdims=True)
    return 0.5 * (1.0 + up @ device.normals_device.T)


def photocell_currents(s_device, k_a, sky_a, device: SunDevice, up_device=None) -> np.ndarray:
    """Noise-free cell currents ``I_i = k max(0, n_i . s) + I_sky (1 + n_i . u) / 2`` [A].

    Parameters
    ----------
    s_device : array-like, shape (3,) or (N, 3)
        Unit vector towards the sun in the device frame [-].
    k_a : float or array-like, shape (N,)
        Current of a cell facing the sun [A] (0 at night or under thick cloud).
    sky_a : float or array-like, shape (N,)
        Sky-light current of a cell facing the zenith [A].
    device : SunDevice
        Cell geometry.
    up_device : array-like, shape (3,) or (N, 3), optional
        Unit up vector in the device frame; a level vehicle when omitted (:func:`device_sun_and_up` gives both
        vectors from an attitude).

    Returns
    -------
    numpy.ndarray, shape (7,) or (N, 7)
        Currents of cells 1..7 [A] (column order of the ``sun`` stream).
    """
    cos_incidence = np.asarray(s_device, dtype=float) @ device.normals_device.T
    direct = np.asarray(k_a, dtype=float)[..., None] * np.maximum(cos_incidence, 0.0)
    return direct + np.asarray(sky_a, dtype=float)[..., None] * sky_view_factors(device, up_device)


def device_sun_and_up(r_nb, s_ned, device: SunDevice) -> tuple[np.ndarray, np.ndarray]:
    """Sun and up unit vectors in the device frame for attitudes ``r_nb``.

    Parameters
    ----------
    r_nb : array-like, shape (3, 3) or (N, 3, 3)
        Body FRD -> NED rotations.
    s_ned : array-like, shape (3,) or (N, 3)
        Unit vector towards the sun in NED.
    device : SunDevice
        Provides the mounting ``R_bd``.

    Returns
    -------
    s_device, up_device : numpy.ndarray, shape (..., 3)
        ``R_bd^T R_nb^T s_n`` and ``R_bd^T R_nb^T (0, 0, -1)``.
    """
    r_nb = np.asarray(r_nb, dtype=float)
    r_bd = device.body_from_device
    s_body = np.einsum("...ji,...j->...i", r_nb, np.asarray(s_ned, dtype=float))
    up_body = -r_nb[..., 2, :]
    return s_body @ r_bd, up_body @ r_bd


# ----------------------------------------------------------------------------------------------------------------
# Per-epoch kernel of the adaptive least squares. Explicit loops on tiny arrays and scratch space allocated once
# per call: a BLAS/LAPACK call or a heap allocation per epoch would cost more than the arithmetic.
# ----------------------------------------------------------------------------------------------------------------
# Rows of the scratch arrays: cell flags (bool, n_cells wide), vectors (4 wide), 4x4 matrices.
_AVAILABLE, _CORE, _EXCLUDED, _READMITTED, _LIT, _DARK, _USABLE, _USED, _FIT_LIT, _FAULTY, _START_EXCLUDED = range(11)
_N_FLAGS = 11
_S, _S_NEW, _SOLUTION, _ROW, _RHS, _START_S = range(6)
_NORMAL, _INVERSE, _LOW, _LOW_INV = range(4)


class _KernelSettings(NamedTuple):
    """Scalars of the adaptive kernel (see :class:`SunSolverConfig`); an infinite prior sigma = no prior."""

    noise_a: float
    model_error_rel: float
    kappa: float
    cos_lit_min: float
    cos_dark_max: float
    cond_max: float
    n_initial: int
    max_iterations: int
    n_alternatives: int
    sky_prior_a: float
    sky_prior_sigma_a: float
    k_prior_a: float
    k_prior_sigma_a: float


@njit(cache=True)
def _spd_inverse(mat, n):
    """Inverse of the leading n x n (n <= 4) block of the symmetric positive-definite ``mat[_NORMAL]`` into
    ``mat[_INVERSE]`` (Cholesky); False when a pivot is below 1e-12 of the largest diagonal element."""
    m, out, low, low_inv = mat[_NORMAL], mat[_INVERSE], mat[_LOW], mat[_LOW_INV]
    scale = 0.0
    for i in range(n):
        scale = max(scale, m[i, i])
    if not cholesky_lower(m, low, n, 1e-12 * scale):
        return False
    for j in range(n):
        low_inv[j, j] = 1.0 / low[j, j]
        for i in range(j + 1, n):
            value = 0.0
            for p in range(j, i):
                value -= low[i, p] * low_inv[p, j]
            low_inv[i, j] = value / low[i, i]
    for i in range(n):
        for j in range(n):
            value = 0.0
            for p in range(max(i, j), n):
                value += low_inv[p, i] * low_inv[p, j]
            out[i, j] = value
    return True


@njit(cache=True)
def _condition_sym3(m):
    """Condition number of the symmetric positive semi-definite block ``m[:3, :3]`` (closed-form eigenvalues)."""
    off = m[0, 1] ** 2 + m[0, 2] ** 2 + m[1, 2] ** 2
    mean = (m[0, 0] + m[1, 1] + m[2, 2]) / 3.0
    spread = np.sqrt(((m[0, 0] - mean) ** 2 + (m[1, 1] - mean) ** 2 + (m[2, 2] - mean) ** 2 + 2.0 * off) / 6.0)
    if spread <= 1e-15 * abs(mean):
        return 1.0 if mean > 0.0 else np.inf
    b00, b11, b22 = (m[0, 0] - mean) / spread, (m[1, 1] - mean) / spread, (m[2, 2] - mean) / spread
    b01, b02, b12 = m[0, 1] / spread, m[0, 2] / spread, m[1, 2] / spread
    half_det = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    phi = np.arccos(min(1.0, max(-1.0, half_det))) / 3.0
    largest = mean + 2.0 * spread * np.cos(phi)
    smallest = mean + 2.0 * spread * np.cos(phi + 2.0 * np.pi / 3.0)
    return largest / smallest if smallest > 0.0 else np.inf


@njit(cache=True)
def _design_row(normals, sky_factor, lit, i, row):
    """Row of cell i in ``[n_i lit_i, f_i] (k s, I_sky) = I_i``."""
    for p in range(3):
        row[p] = normals[i, p] if lit[i] else 0.0
    row[3] = sky_factor[i]


@njit(cache=True)
def _residual_leverage(current, normals, sky_factor, lit, i, vec, mat):
    """Residual r_i [A] of cell i against ``vec[_SOLUTION]`` and its leverage a_i^T M^-1 a_i [-]."""
    row, solution, m_inv = vec[_ROW], vec[_SOLUTION], mat[_INVERSE]
    _design_row(normals, sky_factor, lit, i, row)
    residual = current[i]
    leverage = 0.0
    for p in range(4):
        residual -= row[p] * solution[p]
        for q in range(4):
            leverage += row[p] * m_inv[p, q] * row[q]
    return residual, leverage


@njit(cache=True)
def _joint_fit(current, normals, sky_factor, lit, dark, sky_weight, sky_prior_a, k_weight, k_prior_a, vec, mat):
    """Least squares of the lit and dark cells' rows plus the prior rows (relative weights, 0 = unused).

    Sky prior row: ``I_sky = sky_prior_a``; k prior row: ``s . (k s) = k_prior_a`` linearised about the current
    direction ``vec[_S]``. Writes ``vec[_SOLUTION]`` = (k s, I_sky) and ``mat[_INVERSE]``; returns
    (cond(N_L^T N_L) of the lit normals, ok).
    """
    m, b, row, solution, m_inv, s = mat[_NORMAL], vec[_RHS], vec[_ROW], vec[_SOLUTION], mat[_INVERSE], vec[_S]
    m[:] = 0.0
    b[:] = 0.0
    for i in range(current.shape[0]):
        if lit[i] or dark[i]:
            _design_row(normals, sky_factor, lit, i, row)
            for p in range(4):
                b[p] += row[p] * current[i]
                for q in range(4):
                    m[p, q] += row[p] * row[q]
    condition = _condition_sym3(m)
    if sky_weight > 0.0:
        m[3, 3] += sky_weight
        b[3] += sky_weight * sky_prior_a
    if k_weight > 0.0:
        for p in range(3):
            b[p] += k_weight * k_prior_a * s[p]
            for q in range(3):
                m[p, q] += k_weight * s[p] * s[q]
    if not _spd_inverse(mat, 4):
        return condition, False
    for p in range(4):
        value = 0.0
        for q in range(4):
            value += m_inv[p, q] * b[q]
        solution[p] = value
    return condition, True


@njit(cache=True)
def _initial_direction(current, normals, sky_factor, n_initial, flags, vec, mat):
    """Direction from the ``n_initial`` largest currents, the sky removed at its upper bound min(I_i / f_i).

    Marks those cells in ``flags[_CORE]`` and writes the unit vector into ``vec[_S]``; returns (k [A], ok).
    """
    available, core, s, m, b = flags[_AVAILABLE], flags[_CORE], vec[_S], mat[_NORMAL], vec[_RHS]
    n_cells = current.shape[0]
    sky = np.inf
    for i in range(n_cells):
        core[i] = False
        if available[i] and sky_factor[i] > 0.1:
            sky = min(sky, current[i] / sky_factor[i])
    sky = max(sky, 0.0) if np.isfinite(sky) else 0.0
    m[:] = 0.0
    b[:] = 0.0
    for _ in range(n_initial):
        largest = -1
        for i in range(n_cells):
            if available[i] and not core[i] and (largest < 0 or current[i] > current[largest]):
                largest = i
        if largest < 0:
            break
        core[largest] = True
        y = current[largest] - sky * sky_factor[largest]
        for p in range(3):
            b[p] += normals[largest, p] * y
            for q in range(3):
                m[p, q] += normals[largest, p] * normals[largest, q]
    if not _spd_inverse(mat, 3):
        return 0.0, False
    m_inv = mat[_INVERSE]
    for p in range(3):
        s[p] = m_inv[p, 0] * b[0] + m_inv[p, 1] * b[1] + m_inv[p, 2] * b[2]
    k = np.sqrt(s[0] ** 2 + s[1] ** 2 + s[2] ** 2)
    if k == 0.0:
        return 0.0, False
    for p in range(3):
        s[p] /= k
    return k, True


@njit(cache=True)
def _classify(normals, s, usable, cos_lit_min, cos_dark_max, lit, dark):
    """Lit (``n . s > cos_lit_min``) and dark (``n . s < cos_dark_max``) usable cells; returns their counts."""
    n_lit = 0
    n_dark = 0
    for i in range(normals.shape[0]):
        c = normals[i, 0] * s[0] + normals[i, 1] * s[1] + normals[i, 2] * s[2]
        lit[i] = usable[i] and c > cos_lit_min
        dark[i] = usable[i] and c < cos_dark_max
        n_lit += lit[i]
        n_dark += dark[i]
    return n_lit, n_dark


@njit(cache=True)
def _classification_holds(normals, s, usable, lit, dark, cos_lit_min, cos_dark_max):
    """True when the cell classes agree with direction ``s`` (within ``_CLASS_BAND`` of the thresholds)."""
    for i in range(normals.shape[0]):
        if not usable[i]:
            continue
        c = normals[i, 0] * s[0] + normals[i, 1] * s[1] + normals[i, 2] * s[2]
        if lit[i] != (c > cos_lit_min) and abs(c - cos_lit_min) > _CLASS_BAND:
            return False
        if dark[i] != (c < cos_dark_max) and abs(c - cos_dark_max) > _CLASS_BAND:
            return False
    return True


@njit(cache=True)
def _refine(current, normals, sky_factor, st, k, flags, vec, mat):
    """Steps 2 and 3 of :func:`_solve_epoch` from direction ``vec[_S]``, scale ``k`` and ``flags[_EXCLUDED]``.

    On success leaves the final fit in ``vec[_S]``, ``vec[_SOLUTION]``, ``mat[_INVERSE]``, the fitted cells in
    ``flags[_USED]`` (lit ones in ``flags[_FIT_LIT]``) and the faulty ones in ``flags[_FAULTY]``.
    Returns (status, k [A], current sigma [A], residual sum of squares [A^2], number of faulty cells).
    """
    n_cells = current.shape[0]
    available, excluded, readmitted = flags[_AVAILABLE], flags[_EXCLUDED], flags[_READMITTED]
    lit, dark, usable, used, fit_lit, faulty = (flags[_LIT], flags[_DARK], flags[_USABLE], flags[_USED],
                                                flags[_FIT_LIT], flags[_FAULTY])
    s, s_new, solution, m_inv = vec[_S], vec[_S_NEW], vec[_SOLUTION], mat[_INVERSE]
    use_sky = np.isfinite(st.sky_prior_sigma_a)
    use_k = np.isfinite(st.k_prior_sigma_a)
    for _ in range(st.max_iterations):
        for i in range(n_cells):
            usable[i] = available[i] and not excluded[i]
        n_lit, n_dark = _classify(normals, s, usable, st.cos_lit_min, st.cos_dark_max, lit, dark)
        if n_lit < 3 or (n_lit + n_dark < 4 and not use_sky):
            return STATUS_TOO_FEW_CELLS, k, np.nan, np.nan, 0
        sigma = np.sqrt(st.noise_a ** 2 + (st.model_error_rel * k) ** 2)
        sky_weight = (sigma / st.sky_prior_sigma_a) ** 2 if use_sky else 0.0
        k_weight = (sigma / st.k_prior_sigma_a) ** 2 if use_k else 0.0
        # The k prior row is linearised about s: re-linearise (same cells) until the direction stops moving.
        for _ in range(_K_PRIOR_ITERATIONS if use_k else 1):
            condition, ok = _joint_fit(current, normals, sky_factor, lit, dark, sky_weight, st.sky_prior_a,
                                       k_weight, st.k_prior_a, vec, mat)
            if not ok or condition > st.cond_max:
                return STATUS_ILL_CONDITIONED, k, np.nan, np.nan, 0
            k_new = np.sqrt(solution[0] ** 2 + solution[1] ** 2 + solution[2] ** 2)
            if k_new == 0.0:
                return STATUS_LOW_K, k, np.nan, np.nan, 0
            moved = 0.0
            for p in range(3):
                s_new[p] = solution[p] / k_new
                moved += (s_new[p] - s[p]) ** 2
            if not use_k or moved < 1e-12:
                break
            s[:] = s_new
        # Studentised residuals w = r / (sigma sqrt(1 - h)) of the cells (and sqrt(weight) r / (sigma sqrt(1 - h))
        # of the prior rows); the largest is the best leave-one-out candidate.
        rss = 0.0
        worst = -1
        worst_w = st.kappa
        for i in range(n_cells):
            if lit[i] or dark[i]:
                residual, leverage = _residual_leverage(current, normals, sky_factor, lit, i, vec, mat)
                rss += residual * residual
                if leverage < 1.0 - 1e-9 and abs(residual) > worst_w * sigma * np.sqrt(1.0 - leverage):
                    worst_w = abs(residual) / (sigma * np.sqrt(1.0 - leverage))
                    worst = i
        if use_sky:
            residual = st.sky_prior_a - solution[3]
            leverage = sky_weight * m_inv[3, 3]
            w = abs(residual) * np.sqrt(sky_weight) / (sigma * np.sqrt(max(1.0 - leverage, 1e-12)))
            if w > worst_w:
                worst_w = w
                worst = n_cells
        if use_k:
            residual = st.k_prior_a
            leverage = 0.0
            for p in range(3):
                residual -= s[p] * solution[p]
                for q in range(3):
                    leverage += s[p] * m_inv[p, q] * s[q]
            leverage *= k_weight
            w = abs(residual) * np.sqrt(k_weight) / (sigma * np.sqrt(max(1.0 - leverage, 1e-12)))
            if w > worst_w:
                worst_w = w
                worst = n_cells + 1
        if worst == n_cells:  # the sky light differs from the log's: no prior for this epoch
            use_sky = False
            continue
        if worst == n_cells + 1:  # so does k (passing cloud): no prior for this epoch
            use_k = False
            continue
        k = k_new
        if worst >= 0:
            lit_left = n_lit - lit[worst]
            dark_left = n_dark - dark[worst]
            if lit_left < 3 or (lit_left + dark_left < 4 and not use_sky):
                return STATUS_INCONSISTENT, k, np.nan, np.nan, 0
            excluded[worst] = True
            s[:] = s_new
            continue
        s[:] = s_new
        if not _classification_holds(normals, s, usable, lit, dark, st.cos_lit_min, st.cos_dark_max):
            continue
        # Fixed point: re-admit excluded cells the fit predicts (once each), else finish.
        for i in range(n_cells):
            used[i] = lit[i] or dark[i]
            fit_lit[i] = lit[i]
            usable[i] = available[i] and excluded[i]
        _classify(normals, s, usable, st.cos_lit_min, st.cos_dark_max, lit, dark)
        again = False
        n_faulty = 0
        for i in range(n_cells):
            faulty[i] = False
            if lit[i] or dark[i]:
                residual, leverage = _residual_leverage(current, normals, sky_factor, lit, i, vec, mat)
                consistent = abs(residual) <= st.kappa * sigma * np.sqrt(1.0 + leverage)
                if consistent and not readmitted[i]:
                    excluded[i] = False
                    readmitted[i] = True
                    again = True
                faulty[i] = not consistent
                n_faulty += faulty[i]
        if again:
            continue
        return STATUS_OK, k, sigma, rss, n_faulty
    return STATUS_INCONSISTENT, k, np.nan, np.nan, 0


@njit(cache=True)
def _suspects(current, normals, sky_factor, flags, vec, mat, n_suspects, suspects, suspicion):
    """The ``n_suspects`` used lit cells of the last fit with the largest studentised residuals, into
    ``suspects`` (-1 = none; ``suspicion``: scratch, one per cell); returns how many there are."""
    fit_lit, used = flags[_FIT_LIT], flags[_USED]
    n_cells = current.shape[0]
    for i in range(n_cells):
        suspicion[i] = -1.0
        if used[i] and fit_lit[i]:
            residual, leverage = _residual_leverage(current, normals, sky_factor, fit_lit, i, vec, mat)
            suspicion[i] = abs(residual) / np.sqrt(max(1.0 - leverage, 1e-12))
    count = 0
    for j in range(n_suspects):
        best = -1
        for i in range(n_cells):
            if suspicion[i] >= 0.0 and (best < 0 or suspicion[i] > suspicion[best]):
                best = i
        suspects[j] = best
        if best < 0:
            break
        suspicion[best] = -1.0
        count += 1
    return count


@njit(cache=True)
def _robust_score(current, normals, sky_factor, available, s, k, sky, sigma, st):
    """Sum over the available cells of min((r_i / sigma)^2, kappa^2), r_i against the full model
    ``k max(0, n_i . s) + sky f_i``, plus the same for the priors on sky and k (truncated quadratic, as MSAC
    scores hypotheses): a cell or prior a hypothesis rejects costs ``kappa^2``, one it explains its squared
    standardised residual."""
    cap = st.kappa * st.kappa
    score = min(((sky - st.sky_prior_a) / st.sky_prior_sigma_a) ** 2, cap)
    score += min(((k - st.k_prior_a) / st.k_prior_sigma_a) ** 2, cap)
    for i in range(current.shape[0]):
        if available[i]:
            c = normals[i, 0] * s[0] + normals[i, 1] * s[1] + normals[i, 2] * s[2]
            w = (current[i] - k * max(c, 0.0) - sky * sky_factor[i]) / sigma
            score += min(w * w, cap)
    return score


@njit(cache=True)
def _no_solution(status):
    """The return tuple of :func:`_solve_epoch` without a solution."""
    return status, np.nan, np.nan, np.nan, 0, np.nan, np.nan, np.nan


@njit(cache=True)
def _solve_epoch(current, normals, sky_factor, st, s_out, cells_used, faulty, flags, vec, mat, suspects,
                 suspicion):
    """Adaptive LS for one epoch; writes ``s_out`` (3,), ``cells_used`` (7,), ``faulty`` (7,).

    1. Core: the ``n_initial`` largest currents (a stuck-at-zero cell is never among them while enough cells are
       lit) give a first direction and a joint fit; every other cell whose current this fit does not predict
       (prediction test at ``kappa``) starts excluded.
    2. Loop: classify (lit / dark / grazing) with the current direction, fit, exclude the row with the largest
       studentised residual beyond ``kappa`` (data snooping; a prior row that fails is dropped for this epoch),
       until the fit passes and its own direction gives the same classes (a fixed point: a linear fit alone
       can trade a stuck cell for an absurd direction).
    3. Excluded cells that the final fit predicts after all are re-admitted once (then back to 2).
    4. With a faulty cell, a gross error on a well-lit cell may have been blamed on another: redo 2-3 with each of
       the ``n_alternatives`` most suspicious accepted cells excluded from the start, and keep the solution with
       the smallest truncated-quadratic score over all cells (:func:`_robust_score`; an alternative must win by
       ``_ALTERNATIVE_MARGIN``). Faulty: the excluded cells the kept solution does not predict.

    ``st``: :class:`_KernelSettings`; ``flags``, ``vec``, ``mat``, ``suspects`` (n_alternatives ints),
    ``suspicion`` (one per cell): scratch space (rows ``_AVAILABLE``.., ``_S``.., ``_NORMAL``..).
    Returns (status, k [A], sky [A], residual sum of squares [A^2], fitted cells, sigma [rad], and the 1-sigma
    of sky and k per unit current sigma [-]).
    """
    n_cells = current.shape[0]
    available, core, excluded, readmitted = flags[_AVAILABLE], flags[_CORE], flags[_EXCLUDED], flags[_READMITTED]
    lit, dark, used, fault = flags[_LIT], flags[_DARK], flags[_USED], flags[_FAULTY]
    s, solution, m_inv = vec[_S], vec[_SOLUTION], mat[_INVERSE]
    n_available = 0
    for i in range(n_cells):
        available[i] = np.isfinite(current[i])
        n_available += available[i]
        excluded[i] = False
        readmitted[i] = False
        cells_used[i] = False
        faulty[i] = False
    s_out[:] = np.nan
    if n_available < 3:
        return _no_solution(STATUS_NO_DATA)
    k, ok = _initial_direction(current, normals, sky_factor, st.n_initial, flags, vec, mat)
    if not ok:
        return _no_solution(STATUS_ILL_CONDITIONED)
    # 1. Screen the non-core cells against the core's fit.
    use_sky = np.isfinite(st.sky_prior_sigma_a)
    n_lit, n_dark = _classify(normals, s, core, st.cos_lit_min, st.cos_dark_max, lit, dark)
    if n_lit >= 3 and (n_lit + n_dark >= 4 or use_sky):
        sigma = np.sqrt(st.noise_a ** 2 + (st.model_error_rel * k) ** 2)
        _, ok = _joint_fit(current, normals, sky_factor, lit, dark, (sigma / st.sky_prior_sigma_a) ** 2,
                           st.sky_prior_a, (sigma / st.k_prior_sigma_a) ** 2, st.k_prior_a, vec, mat)
        k_core = np.sqrt(solution[0] ** 2 + solution[1] ** 2 + solution[2] ** 2)
        if ok and k_core > 0.0:
            k = k_core
            for p in range(3):
                s[p] = solution[p] / k
            sigma = np.sqrt(st.noise_a ** 2 + (st.model_error_rel * k) ** 2)
            _classify(normals, s, available, st.cos_lit_min, st.cos_dark_max, lit, dark)
            for i in range(n_cells):
                if (lit[i] or dark[i]) and not core[i]:
                    residual, leverage = _residual_leverage(current, normals, sky_factor, lit, i, vec, mat)
                    excluded[i] = abs(residual) > st.kappa * sigma * np.sqrt(1.0 + leverage)
    start_s, start_excluded = vec[_START_S], flags[_START_EXCLUDED]
    start_s[:] = s
    start_excluded[:] = excluded
    # 2./3.
    best = _no_solution(STATUS_INCONSISTENT)
    best_score = np.inf
    score_sigma = 0.0
    n_tries = 1
    attempt = 0
    while attempt < n_tries:
        if attempt > 0:  # 4. an alternative: the suspect excluded (and never re-admitted) from the start
            s[:] = start_s
            excluded[:] = start_excluded
            readmitted[:] = False
            excluded[suspects[attempt - 1]] = True
            readmitted[suspects[attempt - 1]] = True
        status, k_fit, sigma, rss, n_faulty = _refine(current, normals, sky_factor, st, k, flags, vec, mat)
        if attempt == 0:
            if status != STATUS_OK:
                return _no_solution(status)
            score_sigma = sigma
            if n_faulty > 0 and st.n_alternatives > 0:
                n_tries = 1 + _suspects(current, normals, sky_factor, flags, vec, mat, st.n_alternatives, suspects,
                                        suspicion)
        if status != STATUS_OK:
            attempt += 1
            continue
        score = _robust_score(current, normals, sky_factor, available, s, k_fit, solution[3], score_sigma, st)
        if score < best_score - (_ALTERNATIVE_MARGIN if attempt > 0 else 0.0):
            best_score = score
            cov_along = 0.0
            for p in range(3):
                for q in range(3):
                    cov_along += s[p] * m_inv[p, q] * s[q]
            spread = max(m_inv[0, 0] + m_inv[1, 1] + m_inv[2, 2] - cov_along, 0.0)
            best = (STATUS_OK, k_fit, solution[3], rss, int(used.sum()), sigma * np.sqrt(spread / 2.0) / k_fit,
                    np.sqrt(m_inv[3, 3]), np.sqrt(cov_along))
            s_out[:] = s[:3]
            cells_used[:] = used
            faulty[:] = fault
        attempt += 1
    return best


@njit(cache=True)
def _adaptive_kernel(currents, normals, sky_factor, st, s_out, k_out, sky_out, rss_out, n_fit_out, sigma_out,
                     sky_gain_out, k_gain_out, cells_used, faulty, status):
    flags = np.zeros((_N_FLAGS, currents.shape[1]), dtype=np.bool_)
    vec = np.zeros((6, 4))
    mat = np.zeros((4, 4, 4))
    suspects = np.full(max(st.n_alternatives, 1), -1)
    suspicion = np.zeros(currents.shape[1])
    for e in range(currents.shape[0]):
        (status[e], k_out[e], sky_out[e], rss_out[e], n_fit_out[e], sigma_out[e], sky_gain_out[e],
         k_gain_out[e]) = _solve_epoch(currents[e], normals, sky_factor[e], st, s_out[e], cells_used[e],
                                       faulty[e], flags, vec, mat, suspects, suspicion)


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
    ``s = x / |x|``, ``k = |x|`` (note 8.3 with the sky current of 8.4 (1)). Exact when all cells are lit and
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

    Algorithm in the module docstring (note 8.4). The per-epoch numba kernel runs twice: pass 1 without priors,
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
    """Allocate the outputs and run :func:`_adaptive_kernel` once.

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
    settings = _KernelSettings(
        float(noise), float(config.model_error_rel), float(config.kappa),
        float(np.cos(np.radians(config.max_incidence_deg))), float(config.dark_cos_max), float(config.cond_max),
        int(config.n_initial), int(config.max_iterations), int(config.n_alternatives), *map(float, priors))
    _adaptive_kernel(currents, np.ascontiguousarray(device.normals_device), sky_factor, settings,
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


# ----------------------------------------------------------------------------------------------------------------
# Measurement model for the filters (numba leaf functions; plain float64 arrays in, new arrays out)
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=True)
def sun_measurement(r_nb, s_ned):
    """Predicted body-frame sun vector ``h = C_bn s_n = R_nb^T s_n``, shape (3,).

    Parameters
    ----------
    r_nb : numpy.ndarray, shape (3, 3)
        Body FRD -> NED rotation.
    s_ned : numpy.ndarray, shape (3,)
        Unit vector towards the sun in NED (``estimators.environment.sun_direction_ned``).
    """
    return r_nb.T @ s_ned


@njit(cache=True)
def _cross_matrix_times(h, w):
    """[h]x w for a 3x3 matrix w: column j is h x w[:, j]."""
    out = np.empty((3, 3))
    for j in range(3):
        out[0, j] = h[1] * w[2, j] - h[2] * w[1, j]
        out[1, j] = h[2] * w[0, j] - h[0] * w[2, j]
        out[2, j] = h[0] * w[1, j] - h[1] * w[0, j]
    return out


@njit(cache=True)
def sun_jacobian_euler(r_nb, s_ned):
    """``dh/dTheta = [h]x W(Theta)`` for ZYX Euler angles Theta = (roll, pitch, yaw), shape (3, 3) [1/rad].

    ``W = [[1, 0, -s_th], [0, c_ph, s_ph c_th], [0, -s_ph, c_ph c_th]]`` (omega = W Theta_dot, note 1.1) is built
    from ``r_nb`` itself (``R31 = -s_th``, ``R32 = s_ph c_th``, ``R33 = c_ph c_th``); singular at pitch +-90 deg.

    Parameters
    ----------
    r_nb : numpy.ndarray, shape (3, 3)
        Body FRD -> NED rotation of the state's Euler angles.
    s_ned : numpy.ndarray, shape (3,)
        Unit vector towards the sun in NED.
    """
    cos_pitch = np.hypot(r_nb[2, 1], r_nb[2, 2])
    w = np.zeros((3, 3))
    w[0, 0] = 1.0
    w[0, 2] = r_nb[2, 0]
    w[1, 1] = r_nb[2, 2] / cos_pitch
    w[1, 2] = r_nb[2, 1]
    w[2, 1] = -r_nb[2, 1] / cos_pitch
    w[2, 2] = r_nb[2, 2]
    return _cross_matrix_times(r_nb.T @ s_ned, w)


@njit(cache=True)
def sun_jacobian_error_angle(r_nb, s_ned):
    """``dh/d(dtheta) = [h]x`` for the body-axes error angle ``R = R_hat Exp(dtheta)``, shape (3, 3) [1/rad].

    Parameters
    ----------
    r_nb : numpy.ndarray, shape (3, 3)
        Nominal body FRD -> NED rotation.
    s_ned : numpy.ndarray, shape (3,)
        Unit vector towards the sun in NED.
    """
    return _cross_matrix_times(r_nb.T @ s_ned, np.eye(3))


@njit(cache=True)
def sun_tangent_basis(h):
    """Orthonormal basis of the plane perpendicular to ``h`` (normalised first), shape (3, 2), columns
    ``(t1, u x t1)`` with ``u = h / |h|``; the one tangent basis of the three filters' sun updates.

    For the 2-DOF form of the update (note 8.5): ``nu = T^T z``, ``H' = T^T H``, ``R' = sigma_rad^2 I_2``.
    """
    norm = np.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2])
    u0, u1, u2 = h[0] / norm, h[1] / norm, h[2] / norm
    if abs(u0) < 0.9:
        a0, a1, a2 = 1.0, 0.0, 0.0
    else:
        a0, a1, a2 = 0.0, 1.0, 0.0
    d = a0 * u0 + a1 * u1 + a2 * u2
    t0, t1, t2 = a0 - d * u0, a1 - d * u1, a2 - d * u2
    tn = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    t0, t1, t2 = t0 / tn, t1 / tn, t2 / tn
    basis = np.empty((3, 2))
    basis[0, 0], basis[1, 0], basis[2, 0] = t0, t1, t2
    basis[0, 1] = u1 * t2 - u2 * t1
    basis[1, 1] = u2 * t0 - u0 * t2
    basis[2, 1] = u0 * t1 - u1 * t0
    return basis


@njit(cache=True)
def tangent_projection(basis, axis, z, h3, H3, H):
    """One scalar of the 2-DOF sun update (note 8.5): the innovation ``nu = t^T (z - h)`` along the tangent axis
    ``t = basis[:, axis]`` and its Jacobian row ``H = t^T H3`` (written into ``H``, length n).

    ``z``: measured body-frame unit vector (its first 3 entries); ``h3`` (3,) and ``H3`` (3, n): predicted vector
    and its Jacobian.
    """
    nu = 0.0
    for c in range(3):
        nu += basis[c, axis] * (z[c] - h3[c])
    for i in range(H.shape[0]):
        H[i] = basis[0, axis] * H3[0, i] + basis[1, axis] * H3[1, i] + basis[2, axis] * H3[2, i]
    return nu


@njit(cache=True)
def sun_measurement_noise(sigma_rad):
    """Measurement covariance of the 3-vector form, ``sigma_rad^2 I_3`` [-], from the solver's ``sigma_rad``."""
    return sigma_rad * sigma_rad * np.eye(3)
