"""Per-stage steps of the three-stage kernel (numba): state propagation, the deferred covariance propagation of
stages 1 and 3, and the measurement updates of the three stages.

The models are in :mod:`estimators.three_stage.model` and :mod:`estimators.three_stage.measurements`, the EKF
algebra (transition matrix, covariance propagation, scalar Joseph update, whitening, repair) in
:mod:`estimators.core.linalg`; the loop that calls these steps in the order of the shared schedule is
:func:`estimators.three_stage.kernel.run_kernel`. Arguments: ``prm`` is the run's
:class:`~estimators.three_stage.kernel.KernelParams`, ``w`` a stage's and ``mw`` the measurement
work arrays (:class:`~estimators.three_stage.kernel.StageWork`,
:class:`~estimators.three_stage.kernel.MeasurementWork`), ``diag_f, diag_i, counters`` the recorder arrays.

The steps called per sample or per update are ``inline="always"``: a non-inlined numba call that branches keeps a
reference-count pair per array argument (and per array in a tuple argument), which costs more than these small
computations.
"""

from __future__ import annotations

import math

from numba import njit

from estimators.core import linalg, reacquisition, recorder, rotations
from estimators.core.recorder import C_REPAIRS, C_RESETS, C_UPDATES
from estimators.core.results import ACCEL, WIND
from estimators.inputs.records import GPS_POS, GPS_VEL, MAG
from estimators.sun.measurement import sun_tangent_basis
from estimators.three_stage.measurements import (
    measured_heading,
    stage1_h_acceleration,
    stage1_h_airspeed,
    stage2_h,
    stage3_fw_h_gps_velocity,
    stage3_fw_h_wind,
    stage3_fw_wind_input_jacobian,
)
from estimators.three_stage.model import (
    corrected_heading,
    euler_yaw_rate,
    ned_acceleration,
    stage1_A,
    stage1_G,
    stage1_rates,
    stage2_G,
    stage3_fw_jacobians,
    stage3_fw_rates,
    stage3_mc_f,
)

#: Correlation time of the airspeed and stage-2 heading errors entering stage 3 as inputs [s].
INPUT_CORRELATION_S = 1.0
#: Smallest eigenvalue kept by the covariance repair.
EIG_FLOOR = 1e-12


# ----------------------------------------------------------------------------------------------------------------
# propagation


@njit(cache=True)
def _stage1_rates_at(phi, theta, p, q, r):
    return stage1_rates(math.sin(phi), math.cos(phi), math.tan(theta), p, q, r)


@njit(cache=True)
def _rk4_stage1(x, p, q, r, k1, dt):
    """Classical RK4 of eq 18 over ``dt`` with the rates held, in place; ``k1`` = (phi_dot, theta_dot) at ``x``."""
    phi, theta = x[0], x[1]
    a1, b1 = k1
    a2, b2 = _stage1_rates_at(phi + 0.5 * dt * a1, theta + 0.5 * dt * b1, p, q, r)
    a3, b3 = _stage1_rates_at(phi + 0.5 * dt * a2, theta + 0.5 * dt * b2, p, q, r)
    a4, b4 = _stage1_rates_at(phi + dt * a3, theta + dt * b3, p, q, r)
    x[0] = phi + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    x[1] = theta + dt / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)


@njit(cache=True)
def _rk4_stage3_fw(x, va, psi_dot, cps, sps, turn, dt):
    """Classical RK4 of the fixed-wing navigation model over ``dt`` with the inputs held (heading cosine and sine,
    g tan(phi)), in place."""
    vg, chi, wn, we = x[2], x[3], x[4], x[5]
    k1 = stage3_fw_rates(vg, chi, wn, we, va, psi_dot, cps, sps, turn)
    k2 = stage3_fw_rates(vg + 0.5 * dt * k1[2], chi + 0.5 * dt * k1[3], wn, we, va, psi_dot, cps, sps, turn)
    k3 = stage3_fw_rates(vg + 0.5 * dt * k2[2], chi + 0.5 * dt * k2[3], wn, we, va, psi_dot, cps, sps, turn)
    k4 = stage3_fw_rates(vg + dt * k3[2], chi + dt * k3[3], wn, we, va, psi_dot, cps, sps, turn)
    x[0] += dt / 6.0 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0])
    x[1] += dt / 6.0 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1])
    x[2] += dt / 6.0 * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2])
    x[3] = rotations.wrap_pi(chi + dt / 6.0 * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3]))


