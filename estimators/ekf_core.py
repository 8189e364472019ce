"""Numba leaf functions shared by the three Kalman filters (math note section 2).

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
* :func:`is_healthy` / :func:`reset_filter` -- divergence detection (non-finite state or covariance) and reset
  to a safe state; the caller counts resets and reports them.
* :func:`record_update` / :func:`record_output` -- the diagnostics and output recorders writing into
  preallocated arrays with a counter.
* :func:`gps_monitor` / :func:`gps_record` / :func:`gps_reset_due` / :func:`gps_acquired` -- the GPS
  re-acquisition rule of math note 2.3 (a position component or a velocity component rejected continuously for
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

#: Columns of the float diagnostics array.
DIAG_FLOAT_COLUMNS = ("time_s", "innovation", "innovation_var", "nis")
#: Columns of the integer diagnostics array.
DIAG_INT_COLUMNS = ("sensor", "component", "accepted")

# counter slots shared by the three filters' kernels (read by estimators.results when building the report)
C_DIAG = 0  # diagnostics rows written (record_update)
C_DIAG_DROPPED = 1  # diagnostics rows dropped (record_update)
C_RESETS = 2  # divergence resets
C_GPS_RESETS = 3  # GPS re-acquisition resets (math note 2.3)
C_REPAIRS = 4  # covariance eigenvalue repairs
C_UPDATES = 5  # scalar updates attempted
C_OUTPUTS = 6  # output epochs written
N_SHARED_COUNTERS = 7


def diagnostics_arrays(capacity: int) -> tuple[np.ndarray, np.ndarray]:
    """Zeroed recorder arrays ``(diag_f, diag_i)`` for at most ``capacity`` scalar updates (plain Python)."""
    return (np.zeros((capacity, len(DIAG_FLOAT_COLUMNS))),
            np.zeros((capacity, len(DIAG_INT_COLUMNS)), dtype=np.int64))


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
    """Second-order transition matrix ``F = I + A dt + (A dt)^2 / 2`` (math note 2.2), written into ``F``.

    Only the leading rows of ``A`` with dynamics (:func:`dynamic_rows`) are non-zero, so ``A A`` is
    ``A[:, :m] A[:m, :]`` and the rows from ``m`` on are identity rows; the products are dense over that block
    (no data-dependent branches in the inner loops).

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
    m = dynamic_rows(A, False)
    half_dt2 = 0.5 * dt * dt
    for i in range(n):
        for j in range(n):
            F[i, j] = 0.0
        F[i, i] = 1.0
    for i in range(m):
        for j in range(n):
            F[i, j] += A[i, j] * dt
        for k in range(m):
            c = A[i, k] * half_dt2
            for j in range(n):
                F[i, j] += c * A[k, j]


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
    symmetric; :func:`propagate_sparse` does the product."""
    n = P.shape[0]
    m = dynamic_rows(F, True)
    values = np.empty((m, n))
    cols = np.empty((m, n), dtype=np.int64)
    counts = np.empty(m, dtype=np.int64)
    sparse_rows(F, np.arange(n), values, cols, counts)
    propagate_sparse(P, values, cols, counts, work)
    for i in range(n):
        for j in range(i, n):
            v = P[i, j] + Qd[i, j]
            P[i, j] = v
            P[j, i] = v


@njit(cache=True)
def scalar_update(P, H, nu, r_var, gate, dx, ph):
    """One scalar measurement update in Joseph form with chi-square gating (math note 2.3).

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
    deviation is capped at 180 deg, math note 7.2).
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
def is_healthy(x, P):
    """True when the state and covariance are finite and every variance is positive."""
    n = x.shape[0]
    for i in range(n):
        if not math.isfinite(x[i]) or not (P[i, i] > 0.0):
            return False
        for j in range(n):
            if not math.isfinite(P[i, j]):
                return False
    return True


@njit(cache=True)
def reset_filter(x, P, x_safe, P_reset):
    """Divergence reset: ``x <- x_safe`` (last healthy state), ``P <- P_reset`` (initial covariance)."""
    n = x.shape[0]
    for i in range(n):
        x[i] = x_safe[i]
        for j in range(n):
            P[i, j] = P_reset[i, j]


@njit(cache=True)
def record_update(diag_f, diag_i, counter, time_s, sensor, component, nu, S, nis, accepted):
    """Append one scalar update to the diagnostics arrays (``counter[0]`` rows used, ``counter[1]`` dropped)."""
    k = counter[0]
    if k >= diag_f.shape[0]:
        counter[1] += 1
        return
    diag_f[k, 0] = time_s
    diag_f[k, 1] = nu
    diag_f[k, 2] = S
    diag_f[k, 3] = nis
    diag_i[k, 0] = sensor
    diag_i[k, 1] = component
    diag_i[k, 2] = 1 if accepted else 0
    counter[0] = k + 1


