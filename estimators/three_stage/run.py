"""Three-stage series estimator (paper section 3.1 and Algorithm 1; docs/three_stage.md): options, state tables,
kernel setup and :func:`run`, the registry entry of :mod:`estimators.api`.

Three small EKFs in series, each feeding the next its estimate as an input (process models in
:mod:`estimators.three_stage.model`, measurement models in :mod:`estimators.three_stage.measurements`, the steps in
:mod:`estimators.three_stage.stages`, the compiled loop in :mod:`estimators.three_stage.kernel`, the EKF algebra in
:mod:`estimators.core.linalg`; state vectors in docs/three_stage.md, 'State vectors'):

1. **Roll and pitch** ``x1 = (phi, theta)`` [rad], propagated with the bias-corrected gyro (bias from the still
   window at the start, docs/estimators.md, 'Initial alignment'; no bias states), updated with the accelerometer:
   three sequential scalar updates, re-linearised after each (Algorithm 1), at ``accel_update_rate_hz`` (the
   paper's 50 Hz estimator rate) with the specific force and the rates averaged over the update interval.
   Fixed-wing with airspeed: the steady flight model with the centripetal term (eq 20/21 corrected); otherwise
   gravity only (``V_a = 0``) or, with ``gps_acceleration``, ``h = C_bn (a_n - g_n)`` with the low-passed
   derivative of the GPS velocity (docs/three_stage.md, 'Missing sensors'). R: the accelerometer density of the
   config at the update rate (floored: it must cover model error), eq 52's ``tau`` on the body-y entry, plus
   ``d^2`` when the specific-force magnitude misses the model by ``d > manoeuvre_threshold_m_s2``
   (docs/three_stage.md, 'Stage 1: roll and pitch').
2. **Heading** ``x2 = psi_2`` [rad], propagated with ``psi_dot = (q s_ph + r c_ph) / c_th`` (eq 22 corrected),
   updated with the magnetometer (unit vector against the unit World Magnetic Model field, eq 24/25 corrected)
   and/or the photocell sun vector (tangent-plane form), whichever the replay inputs carry
   (``heading="mag"|"sun"|"mag+sun"`` of :func:`estimators.inputs.build.build_replay_inputs`). Cascade
   consistency: R is inflated by the stage-1 covariance, ``R_eff = R + J P1 J^T`` with ``J = dh/d(phi, theta)``;
   the correlated vector is gated as a whole (chi-square) and whitened (Cholesky) before its scalar updates.
   Heading re-acquisition (the GPS rule of docs/estimators.md, 'GPS re-acquisition', applied to heading): when
   every heading vector has been gated out for ``timing.gps_reset_after_s``, the heading restarts at the one the
   measured vector implies at the stage-1 roll and pitch, with the alignment's variance (counted and reported).
   See docs/three_stage.md, 'Stage 2: heading'.
3. **Navigation** at the GPS epochs (Algorithm 1 as corrected in docs/three_stage.md, 'Corrections to the
   paper'; docs/three_stage.md, 'Stage 3: navigation and wind'). Fixed-wing with airspeed: ``x3 = (p_n, p_e,
   V_g, chi, w_n, w_e, dev_a, dev_b, dev_c)`` (eq 26-33 corrected) driven by ``u = (V_a, q, r, phi, theta,
   psi_2)``, where the heading ``psi = psi_2 - (dev_a + dev_b sin psi_2 + dev_c cos psi_2)`` is the stage-2
   heading corrected by a compass-deviation model [ADD: a body-fixed horizontal field error, i.e. the
   magnetometer's hard iron and the vertical field seen through stage 1's tilt error, makes the heading error a
   constant plus a sinusoid of the heading; observable through the wind triangle in turns, like B&M's psi state;
   zero sigmas give the paper's 6 states]; the reported yaw is that corrected heading while this stage runs. Per
   GPS epoch the wind-triangle pseudo-measurement (``R = J diag(sigma_Va^2, P_psi) J^T + sigma_w^2 I``, whitened,
   ungated), then GPS north, east, then velocity (NED form, or ground speed and course with
   ``gps_velocity_mode="paper"``). It starts at the first GPS epoch with a ground speed above V_min (the model is
   invalid on the ground and in the hand launch): position, velocity and wind are NaN before. Otherwise
   (multicopter, or no airspeed): ``x3 = (p_n, p_e, v_n, v_e)`` driven by the NED acceleration from the
   accelerometer and the stage-1/2 attitude, from the first GPS epoch; no wind.
   Height is not estimated: it is the low-passed barometer altitude (offset to GPS height removed by the replay
   inputs), or the low-passed GPS height without a barometer (docs/three_stage.md, 'Missing sensors'); the
   vertical speed is the low-passed rate of that filter. The airspeed input is the low-passed true airspeed.

States at the IMU rate; covariances of stages 1 and 3 at ``timing.covariance_rate_hz`` and before every
measurement update, stage 1 updated at ``accel_update_rate_hz``: the schedule of the three filters
(:func:`estimators.core.schedule.build_schedule`, docs/estimators.md, 'Scheduling rule'), built here and executed by
:func:`estimators.three_stage.kernel.run_kernel`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtrc, chdtri

from calib.figures import FIGURES
from estimators.config import EstimatorConfig
from estimators.core import recorder
from estimators.core.recorder import C_DIAG, C_OUTPUTS
from estimators.core.results import EstimatorRun, diagnostics_frame, kernel_report, replay_details, states_frame
from estimators.core.schedule import build_schedule
from estimators.core.state_table import StateSpec, initial_covariance, process_noise_psd
from estimators.inputs import records
from estimators.inputs.records import GPS_POS, GPS_VEL, MAG, OUTPUT, SUN, ReplayInputs
from estimators.three_stage.control import C_HEADING_RESETS, C_PITCH_GUARD, N_COUNTERS
from estimators.three_stage.kernel import (
    O_PD,
    O_PE_STD,
    O_PITCH,
    O_PITCH_STD,
    O_PN,
    O_PN_STD,
    O_ROLL,
    O_ROLL_STD,
    O_TIME,
    O_VD,
    O_VE_STD,
    O_VN,
    O_VN_STD,
    O_WE,
    O_WE_STD,
    O_WN,
    O_WN_STD,
    O_YAW,
    O_YAW_STD,
    OUT_COLUMNS,
    KernelParams,
    run_kernel,
)
from estimators.three_stage.model import I_DEVIATION, stage3_mc_A
from ingest.flightlog import FlightLog

NAME = "three_stage"
#: Event kinds fused as measurement updates (the barometer and the airspeed are low-passed inputs of the stages).
FUSED_KINDS = (MAG, SUN, GPS_POS, GPS_VEL)

#: Event kinds the replay inputs may carry that this estimator does not use (fixed-wing sideslip and no-GPS
#: zero-velocity pseudo-measurements of the full-state filters).
UNUSED_SENSORS = ("sideslip", "zero_velocity")
#: Why they are skipped (a property of the estimator, not of the log: app.notes shows it as expected).
NOT_IN_THREE_STAGE = "not part of the three-stage estimator"

# process-noise densities of the model-error random walks (the gyro enters through G; see the state tables)
ROLL_PITCH_RW_RAD_SQRT_S = math.radians(0.3)  # residual gyro bias / scale / cross-axis error
YAW_RW_RAD_SQRT_S = math.radians(0.3)
POSITION_RW_M_SQRT_S = 0.3  # unmodelled kinematics between GPS epochs
GROUND_SPEED_RW_M_S_SQRT_S = 0.5  # unmodelled longitudinal acceleration (V_a changes)
COURSE_RW_RAD_SQRT_S = math.radians(3.0)  # coordinated-turn model error (roll error, sideslip)
VELOCITY_RW_M_S_SQRT_S = 0.3  # multicopter mode: accelerometer bias and vibration beyond the density


@dataclass(frozen=True)
class ThreeStageOptions:
    """Settings of the three-stage estimator beyond the shared :class:`~estimators.config.EstimatorConfig`.

    Attributes
    ----------
    accel_update_rate_hz : float
        Rate of the stage-1 accelerometer updates [Hz]; the specific force is averaged over the interval (paper:
        IMU and estimator at 50 Hz).
    accel_sigma_floor_m_s2, mag_sigma_floor, gps_pos_sigma_floor_m, gps_vel_sigma_floor_m_s : float
        Floors of the measurement noise [m/s^2 at the update rate, field units, m, m/s]: with no bias states the
        three-stage R must cover model error (accelerometer and magnetometer biases, unmodelled accelerations, the
        GPS velocity lag of the coordinated-turn model: docs/three_stage.md, 'Stage 1: roll and pitch', 'Stage 2:
        heading' and 'Stage 3: navigation and wind'), whatever the sensor noise of the configuration. Defaults:
        the paper's in-flight accelerometer noise at 50 Hz (Table 4, up to 0.25 m/s^2), 0.03 on the unit vector,
        0.5 m and 0.1 m/s.
    accel_gate : float
        Stage-1 gate in innovation standard deviations (3..5; docs/three_stage.md, 'Stage 1: roll and pitch').
    manoeuvre_threshold_m_s2 : float
        ``| |f_m| - |h(x)| |`` above which the squared mismatch is added to the accelerometer variance [m/s^2]
        (0.5..1; docs/three_stage.md, 'Stage 1: roll and pitch').
    gps_acceleration : bool
        Without airspeed: stage 1 uses ``h = C_bn (a_n - g_n)`` with the GPS-derived acceleration instead of
        gravity only (docs/three_stage.md, 'Missing sensors').
    cascade_inflation : bool
        Inflate the stage-2 R by the stage-1 covariance (docs/three_stage.md, 'Stage 2: heading').
    airspeed_lpf_s, baro_lpf_s, vertical_speed_lpf_s, gps_acceleration_lpf_s : float
        First-order low-pass time constants [s] of the airspeed input, the height, the vertical speed and the GPS
        acceleration.
    wind_pseudo_sigma_m_s : float
        Model error of the wind triangle (sideslip, flight-path angle, vertical wind) [m/s], added to the variance
        propagated from airspeed and heading.
    deviation_sigma_deg, deviation_rw_deg_sqrt_s : float
        Initial sigma [deg] and random walk [deg/sqrt(s)] of each coefficient of the fixed-wing stage-3 compass
        deviation model ``a + b sin psi_2 + c cos psi_2`` of the stage-2 heading error (body-fixed field errors:
        hard iron, and the vertical field seen through stage 1's tilt error), observed by the wind triangle in
        turns. 0 and 0 give the paper's 6-state navigation stage.
    """

    accel_update_rate_hz: float = 50.0
    accel_sigma_floor_m_s2: float = 0.25
    mag_sigma_floor: float = 0.03
    gps_pos_sigma_floor_m: float = 0.5
    gps_vel_sigma_floor_m_s: float = 0.1
    accel_gate: float = 5.0
    manoeuvre_threshold_m_s2: float = 0.5
    gps_acceleration: bool = False
    cascade_inflation: bool = True
    airspeed_lpf_s: float = 0.2
    baro_lpf_s: float = 0.5
    vertical_speed_lpf_s: float = 1.0
    gps_acceleration_lpf_s: float = 0.5
    wind_pseudo_sigma_m_s: float = 0.3
    deviation_sigma_deg: float = 5.0
    deviation_rw_deg_sqrt_s: float = 0.02

    def __post_init__(self):
        for name in ("accel_update_rate_hz", "accel_gate", "airspeed_lpf_s", "baro_lpf_s",
                     "vertical_speed_lpf_s", "gps_acceleration_lpf_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"ThreeStageOptions.{name} must be a positive number, got {value!r}")
        for name in ("manoeuvre_threshold_m_s2", "wind_pseudo_sigma_m_s", "deviation_sigma_deg",
                     "accel_sigma_floor_m_s2", "mag_sigma_floor", "gps_pos_sigma_floor_m", "gps_vel_sigma_floor_m_s",
                     "deviation_rw_deg_sqrt_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"ThreeStageOptions.{name} must be a non-negative number, got {value!r}")


# ----------------------------------------------------------------------------------------------------------------
# state tables (x0, P0 and the random-walk densities are built from them)


def stage1_states(config: EstimatorConfig) -> tuple[StateSpec, ...]:
    """Stage 1 (roll, pitch); initial sigma from ``config.initial.roll_pitch_deg``."""
    sigma0 = math.radians(config.initial.roll_pitch_deg)
    return (StateSpec("roll_rad", "rad", sigma0, ROLL_PITCH_RW_RAD_SQRT_S),
            StateSpec("pitch_rad", "rad", sigma0, ROLL_PITCH_RW_RAD_SQRT_S))


def stage2_states(config: EstimatorConfig, *, absolute_yaw: bool) -> tuple[StateSpec, ...]:
    """Stage 2 (heading); initial sigma ``initial.yaw_deg`` with an absolute heading source, else unaided."""
    sigma0 = math.radians(config.initial.yaw_deg if absolute_yaw else config.initial.yaw_unaided_deg)
    return (StateSpec("yaw_rad", "rad", sigma0, YAW_RW_RAD_SQRT_S),)


def stage3_fixed_wing_states(config: EstimatorConfig, options: ThreeStageOptions) -> tuple[StateSpec, ...]:
    """Stage 3, fixed-wing mode (docs/three_stage.md, 'Stage 3: navigation and wind'); wind walk from
    ``config.noise.wind_rw_m_s_sqrt_s``; the heading deviation of stage 2 from ``options``."""
    ini = config.initial
    return (StateSpec("pn_m", "m", ini.position_m, POSITION_RW_M_SQRT_S),
            StateSpec("pe_m", "m", ini.position_m, POSITION_RW_M_SQRT_S),
            StateSpec("vg_m_s", "m/s", ini.velocity_m_s, GROUND_SPEED_RW_M_S_SQRT_S),
            StateSpec("chi_rad", "rad", math.radians(ini.yaw_deg), COURSE_RW_RAD_SQRT_S),
            StateSpec("wind_n_m_s", "m/s", ini.wind_m_s, config.noise.wind_rw_m_s_sqrt_s),
            StateSpec("wind_e_m_s", "m/s", ini.wind_m_s, config.noise.wind_rw_m_s_sqrt_s),
            *(StateSpec(f"deviation_{name}_rad", "rad", math.radians(options.deviation_sigma_deg),
                        math.radians(options.deviation_rw_deg_sqrt_s)) for name in ("a", "b", "c")))


def stage3_multicopter_states(config: EstimatorConfig) -> tuple[StateSpec, ...]:
    """Stage 3, multicopter / no-airspeed mode (docs/three_stage.md, 'Stage 3: navigation and wind')."""
    ini = config.initial
    return (StateSpec("pn_m", "m", ini.position_m, POSITION_RW_M_SQRT_S),
            StateSpec("pe_m", "m", ini.position_m, POSITION_RW_M_SQRT_S),
            StateSpec("vn_m_s", "m/s", ini.velocity_m_s, VELOCITY_RW_M_S_SQRT_S),
            StateSpec("ve_m_s", "m/s", ini.velocity_m_s, VELOCITY_RW_M_S_SQRT_S))


# ----------------------------------------------------------------------------------------------------------------
# orchestration


@dataclass(frozen=True)
class KernelSetup:
    """Initial states, covariances and parameters of one run (what :func:`run_kernel` receives), and the two
    intervals of its schedule [s] (:func:`estimators.core.schedule.build_schedule`)."""

    tables: dict[str, tuple[StateSpec, ...]]
    x1: np.ndarray
    P1: np.ndarray
    x2: np.ndarray
    P2: np.ndarray
    x3: np.ndarray
    P3: np.ndarray
    params: KernelParams
    covariance_dt_s: float
    accel_update_dt_s: float
    modes: dict[str, str] = field(default_factory=dict)


def kernel_setup(inputs: ReplayInputs, config: EstimatorConfig, options: ThreeStageOptions) -> KernelSetup:
    """State tables, initial values and kernel parameters of one run (modes from the sensor plan,
    docs/three_stage.md, 'Missing sensors')."""
    plan, align, noise = inputs.plan, inputs.alignment, config.noise
    fixed_wing_nav = plan.fixed_wing and plan.has_airspeed
    tables = {"stage1": stage1_states(config),
              "stage2": stage2_states(config, absolute_yaw=align.yaw_source != "none"),
              "stage3": (stage3_fixed_wing_states(config, options) if fixed_wing_nav
                         else stage3_multicopter_states(config))}
    n3 = len(tables["stage3"])
    accel_var = stage1_accel_variance(config, options)
    variance_floor = np.zeros(len(records.SENSOR_NAMES))
    variance_floor[MAG] = options.mag_sigma_floor ** 2
    variance_floor[GPS_POS] = options.gps_pos_sigma_floor_m ** 2
    variance_floor[GPS_VEL] = options.gps_vel_sigma_floor_m_s ** 2
    angle_cap = np.pi ** 2
    max_var3 = np.full(n3, 1e12)
    if fixed_wing_nav:
        max_var3[3] = angle_cap
        max_var3[I_DEVIATION:] = angle_cap
    gates = config.gates
    calibrated = config.calibrated
    gyro_bias = align.gyro_bias_rad_s if calibrated.gyro_bias_rad_s is None else calibrated.gyro_bias_rad_s
    params = KernelParams(
        gravity_m_s2=inputs.gravity_m_s2, gyro_bias_rad_s=np.asarray(gyro_bias, dtype=float),
        gyro_psd=np.full(3, noise.gyro_noise_rad_s_sqrt_hz ** 2), accel_psd=noise.accel_noise_m_s2_sqrt_hz ** 2,
        accel_var=accel_var, variance_floor=variance_floor, accel_gate=options.accel_gate,
        manoeuvre_threshold_m_s2=options.manoeuvre_threshold_m_s2,
        airspeed_model=plan.fixed_wing and plan.has_airspeed,
        gps_acceleration=options.gps_acceleration and plan.has_gps and not plan.has_airspeed,
        fixed_wing_nav=fixed_wing_nav, paper_gps_velocity=config.gps_velocity_mode == "paper",
        height_from_gps=plan.has_gps and not plan.has_baro,
        initial_height_m=-float(align.position_ned_m[2]) if plan.has_baro or plan.has_gps else math.nan,
        cascade_inflation=options.cascade_inflation,
        qc1=process_noise_psd(tables["stage1"]), qc2=float(process_noise_psd(tables["stage2"])[0, 0]),
        qc3=process_noise_psd(tables["stage3"]), a3_multicopter=stage3_mc_A(),
        p1_0=initial_covariance(tables["stage1"]), p2_0=initial_covariance(tables["stage2"]),
        p3_0=initial_covariance(tables["stage3"]),
        max_var1=np.full(2, angle_cap), max_var2=np.full(1, angle_cap), max_var3=max_var3,
        mag_field_ned=np.asarray(inputs.mag_field_ned, dtype=float), mag_gate_d2=vector_gate(gates.mag, 3),
        sun_gate_d2=vector_gate(gates.sun, 2),
        gps_pos_gate=gates.gps_pos, gps_vel_gate=gates.gps_vel, airspeed_var=noise.airspeed_sigma_m_s ** 2,
        wind_pseudo_var=options.wind_pseudo_sigma_m_s ** 2, airspeed_lpf_s=options.airspeed_lpf_s,
        baro_lpf_s=options.baro_lpf_s, vertical_speed_lpf_s=options.vertical_speed_lpf_s,
        gps_acceleration_lpf_s=options.gps_acceleration_lpf_s,
        min_ground_speed_m_s=config.timing.min_ground_speed_m_s, gps_reset_after_s=config.timing.gps_reset_after_s,
        gps_outage_reset_s=config.timing.gps_outage_reset_s)
    modes = {"stage1": ("airspeed (centripetal)" if params.airspeed_model
                        else "gps_acceleration" if params.gps_acceleration else "gravity_only"),
             "stage2": "+".join(s for s, used in (("mag", plan.has_mag), ("sun", plan.has_sun)) if used)
             or "dead_reckoned",
             "stage3": ("fixed_wing" if fixed_wing_nav else "multicopter") if plan.has_gps else "none",
             "height": "baro" if plan.has_baro else "gps" if plan.has_gps else "none"}
    return KernelSetup(tables=tables, x1=np.array([align.roll_rad, align.pitch_rad]), P1=params.p1_0.copy(),
                       x2=np.array([align.yaw_rad]), P2=params.p2_0.copy(), x3=np.zeros(n3),
                       P3=params.p3_0.copy(), params=params, covariance_dt_s=1.0 / config.timing.covariance_rate_hz,
                       accel_update_dt_s=1.0 / options.accel_update_rate_hz, modes=modes)


def stage1_accel_variance(config: EstimatorConfig, options: ThreeStageOptions) -> np.ndarray:
    """Stage-1 accelerometer variance per body axis at the update rate [(m/s^2)^2]: the calibrated per-axis
    density (eq 51) or the isotropic one, times the update rate, floored by the model error, times eq 52's tau on
    body y (docs/three_stage.md, 'Stage 1: roll and pitch')."""
    calibrated = config.calibrated
    density = (np.asarray(calibrated.accel_axis_density, dtype=float) if calibrated.accel_axis_density is not None
               else np.full(3, config.noise.accel_noise_m_s2_sqrt_hz))
    floor = (options.accel_sigma_floor_m_s2 if calibrated.accel_stage1_floor_m_s2 is None
             else calibrated.accel_stage1_floor_m_s2)
    variance = np.maximum(density ** 2 * options.accel_update_rate_hz, floor ** 2)
    variance[1] *= calibrated.accel_tau
    return variance


def vector_gate(gate_sigma: float, n_components: int) -> float:
    """Chi-square threshold on ``nu^T S^-1 nu`` of an ``n_components`` vector with the same false-rejection
    probability as the scalar gate ``|nu| / sqrt(S) > gate_sigma`` (docs/three_stage.md, 'Stage 2: heading'); inf
    stays inf."""
    if not math.isfinite(gate_sigma):
        return math.inf
    # chi2.isf(chi2.sf(g^2, 1), n) from scipy.special (scipy.stats costs the CLI most of a second to import)
    return float(chdtri(n_components, chdtrc(1, gate_sigma ** 2)))


def diagnostics_capacity(ev: records.MeasurementEvents, imu_duration_s: float, options: ThreeStageOptions) -> int:
    """Upper bound of the number of scalar updates of a run."""
    per_kind = np.zeros(len(records.SENSOR_NAMES), dtype=np.int64)
    per_kind[GPS_POS] = 4  # wind pseudo (2) + north, east
    per_kind[GPS_VEL] = 2
    per_kind[MAG] = 3
    per_kind[SUN] = 2
    n_accel = 3 * (int(imu_duration_s * options.accel_update_rate_hz) + 2)
    return int(per_kind[ev.kind].sum()) + n_accel


def run(flight_log: FlightLog, inputs: ReplayInputs, config: EstimatorConfig, *,
        options: ThreeStageOptions | None = None) -> EstimatorRun:
    """Run the three-stage estimator on prepared inputs (the registry entry of :mod:`estimators.api`).

    Parameters
    ----------
    flight_log : FlightLog
        The log (unused beyond ``inputs``; part of the common estimator signature).
    inputs : ReplayInputs
        From :func:`estimators.inputs.build.build_replay_inputs` (heading sources, output epochs, alignment).
    config : EstimatorConfig
        Shared noise, gates, initial sigmas and timing.
    options : ThreeStageOptions, optional
        Settings of this estimator (defaults when None).

    Returns
    -------
    EstimatorRun
        States at the output epochs (NaN position/velocity before stage 3 starts and without GPS; wind only in
        fixed-wing mode), one diagnostics row per scalar update, and the report (modes, resets, timings).
    """
    del flight_log
    options = ThreeStageOptions() if options is None else options
    started = time.perf_counter()
    setup = kernel_setup(inputs, config, options)
    ev, imu = inputs.events, inputs.imu
    out = np.full((ev.count(OUTPUT), len(OUT_COLUMNS)), np.nan)
    capacity = diagnostics_capacity(ev, float(imu.time_s[-1] - imu.time_s[0]), options)
    diag_f, diag_i = recorder.diagnostics_arrays(capacity)
    counters = np.zeros(N_COUNTERS, dtype=np.int64)
    x1, P1, x2, P2 = setup.x1.copy(), setup.P1.copy(), setup.x2.copy(), setup.P2.copy()
    x3, P3 = setup.x3.copy(), setup.P3.copy()
    schedule_started = time.perf_counter()
    op, op_value, op_index = build_schedule(imu.time_s, ev.time_s, ev.kind, ev.imu_index, setup.covariance_dt_s,
                                            setup.accel_update_dt_s, fused_kinds=FUSED_KINDS)
    kernel_started = time.perf_counter()
    accel = imu.accel_m_s2
    if config.calibrated.accel_bias_m_s2 is not None:  # no bias states: the calibrated bias is removed up front
        accel = accel - np.asarray(config.calibrated.accel_bias_m_s2, dtype=float)
    run_kernel(op, op_value, op_index, imu.time_s, imu.gyro_rad_s, accel, ev.kind, ev.values, ev.variances,
               setup.params, x1, P1, x2, P2, x3, P3, out, diag_f, diag_i, counters)
    kernel_s = time.perf_counter() - kernel_started
    o = out[:counters[C_OUTPUTS]]
    plan = inputs.plan
    deg = np.degrees
    std = {"roll_deg_std": deg(o[:, O_ROLL_STD]), "pitch_deg_std": deg(o[:, O_PITCH_STD]),
           "yaw_deg_std": deg(o[:, O_YAW_STD]), "pos_n_m_std": o[:, O_PN_STD], "pos_e_m_std": o[:, O_PE_STD],
           "vn_m_s_std": o[:, O_VN_STD], "ve_m_s_std": o[:, O_VE_STD], "wind_n_m_s_std": o[:, O_WN_STD],
           "wind_e_m_s_std": o[:, O_WE_STD]}
    states = states_frame(o[:, O_TIME], o[:, O_ROLL], o[:, O_PITCH], o[:, O_YAW], o[:, O_PN:O_PD + 1],
                          o[:, O_VN:O_VD + 1], o[:, O_WN:O_WE + 1], inputs.origin, std=std,
                          navigation=plan.has_gps, wind=setup.params.fixed_wing_nav)
    warnings = []
    if counters[C_PITCH_GUARD]:
        warnings.append(f"{counters[C_PITCH_GUARD]} attitude updates skipped at |pitch| > 85 deg")
    if counters[C_HEADING_RESETS]:
        warnings.append(f"heading re-acquired {counters[C_HEADING_RESETS]} times (every heading vector rejected "
                        f"for {config.timing.gps_reset_after_s:g} s)")
    navigating = np.isfinite(o[:, O_PN])
    details = {
        "modes": setup.modes,
        "states": {stage: [s.name for s in table] for stage, table in setup.tables.items()},
        "final_state": {"stage1": x1.tolist(), "stage2": x2.tolist(), "stage3": x3.tolist()},
        "gyro_bias_rad_s": setup.params.gyro_bias_rad_s.tolist(),
        "stage3_start_s": float(o[navigating, O_TIME][0]) if navigating.any() else None,
        "heading_resets": int(counters[C_HEADING_RESETS]),
        "accel_update_rate_hz": options.accel_update_rate_hz,
        FIGURES.accel_tau.name: config.calibrated.accel_tau,
        "accel_variance_m2_s4": setup.params.accel_var.tolist(),
        "accel_bias_removed_m_s2": (None if config.calibrated.accel_bias_m_s2 is None
                                    else list(config.calibrated.accel_bias_m_s2)),
        **replay_details(inputs),
    }
    unused = {name: NOT_IN_THREE_STAGE for name in UNUSED_SENSORS if name in plan.used}
    report = kernel_report(NAME, inputs, counters, diverged="a stage", warnings=warnings, details=details,
                           used=tuple(s for s in plan.used if s not in unused), skipped={**plan.skipped, **unused},
                           timings_s={"schedule": kernel_started - schedule_started, "kernel": kernel_s,
                                      "total": time.perf_counter() - started})
    return EstimatorRun(states=states, diagnostics=diagnostics_frame(diag_f, diag_i, int(counters[C_DIAG])),
                        report=report)
