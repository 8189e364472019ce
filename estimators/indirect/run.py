"""Full-state indirect filter: settings, schedule and table assembly of one run (the registry entry of
:mod:`estimators.api`; the loop is :func:`estimators.indirect.kernel.run_kernel`).

Nominal state (:mod:`estimators.indirect.model`): position NED, ground velocity NED, attitude quaternion (body FRD ->
NED), gyro bias, accelerometer bias, wind (north, east), magnetometer hard-iron bias, barometer offset, the z
accelerometer's cross-axis sensitivities to x and y (``accel_cross_axis_states``, with GPS).
Error state: the table :func:`error_state_table` (name, unit, initial sigma, process sigma), from which P0 and the
random walks are built (docs/indirect.md, 'State vector'); a block is present only when it helps, exactly as in the
direct filter (same sensor plan from :mod:`estimators.inputs.build`; docs/indirect.md, 'Missing sensors'):
accelerometer bias with ``accel_bias_states`` and GPS; wind only with an airspeed sensor (absent states are removed
from P, not frozen); magnetometer bias only with a fused magnetometer; barometer offset only with barometer and GPS.

Outputs: Euler angles from the quaternion (:func:`ingest.frames.quat_to_euler`), their standard deviations
``S(Theta) P_thth S(Theta)^T``.
"""

from __future__ import annotations

import math
import time

import numpy as np

from estimators.config import EstimatorConfig
from estimators.core import recorder
from estimators.core.full_state import (
    MIN_VARIANCE,
    accel_bias_degradations,
    diagnostics_capacity,
    shared_settings,
)
from estimators.core.recorder import C_DIAG, C_OUTPUTS
from estimators.core.results import EstimatorRun, diagnostics_frame, kernel_report, replay_details, states_frame
from estimators.core.schedule import build_schedule
from estimators.core.state_table import StateSpec, initial_sigmas, random_walk_psd
from estimators.indirect import model as m
from estimators.indirect.kernel import N_COUNTERS, OUT_COLUMNS, IndirectSettings, run_kernel
from estimators.inputs import records
from estimators.inputs.records import OUTPUT, ReplayInputs
from ingest.flightlog import FlightLog
from ingest.frames import euler_to_quat, quat_to_euler

NAME = "full_state_indirect"

#: Cap of the attitude-error variances: 180 deg standard deviation (docs/indirect.md, 'State vector').
MAX_ATTITUDE_VAR_RAD2 = math.pi ** 2
#: Cap of the other error-state variances.
MAX_VARIANCE = 1e12
#: PX4 parameters of the GPS antenna position in the body frame [m].
GPS_LEVER_ARM_PARAMETERS = ("EKF2_GPS_POS_X", "EKF2_GPS_POS_Y", "EKF2_GPS_POS_Z")
#: Nominal-state names (report), in the order of :mod:`estimators.indirect.model`.
NOMINAL_NAMES = ("pn", "pe", "pd", "vn", "ve", "vd", "qw", "qx", "qy", "qz", "bgx", "bgy", "bgz", "bax", "bay",
                 "baz", "wn", "we", "bmx", "bmy", "bmz", "bb", "kzx", "kzy")
INJECT_MODES = ("group", "scalar")


