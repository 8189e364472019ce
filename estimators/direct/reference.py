"""Plain-NumPy twin of the full-state direct filter (conventions practice 5: a readable reference of the compiled
kernel, run by the equivalence test).

The models are written in matrix form straight from the math note (section 4 blocks: ``R``, ``S``, ``W``,
``[a]x``), independently of the scalar-unrolled numba functions of :mod:`estimators.direct.kernel`; the event
loop mirrors :func:`estimators.direct.kernel.run_kernel` step for step (same propagation splitting, same
covariance schedule, same update order), so both must produce the same trajectory to round-off.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.core.full_state import (
    EIG_FLOOR,
    P_COV_DT,
    P_FIELD,
    P_G,
    P_GPS_OUTAGE_S,
    P_GPS_REJECT_S,
    P_NA2,
    P_NG2,
    P_PAPER_VEL,
    P_VMIN,
    PD_CHECK_EVERY,
)
from estimators.core.recorder import C_DIAG, C_GPS_RESETS, C_OUTPUTS, C_REPAIRS, C_RESETS, C_UPDATES
from estimators.direct.kernel import C_FLUSHES, C_PITCH_GUARD, L_BA, L_BB, L_BM, L_W, P_PAPER_INDIRECT, PITCH_GUARD_RAD
from estimators.inputs.records import AIRSPEED, BARO, GPS_POS, GPS_VEL, MAG, OUTPUT, SIDESLIP, SUN, ZERO_VELOCITY


def wrap(angle):
    """[-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def skew(a):
    """[a]x with [a]x b = a x b."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def euler_matrices(theta3):
    """R_nb, S (Theta_dot = S omega) and W = S^-1 for ZYX Euler angles (roll, pitch, yaw)."""
    phi, theta, psi = theta3
    rx = np.array([[1, 0, 0], [0, math.cos(phi), -math.sin(phi)], [0, math.sin(phi), math.cos(phi)]])
    ry = np.array([[math.cos(theta), 0, math.sin(theta)], [0, 1, 0], [-math.sin(theta), 0, math.cos(theta)]])
    rz = np.array([[math.cos(psi), -math.sin(psi), 0], [math.sin(psi), math.cos(psi), 0], [0, 0, 1]])
    W = np.array([[1.0, 0.0, -math.sin(theta)],
                  [0.0, math.cos(phi), math.sin(phi) * math.cos(theta)],
                  [0.0, -math.sin(phi), math.cos(phi) * math.cos(theta)]])
    return rz @ ry @ rx, np.linalg.inv(W), W


def _blocks(x, layout):
    return x[0:3], x[3:6], x[6:9], x[9:12], (x[layout[L_BA]:layout[L_BA] + 3] if layout[L_BA] >= 0 else np.zeros(3))


def f(x, gyro, accel, g, layout):
    """Corrected eq 36."""
    _, V, theta3, bg, ba = _blocks(x, layout)
    R, S, _ = euler_matrices(theta3)
    omega = gyro - bg
    xdot = np.zeros_like(x)
    xdot[0:3] = R @ V
    xdot[3:6] = np.cross(V, omega) + (accel - ba) + R.T @ np.array([0.0, 0.0, g])
    xdot[6:9] = S @ omega
    return xdot


def A_matrix(x, gyro, g, layout):
    """Eq 37 blocks (math note 4)."""
    n = len(x)
    _, V, theta3, bg, _ = _blocks(x, layout)
    R, S, W = euler_matrices(theta3)
    _, q, r = gyro - bg
    phi, theta = theta3[0], theta3[1]
    cph, sph, cth, sth = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta)
    A = np.zeros((n, n))
    A[0:3, 3:6] = R
    A[0:3, 6:9] = -R @ skew(V) @ W
    A[3:6, 3:6] = -skew(gyro - bg)
    A[3:6, 6:9] = skew(R.T @ np.array([0.0, 0.0, g])) @ W
    A[3:6, 9:12] = -skew(V)
    if layout[L_BA] >= 0:
        A[3:6, layout[L_BA]:layout[L_BA] + 3] = -np.eye(3)
    A[6:9, 6:9] = [[(q * cph - r * sph) * sth / cth, (q * sph + r * cph) / cth ** 2, 0.0],
                   [-q * sph - r * cph, 0.0, 0.0],
                   [(q * cph - r * sph) / cth, (q * sph + r * cph) * sth / cth ** 2, 0.0]]
    A[6:9, 9:12] = -S
    return A


def Qc_matrix(x, ng2, na2, rw_var, layout):
    """G_g N_g^2 G_g^T + G_a N_a^2 G_a^T + diag(random walks)."""
    n = len(x)
    _, V, theta3, _, _ = _blocks(x, layout)
    _, S, _ = euler_matrices(theta3)
    G_g = np.zeros((n, 3))
    G_g[3:6] = -skew(V)
    G_g[6:9] = -S
    G_a = np.zeros((n, 3))
    G_a[3:6] = -np.eye(3)
    return ng2 * G_g @ G_g.T + na2 * G_a @ G_a.T + np.diag(rw_var)


def h_and_H(x, kind, comp, values, field, layout):
    """Scalar measurement model and Jacobian row (math note 4, B1-B7)."""
    n = len(x)
    _, V, theta3, _, _ = _blocks(x, layout)
    R, _, W = euler_matrices(theta3)
    H = np.zeros(n)
    if kind == BARO:
        H[2] = -1.0
        if layout[L_BB] >= 0:
            H[layout[L_BB]] = 1.0
            return -x[2] + x[layout[L_BB]], H
        return -x[2], H
    if kind == GPS_POS:
        H[comp] = 1.0
        return x[comp], H
    if kind in (AIRSPEED, SIDESLIP):
        iw = layout[L_W]
        wbar = np.array([x[iw], x[iw + 1], 0.0]) if iw >= 0 else np.zeros(3)
        a = R.T @ wbar
        vr = V - a
        dvr_dtheta = -skew(a) @ W
        dvr_dw = -R.T[:, 0:2]
        if kind == AIRSPEED:
            va = max(np.linalg.norm(vr), 1e-3)
            H[3:6] = vr / va
            H[6:9] = vr @ dvr_dtheta / va
            if iw >= 0:
                H[iw:iw + 2] = vr @ dvr_dw / va
            return va, H
        H[3:6] = [0.0, 1.0, 0.0]
        H[6:9] = dvr_dtheta[1]
        if iw >= 0:
            H[iw:iw + 2] = dvr_dw[1]
        return vr[1], H
    if kind in (GPS_VEL, ZERO_VELOCITY):
        vel = R @ V
        rows = np.zeros((3, n))
        rows[:, 3:6] = R
        rows[:, 6:9] = -R @ skew(V) @ W
        if comp < 3:
            return vel[comp], rows[comp]
        vg = max(math.hypot(vel[0], vel[1]), 1e-3)
        if comp == 3:
            return vg, (vel[0] * rows[0] + vel[1] * rows[1]) / vg
        return math.atan2(vel[1], vel[0]), (-vel[1] * rows[0] + vel[0] * rows[1]) / vg ** 2
    ref = np.asarray(field) if kind == MAG else np.asarray(values[3:6])
    b = R.T @ ref
    H[6:9] = (skew(b) @ W)[comp]
    h = b[comp]
    if kind == MAG and layout[L_BM] >= 0:
        H[layout[L_BM] + comp] = 1.0
        h += x[layout[L_BM] + comp]
    return h, H


def rk4(x, gyro, accel, dt, g, layout):
    k1 = f(x, gyro, accel, g, layout)
    k2 = f(x + 0.5 * dt * k1, gyro, accel, g, layout)
    k3 = f(x + 0.5 * dt * k2, gyro, accel, g, layout)
    k4 = f(x + dt * k3, gyro, accel, g, layout)
    out = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    out[6], out[8] = wrap(out[6]), wrap(out[8])
    return out


def joseph_update(P, H, nu, r_var, gate):
    """Returns (accepted, S, nis, dx, P+)."""
    S = H @ P @ H + r_var
    if not (S > 0.0) or not math.isfinite(S) or not math.isfinite(nu):
        return False, S, math.nan, np.zeros(len(H)), P
    nis = nu * nu / S
    if gate > 0.0 and nis > gate * gate:
        return False, S, nis, np.zeros(len(H)), P
    K = P @ H / S
    I_KH = np.eye(len(H)) - np.outer(K, H)
    P_new = I_KH @ P @ I_KH.T + r_var * np.outer(K, K)
    return True, S, nis, K * nu, 0.5 * (P_new + P_new.T)


def repair(P, min_var, max_var, check_pd):
    """Variance limits, then (``check_pd``) eigenvalue clipping when the Cholesky test fails; returns
    (P, repaired)."""
    for i in range(len(P)):
        if P[i, i] < min_var[i]:
            P[i, i] = min_var[i]
        elif P[i, i] > max_var[i]:
            scale = math.sqrt(max_var[i] / P[i, i])
            P[i, :] *= scale
            P[:, i] *= scale
    if not check_pd or not np.all(np.isfinite(P)):
        return P, False
    try:
        np.linalg.cholesky(P)
        return P, False
    except np.linalg.LinAlgError:
        values, vectors = np.linalg.eigh(P)
        P = vectors @ np.diag(np.maximum(values, EIG_FLOOR)) @ vectors.T
        return 0.5 * (P + P.T), True


def healthy(x, P):
    return bool(np.all(np.isfinite(x)) and np.all(np.isfinite(P)) and np.all(np.diag(P) > 0))


def tangent_basis(h):
    u = h / np.linalg.norm(h)
    a = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = a - (a @ u) * u
    t1 /= np.linalg.norm(t1)
    return np.column_stack([t1, np.cross(u, t1)])


def components(kind, values, paper_vel, vmin):
    """Scalar components of an event (paper-mode GPS velocity: ground speed and course, none below ``vmin``)."""
    if kind in (BARO, AIRSPEED, SIDESLIP):
        return [0]
    if kind == SUN:
        return [0, 1]
    if kind == GPS_VEL and paper_vel:
        return [] if math.hypot(values[0], values[1]) < vmin else [3, 4]
    return [0, 1, 2]


def innovation(kind, comp, values, variances, h):
    """(nu, R) of a scalar component predicted as ``h``; paper-mode ground speed and course from the NED
    velocity (sigma_chi = sigma_V / V_g), the course innovation wrapped."""
    if kind == GPS_VEL and comp >= 3:
        vg = math.hypot(values[0], values[1])
        z, r_var = (vg, variances[0]) if comp == 3 else (math.atan2(values[1], values[0]), variances[0] / vg ** 2)
    else:
        z, r_var = values[comp], variances[comp]
    nu = z - h
    return (wrap(nu) if kind == GPS_VEL and comp == 4 else nu), r_var


def record(diag_f, diag_i, counters, t, kind, comp, nu, s_var, nis, accepted):
    """One scalar update: counted and written to the diagnostics arrays."""
    counters[C_UPDATES] += 1
    row = counters[C_DIAG]
    diag_f[row] = t, nu, s_var, nis
    diag_i[row] = kind, comp, int(accepted)
    counters[C_DIAG] += 1


class GpsMonitor:
    """GPS re-acquisition rule of math note 2.3 (the twin of :func:`estimators.core.reacquisition.gps_reset_due`): a reset
    of position and velocity when a GPS position or velocity component has been rejected continuously for
    ``reject_s``, or when GPS returns after an outage longer than ``outage_s``. The kind whose event triggers is
    reset at once, the other kind at its next event; the first position event resets the position only."""

    def __init__(self, reject_s, outage_s):
        self.reject_s, self.outage_s = reject_s, outage_s
        self.seen = {GPS_POS: -math.inf, GPS_VEL: -math.inf}
        self.pending = {GPS_POS: False, GPS_VEL: False}
        self.streak_start = {}  # (kind, channel) -> start of its current rejection streak

    def record(self, kind, comp, t, accepted):
        channel = (kind, comp if kind == GPS_POS or comp < 3 else comp - 3)
        if accepted:
            self.streak_start.pop(channel, None)
        else:
            self.streak_start.setdefault(channel, t)

    def reset_due(self, kind, t):
        """(reset this kind's states now, count a new reset event)."""
        other = GPS_VEL if kind == GPS_POS else GPS_POS
        last, self.seen[kind] = self.seen[kind], t
        if kind == GPS_POS and last == -math.inf:
            return True, False
        if self.pending[kind]:
            self.pending[kind] = False
            return True, False
        outage = last > -math.inf and t - last > self.outage_s
        if not (outage or any(t - start >= self.reject_s for start in self.streak_start.values())):
            return False, False
        self.streak_start.clear()
        self.pending[other] = True
        return True, True


def reset_to_gps(x, P, kind, values, variances, layout, move_wind):
    """Position, or NED velocity (body state ``V = R^T v_gps``), to the GPS: the new error is the GPS noise,
    uncorrelated with the other states (in body axes ``dV = R^T dv + [V]x W dTheta``); with ``move_wind`` the
    wind moves with the ground velocity (``w += v_gps - R V_old``, north and east), keeping the air-relative
    velocity. ``e' = T e + G n``, ``P' = T P T^T + G R G^T``."""
    x, P = x.copy(), P.copy()
    if kind == GPS_POS:
        x[0:3] = values[0:3]
        P[0:3, :] = 0.0
        P[:, 0:3] = 0.0
        P[0:3, 0:3] = np.diag(variances[0:3])
        return x, P
    n = len(x)
    T, G = np.eye(n), np.zeros((n, 3))
    iw = layout[L_W]
    if move_wind:
        for c in range(2):
            h, H = h_and_H(x, GPS_VEL, c, values, values, layout)
            x[iw + c] += values[c] - h
            T[iw + c] -= H
            G[iw + c, c] = 1.0
    R, _, W = euler_matrices(x[6:9])
    x[3:6] = R.T @ values[0:3]
    T[3:6, :] = 0.0
    T[3:6, 6:9] = skew(x[3:6]) @ W
    G[3:6] = R.T
    return x, T @ P @ T.T + G @ np.diag(variances[0:3]) @ G.T


def run_reference(imu_t, imu_gyro, imu_accel, ev_t, ev_kind, ev_imu, ev_val, ev_var, x0, P0, layout, params,
                  gates, rw_var, min_var, max_var, out_f, out_x, out_sx, diag_f, diag_i, counters):
    """Same signature and outputs as :func:`estimators.direct.kernel.run_kernel`."""
    x, P, x_safe = x0.copy(), P0.copy(), x0.copy()
    g, cov_dt, field = params[P_G], params[P_COV_DT], params[P_FIELD:P_FIELD + 3]
    paper_vel, paper_indirect = params[P_PAPER_VEL] > 0.5, params[P_PAPER_INDIRECT] > 0.5
    state = {"acc_dt": 0.0, "acc_gyro": np.zeros(3), "x_cov": x0.copy()}

    def flush():
        nonlocal P
        dt = state["acc_dt"]
        A = A_matrix(state["x_cov"], state["acc_gyro"] / dt, g, layout)
        F = np.eye(len(x)) + A * dt + A @ A * dt * dt / 2.0
        P_new = F @ P @ F.T + Qc_matrix(state["x_cov"], params[P_NG2], params[P_NA2], rw_var, layout) * dt
        counters[C_FLUSHES] += 1
        P, repaired = repair(0.5 * (P_new + P_new.T), min_var, max_var,
                             check_pd=counters[C_FLUSHES] % PD_CHECK_EVERY == 0)
        counters[C_REPAIRS] += repaired
        state["acc_dt"], state["acc_gyro"] = 0.0, np.zeros(3)

    def reset_if_diverged():
        nonlocal x, P
        if not healthy(x, P):
            x, P = x_safe.copy(), P0.copy()
            counters[C_RESETS] += 1

    gps = GpsMonitor(params[P_GPS_REJECT_S], params[P_GPS_OUTAGE_S])
    air_ok = False  # the last airspeed update was accepted
    n_out, t, j = 0, imu_t[0], 0
    for k in range(len(imu_t)):
        gyro, accel = imu_gyro[k], imu_accel[k]
        while True:
            at_event = j < len(ev_t) and ev_imu[j] == k
            t_next = ev_t[j] if at_event else imu_t[k]
            if t_next > t:
                if state["acc_dt"] == 0.0:
                    state["x_cov"] = x.copy()
                step = t_next - t
                x = rk4(x, gyro, accel, step, g, layout)
                state["acc_dt"] += step
                state["acc_gyro"] = state["acc_gyro"] + gyro * step
                t = t_next
                if state["acc_dt"] >= cov_dt * (1.0 - 1e-9):
                    flush()
                    reset_if_diverged()
            if not at_event:
                break
            kind, values = ev_kind[j], ev_val[j]
            if kind == OUTPUT:
                if not np.all(np.isfinite(x)):
                    x, P = x_safe.copy(), P0.copy()
                    counters[C_RESETS] += 1
                x_safe = x.copy()
                _output(x, P, layout, field, t, out_f, n_out)
                out_x[n_out], out_sx[n_out] = x, np.sqrt(np.maximum(np.diag(P), 0.0))
                n_out += 1
                j += 1
                continue
            if abs(x[7]) > PITCH_GUARD_RAD and kind not in (BARO, GPS_POS):
                counters[C_PITCH_GUARD] += 1
                j += 1
                continue
            if kind in (GPS_POS, GPS_VEL):
                reset, counted = gps.reset_due(kind, t)
                if reset:
                    x, P = reset_to_gps(x, P, kind, values, ev_var[j], layout, air_ok and layout[L_W] >= 0)
                    counters[C_GPS_RESETS] += counted
                    j += 1
                    continue
            comps = components(kind, values, paper_vel, params[P_VMIN])
            x_prior, x_err = x.copy(), np.zeros(len(x))
            if kind == SUN:
                basis = tangent_basis(np.array([h_and_H(x, kind, c, values, field, layout)[0] for c in range(3)]))
            for c in comps:
                x_lin = x_prior if paper_indirect else x
                if kind == SUN:
                    rows = [h_and_H(x_lin, kind, cc, values, field, layout) for cc in range(3)]
                    h3 = np.array([r[0] for r in rows])
                    H3 = np.array([r[1] for r in rows])
                    nu, H, r_var = basis[:, c] @ (values[0:3] - h3), basis[:, c] @ H3, ev_var[j, c]
                else:
                    h, H = h_and_H(x_lin, kind, c, values, field, layout)
                    nu, r_var = innovation(kind, c, values, ev_var[j], h)
                if paper_indirect:
                    nu -= H @ x_err
                accepted, s_var, nis, dx, P = joseph_update(P, H, nu, r_var, gates[kind])
                record(diag_f, diag_i, counters, t, kind, c, nu, s_var, nis, accepted)
                if kind in (GPS_POS, GPS_VEL):
                    gps.record(kind, c, t, accepted)
                elif kind == AIRSPEED:
                    air_ok = accepted
                if accepted:
                    if paper_indirect:
                        x_err = x_err + dx
                    else:
                        x = x + dx
                        x[6], x[8] = wrap(x[6]), wrap(x[8])
            if paper_indirect:
                x = x + x_err
                x[6], x[8] = wrap(x[6]), wrap(x[8])
            j += 1
    if state["acc_dt"] > 0.0:
        flush()
    counters[C_OUTPUTS] = n_out
    return x, P


def _output(x, P, layout, field, t, out_f, row):
    vel_rows = [h_and_H(x, GPS_VEL, c, np.zeros(6), field, layout) for c in range(3)]
    iw = layout[L_W]
    wind = (x[iw], x[iw + 1]) if iw >= 0 else (math.nan, math.nan)
    wind_std = (math.sqrt(P[iw, iw]), math.sqrt(P[iw + 1, iw + 1])) if iw >= 0 else (math.nan, math.nan)
    out_f[row] = [t, *x[6:9], *x[0:3], *(v for v, _ in vel_rows), *wind,
                  *np.sqrt(np.diag(P)[6:9]), *np.sqrt(np.diag(P)[0:3]),
                  *(math.sqrt(max(H @ P @ H, 0.0)) for _, H in vel_rows), *wind_std]
