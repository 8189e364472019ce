"""Numba leaf functions shared by the three Kalman filters (docs/estimators.md, 'EKF algebra').

Every function here is ``@njit(cache=True)``, works in place on preallocated float64 arrays and allocates
nothing, so the filters' time loops can call it per sample without Python overhead. The filters own the models
(state layout, ``f``, ``A``, ``h``, ``H``); this module owns the generic EKF algebra:

* :func:`transition_matrix` -- ``F = I + A dt + (A dt)^2 / 2`` from a continuous Jacobian ``A``.
* :func:`propagate_sparse` -- ``P <- F P F^T`` for an ``F`` that is the identity after its leading rows with
  dynamics (bias, wind and offset states), given as sparse rows (:func:`sparse_rows`); exactly symmetric.
  :func:`propagate_covariance` is the same for a dense ``F`` plus ``Qd``.
* :func:`scalar_update` -- one scalar measurement in Joseph form with chi-square gating; returns the correction
  ``dx`` (the caller adds it and wraps angles, or injects it into a nominal state), the innovation variance
  ``S`` and the normalised innovation squared ``NIS = nu^2 / S``.
* :func:`limit_variances` / :func:`repair_covariance` -- variance limits (cheap, every propagation) and positive
  definiteness (Cholesky test, eigenvalue clipping only when it fails).
* :func:`copy_into` / :func:`copy_rows_into` -- array copies as loops: a numpy slice assignment between arrays
  compiles numba's shape-mismatch error message (some 30 string functions per process and array rank).
* :func:`is_healthy` / :func:`reset_filter` -- divergence detection (non-finite state or covariance) and reset
  to a safe state; the caller counts resets and reports them.
* :func:`record_update` / :func:`record_output` -- the diagnostics and output recorders writing into
  preallocated arrays with a counter.
* :func:`gps_monitor` / :func:`gps_record` / :func:`gps_reset_due` / :func:`gps_acquired` -- the GPS
  re-acquisition rule of docs/estimators.md, 'GPS re-acquisition' (a position component or a velocity component rejected
  continuously for
  ``T_rej``, or GPS back after an outage longer than ``T_out`` -> reset position and velocity to the GPS), and
  :func:`reset_covariance_block` for the reset's covariance (variances to R, cross-covariances zeroed).

Diagnostics layout (one row per scalar update, :data:`DIAG_FLOAT_COLUMNS` / :data:`DIAG_INT_COLUMNS`,
allocated by :func:`diagnostics_arrays`): ``diag_f[k] = (time_s, innovation, innovation_var, nis)`` and
``diag_i[k] = (sensor kind, component, accepted)``; ``counter[0]`` is the number of rows written. Rows beyond the
preallocated size are dropped and counted in ``counter[1]``. The filters' int64 counter arrays share the slots
``C_*`` below (0 and 1 are the recorder's); each filter appends its own after :data:`N_SHARED_COUNTERS`.
"""


from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def symmetrize(P):
    """Replace ``P`` by ``(P + P^T) / 2`` in place."""
    n = P.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = v
            P[j, i] = v


@njit(cache=True)
def dynamic_rows(M, identity):
    """Number of leading rows ``m`` of ``M`` beyond which every row is a row of the identity (``identity``) or
    zero: the filters put the states with dynamics first, the biases, wind and offsets (random walks) after."""
    n = M.shape[0]
    for i in range(n - 1, -1, -1):
        for j in range(n):
            if M[i, j] != (1.0 if identity and i == j else 0.0):
                return i + 1
    return 0


@njit(cache=True)
def transition_matrix(A, dt, F):
    """Second-order transition matrix ``F = I + A dt + (A dt)^2 / 2`` (docs/estimators.md, 'Process noise and random
    walks'), written into ``F``.

    Only the leading rows of ``A`` with dynamics (:func:`dynamic_rows`) are non-zero, so ``A A`` is
    ``A[:, :m] A[:m, :]`` and the rows from ``m`` on are identity rows. Most of ``A[:m, :m]`` is zero (position
    rows see velocity and attitude only), so a zero coefficient skips its row product (the inner loop stays
    branch-free); the result is the dense product's exactly.

    Parameters
    ----------
    A : ndarray (n, n)
        Continuous-time Jacobian df/dx, evaluated at the pre-step estimate.
    dt : float
        Step [s].
    F : ndarray (n, n)
        Output.
    """
    n = A.shape[0]
    m = dynamic_rows(A, bool(False))  # bool(): one compile for both callers
    half_dt2 = 0.5 * dt * dt
    for i in range(m):
        for j in range(n):
            F[i, j] = A[i, j] * dt
        F[i, i] += 1.0
        for k in range(m):
            c = A[i, k] * half_dt2
            if c != 0.0:
                for j in range(n):
                    F[i, j] += c * A[k, j]
    for i in range(m, n):
        for j in range(n):
            F[i, j] = 0.0
        F[i, i] = 1.0