def error_state_table(config: EstimatorConfig, *, absolute_yaw: bool) -> tuple[StateSpec, ...]:
    """All error states in the order of :mod:`estimators.indirect.model` (``E_*``); P0 and the walks come from here.

    Parameters
    ----------
    config : EstimatorConfig
        Initial sigmas (``initial``) and random-walk densities (``noise``).
    absolute_yaw : bool
        An absolute heading source exists (initial yaw sigma ``initial.yaw_deg``, else ``yaw_unaided_deg``).

    Notes
    -----
    The attitude rows give roll, pitch and yaw sigmas; P0's attitude block is their image under
    ``dtheta = W(Theta) dTheta`` (docs/indirect.md, 'State vector'), which equals the diagonal at level attitude.
    """
    ini, noise = config.initial, config.noise
    rad = math.radians
    yaw_sigma = rad(ini.yaw_deg if absolute_yaw else ini.yaw_unaided_deg)
    rows = [StateSpec(n, "m", ini.position_m, 0.0) for n in ("dpn", "dpe", "dpd")]
    rows += [StateSpec(n, "m/s", ini.velocity_m_s, 0.0) for n in ("dvn", "dve", "dvd")]
    rows += [StateSpec("dthx", "rad", rad(ini.roll_pitch_deg), 0.0),
             StateSpec("dthy", "rad", rad(ini.roll_pitch_deg), 0.0), StateSpec("dthz", "rad", yaw_sigma, 0.0)]
    rows += [StateSpec(n, "rad/s", rad(ini.gyro_bias_deg_s), noise.gyro_bias_rw_rad_s2_sqrt_hz)
             for n in ("dbgx", "dbgy", "dbgz")]
    rw_z = noise.accel_bias_rw_z_m_s3_sqrt_hz  # z may walk faster (cross-axis coupling, as the direct filter)
    rows += [StateSpec(n, "m/s^2", ini.accel_bias_m_s2, noise.accel_bias_rw_m_s3_sqrt_hz) for n in ("dbax", "dbay")]
    rows.append(StateSpec("dbaz", "m/s^2", ini.accel_bias_m_s2,
                          noise.accel_bias_rw_m_s3_sqrt_hz if rw_z is None else rw_z))
    rows += [StateSpec(n, "m/s", ini.wind_m_s, noise.wind_rw_m_s_sqrt_s) for n in ("dwn", "dwe")]
    rows += [StateSpec(n, "-", ini.mag_bias, noise.mag_bias_rw_sqrt_s) for n in ("dbmx", "dbmy", "dbmz")]
    rows.append(StateSpec("dbb", "m", ini.baro_bias_m, noise.baro_bias_rw_m_sqrt_s))
    rows += [StateSpec(n, "-", ini.accel_cross_axis, noise.accel_cross_axis_rw_sqrt_s) for n in ("dkzx", "dkzy")]
    return tuple(rows)


def active_error_states(config: EstimatorConfig, plan: records.SensorPlan) -> np.ndarray:
    """Indices (into :func:`error_state_table`) of the error states estimated for a sensor plan
    (docs/indirect.md, 'Missing sensors')."""
    active = np.zeros(m.NE, dtype=bool)
    active[:m.E_BA] = True  # dp, dv, dtheta, db_g
    # without GPS the accelerometer bias has no absolute velocity reference, as the direct filter
    active[m.E_BA:m.E_BA + 3] = config.accel_bias_states and plan.has_gps
    active[m.E_W:m.E_W + 2] = plan.has_airspeed
    active[m.E_BM:m.E_BM + 3] = plan.has_mag and config.mag_bias_states
    active[m.E_BB] = plan.has_baro and plan.has_gps and config.baro_bias_state
    # z accelerometer cross-axis: k_zx (climbs, descents and accelerations change the forward specific force);
    # k_zy only off fixed-wing, whose coordinated flight keeps the lateral specific force near zero (unobservable)
    cross_axis = config.accel_bias_states and config.accel_cross_axis_states and plan.has_gps
    active[m.E_KZ] = cross_axis
    active[m.E_KZ + 1] = cross_axis and not plan.fixed_wing
    return np.flatnonzero(active).astype(np.int64)


def active_error_table(inputs: ReplayInputs, config: EstimatorConfig) -> tuple[StateSpec, ...]:
    """The rows of :func:`error_state_table` estimated in a run (those of :func:`active_error_states`)."""
    full_table = _full_table(inputs, config)
    return tuple(full_table[i] for i in active_error_states(config, inputs.plan))


def _full_table(inputs: ReplayInputs, config: EstimatorConfig) -> tuple[StateSpec, ...]:
    return error_state_table(config, absolute_yaw=inputs.alignment.yaw_source != "none" or inputs.plan.has_sun)