@njit(cache=True)
def _add_input_noise(G, variances, scale, Q):
    """``Q += G diag(variances) G^T * scale`` over the rows of ``G`` (skipping its zero entries)."""
    n, m = G.shape
    for c in range(m):
        for i in range(n):
            g_ic = G[i, c] * variances[c] * scale
            if g_ic != 0.0:
                for j in range(n):
                    Q[i, j] += g_ic * G[j, c]


@njit(cache=True, inline="always")
def propagate_states(dt, rates, f_b, va, prm, x1, x2, P2, x3, stage3_on):
    """The three states over ``dt`` [s] with the IMU row and airspeed held (RK4 / exact integration), and the
    stage-2 variance (A = 0: P += G N_g^2 G^T dt + q dt); the trigonometry of the pre-step roll and pitch is
    shared by the stages."""
    phi, theta, psi2 = x1[0], x1[1], x2[0]
    p, q, r = rates[0], rates[1], rates[2]
    sph, cph, cth = math.sin(phi), math.cos(phi), math.cos(theta)
    g2 = stage2_G(sph, cph, cth)
    variance_rate = prm.qc2
    for c in range(3):
        variance_rate += g2[c] * g2[c] * prm.gyro_psd[c]
    P2[0, 0] += variance_rate * dt
    psi_dot = euler_yaw_rate(sph, cph, cth, q, r)
    _rk4_stage1(x1, p, q, r, stage1_rates(sph, cph, math.tan(theta), p, q, r), dt)
    x2[0] = rotations.wrap_pi(psi2 + psi_dot * dt)  # A = 0 (eq 23): exact with the held inputs
    if not stage3_on:
        return
    if prm.fixed_wing_nav:
        psi, _, _ = corrected_heading(x3, psi2)
        _rk4_stage3_fw(x3, va, psi_dot, math.cos(psi), math.sin(psi), prm.gravity_m_s2 * sph / cph, dt)
    else:
        rate = stage3_mc_f(x3, ned_acceleration(phi, theta, psi2, f_b, prm.gravity_m_s2))
        for i in range(2):  # exact for the held acceleration
            x3[i] += (rate[i] + 0.5 * dt * rate[2 + i]) * dt
            x3[2 + i] += rate[2 + i] * dt


@njit(cache=True)
def accumulate(acc, dt, rates, f_b, va):
    """Sum the inputs of an interval (a deferred covariance propagation, an accelerometer update interval):
    ``acc = (dt, omega dt, f dt, V_a dt)``."""
    linalg.accumulate_inputs(acc, dt, rates, f_b)
    acc[7] += va * dt


@njit(cache=True)
def accumulate_intervals(acc_meas, acc1, acc3, stage3_on, dt, rates, f_b, va):
    """:func:`accumulate` over the open intervals: the accelerometer update interval ``acc_meas``, the stage-1
    covariance ``acc1`` and, once stage 3 runs, the stage-3 covariance ``acc3``."""
    accumulate(acc_meas, dt, rates, f_b, va)
    accumulate(acc1, dt, rates, f_b, va)
    if stage3_on:
        accumulate(acc3, dt, rates, f_b, va)


@njit(cache=True, inline="always")
def flush_stage1(acc, x1_start, P1, prm, A, G, F, Q, W, rates, values, cols, counts, columns):
    """Stage-1 covariance over the accumulated interval: F from the interval-start state and the mean rates,
    Q = G N_g^2 G^T dt + Qc dt (docs/estimators.md, 'Scheduling rule'). The work arrays of the stage are passed
    one by one (passing the work tuple costs a reference-count pair per member); ``values .. columns`` are the
    scratch of :func:`linalg.propagate_covariance_into`."""
    dt = acc[0]
    if dt <= 0.0:
        return
    for i in range(3):
        rates[i] = acc[1 + i] / dt
    linalg.transition_matrix(stage1_A(x1_start, rates, A), dt, F)
    for i in range(2):
        for j in range(2):
            Q[i, j] = prm.qc1[i, j] * dt
    _add_input_noise(stage1_G(x1_start, G), prm.gyro_psd, dt, Q)
    linalg.propagate_covariance_into(P1, F, Q, W, values, cols, counts, columns)
    acc[:] = 0.0