@njit(cache=True)
def sparse_rows(F, columns, values, cols, counts):
    """The leading ``m = counts.shape[0]`` rows of ``F`` over the state columns ``columns`` as sparse rows for
    :func:`propagate_sparse`: row ``i`` has ``counts[i]`` non-zeros ``values[i, c]`` in the columns
    ``cols[i, c]`` (positions in ``columns``, increasing); ``values``, ``cols`` (m, len(columns)) and ``counts``
    (m,) are outputs.

    The filters' dynamic rows are mostly zeros (position rows see velocity and attitude only, attitude rows
    attitude and gyro bias); listing the non-zeros once keeps the data-dependent branch out of the products."""
    for i in range(counts.shape[0]):
        count = 0
        for a in range(columns.shape[0]):
            f = F[i, columns[a]]
            values[i, count] = f
            cols[i, count] = a
            count += 1 if f != 0.0 else 0  # branch-free compaction: a zero is overwritten by the next entry
        counts[i] = count


@njit(cache=True)
def propagate_sparse(P, values, cols, counts, work):
    """``P <- F P F^T`` in place, exactly symmetric, for an ``F`` that is the identity except its first
    ``m = counts.shape[0]`` rows ``F_d``, given as sparse rows (:func:`sparse_rows`); the states from ``m`` on
    are random walks (biases, wind, offsets). With ``W = F_d P`` (the first m rows of ``work``):
    ``P_dd <- W F_d^T``, ``P_ds <- W_s``, ``P_ss`` unchanged, so the static rows are never multiplied. The
    caller adds the process noise."""
    n = P.shape[0]
    m = counts.shape[0]
    for i in range(m):
        for j in range(n):
            work[i, j] = 0.0
        for c in range(counts[i]):
            f_ik = values[i, c]
            k = cols[i, c]
            for j in range(n):
                work[i, j] += f_ik * P[k, j]
    for i in range(m):
        for j in range(i, m):
            s = 0.0
            for c in range(counts[j]):
                s += work[i, cols[j, c]] * values[j, c]
            P[i, j] = s
            P[j, i] = s
        for j in range(m, n):
            P[i, j] = work[i, j]
            P[j, i] = work[i, j]


@njit(cache=True)
def propagate_covariance(P, F, Qd, work):
    """``P <- F P F^T + Qd`` for a dense ``F`` whose rows after the states with dynamics are identity rows
    (:func:`dynamic_rows`) and a symmetric ``Qd``; ``P, F, Qd`` (n, n); ``work`` (n, n) scratch. Exactly
    symmetric; :func:`propagate_sparse` does the product. Allocates its sparse-row scratch: per-sample callers use
    :func:`propagate_covariance_into`."""
    n = P.shape[0]
    propagate_covariance_into(P, F, Qd, work, np.empty((n, n)), np.empty((n, n), dtype=np.int64),
                              np.empty(n, dtype=np.int64), np.arange(n))


@njit(cache=True)
def propagate_covariance_into(P, F, Qd, work, values, cols, counts, columns):
    """:func:`propagate_covariance` with preallocated scratch: ``values`` (n, n) float64, ``cols`` (n, n) and
    ``counts`` (n,) int64, ``columns`` = ``arange(n)``; nothing is allocated."""
    n = P.shape[0]
    m = dynamic_rows(F, bool(True))
    sparse_rows(F, columns, values[:m], cols[:m], counts[:m])
    propagate_sparse(P, values[:m], cols[:m], counts[:m], work)
    for i in range(n):
        for j in range(i, n):
            v = P[i, j] + Qd[i, j]
            P[i, j] = v
            P[j, i] = v


@njit(cache=True)
def quadratic_form(v, P, first):
    """``v^T P[first:, first:] v`` for a short tuple ``v``."""
    s = 0.0
    for a in range(len(v)):
        for b in range(len(v)):
            s += v[a] * P[first + a, first + b] * v[b]
    return s


@njit(cache=True, inline="always")
def forward_solve(L, B, m):
    """``B[:m] <- L^-1 B[:m]`` in place for the lower-triangular ``L[:m, :m]`` and ``B`` (>= m, k)."""
    k = B.shape[1]
    for i in range(m):
        for j in range(i):
            for c in range(k):
                B[i, c] -= L[i, j] * B[j, c]
        for c in range(k):
            B[i, c] /= L[i, i]