def attitude_matrices(roll_rad, pitch_rad):
    """``S(Theta)`` (Euler rates from body rates; dTheta = S dtheta) and ``W = S^-1`` (docs/indirect.md,
    'State vector'), (..., 3, 3)."""
    cph, sph = np.cos(roll_rad), np.sin(roll_rad)
    cth, sth = np.cos(pitch_rad), np.sin(pitch_rad)
    zero, one = np.zeros_like(cph), np.ones_like(cph)
    S = np.moveaxis(np.array([[one, sph * sth / cth, cph * sth / cth], [zero, cph, -sph],
                              [zero, sph / cth, cph / cth]]), (0, 1), (-2, -1))
    W = np.moveaxis(np.array([[one, zero, -sth], [zero, cph, sph * cth], [zero, -sph, cph * cth]]),
                    (0, 1), (-2, -1))
    return S, W


def gps_lever_arm_m(flight_log: FlightLog) -> np.ndarray:
    """GPS antenna position in body FRD [m] from the log's ``EKF2_GPS_POS_X/Y/Z`` (zeros when absent)."""
    params = flight_log.meta.parameters
    values = [float(params.get(name, 0.0)) for name in GPS_LEVER_ARM_PARAMETERS]
    return np.array([v if math.isfinite(v) else 0.0 for v in values])


def kernel_settings(inputs: ReplayInputs, config: EstimatorConfig, flight_log: FlightLog, *,
                    inject: str = "group") -> IndirectSettings:
    """x0, P0, the active error states and the scalars of one run (:class:`estimators.indirect.kernel.IndirectSettings`;
    ``inject`` as :func:`run`)."""
    if inject not in INJECT_MODES:
        raise ValueError(f"inject must be 'group' or 'scalar', got {inject!r}")
    align = inputs.alignment
    full_table = _full_table(inputs, config)
    sel = active_error_states(config, inputs.plan)
    x0 = np.zeros(m.NX)
    x0[m.X_P:m.X_P + 3] = align.position_ned_m
    x0[m.X_V:m.X_V + 3] = align.velocity_ned_m_s
    x0[m.X_Q:m.X_Q + 4] = euler_to_quat(align.roll_rad, align.pitch_rad, align.yaw_rad)
    x0[m.X_BG:m.X_BG + 3] = align.gyro_bias_rad_s
    sigma0 = initial_sigmas(full_table)
    P0_full = np.diag(sigma0 ** 2)
    _, W = attitude_matrices(align.roll_rad, align.pitch_rad)
    th = slice(m.E_TH, m.E_TH + 3)
    P0_full[th, th] = W @ np.diag(sigma0[th] ** 2) @ W.T
    n = len(sel)
    max_var = np.full(n, MAX_VARIANCE)
    max_var[(sel >= m.E_TH) & (sel < m.E_TH + 3)] = MAX_ATTITUDE_VAR_RAD2
    return IndirectSettings(
        **shared_settings(inputs, config), x0=x0, P0=np.ascontiguousarray(P0_full[np.ix_(sel, sel)]), sel=sel,
        walk_psd=np.ascontiguousarray(random_walk_psd(full_table)[sel]), min_var=np.full(n, MIN_VARIANCE),
        max_var=max_var, lever_arm_m=gps_lever_arm_m(flight_log), inject_scalar=inject == "scalar")


def run(flight_log: FlightLog, inputs: ReplayInputs, config: EstimatorConfig, *,
        inject: str = "group") -> EstimatorRun:
    """Run the error-state filter on prepared inputs (the registry entry of :mod:`estimators.api`).

    Parameters
    ----------
    flight_log : FlightLog
        The log (its parameters give the GPS lever arm).
    inputs : ReplayInputs
        From :func:`estimators.inputs.build.build_replay_inputs`.
    config : EstimatorConfig
    inject : {"group", "scalar"}
        Inject the error estimate and reset after each sensor's group of scalar updates (default, the paper's
        Alg. 3) or after every scalar (re-linearised; docs/indirect.md, 'Injection and reset').
    """
    started = time.perf_counter()
    settings = kernel_settings(inputs, config, flight_log, inject=inject)
    ev, imu = inputs.events, inputs.imu
    op, op_dt, op_index = build_schedule(imu.time_s, ev.time_s, ev.kind, ev.imu_index, settings.covariance_dt_s,
                                         math.inf)
    n = len(settings.sel)
    n_out = ev.count(OUTPUT)
    out_f = np.full((n_out, len(OUT_COLUMNS)), np.nan)
    out_sd = np.full((n_out, n + 3), np.nan)
    diag_f, diag_i = recorder.diagnostics_arrays(diagnostics_capacity(ev))
    counters = np.zeros(N_COUNTERS, dtype=np.int64)
    kernel_started = time.perf_counter()
    x_final, _ = run_kernel(imu.gyro_rad_s, imu.accel_m_s2, ev.kind, ev.imu_index, ev.values, ev.variances, op,
                            op_dt, op_index, settings, out_f, out_sd, diag_f, diag_i, counters)
    kernel_s = time.perf_counter() - kernel_started
    return _assemble(inputs, config, settings, out_f, out_sd, diag_f, diag_i, counters, x_final, inject=inject,
                     timings={"kernel": kernel_s, "total": time.perf_counter() - started})


