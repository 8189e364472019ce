"""Plain-NumPy twin of the full-state indirect filter (conventions practice 5: a readable reference of the compiled
kernel, run by the equivalence test).

The model is written in matrix form straight from math note 5.3-5.4 (rotation matrices and rotation vectors from
:class:`scipy.spatial.transform.Rotation`, Hamilton products as 4 x 4 matrices, blocks assigned by slices),
independently of the scalar-unrolled numba functions of :mod:`estimators.indirect.model`; the EKF algebra is the
NumPy twin shared with the direct filter (:mod:`estimators.direct.reference`). The event loop mirrors
:func:`estimators.indirect.kernel.run_kernel` step for step (same propagation splitting, same covariance
schedule, same group accumulation and injection), so both produce the same trajectory to round-off.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from estimators.core.full_state import (
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
from estimators.core.recorder import C_GPS_RESETS, C_OUTPUTS, C_REPAIRS, C_RESETS
from estimators.direct.reference import (
    GpsMonitor,
    components,
    healthy,
    innovation,
    joseph_update,
    record,
    repair,
    skew,
    tangent_basis,
)
from estimators.indirect import model as m
from estimators.indirect.kernel import C_FLUSHES, P_INJECT_SCALAR, P_LEVER
from estimators.inputs.records import AIRSPEED, BARO, GPS_POS, GPS_VEL, MAG, OUTPUT, SIDESLIP, SUN, ZERO_VELOCITY

P_, V_, Q_, BG_, BA_, W_, BM_, KZ_ = (slice(m.X_P, m.X_P + 3), slice(m.X_V, m.X_V + 3), slice(m.X_Q, m.X_Q + 4),
                                      slice(m.X_BG, m.X_BG + 3), slice(m.X_BA, m.X_BA + 3), slice(m.X_W, m.X_W + 2),
                                      slice(m.X_BM, m.X_BM + 3), slice(m.X_KZ, m.X_KZ + 2))
DP, DV, DTH, DBG, DBA, DW, DBM, DKZ = (slice(m.E_P, m.E_P + 3), slice(m.E_V, m.E_V + 3), slice(m.E_TH, m.E_TH + 3),
                                       slice(m.E_BG, m.E_BG + 3), slice(m.E_BA, m.E_BA + 3), slice(m.E_W, m.E_W + 2),
                                       slice(m.E_BM, m.E_BM + 3), slice(m.E_KZ, m.E_KZ + 2))


def cross_axis(x):
    """K with f = K (accel - b_a): the z accelerometer's cross-axis sensitivities removed."""
    K = np.eye(3)
    K[2, 0:2] = -x[KZ_]
    return K


def rotation(q):
    """R(q) of a (w, x, y, z) quaternion."""
    return Rotation.from_quat(np.roll(q, -1)).as_matrix()


def exp_so3(phi):
    """Exp(phi) as a rotation matrix."""
    return Rotation.from_rotvec(phi).as_matrix()


def exp_quat(phi):
    """Exp(phi) = (cos(|phi|/2), sin(|phi|/2) phi/|phi|)."""
    angle = np.linalg.norm(phi)
    if angle < 1e-12:
        return np.array([1.0, *(0.5 * phi)])
    return np.array([math.cos(angle / 2), *(math.sin(angle / 2) * phi / angle)])


def quat_product(a, b):
    """Hamilton product a (x) b = L(a) b."""
    w, x, y, z = a
    L = np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])
    return L @ b


def right_jacobian(phi):
    """J_r(phi) = I - (1 - cos a)/a^2 [phi]x + (a - sin a)/a^3 [phi]x^2."""
    a = np.linalg.norm(phi)
    K = skew(phi)
    if a < 1e-4:
        return np.eye(3) - (0.5 - a * a / 24.0) * K + (1.0 / 6.0 - a * a / 120.0) * K @ K
    return np.eye(3) - (1.0 - math.cos(a)) / a ** 2 * K + (a - math.sin(a)) / a ** 3 * K @ K