@njit(cache=True, inline="always")
def sandwich(J, P, m, out):
    """``out[:m, :m] = J[:m] P J[:m]^T`` for small matrices."""
    n = P.shape[0]
    for i in range(m):
        for j in range(m):
            s = 0.0
            for a in range(n):
                for b in range(n):
                    s += J[i, a] * P[a, b] * J[j, b]
            out[i, j] = s


@njit(cache=True)
def scalar_update(P, H, nu, r_var, gate, dx, ph):
    """One scalar measurement update in Joseph form with chi-square gating (docs/estimators.md, 'EKF algebra').

    Parameters
    ----------
    P : ndarray (n, n)
        Prior covariance; replaced by the posterior when the update is accepted.
    H : ndarray (n,)
        Measurement Jacobian row dh/dx.
    nu : float
        Innovation ``z - h(x)`` (already wrapped for angles).
    r_var : float
        Measurement variance R.
    gate : float
        Reject when ``|nu| / sqrt(S) > gate``; ``inf`` (or <= 0) disables the gate (pseudo-measurements).
    dx : ndarray (n,)
        Output: the correction ``K nu`` (zeros when rejected). The caller adds it to the state.
    ph : ndarray (n,)
        Scratch for ``P H^T``.

    Returns
    -------
    accepted : bool
    S : float
        Innovation variance ``H P H^T + R``.
    nis : float
        Normalised innovation squared ``nu^2 / S``.
    """
    n = P.shape[0]
    # ph = P H^T, using the symmetry of P to walk rows of P for the non-zero entries of H
    for i in range(n):
        ph[i] = 0.0
    for j in range(n):
        h_j = H[j]
        if h_j != 0.0:
            for i in range(n):
                ph[i] += P[j, i] * h_j
    hph = 0.0
    for i in range(n):
        hph += H[i] * ph[i]
    S = hph + r_var
    for i in range(n):
        dx[i] = 0.0
    if not (S > 0.0) or not math.isfinite(S) or not math.isfinite(nu):
        return False, S, math.nan
    nis = nu * nu / S
    if gate > 0.0 and nis > gate * gate:
        return False, S, nis
    # K = P H^T / S; dx = K nu. Joseph form P+ = (I - K H) P (I - K H)^T + K R K^T expanded with H P = ph^T
    # (exact for any gain K): P+ = P - K ph^T - ph K^T + (H P H^T + R) K K^T. Unlike the short form
    # P - K ph^T it stays quadratic in K, so a round-off error in K changes P+ only to second order (the point
    # of Joseph's form). It is symmetric: the upper triangle is computed from the symmetrised prior and
    # mirrored.
    inv_s = 1.0 / S
    for i in range(n):
        dx[i] = ph[i] * inv_s  # K, turned into K nu below
    for i in range(n):
        k_i = dx[i]
        ph_i = ph[i]
        for j in range(i, n):
            k_j = dx[j]
            v = 0.5 * (P[i, j] + P[j, i]) - k_i * ph[j] - ph_i * k_j + S * k_i * k_j
            P[i, j] = v
            P[j, i] = v
    for i in range(n):
        dx[i] *= nu
    return True, S, nis


@njit(cache=True)
def limit_variances(P, min_var, max_var):
    """Keep every variance within ``[min_var[i], max_var[i]]`` (cheap; call after every propagation).

    Variances below the floor are raised to it (adding a diagonal term keeps P positive semi-definite);
    variances above the cap are scaled down with their row and column (correlations kept; e.g. the yaw standard
    deviation is capped at 180 deg, docs/estimators.md, 'Divergence and covariance repair').
    """
    n = P.shape[0]
    for i in range(n):
        if P[i, i] < min_var[i]:
            P[i, i] = min_var[i]
        elif P[i, i] > max_var[i]:
            scale = math.sqrt(max_var[i] / P[i, i])
            for j in range(n):
                P[i, j] *= scale
                P[j, i] *= scale