def _assemble(inputs: ReplayInputs, config: EstimatorConfig, settings: IndirectSettings, out_f, out_sd, diag_f,
              diag_i, counters, x_final, *, inject, timings) -> EstimatorRun:
    plan = inputs.plan
    count = int(counters[C_OUTPUTS])
    o, sd = out_f[:count], out_sd[:count]
    sel = list(settings.sel)
    n = len(sel)
    x = o[:, 1:]
    roll, pitch, yaw = quat_to_euler(x[:, m.X_Q:m.X_Q + 4])
    # Euler standard deviations: dTheta = S(Theta) dtheta
    col = {e: a for a, e in enumerate(sel)}
    th = [col[m.E_TH + i] for i in range(3)]
    P_th = np.zeros((count, 3, 3))
    for i in range(3):
        P_th[:, i, i] = sd[:, th[i]] ** 2
    for (i, j), c in (((0, 1), n), ((0, 2), n + 1), ((1, 2), n + 2)):
        P_th[:, i, j] = P_th[:, j, i] = sd[:, c]
    S, _ = attitude_matrices(roll, pitch)
    euler_std = np.sqrt(np.maximum(np.einsum("kij,kjl,kil->ki", S, P_th, S), 0.0))
    deg = np.degrees
    wind = plan.has_airspeed
    std = {"roll_deg_std": deg(euler_std[:, 0]), "pitch_deg_std": deg(euler_std[:, 1]),
           "yaw_deg_std": deg(euler_std[:, 2]),
           "pos_n_m_std": sd[:, col[m.E_P]], "pos_e_m_std": sd[:, col[m.E_P + 1]], "alt_m_std": sd[:, col[m.E_P + 2]],
           "vn_m_s_std": sd[:, col[m.E_V]], "ve_m_s_std": sd[:, col[m.E_V + 1]], "vd_m_s_std": sd[:, col[m.E_V + 2]]}
    if wind:
        std["wind_n_m_s_std"] = sd[:, col[m.E_W]]
        std["wind_e_m_s_std"] = sd[:, col[m.E_W + 1]]
    states = states_frame(o[:, 0], roll, pitch, yaw, x[:, m.X_P:m.X_P + 3], x[:, m.X_V:m.X_V + 3],
                          x[:, m.X_W:m.X_W + 2] if wind else None, inputs.origin, std=std,
                          navigation=plan.has_gps, wind=wind)
    diagnostics = diagnostics_frame(diag_f, diag_i, int(counters[C_DIAG]))
    table = active_error_table(inputs, config)
    details = {
        "mode": f"error-state (multiplicative quaternion), injection per {inject}",
        "states": [s.name for s in table],
        "final_state": {name: float(x_final[i]) for i, name in enumerate(NOMINAL_NAMES)},
        "final_state_std": {s.name: float(sd[-1, a]) if count else math.nan for a, s in enumerate(table)},
        "gps_lever_arm_m": [float(v) for v in settings.lever_arm_m],
        **replay_details(inputs),
    }
    report = kernel_report(NAME, inputs, counters, timings_s=timings, details=details,
                           degradations=accel_bias_degradations(plan, m.E_BA in sel, config.accel_bias_states))
    return EstimatorRun(states=states, diagnostics=diagnostics, report=report)
