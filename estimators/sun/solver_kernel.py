"""Compiled per-epoch adaptive least-squares solver of the sun vector (docs/sun.md, 'Solvers'): status codes,
scratch-array layout and the numba kernels behind :func:`estimators.sun.solver.solve_sun_adaptive`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from estimators.core.linalg import cholesky_lower, copy_into

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
#: Tolerance [-] (in cos of the incidence) of the lit/dark thresholds when checking a solution's cell classes.
_CLASS_BAND = 0.05
#: Score margin [-] (in squared standardised residuals) by which an alternative fault hypothesis must beat the
#: first one to replace it: ties go to the hypothesis that excludes fewer cells.
_ALTERNATIVE_MARGIN = 1.0
#: Most re-linearisations of the k prior row per fit.
_K_PRIOR_ITERATIONS = 5


# ----------------------------------------------------------------------------------------------------------------
# Per-epoch kernel of the adaptive least squares. Explicit loops on tiny arrays and scratch space allocated once
# per call: a BLAS/LAPACK call or a heap allocation per epoch would cost more than the arithmetic.
# ----------------------------------------------------------------------------------------------------------------
# Rows of the scratch arrays: cell flags (bool, n_cells wide), vectors (4 wide), 4x4 matrices.
_AVAILABLE, _CORE, _EXCLUDED, _READMITTED, _LIT, _DARK, _USABLE, _USED, _FIT_LIT, _FAULTY, _START_EXCLUDED = range(11)
_N_FLAGS = 11
_S, _S_NEW, _SOLUTION, _ROW, _RHS, _START_S = range(6)
_NORMAL, _INVERSE, _LOW, _LOW_INV = range(4)


class KernelSettings(NamedTuple):
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
    if not _spd_inverse(mat, int(4)):  # int(): one compile for both sizes
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
    if not _spd_inverse(mat, int(3)):
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
def _worst_row(current, normals, sky_factor, st, lit, dark, sigma, use_sky, sky_weight, use_k, k_weight, vec, mat):
    """The row with the largest studentised residual beyond ``st.kappa`` of the fit in ``vec``/``mat``: a cell
    index, ``n_cells`` (the sky prior), ``n_cells + 1`` (the k prior) or -1 (none); and the cells' residual sum of
    squares [A^2]. Studentised: ``w = r / (sigma sqrt(1 - h))`` of a cell, ``sqrt(weight) r / (sigma sqrt(1 - h))``
    of a prior row; the largest is the best leave-one-out candidate."""
    n_cells = current.shape[0]
    s, solution, m_inv = vec[_S], vec[_SOLUTION], mat[_INVERSE]
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
            worst = n_cells + 1
    return worst, rss


@njit(cache=True)
def _readmit(current, normals, sky_factor, st, sigma, flags, vec, mat):
    """At a fixed point of :func:`_refine`: book the fitted cells (``flags[_USED]``, lit ones in
    ``flags[_FIT_LIT]``), re-admit the excluded cells the fit predicts (once each) and mark the faulty ones
    (``flags[_FAULTY]``). Returns (a cell was re-admitted, number of faulty cells)."""
    n_cells = current.shape[0]
    available, excluded, readmitted = flags[_AVAILABLE], flags[_EXCLUDED], flags[_READMITTED]
    lit, dark, usable, used, fit_lit, faulty = (flags[_LIT], flags[_DARK], flags[_USABLE], flags[_USED],
                                                flags[_FIT_LIT], flags[_FAULTY])
    for i in range(n_cells):
        used[i] = lit[i] or dark[i]
        fit_lit[i] = lit[i]
        usable[i] = available[i] and excluded[i]
    _classify(normals, vec[_S], usable, st.cos_lit_min, st.cos_dark_max, lit, dark)
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
    return again, n_faulty


@njit(cache=True)
def _refine(current, normals, sky_factor, st, k, flags, vec, mat):
    """Steps 2 and 3 of :func:`_solve_epoch` from direction ``vec[_S]``, scale ``k`` and ``flags[_EXCLUDED]``.

    On success leaves the final fit in ``vec[_S]``, ``vec[_SOLUTION]``, ``mat[_INVERSE]``, the fitted cells in
    ``flags[_USED]`` (lit ones in ``flags[_FIT_LIT]``) and the faulty ones in ``flags[_FAULTY]``.
    Returns (status, k [A], current sigma [A], residual sum of squares [A^2], number of faulty cells).
    """
    n_cells = current.shape[0]
    available, excluded = flags[_AVAILABLE], flags[_EXCLUDED]
    lit, dark, usable = flags[_LIT], flags[_DARK], flags[_USABLE]
    s, s_new, solution = vec[_S], vec[_S_NEW], vec[_SOLUTION]
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
            copy_into(s, s_new)
        worst, rss = _worst_row(current, normals, sky_factor, st, lit, dark, sigma, use_sky, sky_weight, use_k,
                                k_weight, vec, mat)
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
            copy_into(s, s_new)
            continue
        copy_into(s, s_new)
        if not _classification_holds(normals, s, usable, lit, dark, st.cos_lit_min, st.cos_dark_max):
            continue
        again, n_faulty = _readmit(current, normals, sky_factor, st, sigma, flags, vec, mat)
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
def _screen(current, normals, sky_factor, st, k, flags, vec, mat):
    """Step 1 of :func:`_solve_epoch`: a joint fit of the core cells (``flags[_CORE]``) from direction ``vec[_S]``
    and scale ``k`` [A]; every other cell whose current that fit does not predict (prediction test at ``kappa``)
    starts excluded (``flags[_EXCLUDED]``). Returns the scale [A] of the core fit (``k`` when there is none)."""
    n_cells = current.shape[0]
    available, core, excluded, lit, dark = flags[_AVAILABLE], flags[_CORE], flags[_EXCLUDED], flags[_LIT], flags[_DARK]
    s, solution = vec[_S], vec[_SOLUTION]
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
    return k


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

    ``st``: :class:`KernelSettings`; ``flags``, ``vec``, ``mat``, ``suspects`` (n_alternatives ints),
    ``suspicion`` (one per cell): scratch space (rows ``_AVAILABLE``.., ``_S``.., ``_NORMAL``..).
    Returns (status, k [A], sky [A], residual sum of squares [A^2], fitted cells, sigma [rad], and the 1-sigma
    of sky and k per unit current sigma [-]).
    """
    n_cells = current.shape[0]
    available, excluded, readmitted = flags[_AVAILABLE], flags[_EXCLUDED], flags[_READMITTED]
    used, fault = flags[_USED], flags[_FAULTY]
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
        return _no_solution(int(STATUS_NO_DATA))  # int(): one compile, not one per status
    k, ok = _initial_direction(current, normals, sky_factor, st.n_initial, flags, vec, mat)
    if not ok:
        return _no_solution(int(STATUS_ILL_CONDITIONED))
    k = _screen(current, normals, sky_factor, st, k, flags, vec, mat)
    start_s, start_excluded = vec[_START_S], flags[_START_EXCLUDED]
    copy_into(start_s, s)
    copy_into(start_excluded, excluded)
    # 2./3.
    best = _no_solution(int(STATUS_INCONSISTENT))
    best_score = np.inf
    score_sigma = 0.0
    n_tries = 1
    attempt = 0
    while attempt < n_tries:
        if attempt > 0:  # 4. an alternative: the suspect excluded (and never re-admitted) from the start
            copy_into(s, start_s)
            copy_into(excluded, start_excluded)
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
            copy_into(s_out, s)
            copy_into(cells_used, used)
            copy_into(faulty, fault)
        attempt += 1
    return best


@njit(cache=True)
def adaptive_kernel(currents, normals, sky_factor, st, s_out, k_out, sky_out, rss_out, n_fit_out, sigma_out,
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