@njit(cache=True, inline="always")
def flush_stage3(acc, x3_start, attitude_start, P1, P2, P3, prm, A, G, F, Q, W, u, input_var, values, cols, counts,
                 columns):
    """Stage-3 covariance over the accumulated interval, from the interval-start state and attitude
    (phi, theta, psi_2) and the mean inputs (work arrays one by one, as in :func:`flush_stage1`)."""
    dt = acc[0]
    if dt <= 0.0:
        return
    n3 = x3_start.shape[0]
    for i in range(n3):
        for j in range(n3):
            Q[i, j] = prm.qc3[i, j] * dt
    if prm.fixed_wing_nav:
        u[0], u[1], u[2] = acc[7] / dt, acc[2] / dt, acc[3] / dt
        u[3], u[4], u[5] = attitude_start[0], attitude_start[1], attitude_start[2]
        stage3_fw_jacobians(x3_start, u, prm.gravity_m_s2, A, G)
        linalg.transition_matrix(A, dt, F)
        # airspeed and stage-2 heading errors as inputs: first-order Gauss-Markov errors with the correlation
        # time INPUT_CORRELATION_S have the low-frequency density 2 sigma^2 T (docs/three_stage.md, 'Stage 3:
        # navigation and wind')
        input_var[0], input_var[1] = prm.airspeed_var, P2[0, 0]
        _add_input_noise(G, input_var, 2.0 * INPUT_CORRELATION_S * dt, Q)
    else:
        linalg.transition_matrix(prm.a3_multicopter, dt, F)
        # accelerometer density (rotation-invariant) plus the tilt error g * delta (docs/three_stage.md, 'Stage 3:
        # navigation and wind')
        velocity_var = prm.accel_psd * dt + prm.gravity_m_s2 ** 2 * max(P1[0, 0], P1[1, 1]) * dt * dt
        Q[2, 2] += velocity_var
        Q[3, 3] += velocity_var
    linalg.propagate_covariance_into(P3, F, Q, W, values, cols, counts, columns)
    acc[:] = 0.0


# ----------------------------------------------------------------------------------------------------------------
# upkeep


@njit(cache=True)
def record(diag_f, diag_i, counters, t, sensor, component, nu, s_var, nis, accepted):
    """One diagnostics row, and the count of attempted scalar updates."""
    counters[C_UPDATES] += 1
    recorder.record_update(diag_f, diag_i, counters, t, sensor, component, nu, s_var, nis, accepted)


@njit(cache=True, inline="always")
def check_health(x, P, x_safe, P0, counters):
    """Divergence reset (non-finite state or covariance -> last healthy state, initial covariance)."""
    if linalg.is_healthy(x, P):
        linalg.copy_into(x_safe, x)
    else:
        linalg.reset_filter(x, P, x_safe, P0)
        counters[C_RESETS] += 1


@njit(cache=True, inline="always")
def repair(P, max_var, w, counters):
    """Covariance limits and positive definiteness after measurement updates (:func:`linalg.repair_covariance`)."""
    if linalg.repair_covariance(P, w.min_var, max_var, w.W, EIG_FLOOR):
        counters[C_REPAIRS] += 1


# ----------------------------------------------------------------------------------------------------------------
# stage 1: accelerometer


@njit(cache=True, inline="always")
def _stage1_model(x1, yaw_rad, rates, va, accel_n, airspeed_model, gravity_m_s2, h, c, jac):
    """Stage-1 accelerometer model into ``h`` (3,) and dh/d(phi, theta) into ``c`` (3, 2): steady flight with
    airspeed, else the acceleration form (``jac`` (3, 3) scratch)."""
    if airspeed_model:
        stage1_h_airspeed(x1, rates, va, gravity_m_s2, h, c)
    else:
        _, c_tilt = stage1_h_acceleration(x1, yaw_rad, accel_n, gravity_m_s2, h, jac)
        linalg.copy_rows_into(c, c_tilt, c.shape[0])