@njit(cache=True)
def record_output(out, row, values):
    """Write ``values`` into row ``row`` of the output array (the caller advances ``row``)."""
    if row < out.shape[0]:
        for j in range(values.shape[0]):
            out[row, j] = values[j]


@njit(cache=True)
def wrap_pi(angle_rad):
    """Wrap an angle [rad] to [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


# ----------------------------------------------------------------------------------------------------------------
# GPS re-acquisition (math note 2.3)
#
# The monitor is a float64 array: the last position and velocity event times, a "reset pending" flag per kind
# (a reset triggered at one kind's event resets the other kind's states at its next event; at one GPS epoch the
# position event comes first) and, per GPS channel (position n, e, d, velocity 0, 1, 2; the paper-mode ground
# speed and course use velocity channels 0 and 1), the start of its current rejection streak (inf: the last
# update of that channel was accepted).

GM_POS_SEEN = 0
GM_VEL_SEEN = 1
GM_POS_PENDING = 2
GM_VEL_PENDING = 3
GM_STREAK = 4  # 4..9: rejection streak start per channel
GPS_CHANNELS = 6
GPS_MONITOR_SIZE = GM_STREAK + GPS_CHANNELS


@njit(cache=True)
def gps_monitor():
    """A new monitor: no GPS seen yet, nothing pending, no rejection streak."""
    mon = np.empty(GPS_MONITOR_SIZE)
    mon[GM_POS_SEEN] = -math.inf
    mon[GM_VEL_SEEN] = -math.inf
    mon[GM_POS_PENDING] = 0.0
    mon[GM_VEL_PENDING] = 0.0
    for c in range(GPS_CHANNELS):
        mon[GM_STREAK + c] = math.inf
    return mon


@njit(cache=True)
def gps_channel(position, component):
    """Monitor channel of a GPS scalar update: position n/e/d -> 0..2, velocity components 0..2 -> 3..5,
    the paper-mode ground speed (3) and course (4) -> 3, 4."""
    if position:
        return component
    return 3 + (component if component < 3 else component - 3)


@njit(cache=True)
def gps_record(mon, position, component, t, accepted):
    """Book one gated GPS scalar update at time ``t`` [s]: an acceptance ends the channel's rejection streak, a
    rejection starts one (or continues it)."""
    slot = GM_STREAK + gps_channel(position, component)
    if accepted:
        mon[slot] = math.inf
    elif mon[slot] == math.inf:
        mon[slot] = t


@njit(cache=True)
def gps_acquired(mon, t):
    """Mark position and velocity as (re)acquired at ``t``: seen now, nothing pending, no rejection streak."""
    mon[GM_POS_SEEN] = t
    mon[GM_VEL_SEEN] = t
    mon[GM_POS_PENDING] = 0.0
    mon[GM_VEL_PENDING] = 0.0
    for c in range(GPS_CHANNELS):
        mon[GM_STREAK + c] = math.inf


@njit(cache=True)
def gps_reset_due(mon, position, t, reject_s, outage_s):
    """Decide at a GPS position (``position``) or velocity event at ``t`` [s] whether its states are reset to the
    GPS instead of updated (math note 2.3), and update the monitor.

    A reset is due when a reset triggered at the other kind's event is pending, when this kind returns after an
    outage longer than ``outage_s``, or when any GPS channel (position or velocity) has been rejected
    continuously for ``reject_s`` or more. A new trigger clears every streak and leaves the other kind's reset
    pending, so position and velocity are reset together. The first position event (acquisition) resets the
    position only: the first velocity fixes are fused, so that the velocity drift accumulated before the first
    fix corrects the tilt through its correlation (if they are rejected, the rejection rule resets both).

    Returns
    -------
    reset : bool
        Reset this kind's states to the GPS values (variances to R, cross-covariances zeroed).
    counted : bool
        This is a new reset event to count (not the pending half of one, not the first acquisition).
    """
    seen = GM_POS_SEEN if position else GM_VEL_SEEN
    pending = GM_POS_PENDING if position else GM_VEL_PENDING
    other_pending = GM_VEL_PENDING if position else GM_POS_PENDING
    last = mon[seen]
    mon[seen] = t
    if position and last == -math.inf:
        return True, False
    if mon[pending] > 0.0:
        mon[pending] = 0.0
        return True, False
    outage = last > -math.inf and t - last > outage_s
    rejected = False
    for c in range(GPS_CHANNELS):
        if t - mon[GM_STREAK + c] >= reject_s:
            rejected = True
    if not (outage or rejected):
        return False, False
    for c in range(GPS_CHANNELS):
        mon[GM_STREAK + c] = math.inf
    mon[other_pending] = 1.0
    return True, True


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
