"""Full-state direct EKF (paper section 3.2; docs/direct.md): settings, schedule and table assembly of one run (the
registry entry of :mod:`estimators.api`; the loop is :func:`estimators.direct.kernel.run_kernel`).

State: the table :func:`direct_state_table` (:mod:`estimators.direct.model`; docs/direct.md, 'State vector'), a
block present only when it helps (docs/direct.md, 'Missing sensors'): accelerometer bias with
``accel_bias_states`` and GPS (without GPS it has no absolute velocity reference), wind only with an airspeed
sensor, magnetometer bias only with a fused magnetometer, barometer offset only with barometer and GPS. x0 from
the initial alignment (docs/estimators.md, 'Initial alignment'), P0 and the random walks from the table.

The schedule (docs/estimators.md, 'Scheduling rule') is built here, once per run, and executed by the kernel.
``mode="paper_indirect"`` runs the paper's indirect filter literally (:mod:`estimators.direct.kernel`).
"""

from __future__ import annotations

import math
import time

import numpy as np

from estimators.config import EstimatorConfig
from estimators.core import recorder
from estimators.core.full_state import MIN_VARIANCE, accel_bias_degradations, diagnostics_capacity, shared_settings
from estimators.core.recorder import C_DIAG, C_OUTPUTS
from estimators.core.results import EstimatorRun, diagnostics_frame, kernel_report, replay_details, states_frame
from estimators.core.schedule import build_schedule
from estimators.core.state_table import StateSpec, initial_covariance, random_walk_psd
from estimators.direct.kernel import C_PITCH_GUARD, N_COUNTERS, OUT_COLUMNS, DirectSettings, run_kernel
from estimators.direct.model import I_BG, I_P, I_TH, I_V, layout_of, state_table
from estimators.inputs.records import OUTPUT, ReplayInputs
from ingest.flightlog import FlightLog
from ingest.frames import euler_to_matrix

NAME = "full_state_direct"
MODES = ("direct", "paper_indirect")
#: Cap of the yaw variance: 180 deg standard deviation (docs/direct.md, 'State vector').
MAX_YAW_VAR_RAD2 = math.pi ** 2
#: Cap of the other variances.
MAX_VARIANCE = 1e12


def direct_state_table(inputs: ReplayInputs, config: EstimatorConfig) -> tuple[StateSpec, ...]:
    """The state table of a run from its sensor plan (see the module docstring)."""
    plan, align = inputs.plan, inputs.alignment
    return state_table(config, accel_bias=config.accel_bias_states and plan.has_gps, wind=plan.has_airspeed,
                       mag_bias=plan.has_mag and config.mag_bias_states,
                       baro_bias=plan.has_baro and plan.has_gps and config.baro_bias_state,
                       absolute_yaw=align.yaw_source != "none" or plan.has_sun)


def kernel_settings(inputs: ReplayInputs, config: EstimatorConfig, *, mode: str = "direct") -> DirectSettings:
    """x0, P0, the layout and the scalars of one run (:class:`estimators.direct.kernel.DirectSettings`; ``mode``
    as :func:`run`)."""
    if mode not in MODES:
        raise ValueError(f"mode must be 'direct' or 'paper_indirect', got {mode!r}")
    align = inputs.alignment
    table = direct_state_table(inputs, config)
    names = [s.name for s in table]
    n = len(table)
    x0 = np.zeros(n)
    x0[I_P:I_P + 3] = align.position_ned_m
    r_nb = euler_to_matrix(align.roll_rad, align.pitch_rad, align.yaw_rad)
    x0[I_V:I_V + 3] = r_nb.T @ align.velocity_ned_m_s
    x0[I_TH:I_TH + 3] = align.roll_rad, align.pitch_rad, align.yaw_rad
    x0[I_BG:I_BG + 3] = align.gyro_bias_rad_s
    max_var = np.full(n, MAX_VARIANCE)
    max_var[names.index("yaw")] = MAX_YAW_VAR_RAD2
    return DirectSettings(**shared_settings(inputs, config), x0=x0, P0=initial_covariance(table),
                          layout=layout_of(table), walk_psd=random_walk_psd(table), min_var=np.full(n, MIN_VARIANCE),
                          max_var=max_var, paper_indirect=mode == "paper_indirect")