@njit(cache=True, inline="always")
def stage1_update(t, f_mean, rates_mean, va, accel_n, prm, x1, P1, x2, w, mw, diag_f, diag_i, counters):
    """Three sequential scalar accelerometer updates, re-linearised after each (Algorithm 1, stage 1;
    docs/three_stage.md, 'Stage 1: roll and pitch')."""
    h, c = mw.h, mw.c
    _stage1_model(x1, x2[0], rates_mean, va, accel_n, prm.airspeed_model, prm.gravity_m_s2, h, c, mw.jac)
    mismatch = abs(math.sqrt(f_mean[0] ** 2 + f_mean[1] ** 2 + f_mean[2] ** 2)
                   - math.sqrt(h[0] ** 2 + h[1] ** 2 + h[2] ** 2))
    extra_var = mismatch * mismatch if mismatch > prm.manoeuvre_threshold_m_s2 else 0.0
    for axis in range(3):
        nu = f_mean[axis] - h[axis]
        accepted, s_var, nis = linalg.scalar_update(P1, c[axis], nu, prm.accel_var[axis] + extra_var,
                                                      prm.accel_gate, w.dx, w.ph)
        record(diag_f, diag_i, counters, t, int(ACCEL), axis, nu, s_var, nis, accepted)
        if accepted:
            x1 += w.dx
            _stage1_model(x1, x2[0], rates_mean, va, accel_n, prm.airspeed_model, prm.gravity_m_s2, h, c,
                          mw.jac)  # re-linearise


# ----------------------------------------------------------------------------------------------------------------
# vector updates (stage 2, the stage-3 wind pseudo-measurement)


@njit(cache=True, inline="always")
def whitened_update(t, sensor, x, P, m, nu, H, R, gate_d2, w, mw, diag_f, diag_i, counters):
    """A vector measurement with correlated noise R, gated as a whole, then whitened and fused component-wise.

    ``nu`` (>= m, 1), ``H`` (>= m, n) and ``R`` (>= m, >= m) hold the ``m`` components; ``nu`` and ``H`` are
    whitened in place. Gate: the vector is rejected when ``nu^T S^-1 nu > gate_d2`` with ``S = H P H^T + R`` (a
    chi-square threshold for ``m`` components). Fusion: with ``R = L L^T``, ``nu' = L^-1 nu``, ``H' = L^-1 H`` and
    ``R' = I``, one scalar update per component; later components are corrected linearly, so the result equals the
    batch update. Returns whether the vector passed the gate.
    """
    L, S, y = mw.L, mw.S, mw.y
    sensor, m = int(sensor), int(m)  # plain int64: the callees compile once, not per inlined literal
    if not linalg.cholesky_lower(R, L, m, 0.0):
        L[:m, :m] = math.nan  # R not positive definite: NaN innovations, the vector is rejected below
    linalg.forward_solve(L, nu, m)
    linalg.forward_solve(L, H, m)
    # whole-vector Mahalanobis distance in whitened coordinates: S' = H' P H'^T + I
    linalg.sandwich(H, P, m, S)
    for i in range(m):
        S[i, i] += 1.0
    if not linalg.cholesky_lower(S, L, m, 0.0):
        L[:m, :m] = math.nan
    linalg.copy_rows_into(y, nu, m)
    linalg.forward_solve(L, y, m)
    d2 = 0.0
    for i in range(m):
        d2 += y[i, 0] * y[i, 0]
    if not d2 <= gate_d2:
        for i in range(m):
            record(diag_f, diag_i, counters, t, sensor, i, nu[i, 0], S[i, i], nu[i, 0] ** 2 / S[i, i], bool(False))
        return False
    for i in range(m):
        accepted, s_var, nis = linalg.scalar_update(P, H[i], nu[i, 0], 1.0, math.inf, w.dx, w.ph)
        record(diag_f, diag_i, counters, t, sensor, i, nu[i, 0], s_var, nis, accepted)
        if accepted:
            x += w.dx
            for j in range(i + 1, m):
                for c in range(x.shape[0]):
                    nu[j, 0] -= H[j, c] * w.dx[c]
    return True