def propagate(x, gyro, accel, dt, g):
    """Math note 5.3: exact exponential map, mid-interval attitude for the specific force f = K (accel - b_a)."""
    omega, f = gyro - x[BG_], cross_axis(x) @ (accel - x[BA_])
    a = rotation(x[Q_]) @ exp_so3(omega * dt / 2) @ f + np.array([0.0, 0.0, g])
    out = x.copy()
    out[P_] = x[P_] + x[V_] * dt + a * dt * dt / 2
    out[V_] = x[V_] + a * dt
    q = quat_product(x[Q_], exp_quat(omega * dt))
    out[Q_] = q / np.linalg.norm(q)
    return out


def transition_and_noise(x, gyro, accel, dt, ng2, na2, rw_psd):
    """F of one step (blocks of :func:`estimators.indirect.model.transition`) and Q = G Sigma G^T + diag(K^2) dt."""
    K = cross_axis(x)
    omega, f = gyro - x[BG_], K @ (accel - x[BA_])
    R, R_half = rotation(x[Q_]), exp_so3(omega * dt / 2)
    R_mid = R @ R_half
    a_th = -R @ skew(R_half @ f)
    a_bg = R_mid @ skew(f) @ right_jacobian(omega * dt / 2) * dt / 2
    a_kz = -np.outer(R_mid[:, 2], f[0:2])  # f_z = ... - k_zx f_x - k_zy f_y
    F = np.eye(m.NE)
    F[DP, DV] = np.eye(3) * dt
    for block, deriv in ((DTH, a_th), (DBG, a_bg), (DBA, -R_mid @ K), (DKZ, a_kz)):
        F[DP, block] = deriv * dt * dt / 2
        F[DV, block] = deriv * dt
    F[DTH, DTH] = exp_so3(omega * dt).T
    F[DTH, DBG] = -right_jacobian(omega * dt) * dt
    G = np.zeros((m.NE, 6))  # input noise (gyro, accel) enters as the bias errors, minus the bias rows
    G[:m.E_BG, 0:3] = F[:m.E_BG, DBG]
    G[:m.E_BG, 3:6] = F[:m.E_BG, DBA]
    Q = G @ np.diag(np.r_[np.full(3, ng2), np.full(3, na2)] / dt) @ G.T + np.diag(rw_psd) * dt
    return F, Q


def h_and_H(x, kind, comp, values, field, lever, gyro):
    """Math note 5.4 models: predicted scalar and its row over the NE error states."""
    R = rotation(x[Q_])
    H = np.zeros(m.NE)
    wind = np.r_[x[W_], 0.0]
    if kind == BARO:
        H[m.E_P + 2], H[m.E_BB] = -1.0, 1.0
        return x[m.X_BB] - x[m.X_P + 2], H
    if kind == GPS_POS:
        H[m.E_P + comp] = 1.0
        H[DTH] = (-R @ skew(lever))[comp]
        return (x[P_] + R @ lever)[comp], H
    if kind in (GPS_VEL, ZERO_VELOCITY) and comp < 3:
        arm = lever if kind == GPS_VEL else np.zeros(3)
        omega = gyro - x[BG_]
        H[m.E_V + comp] = 1.0
        H[DTH] = (-R @ skew(np.cross(omega, arm)))[comp]
        H[DBG] = (R @ skew(arm))[comp]
        return (x[V_] + R @ np.cross(omega, arm))[comp], H
    if kind == GPS_VEL:  # paper mode: ground speed (3) and course (4)
        vn, ve = x[m.X_V], x[m.X_V + 1]
        vg2 = vn * vn + ve * ve
        if comp == 3:
            H[m.E_V:m.E_V + 2] = np.array([vn, ve]) / math.sqrt(vg2) if vg2 > 1e-6 else 0.0
            return math.sqrt(vg2), H
        H[m.E_V:m.E_V + 2] = np.array([-ve, vn]) / vg2 if vg2 > 1e-6 else 0.0
        return math.atan2(ve, vn), H
    if kind == AIRSPEED:
        air = x[V_] - wind
        va = np.linalg.norm(air)
        if va > 1e-3:
            H[DV], H[DW] = air / va, -air[:2] / va
        return va, H
    if kind == SIDESLIP:
        air_b = R.T @ (x[V_] - wind)
        H[DV], H[DTH], H[DW] = R[:, 1], skew(air_b)[1], -R[:2, 1]
        return air_b[1], H
    ref = field if kind == MAG else values[3:6]
    body = R.T @ ref
    H[DTH] = skew(body)[comp]
    if kind == MAG:
        H[m.E_BM + comp] = 1.0
        return body[comp] + x[m.X_BM + comp], H
    return body[comp], H