@njit(cache=True)
def cholesky_lower(M, L, n, pivot_floor):
    """Lower Cholesky factor of the leading ``n x n`` block of the symmetric ``M`` into the lower triangle of
    ``L`` (the rest of ``L`` is not written). Returns False as soon as a pivot is not above ``pivot_floor`` (not
    positive definite, or not finite); ``L`` is then partly written."""
    for j in range(n):
        d = M[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > pivot_floor:
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            v = M[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k]
            L[i, j] = v / L[j, j]
    return True


@njit(cache=True)
def repair_covariance(P, min_var, max_var, work, eig_floor):
    """Keep ``P`` a usable covariance; returns True when an eigenvalue repair was needed.

    Symmetrises, applies :func:`limit_variances`, then tests positive definiteness with a Cholesky
    factorisation; only when it fails, eigenvalues are clipped to ``eig_floor``. A non-finite ``P`` is left
    alone (returns False): that is divergence, for :func:`is_healthy` and :func:`reset_filter`.

    Parameters
    ----------
    P : ndarray (n, n)
    min_var, max_var : ndarray (n,)
        Variance limits per state.
    work : ndarray (n, n)
        Scratch.
    eig_floor : float
        Smallest eigenvalue kept in a repair.
    """
    n = P.shape[0]
    symmetrize(P)
    limit_variances(P, min_var, max_var)
    for i in range(n):
        for j in range(n):
            if not math.isfinite(P[i, j]):
                return False
    if cholesky_lower(P, work, n, 0.0):
        return False
    values, vectors = np.linalg.eigh(P)
    for k in range(n):
        if not (values[k] > eig_floor):
            values[k] = eig_floor
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += vectors[i, k] * values[k] * vectors[j, k]
            P[i, j] = s
    symmetrize(P)
    return True


@njit(cache=True)
def scheduled_repair(P, min_var, max_var, work, eig_floor, n_propagations, pd_check_every):
    """Covariance upkeep after a propagation: the variance limits every time (:func:`limit_variances`), the full
    positive-definiteness repair (:func:`repair_covariance`) every ``pd_check_every``-th propagation
    (``n_propagations`` counts them, this one included). Returns True when eigenvalues had to be clipped."""
    if n_propagations % pd_check_every == 0:
        return repair_covariance(P, min_var, max_var, work, eig_floor)
    limit_variances(P, min_var, max_var)
    return False


@njit(cache=True)
def accumulate_inputs(acc, dt, gyro, accel):
    """Sum the IMU input over a deferred covariance interval: ``acc[0] += dt``, ``acc[1:4] += gyro dt``,
    ``acc[4:7] += accel dt`` (the mean input is ``acc[1:7] / acc[0]``)."""
    acc[0] += dt
    for i in range(3):
        acc[1 + i] += gyro[i] * dt
        acc[4 + i] += accel[i] * dt


@njit(cache=True)
def copy_into(dst, src):
    """``dst[:] = src[:len(dst)]`` for 1-D arrays (``src`` at least as long)."""
    for i in range(dst.shape[0]):
        dst[i] = src[i]


@njit(cache=True)
def copy_rows_into(dst, src, rows):
    """``dst[:rows] = src[:rows]`` for 2-D arrays of equal width."""
    for i in range(rows):
        for j in range(dst.shape[1]):
            dst[i, j] = src[i, j]


@njit(cache=True)
def is_healthy(x, P):
    """True when the state and covariance (C-contiguous) are finite and every variance is positive."""
    n = x.shape[0]
    for i in range(n):
        if not math.isfinite(x[i]) or not (P[i, i] > 0.0):
            return False
    flat = P.reshape(n * n)
    bad = False
    for a in range(n * n):
        v = flat[a]
        bad |= (v - v) != 0.0  # NaN exactly when v is not finite; without a branch the loop vectorises
    return not bad


@njit(cache=True)
def reset_filter(x, P, x_safe, P_reset):
    """Divergence reset: ``x <- x_safe`` (last healthy state), ``P <- P_reset`` (initial covariance)."""
    n = x.shape[0]
    for i in range(n):
        x[i] = x_safe[i]
        for j in range(n):
            P[i, j] = P_reset[i, j]


@njit(cache=True)
def transform_covariance(P, T, work):
    """``P <- T P T^T`` for a linear change of the error state ``e' = T e`` (dense; ``work`` (n, n) scratch)."""
    n = P.shape[0]
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += T[i, k] * P[k, j]
            work[i, j] = s
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for k in range(n):
                s += work[i, k] * T[j, k]
            P[i, j] = s
            P[j, i] = s


@njit(cache=True)
def reset_covariance_block(P, first, block):
    """Reset the states ``first .. first + m - 1`` of ``P`` to the covariance ``block`` (m, m): their rows and
    columns are zeroed (no correlation with the other states) and the block written."""
    n = P.shape[0]
    m = block.shape[0]
    for a in range(m):
        for j in range(n):
            P[first + a, j] = 0.0
            P[j, first + a] = 0.0
    for a in range(m):
        for b in range(m):
            P[first + a, first + b] = block[a, b]