@njit(cache=True, inline="always")
def stage2_update(t, kind, values, variances, prm, x1, P1, x2, P2, w, mw, diag_f, diag_i, counters):
    """Heading update from a body-frame unit vector: magnetometer (3 components) or sun (2 tangent components)
    (docs/three_stage.md, 'Stage 2: heading').

    Returns ``(gated, heading)``: whether the vector passed the gate, and the heading [rad] the measured vector
    alone implies at the stage-1 roll and pitch (:func:`measured_heading`; for the re-acquisition rule)."""
    z = mw.z
    if kind == MAG:
        norm = math.sqrt(values[0] ** 2 + values[1] ** 2 + values[2] ** 2)
        if not norm > 0.0:
            return True, math.nan
        for i in range(3):
            z[i] = values[i] / norm
        ref = prm.mag_field_ned
        gate_d2 = prm.mag_gate_d2
    else:
        linalg.copy_into(z, values)
        ref = values[3:6]
        gate_d2 = prm.sun_gate_d2
    h, c, j_tilt = stage2_h(x2[0], x1[0], x1[1], ref, mw.h, mw.jac)
    nu, H, J = mw.nu, w.H, mw.tilt
    if kind == MAG:
        m = 3
        for i in range(3):
            nu[i, 0] = z[i] - h[i]
            H[i, 0] = c[i, 0]
            J[i, 0], J[i, 1] = j_tilt[i, 0], j_tilt[i, 1]
    else:
        # 2-DOF tangent-plane form: nu = T^T z, H = T^T C, R = sigma^2 I_2
        m = 2
        basis = sun_tangent_basis(h)
        for i in range(2):
            nu[i, 0], H[i, 0], J[i, 0], J[i, 1] = 0.0, 0.0, 0.0, 0.0
            for a in range(3):
                nu[i, 0] += basis[a, i] * z[a]
                H[i, 0] += basis[a, i] * c[a, 0]
                J[i, 0] += basis[a, i] * j_tilt[a, 0]
                J[i, 1] += basis[a, i] * j_tilt[a, 1]
    R = mw.R
    if prm.cascade_inflation:
        linalg.sandwich(J, P1, m, R)
    else:
        R[:m, :m] = 0.0
    for i in range(m):
        R[i, i] += variances[0]
    heading = measured_heading(z, ref, x1[0], x1[1])
    gated = whitened_update(t, kind, x2, P2, m, nu, H, R, gate_d2, w, mw, diag_f, diag_i, counters)
    x2[0] = rotations.wrap_pi(x2[0])
    return gated, heading


# ----------------------------------------------------------------------------------------------------------------
# stage 3 (GPS epochs)


@njit(cache=True)
def stage3_fw_wind(t, va, vd_gps, prm, x2, P2, x3, P3, w, mw, diag_f, diag_i, counters):
    """Wind-triangle pseudo-measurement z = (0, 0) (eq 31-33 corrected), ungated."""
    vah = math.sqrt(max(va * va - vd_gps * vd_gps, 0.0))
    h, c = stage3_fw_h_wind(x3, vah, x2[0])
    for i in range(2):
        mw.nu[i, 0] = -h[i]
        linalg.copy_into(w.H[i], c[i])
    R = mw.R
    R[:2, :2] = 0.0
    w.input_var[0], w.input_var[1] = prm.airspeed_var, P2[0, 0]
    _add_input_noise(stage3_fw_wind_input_jacobian(x3, vah, x2[0]), w.input_var, 1.0, R)
    R[0, 0] += prm.wind_pseudo_var
    R[1, 1] += prm.wind_pseudo_var
    whitened_update(t, WIND, x3, P3, 2, mw.nu, w.H, R, math.inf, w, mw, diag_f, diag_i, counters)
    x3[3] = rotations.wrap_pi(x3[3])