def inject(x, dx, P):
    """x (+) dx and P <- G P G^T with G_thth = I - [dtheta/2]x (math note 5.4)."""
    out = x.copy()
    for xs, es in ((P_, DP), (V_, DV), (BG_, DBG), (BA_, DBA), (W_, DW), (BM_, DBM), (KZ_, DKZ)):
        out[xs] += dx[es]
    out[m.X_BB] += dx[m.E_BB]
    q = quat_product(x[Q_], exp_quat(dx[DTH]))
    out[Q_] = q / np.linalg.norm(q)
    G = np.eye(len(P))
    G[DTH, DTH] = np.eye(3) - skew(dx[DTH] / 2)  # the attitude block leads the active states (indices equal)
    return out, G @ P @ G.T


def reset_to_gps(x, P, kind, values, variances, field, lever, gyro, sel, move_wind):
    """The nominal position or velocity to the GPS (lever arm included), the block's error the GPS noise; with
    ``move_wind`` the wind moves with the velocity (north, east): ``e' = T e + G n``, ``P' = T P T^T + G R G^T``
    over the active error states ``sel`` (position and velocity lead them)."""
    x, P = x.copy(), P.copy()
    rows = [h_and_H(x, kind, c, values, field, lever, gyro) for c in range(3)]
    correction = values[0:3] - np.array([h for h, _ in rows])
    if kind == GPS_POS:
        x[P_] += correction
        P[DP, :] = 0.0
        P[:, DP] = 0.0
        P[DP, DP] = np.diag(variances[0:3])
        return x, P
    n = len(sel)
    T, G = np.eye(n), np.zeros((n, 3))
    x[V_] += correction
    T[DV] = 0.0
    G[DV] = np.eye(3)
    if move_wind:
        aw = int(np.flatnonzero(sel == m.E_W)[0])
        x[W_] += correction[:2]
        for c in range(2):
            T[aw + c] -= rows[c][1][sel]
            G[aw + c, c] = 1.0
    return x, T @ P @ T.T + G @ np.diag(variances[0:3]) @ G.T