def run(flight_log: FlightLog, inputs: ReplayInputs, config: EstimatorConfig, *,
        mode: str = "direct") -> EstimatorRun:
    """Run the full-state direct filter on prepared inputs (the registry entry of :mod:`estimators.api`).

    Parameters
    ----------
    flight_log : FlightLog
        The log (unused beyond ``inputs``; part of the common estimator signature).
    inputs : ReplayInputs
        From :func:`estimators.inputs.build.build_replay_inputs`.
    config : EstimatorConfig
    mode : {"direct", "paper_indirect"}
        The direct filter, or the paper's indirect filter run literally (:mod:`estimators.direct.kernel`).
    """
    del flight_log
    started = time.perf_counter()
    settings = kernel_settings(inputs, config, mode=mode)
    ev, imu = inputs.events, inputs.imu
    op, op_dt, op_index = build_schedule(imu.time_s, ev.time_s, ev.kind, ev.imu_index, settings.covariance_dt_s,
                                         math.inf)
    n = len(settings.x0)
    n_out = ev.count(OUTPUT)
    out_f = np.full((n_out, len(OUT_COLUMNS)), np.nan)
    out_x = np.full((n_out, n), np.nan)
    out_sx = np.full((n_out, n), np.nan)
    diag_f, diag_i = recorder.diagnostics_arrays(diagnostics_capacity(ev))
    counters = np.zeros(N_COUNTERS, dtype=np.int64)
    kernel_started = time.perf_counter()
    x_final, _ = run_kernel(imu.gyro_rad_s, imu.accel_m_s2, ev.kind, ev.values, ev.variances, op, op_dt, op_index,
                            settings, out_f, out_x, out_sx, diag_f, diag_i, counters)
    kernel_s = time.perf_counter() - kernel_started
    return _assemble(inputs, config, out_f, out_sx, diag_f, diag_i, counters, x_final,
                     timings={"kernel": kernel_s, "total": time.perf_counter() - started}, mode=mode)


def _assemble(inputs: ReplayInputs, config: EstimatorConfig, out_f, out_sx, diag_f, diag_i, counters, x_final, *,
              timings, mode) -> EstimatorRun:
    plan = inputs.plan
    col = {c: i for i, c in enumerate(OUT_COLUMNS)}
    count = int(counters[C_OUTPUTS])
    o = out_f[:count]
    deg = np.degrees
    std = {"roll_deg_std": deg(o[:, col["roll_std"]]), "pitch_deg_std": deg(o[:, col["pitch_std"]]),
           "yaw_deg_std": deg(o[:, col["yaw_std"]]), "pos_n_m_std": o[:, col["pn_std"]],
           "pos_e_m_std": o[:, col["pe_std"]], "alt_m_std": o[:, col["pd_std"]],
           "vn_m_s_std": o[:, col["vn_std"]], "ve_m_s_std": o[:, col["ve_std"]], "vd_m_s_std": o[:, col["vd_std"]],
           "wind_n_m_s_std": o[:, col["wn_std"]], "wind_e_m_s_std": o[:, col["we_std"]]}
    states = states_frame(o[:, col["time_s"]], o[:, col["roll"]], o[:, col["pitch"]], o[:, col["yaw"]],
                          o[:, col["pn"]:col["pd"] + 1], o[:, col["vn"]:col["vd"] + 1],
                          o[:, col["wn"]:col["we"] + 1], inputs.origin, std=std, navigation=plan.has_gps,
                          wind=plan.has_airspeed, height=plan.has_baro or plan.has_gps)
    diagnostics = diagnostics_frame(diag_f, diag_i, int(counters[C_DIAG]))
    names = [s.name for s in direct_state_table(inputs, config)]
    warnings = []
    if counters[C_PITCH_GUARD]:
        warnings.append(f"{counters[C_PITCH_GUARD]} updates skipped at |pitch| > 85 deg (Euler singularity)")
    details = {
        "mode": mode,
        "states": names,
        "final_state": {name: float(x_final[i]) for i, name in enumerate(names)},
        **replay_details(inputs),
        "final_state_std": {name: float(out_sx[count - 1, i]) if count else math.nan
                            for i, name in enumerate(names)},
    }
    report = kernel_report(NAME, inputs, counters, timings_s=timings, details=details, warnings=warnings,
                           degradations=accel_bias_degradations(plan, "bax" in names, config.accel_bias_states))
    return EstimatorRun(states=states, diagnostics=diagnostics, report=report)