@njit(cache=True)
def stage3_gps_position(t, values, variances, prm, x3, P3, w, gps_mon, diag_f, diag_i, counters):
    """GPS north and east (rows of the identity; booked in the re-acquisition monitor ``gps_mon`` as position
    channels 0 and 1)."""
    H = w.H[0]
    for i in range(2):
        H[:] = 0.0
        H[i] = 1.0
        nu = values[i] - x3[i]
        accepted, s_var, nis = linalg.scalar_update(P3, H, nu, variances[i], prm.gps_pos_gate, w.dx, w.ph)
        record(diag_f, diag_i, counters, t, int(GPS_POS), i, nu, s_var, nis, accepted)
        reacquisition.gps_record(gps_mon, bool(True), i, t, accepted)
        if accepted:
            x3 += w.dx
    if prm.fixed_wing_nav:
        x3[3] = rotations.wrap_pi(x3[3])


@njit(cache=True)
def stage3_gps_velocity(t, values, variances, prm, x3, P3, w, gps_mon, diag_f, diag_i, counters):
    """GPS horizontal velocity: NED components (linear in multicopter mode), or V_g and chi in paper mode
    (booked in the re-acquisition monitor ``gps_mon`` as velocity channels 0 and 1)."""
    n = x3.shape[0]
    H = w.H[0]
    if prm.fixed_wing_nav and prm.paper_gps_velocity:
        speed = math.hypot(values[0], values[1])
        if speed < prm.min_ground_speed_m_s:
            return
        course = math.atan2(values[1], values[0])
        for comp in range(2):
            H[:] = 0.0
            H[2 + comp] = 1.0
            if comp == 0:
                nu = speed - x3[2]
                r_var = 0.5 * (variances[0] + variances[1])
            else:
                nu = rotations.wrap_pi(course - x3[3])
                # eq 9 corrected (docs/three_stage.md, 'Corrections to the paper')
                r_var = 0.5 * (variances[0] + variances[1]) / (speed * speed)
            accepted, s_var, nis = linalg.scalar_update(P3, H, nu, r_var, prm.gps_vel_gate, w.dx, w.ph)
            record(diag_f, diag_i, counters, t, int(GPS_VEL), 3 + comp, nu, s_var, nis, accepted)
            reacquisition.gps_record(gps_mon, bool(False), comp, t, accepted)
            if accepted:
                x3 += w.dx
                x3[3] = rotations.wrap_pi(x3[3])
        return
    for comp in range(2):
        if prm.fixed_wing_nav:
            h, c = stage3_fw_h_gps_velocity(x3)
            nu = values[comp] - h[comp]
            for i in range(n):
                H[i] = c[comp, i]
        else:
            nu = values[comp] - x3[2 + comp]
            H[:] = 0.0
            H[2 + comp] = 1.0
        accepted, s_var, nis = linalg.scalar_update(P3, H, nu, variances[comp], prm.gps_vel_gate, w.dx, w.ph)
        record(diag_f, diag_i, counters, t, int(GPS_VEL), comp, nu, s_var, nis, accepted)
        reacquisition.gps_record(gps_mon, bool(False), comp, t, accepted)
        if accepted:
            x3 += w.dx
            if prm.fixed_wing_nav:
                x3[3] = rotations.wrap_pi(x3[3])


@njit(cache=True)
def stage3_init_velocity(values, variances, prm, x3, P3):
    """Velocity states from a GPS velocity (start of stage 3, or reset with the position)."""
    for i in range(2, 4):
        for j in range(x3.shape[0]):
            P3[i, j] = 0.0
            P3[j, i] = 0.0
    if prm.fixed_wing_nav:
        speed = math.hypot(values[0], values[1])
        x3[2] = speed
        x3[3] = math.atan2(values[1], values[0])
        P3[2, 2] = variances[0]
        P3[3, 3] = variances[0] / max(speed * speed, prm.min_ground_speed_m_s ** 2)
    else:
        x3[2] = values[0]
        x3[3] = values[1]
        P3[2, 2] = variances[0]
        P3[3, 3] = variances[1]