def run_reference(imu_t, imu_gyro, imu_accel, ev_t, ev_kind, ev_imu, ev_val, ev_var, x0, P0, sel, params, gates,
                  rw_psd, min_var, max_var, out_f, out_sd, diag_f, diag_i, counters):
    """Same signature and outputs as :func:`estimators.indirect.kernel.run_kernel`."""
    n = len(sel)
    x, P, x_safe = x0.copy(), P0.copy(), x0.copy()
    g, cov_dt, field, lever = params[P_G], params[P_COV_DT], params[P_FIELD:P_FIELD + 3], params[P_LEVER:P_LEVER + 3]
    paper_vel, inject_scalar = params[P_PAPER_VEL] > 0.5, params[P_INJECT_SCALAR] > 0.5
    acc = {"dt": 0.0, "gyro": np.zeros(3), "accel": np.zeros(3), "x": x0.copy()}

    def flush():
        nonlocal P
        dt = acc["dt"]
        F, Q = transition_and_noise(acc["x"], acc["gyro"] / dt, acc["accel"] / dt, dt, params[P_NG2],
                                    params[P_NA2], rw_psd)
        F, Q = F[np.ix_(sel, sel)], Q[np.ix_(sel, sel)]
        P_new = F @ P @ F.T + Q
        counters[C_FLUSHES] += 1
        P, repaired = repair(0.5 * (P_new + P_new.T), min_var, max_var,
                             check_pd=counters[C_FLUSHES] % PD_CHECK_EVERY == 0)
        counters[C_REPAIRS] += repaired
        acc.update(dt=0.0, gyro=np.zeros(3), accel=np.zeros(3))

    def reset_if_diverged():
        nonlocal x, P
        if not (np.all(np.isfinite(x)) and healthy(np.zeros(n), P)):
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
                if acc["dt"] == 0.0:
                    acc["x"] = x.copy()
                step = t_next - t
                x = propagate(x, gyro, accel, step, g)
                acc["dt"] += step
                acc["gyro"] = acc["gyro"] + gyro * step
                acc["accel"] = acc["accel"] + accel * step
                t = t_next
                if acc["dt"] >= cov_dt * (1.0 - 1e-9):
                    flush()
                    reset_if_diverged()
            if not at_event:
                break
            kind, values = ev_kind[j], ev_val[j]
            if kind == OUTPUT:
                reset_if_diverged()
                x_safe = x.copy()
                out_f[n_out, 0], out_f[n_out, 1:] = t, x
                out_sd[n_out, :n] = np.sqrt(np.maximum(np.diag(P), 0.0))
                out_sd[n_out, n:] = P[m.E_TH, m.E_TH + 1], P[m.E_TH, m.E_TH + 2], P[m.E_TH + 1, m.E_TH + 2]
                n_out += 1
                j += 1
                continue
            if acc["dt"] > 0.0:
                flush()
            if kind in (GPS_POS, GPS_VEL):
                reset, counted = gps.reset_due(kind, t)
                if reset:
                    x, P = reset_to_gps(x, P, kind, values, ev_var[j], field, lever, gyro, sel,
                                        air_ok and m.E_W in sel)
                    counters[C_GPS_RESETS] += counted
                    j += 1
                    continue
            comps = components(kind, values, paper_vel, params[P_VMIN])
            if kind == SUN:
                rows = [h_and_H(x, kind, cc, values, field, lever, gyro) for cc in range(3)]
                basis = tangent_basis(np.array([r[0] for r in rows]))
            dx = np.zeros(m.NE)
            any_accepted = False
            for c in comps:
                if kind == SUN:
                    if inject_scalar:
                        rows = [h_and_H(x, kind, cc, values, field, lever, gyro) for cc in range(3)]
                    h3, H3 = np.array([r[0] for r in rows]), np.array([r[1] for r in rows])
                    nu, H_full, r_var = basis[:, c] @ (values[0:3] - h3), basis[:, c] @ H3, ev_var[j, c]
                else:
                    h, H_full = h_and_H(x, kind, c, values, field, lever, gyro)
                    nu, r_var = innovation(kind, c, values, ev_var[j], h)
                nu -= H_full @ dx
                accepted, s_var, nis, dx_r, P = joseph_update(P, H_full[sel], nu, r_var, gates[kind])
                record(diag_f, diag_i, counters, t, kind, c, nu, s_var, nis, accepted)
                if kind in (GPS_POS, GPS_VEL):
                    gps.record(kind, c, t, accepted)
                elif kind == AIRSPEED:
                    air_ok = accepted
                if accepted:
                    any_accepted = True
                    dx[sel] += dx_r
                    if inject_scalar:
                        x, P = inject(x, dx, P)
                        dx = np.zeros(m.NE)
            if any_accepted and not inject_scalar:
                x, P = inject(x, dx, P)
            j += 1
    if acc["dt"] > 0.0:
        flush()
    counters[C_OUTPUTS] = n_out
    return x, P
