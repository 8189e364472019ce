"""Three-stage series estimator (paper section 3.1 and Algorithm 1; math note section 3, degraded modes section 7).

Three small EKFs in series, each feeding the next its estimate as an input (models in
:mod:`estimators.three_stage.model`, the EKF algebra in :mod:`estimators.core.linalg`):

1. **Roll and pitch** ``x1 = (phi, theta)`` [rad], propagated with the bias-corrected gyro (bias from the still
   window at the start, math note 3.0; no bias states), updated with the accelerometer: three sequential scalar
   updates, re-linearised after each (Algorithm 1), at ``accel_update_rate_hz`` (the paper's 50 Hz estimator rate)
   with the specific force and the rates averaged over the update interval. Fixed-wing with airspeed: the steady
   flight model with the centripetal term (eq 20/21 corrected); otherwise gravity only (``V_a = 0``) or, with
   ``gps_acceleration``, ``h = C_bn (a_n - g_n)`` with the low-passed derivative of the GPS velocity (math note
   7.1). R: the accelerometer density of the config at the update rate (floored: it must cover model error), eq
   52's ``tau`` on the body-y entry, plus ``d^2`` when the specific-force magnitude misses the model by
   ``d > manoeuvre_threshold_m_s2``.
2. **Heading** ``x2 = psi_2`` [rad], propagated with ``psi_dot = (q s_ph + r c_ph) / c_th`` (eq 22 corrected),
   updated with the magnetometer (unit vector against the unit World Magnetic Model field, eq 24/25 corrected)
   and/or the photocell sun vector (tangent-plane form of math note 8.5), whichever the replay inputs carry
   (``heading="mag"|"sun"|"mag+sun"`` of :func:`estimators.inputs.build.build_replay_inputs`). Cascade consistency: R is
   inflated by the stage-1 covariance, ``R_eff = R + J P1 J^T`` with ``J = dh/d(phi, theta)``; the correlated
   vector is gated as a whole (chi-square) and whitened (Cholesky) before its scalar updates. Heading
   re-acquisition (the GPS rule of math note 2.3 applied to heading): when every heading vector has been gated
   out for ``timing.gps_reset_after_s``, the heading restarts at the one the measured vector implies at the
   stage-1 roll and pitch, with the alignment's variance (counted and reported).
3. **Navigation** at the GPS epochs (Algorithm 1, T31). Fixed-wing with airspeed: ``x3 = (p_n, p_e, V_g, chi,
   w_n, w_e, dev_a, dev_b, dev_c)`` (eq 26-33 corrected) driven by ``u = (V_a, q, r, phi, theta, psi_2)``, where
   the heading ``psi = psi_2 - (dev_a + dev_b sin psi_2 + dev_c cos psi_2)`` is the stage-2 heading corrected by a
   compass-deviation model [ADD: a body-fixed horizontal field error, i.e. the magnetometer's hard iron and the
   vertical field seen through stage 1's tilt error, makes the heading error a constant plus a sinusoid of the
   heading; observable through the wind triangle in turns, like B&M's psi state, math note 3.3 / 7.2; zero sigmas
   give the paper's 6 states]; the reported yaw is that corrected heading while this stage runs. Per GPS epoch the
   wind-triangle pseudo-measurement (``R = J diag(sigma_Va^2, P_psi) J^T + sigma_w^2 I``, whitened, ungated), then
   GPS north, east, then velocity (NED form, or ground speed and course with ``gps_velocity_mode="paper"``). It
   starts at the first GPS epoch with a ground speed above V_min (the model is invalid on the ground and in the
   hand launch): position, velocity and wind are NaN before. Otherwise (multicopter, or no airspeed):
   ``x3 = (p_n, p_e, v_n, v_e)`` driven by the NED acceleration from the accelerometer and the stage-1/2 attitude
   (math note 3.4), from the first GPS epoch; no wind. Covariances of stages 1 and 3 are propagated at
   ``timing.covariance_rate_hz`` and before their updates (states at the IMU rate).
   Height is not estimated: it is the low-passed barometer altitude (offset to GPS height removed by the replay
   inputs), or the low-passed GPS height without a barometer (math note 7.4); the vertical speed is the low-passed
   rate of that filter. The airspeed input is the low-passed true airspeed (math note 3.0).

Filter quantities per stage (kernel arrays): ``x`` state, ``P`` covariance (prior before, posterior after each
scalar update), innovation ``nu``, its variance ``S``, ``NIS = nu^2 / S``. Every scalar update is a diagnostics
row; the sensors are the shared event kinds plus ``accel`` (stage 1) and ``wind`` (the pseudo-measurement). The
innovations of whitened vector updates (magnetometer, sun, wind) are in whitened units (R = 1).

There is no separate NumPy twin: run with ``NUMBA_DISABLE_JIT=1`` (a fresh process), the same code is the plain
Python/NumPy reference the twin test compares the compiled kernel with.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit
from scipy.stats import chi2

from estimators.config import EstimatorConfig
from estimators.core import linalg, reacquisition, recorder, rotations
from estimators.core.recorder import C_DIAG, C_GPS_RESETS, C_OUTPUTS, C_REPAIRS, C_RESETS, C_UPDATES, N_SHARED_COUNTERS
from estimators.core.results import (
    ACCEL,
    WIND,
    EstimatorRun,
    diagnostics_frame,
    kernel_report,
    replay_details,
    states_frame,
)
from estimators.core.state_table import StateSpec, initial_covariance, process_noise_psd
from estimators.inputs import records
from estimators.inputs.records import AIRSPEED, BARO, GPS_POS, GPS_VEL, MAG, OUTPUT, SUN, ReplayInputs
from estimators.sun.measurement import sun_tangent_basis
from estimators.three_stage.model import (
    I_DEVIATION,
    corrected_heading,
    euler_yaw_rate,
    ned_acceleration,
    stage1_A,
    stage1_G,
    stage1_h_acceleration,
    stage1_h_airspeed,
    stage1_rates,
    stage2_G,
    stage2_h,
    stage3_fw_h_gps_velocity,
    stage3_fw_h_wind,
    stage3_fw_jacobians,
    stage3_fw_rates,
    stage3_fw_wind_input_jacobian,
    stage3_mc_A,
    stage3_mc_f,
)
from ingest.flightlog import FlightLog

NAME = "three_stage"

#: Event kinds the replay inputs may carry that this estimator does not use (fixed-wing sideslip and no-GPS
#: zero-velocity pseudo-measurements of the full-state filters).
UNUSED_SENSORS = ("sideslip", "zero_velocity")
#: Columns of the kernel's output array (angles [rad], positions [m], speeds [m/s]; ``*_std`` 1-sigma).
OUT_COLUMNS = ("time_s", "roll", "pitch", "yaw", "pn", "pe", "pd", "vn", "ve", "vd", "wn", "we",
               "roll_std", "pitch_std", "yaw_std", "pn_std", "pe_std", "vn_std", "ve_std", "wn_std", "we_std")
(O_TIME, O_ROLL, O_PITCH, O_YAW, O_PN, O_PE, O_PD, O_VN, O_VE, O_VD, O_WN, O_WE, O_ROLL_STD, O_PITCH_STD, O_YAW_STD,
 O_PN_STD, O_PE_STD, O_VN_STD, O_VE_STD, O_WN_STD, O_WE_STD) = range(len(OUT_COLUMNS))

# kernel counters: the shared slots of ekf_core (C_DIAG .. C_OUTPUTS), then this filter's
#: Horizontal part of a unit vector below which it gives no heading (:func:`measured_heading`).
MIN_HORIZONTAL = 0.2
C_PITCH_GUARD = N_SHARED_COUNTERS
C_HEADING_RESETS = N_SHARED_COUNTERS + 1  # stage-2 heading re-acquisitions
N_COUNTERS = N_SHARED_COUNTERS + 2

#: Attitude updates are skipped beyond this pitch (Euler singularity, math note 7.6) [rad].
PITCH_GUARD_RAD = math.radians(85.0)
#: An airspeed or GPS value older than this is stale: no centripetal term, no wind pseudo, no GPS acceleration [s].
STALE_AFTER_S = 1.0
#: Correlation time of the airspeed and stage-2 heading errors entering stage 3 as inputs [s].
INPUT_CORRELATION_S = 1.0
#: Variance limits of the covariance repair; angle standard deviations are capped at 180 deg (math note 7.2).
MIN_VARIANCE = 1e-12
EIG_FLOOR = 1e-12
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
    accel_tau : float
        Eq 52 penalty factor on the body-y accelerometer variance [-] (1: none; ``calib.tau`` selects it).
    accel_sigma_floor_m_s2, mag_sigma_floor, gps_pos_sigma_floor_m, gps_vel_sigma_floor_m_s : float
        Floors of the measurement noise [m/s^2 at the update rate, field units, m, m/s]: with no bias states the
        three-stage R must cover model error (accelerometer and magnetometer biases, unmodelled accelerations, the
        GPS velocity lag of the coordinated-turn model; math note 3.1 "R must cover MODEL error", 3.3 floors
        0.5 m / 0.1 m/s), whatever the sensor noise of the configuration. Defaults: the paper's in-flight
        accelerometer noise at 50 Hz (Table 4, up to 0.25 m/s^2), the unit-vector range of math note 3.2.
    accel_gate : float
        Stage-1 gate in innovation standard deviations (math note 3.1: 3..5).
    manoeuvre_threshold_m_s2 : float
        ``| |f_m| - |h(x)| |`` above which the squared mismatch is added to the accelerometer variance [m/s^2]
        (math note 3.1: 0.5..1).
    gps_acceleration : bool
        Without airspeed: stage 1 uses ``h = C_bn (a_n - g_n)`` with the GPS-derived acceleration instead of
        gravity only (math note 7.1).
    cascade_inflation : bool
        Inflate the stage-2 R by the stage-1 covariance (math note 3.2).
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
    accel_tau: float = 1.0
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
        for name in ("accel_update_rate_hz", "accel_tau", "accel_gate", "airspeed_lpf_s", "baro_lpf_s",
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
    """Stage 3, fixed-wing mode (math note 3.3); wind walk from ``config.noise.wind_rw_m_s_sqrt_s``; the heading
    bias of stage 2 from ``options``."""
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
    """Stage 3, multicopter / no-airspeed mode (math note 3.4)."""
    ini = config.initial
    return (StateSpec("pn_m", "m", ini.position_m, POSITION_RW_M_SQRT_S),
            StateSpec("pe_m", "m", ini.position_m, POSITION_RW_M_SQRT_S),
            StateSpec("vn_m_s", "m/s", ini.velocity_m_s, VELOCITY_RW_M_S_SQRT_S),
            StateSpec("ve_m_s", "m/s", ini.velocity_m_s, VELOCITY_RW_M_S_SQRT_S))


class KernelParams(NamedTuple):
    """Scalars and small arrays of one run, read by the compiled kernel (units in the names)."""

    gravity_m_s2: float
    gyro_bias_rad_s: np.ndarray  # (3,) removed from every gyro row
    gyro_psd: np.ndarray  # (3,) gyro noise density squared per axis [rad^2/s]
    accel_psd: float  # accelerometer noise density squared [m^2/s^3]
    accel_var: np.ndarray  # (3,) stage-1 R per axis at the update rate [m^2/s^4], tau on y
    variance_floor: np.ndarray  # (n_kinds,) model-error floor of each event kind's variances
    accel_update_dt_s: float
    covariance_dt_s: float  # interval of the deferred stage-1 and stage-3 covariance propagation [s]
    accel_gate: float
    manoeuvre_threshold_m_s2: float
    airspeed_model: bool  # stage 1 steady-flight model with airspeed (fixed-wing with airspeed)
    gps_acceleration: bool  # stage 1 acceleration form (without airspeed)
    fixed_wing_nav: bool  # stage 3 fixed-wing mode
    paper_gps_velocity: bool  # GPS velocity as ground speed and course
    height_from_gps: bool  # no barometer: height from GPS
    initial_height_m: float  # height above the origin until the first height sample (NaN: no height source)
    cascade_inflation: bool
    qc1: np.ndarray  # (2, 2) random-walk densities [rad^2/s]
    qc2: float
    qc3: np.ndarray  # (n3, n3)
    a3_multicopter: np.ndarray  # (4, 4) constant Jacobian of the multicopter navigation model
    p1_0: np.ndarray
    p2_0: np.ndarray
    p3_0: np.ndarray
    max_var1: np.ndarray
    max_var2: np.ndarray
    max_var3: np.ndarray
    mag_field_ned: np.ndarray  # (3,) unit
    mag_gate_d2: float  # chi-square threshold of the 3-component magnetometer vector
    sun_gate_d2: float  # chi-square threshold of the 2-component sun vector
    gps_pos_gate: float
    gps_vel_gate: float
    airspeed_var: float  # [m^2/s^2]
    wind_pseudo_var: float  # [m^2/s^2]
    airspeed_lpf_s: float
    baro_lpf_s: float
    vertical_speed_lpf_s: float
    gps_acceleration_lpf_s: float
    min_ground_speed_m_s: float
    gps_reset_after_s: float  # T_rej of math note 2.3 [s]
    gps_outage_reset_s: float  # T_out of math note 2.3 [s]


# ----------------------------------------------------------------------------------------------------------------
# stage steps (numba)
#
# The steps called per sample or per update are inline="always": a non-inlined numba call that branches keeps a
# reference-count pair per array argument (and per array in a tuple argument), which costs more than these small
# computations.


class StageWork(NamedTuple):
    """Preallocated work arrays of one stage with ``n`` states: the kernel loop allocates nothing per sample."""

    A: np.ndarray  # (n, n) continuous Jacobian df/dx
    G: np.ndarray  # (n, n_inputs) input-noise Jacobian df/du
    F: np.ndarray  # (n, n) transition matrix
    Q: np.ndarray  # (n, n) discrete process noise
    W: np.ndarray  # (n, n) scratch of the covariance propagation and repair
    u: np.ndarray  # (n_u,) mean inputs of a deferred covariance propagation
    input_var: np.ndarray  # (n_inputs,) variances of the inputs in G
    H: np.ndarray  # (3, n) measurement Jacobian rows (whitened in place by vector updates)
    dx: np.ndarray  # (n,) correction of a scalar update
    ph: np.ndarray  # (n,) P H^T scratch
    min_var: np.ndarray  # (n,) variance floor of the covariance repair


class MeasurementWork(NamedTuple):
    """Preallocated work arrays of the measurement models and vector updates (up to 3 components)."""

    h: np.ndarray  # (3,) predicted measurement
    jac: np.ndarray  # (3, 3) dh/d(phi, theta, psi)
    c: np.ndarray  # (3, 2) stage-1 dh/d(phi, theta) of the airspeed model
    z: np.ndarray  # (3,) measured unit vector
    tilt: np.ndarray  # (3, 2) dh/d(phi, theta) of a heading update (cascade inflation)
    nu: np.ndarray  # (3, 1) innovation (whitened in place)
    R: np.ndarray  # (3, 3) measurement noise
    L: np.ndarray  # (3, 3) Cholesky factor
    S: np.ndarray  # (3, 3) whitened innovation covariance
    y: np.ndarray  # (3, 1) S-whitened innovation
    mean: np.ndarray  # (8,) inputs averaged over the accelerometer update interval
    no_accel: np.ndarray  # (3,) zero NED acceleration (gravity-only stage-1 model)


@njit(cache=True)
def _stage_work(n, n_inputs, n_u):
    """Work arrays of a stage with ``n`` states, ``n_inputs`` noisy inputs and ``n_u`` model inputs."""
    return StageWork(np.zeros((n, n)), np.zeros((n, n_inputs)), np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n)),
                     np.zeros(n_u), np.zeros(n_inputs), np.zeros((3, n)), np.zeros(n),
                     np.zeros(n), np.full(n, MIN_VARIANCE))


@njit(cache=True)
def _measurement_work():
    """Work arrays of the measurement updates."""
    return MeasurementWork(np.zeros(3), np.zeros((3, 3)), np.zeros((3, 2)), np.zeros(3), np.zeros((3, 2)),
                           np.zeros((3, 1)), np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 1)),
                           np.zeros(8), np.zeros(3))


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
def _sandwich(J, P, m, out):
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
def _quadratic_form(v, P, first):
    """``v^T P[first:, first:] v`` for a short tuple ``v``."""
    s = 0.0
    for a in range(len(v)):
        for b in range(len(v)):
            s += v[a] * P[first + a, first + b] * v[b]
    return s


@njit(cache=True, inline="always")
def _forward_solve(L, B, m):
    """``B[:m] <- L^-1 B[:m]`` in place for the lower-triangular ``L[:m, :m]`` and ``B`` (>= m, k)."""
    k = B.shape[1]
    for i in range(m):
        for j in range(i):
            for c in range(k):
                B[i, c] -= L[i, j] * B[j, c]
        for c in range(k):
            B[i, c] /= L[i, i]


@njit(cache=True, inline="always")
def _cholesky_lower(M, m, L):
    """Lower Cholesky factor of ``M[:m, :m]`` into ``L`` (NaN when it is not positive definite)."""
    if not linalg.cholesky_lower(M, L, m, 0.0):
        L[:m, :m] = math.nan


@njit(cache=True, inline="always")
def _propagate_states(dt, rates, f_b, va, prm, x1, x2, P2, x3, stage3_on):
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
def _accumulate(acc, dt, rates, f_b, va):
    """Sum the inputs of an interval for a deferred covariance propagation: (dt, omega dt, f dt, V_a dt)."""
    linalg.accumulate_inputs(acc, dt, rates, f_b)
    acc[7] += va * dt


@njit(cache=True, inline="always")
def _flush_stage1(acc, x1_start, P1, prm, A, G, F, Q, W, rates):
    """Stage-1 covariance over the accumulated interval: F from the interval-start state and the mean rates,
    Q = G N_g^2 G^T dt + Qc dt (math note 2.2). The work arrays of the stage are passed one by one: passing the
    work tuple costs a reference-count pair per member."""
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
    linalg.propagate_covariance(P1, F, Q, W)
    acc[:] = 0.0


@njit(cache=True, inline="always")
def _flush_stage3(acc, x3_start, attitude_start, P1, P2, P3, prm, A, G, F, Q, W, u, input_var):
    """Stage-3 covariance over the accumulated interval, from the interval-start state and attitude
    (phi, theta, psi_2) and the mean inputs (work arrays one by one, as in :func:`_flush_stage1`)."""
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
        # time INPUT_CORRELATION_S have the low-frequency density 2 sigma^2 T (math note 3.3)
        input_var[0], input_var[1] = prm.airspeed_var, P2[0, 0]
        _add_input_noise(G, input_var, 2.0 * INPUT_CORRELATION_S * dt, Q)
    else:
        linalg.transition_matrix(prm.a3_multicopter, dt, F)
        # accelerometer density (rotation-invariant) plus the tilt error g * delta (math note 3.4)
        velocity_var = prm.accel_psd * dt + prm.gravity_m_s2 ** 2 * max(P1[0, 0], P1[1, 1]) * dt * dt
        Q[2, 2] += velocity_var
        Q[3, 3] += velocity_var
    linalg.propagate_covariance(P3, F, Q, W)
    acc[:] = 0.0


@njit(cache=True)
def _record(diag_f, diag_i, counters, t, sensor, component, nu, s_var, nis, accepted):
    counters[C_UPDATES] += 1
    recorder.record_update(diag_f, diag_i, counters, t, sensor, component, nu, s_var, nis, accepted)


@njit(cache=True, inline="always")
def _stage1_model(x1, yaw_rad, rates, va, accel_n, airspeed_model, gravity_m_s2, h, c, jac):
    """Stage-1 accelerometer model into ``h`` (3,) and dh/d(phi, theta) into ``c`` (3, 2): steady flight with
    airspeed, else the acceleration form (``jac`` (3, 3) scratch)."""
    if airspeed_model:
        stage1_h_airspeed(x1, rates, va, gravity_m_s2, h, c)
    else:
        _, c_tilt = stage1_h_acceleration(x1, yaw_rad, accel_n, gravity_m_s2, h, jac)
        c[:, :] = c_tilt


@njit(cache=True, inline="always")
def _stage1_update(t, f_mean, rates_mean, va, accel_n, prm, x1, P1, x2, w, mw, diag_f, diag_i, counters):
    """Three sequential scalar accelerometer updates, re-linearised after each (Algorithm 1, stage 1)."""
    h, c = mw.h, mw.c
    _stage1_model(x1, x2[0], rates_mean, va, accel_n, prm.airspeed_model, prm.gravity_m_s2, h, c, mw.jac)
    mismatch = abs(math.sqrt(f_mean[0] ** 2 + f_mean[1] ** 2 + f_mean[2] ** 2)
                   - math.sqrt(h[0] ** 2 + h[1] ** 2 + h[2] ** 2))
    extra_var = mismatch * mismatch if mismatch > prm.manoeuvre_threshold_m_s2 else 0.0
    for axis in range(3):
        nu = f_mean[axis] - h[axis]
        accepted, s_var, nis = linalg.scalar_update(P1, c[axis], nu, prm.accel_var[axis] + extra_var,
                                                      prm.accel_gate, w.dx, w.ph)
        _record(diag_f, diag_i, counters, t, ACCEL, axis, nu, s_var, nis, accepted)
        if accepted:
            x1 += w.dx
            _stage1_model(x1, x2[0], rates_mean, va, accel_n, prm.airspeed_model, prm.gravity_m_s2, h, c,
                          mw.jac)  # re-linearise


@njit(cache=True, inline="always")
def _whitened_update(t, sensor, x, P, m, nu, H, R, gate_d2, w, mw, diag_f, diag_i, counters):
    """A vector measurement with correlated noise R, gated as a whole, then whitened and fused component-wise.

    ``nu`` (>= m, 1), ``H`` (>= m, n) and ``R`` (>= m, >= m) hold the ``m`` components; ``nu`` and ``H`` are
    whitened in place. Gate: the vector is rejected when ``nu^T S^-1 nu > gate_d2`` with ``S = H P H^T + R`` (a
    chi-square threshold for ``m`` components). Fusion: with ``R = L L^T``, ``nu' = L^-1 nu``, ``H' = L^-1 H`` and
    ``R' = I``, one scalar update per component; later components are corrected linearly, so the result equals the
    batch update. Returns whether the vector passed the gate.
    """
    L, S, y = mw.L, mw.S, mw.y
    _cholesky_lower(R, m, L)
    _forward_solve(L, nu, m)
    _forward_solve(L, H, m)
    # whole-vector Mahalanobis distance in whitened coordinates: S' = H' P H'^T + I
    _sandwich(H, P, m, S)
    for i in range(m):
        S[i, i] += 1.0
    _cholesky_lower(S, m, L)
    y[:m] = nu[:m]
    _forward_solve(L, y, m)
    d2 = 0.0
    for i in range(m):
        d2 += y[i, 0] * y[i, 0]
    if not d2 <= gate_d2:
        for i in range(m):
            _record(diag_f, diag_i, counters, t, sensor, i, nu[i, 0], S[i, i], nu[i, 0] ** 2 / S[i, i], False)
        return False
    for i in range(m):
        accepted, s_var, nis = linalg.scalar_update(P, H[i], nu[i, 0], 1.0, math.inf, w.dx, w.ph)
        _record(diag_f, diag_i, counters, t, sensor, i, nu[i, 0], s_var, nis, accepted)
        if accepted:
            x += w.dx
            for j in range(i + 1, m):
                for c in range(x.shape[0]):
                    nu[j, 0] -= H[j, c] * w.dx[c]
    return True


@njit(cache=True, inline="always")
def _stage2_update(t, kind, values, variances, prm, x1, P1, x2, P2, w, mw, diag_f, diag_i, counters):
    """Heading update from a body-frame unit vector: magnetometer (3 components) or sun (2 tangent components).

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
        z[:] = values[:3]
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
        # 2-DOF tangent-plane form (math note 8.5): nu = T^T z, H = T^T C, R = sigma^2 I_2
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
        _sandwich(J, P1, m, R)
    else:
        R[:m, :m] = 0.0
    for i in range(m):
        R[i, i] += variances[0]
    heading = measured_heading(z, ref, x1[0], x1[1])
    gated = _whitened_update(t, kind, x2, P2, m, nu, H, R, gate_d2, w, mw, diag_f, diag_i, counters)
    x2[0] = rotations.wrap_pi(x2[0])
    return gated, heading


@njit(cache=True)
def measured_heading(z_body, ref_ned, phi, theta):
    """Heading [rad] at which the body-frame unit vector ``z_body`` points along the reference ``ref_ned`` in
    azimuth, at roll ``phi`` and pitch ``theta`` [rad]: with the levelled vector ``l = R_y(theta) R_x(phi) z`` and
    ``R_nb = R_z(psi) R_y R_x``, the reference azimuth is ``psi + azimuth(l)``. NaN when either has no horizontal
    component to speak of."""
    cph, sph, cth, sth = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta)
    level_n = cth * z_body[0] + sth * (sph * z_body[1] + cph * z_body[2])
    level_e = cph * z_body[1] - sph * z_body[2]
    if math.hypot(level_n, level_e) < MIN_HORIZONTAL or math.hypot(ref_ned[0], ref_ned[1]) < MIN_HORIZONTAL:
        return math.nan
    return rotations.wrap_pi(math.atan2(ref_ned[1], ref_ned[0]) - math.atan2(level_e, level_n))


@njit(cache=True)
def _stage3_fw_wind(t, va, vd_gps, prm, x2, P2, x3, P3, w, mw, diag_f, diag_i, counters):
    """Wind-triangle pseudo-measurement z = (0, 0) (eq 31-33 corrected), ungated."""
    vah = math.sqrt(max(va * va - vd_gps * vd_gps, 0.0))
    h, c = stage3_fw_h_wind(x3, vah, x2[0])
    for i in range(2):
        mw.nu[i, 0] = -h[i]
        w.H[i, :] = c[i]
    R = mw.R
    R[:2, :2] = 0.0
    w.input_var[0], w.input_var[1] = prm.airspeed_var, P2[0, 0]
    _add_input_noise(stage3_fw_wind_input_jacobian(x3, vah, x2[0]), w.input_var, 1.0, R)
    R[0, 0] += prm.wind_pseudo_var
    R[1, 1] += prm.wind_pseudo_var
    _whitened_update(t, WIND, x3, P3, 2, mw.nu, w.H, R, math.inf, w, mw, diag_f, diag_i, counters)
    x3[3] = rotations.wrap_pi(x3[3])


@njit(cache=True)
def _stage3_gps_velocity(t, values, variances, prm, x3, P3, w, gps_mon, diag_f, diag_i, counters):
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
                r_var = 0.5 * (variances[0] + variances[1]) / (speed * speed)  # eq 9 corrected (T5)
            accepted, s_var, nis = linalg.scalar_update(P3, H, nu, r_var, prm.gps_vel_gate, w.dx, w.ph)
            _record(diag_f, diag_i, counters, t, GPS_VEL, 3 + comp, nu, s_var, nis, accepted)
            reacquisition.gps_record(gps_mon, False, comp, t, accepted)
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
        _record(diag_f, diag_i, counters, t, GPS_VEL, comp, nu, s_var, nis, accepted)
        reacquisition.gps_record(gps_mon, False, comp, t, accepted)
        if accepted:
            x3 += w.dx
            if prm.fixed_wing_nav:
                x3[3] = rotations.wrap_pi(x3[3])


@njit(cache=True)
def _stage3_init_velocity(values, variances, prm, x3, P3):
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


@njit(cache=True)
def _lowpass(value, sample, dt, tau):
    """One step of a first-order low-pass with time constant ``tau`` over ``dt`` (exact for a held sample)."""
    return value + (1.0 - math.exp(-dt / tau)) * (sample - value)


@njit(cache=True, inline="always")
def _output_row(t, x1, P1, x2, P2, x3, P3, stage3_on, fixed_wing_nav, height, vertical_speed, row):
    row[:] = math.nan
    row[O_TIME] = t
    row[O_ROLL] = x1[0]
    row[O_PITCH] = x1[1]
    row[O_YAW] = x2[0]
    row[O_ROLL_STD] = math.sqrt(P1[0, 0])
    row[O_PITCH_STD] = math.sqrt(P1[1, 1])
    row[O_YAW_STD] = math.sqrt(P2[0, 0])
    row[O_PD] = -height
    row[O_VD] = -vertical_speed
    if not stage3_on:
        return
    row[O_PN] = x3[0]
    row[O_PE] = x3[1]
    row[O_PN_STD] = math.sqrt(P3[0, 0])
    row[O_PE_STD] = math.sqrt(P3[1, 1])
    if fixed_wing_nav:
        # heading corrected by the stage-3 deviation estimate (its correlation with stage 2 is not tracked)
        psi, _, dpsi_ddev = corrected_heading(x3, x2[0])
        row[O_YAW] = rotations.wrap_pi(psi)
        row[O_YAW_STD] = math.sqrt(P2[0, 0] + _quadratic_form(dpsi_ddev, P3, I_DEVIATION))
        c, s, vg = math.cos(x3[3]), math.sin(x3[3]), x3[2]
        row[O_VN] = vg * c
        row[O_VE] = vg * s
        # first-order propagation of the (V_g, chi) covariance to (v_n, v_e)
        row[O_VN_STD] = math.sqrt(max(_quadratic_form((c, -vg * s), P3, 2), 0.0))
        row[O_VE_STD] = math.sqrt(max(_quadratic_form((s, vg * c), P3, 2), 0.0))
        row[O_WN] = x3[4]
        row[O_WE] = x3[5]
        row[O_WN_STD] = math.sqrt(P3[4, 4])
        row[O_WE_STD] = math.sqrt(P3[5, 5])
    else:
        row[O_VN] = x3[2]
        row[O_VE] = x3[3]
        row[O_VN_STD] = math.sqrt(P3[2, 2])
        row[O_VE_STD] = math.sqrt(P3[3, 3])


@njit(cache=True, inline="always")
def _check_health(x, P, x_safe, P0, counters):
    """Divergence reset (non-finite state or covariance -> last healthy state, initial covariance)."""
    if linalg.is_healthy(x, P):
        x_safe[:] = x
    else:
        linalg.reset_filter(x, P, x_safe, P0)
        counters[C_RESETS] += 1


@njit(cache=True, inline="always")
def _repair(P, max_var, w, counters):
    """Covariance limits and positive definiteness after measurement updates (:func:`linalg.repair_covariance`)."""
    if linalg.repair_covariance(P, w.min_var, max_var, w.W, EIG_FLOOR):
        counters[C_REPAIRS] += 1


@njit(cache=True)
def run_kernel(imu_t, imu_gyro, imu_accel, ev_t, ev_kind, ev_imu, ev_val, ev_var, prm, x1, P1, x2, P2, x3, P3,
               out, diag_f, diag_i, counters):
    """The three stages over a whole log (one compiled loop; see the module docstring).

    Parameters
    ----------
    imu_t, imu_gyro, imu_accel : ndarrays (N,), (N, 3), (N, 3)
        IMU rows (:class:`estimators.inputs.records.ImuSamples`): row k holds over ``(imu_t[k-1], imu_t[k]]``.
    ev_t, ev_kind, ev_imu, ev_val, ev_var : ndarrays
        Events (:class:`estimators.inputs.records.MeasurementEvents`).
    prm : KernelParams
    x1, P1, x2, P2 : ndarrays (2,), (2, 2), (1,), (1, 1)
        Stage 1 and 2 state and covariance, initial on entry, final on return (in place).
    x3, P3 : ndarrays (n3,), (n3, n3)
        Stage 3 state and covariance (n3 = 6 fixed-wing, 4 multicopter mode); initialised at the first GPS epoch.
    out : ndarray (K, len(OUT_COLUMNS))
        One row per OUTPUT event.
    diag_f, diag_i : ndarrays
        Diagnostics recorder arrays (:mod:`estimators.core.linalg`).
    counters : int64 (N_COUNTERS,)
    """
    n3 = x3.shape[0]
    w1, w2, w3 = _stage_work(2, 3, 3), _stage_work(1, 3, 3), _stage_work(n3, 2, 6)
    mw = _measurement_work()
    x1_safe, x2_safe, x3_safe = x1.copy(), x2.copy(), x3.copy()
    row = np.empty(out.shape[1])
    rates = np.empty(3)  # bias-corrected gyro row
    variances = np.empty(ev_var.shape[1])  # event variances raised to the model-error floor
    stage3_on = False
    # input sums (dt, omega dt, f dt, V_a dt) of the accelerometer update interval and of the deferred stage-1 and
    # stage-3 covariance propagations, with the states and attitude at the start of those intervals
    acc_meas, acc1, acc3 = np.zeros(8), np.zeros(8), np.zeros(8)
    x1_start, x3_start, attitude_start = x1.copy(), x3.copy(), np.zeros(3)
    next_accel_t = imu_t[0]
    # low-passed inputs and their sample times
    va, va_t = 0.0, -math.inf
    height, height_t = prm.initial_height_m, -math.inf
    vertical_speed = 0.0 if math.isfinite(height) else math.nan
    gps_vel, gps_vel_t = np.zeros(3), -math.inf
    gps_acc = np.zeros(3)
    gps_pos, gps_pos_var = np.zeros(2), np.zeros(2)
    gps_pos_t = -math.inf
    gps_mon = reacquisition.gps_monitor()  # re-acquisition rule (math note 2.3), armed when stage 3 starts
    heading_rejected_since = math.inf  # start of the current streak of gated-out heading vectors
    P2_reset = P2[0, 0]  # the alignment's heading variance, given to a re-acquired heading
    n_out = 0
    t = imu_t[0]
    ie = 0
    n_ev = ev_t.shape[0]
    for k in range(imu_t.shape[0]):
        for i in range(3):
            rates[i] = imu_gyro[k, i] - prm.gyro_bias_rad_s[i]
        f_b = imu_accel[k]
        while True:
            at_event = ie < n_ev and ev_imu[ie] <= k
            t_next = ev_t[ie] if at_event else imu_t[k]
            if t_next > t:
                dt = t_next - t
                va_in = va if t - va_t < STALE_AFTER_S else 0.0
                if acc1[0] == 0.0:
                    x1_start[:] = x1
                if stage3_on and acc3[0] == 0.0:
                    x3_start[:] = x3
                    attitude_start[0], attitude_start[1], attitude_start[2] = x1[0], x1[1], x2[0]
                _propagate_states(dt, rates, f_b, va_in, prm, x1, x2, P2, x3, stage3_on)
                _accumulate(acc_meas, dt, rates, f_b, va_in)
                _accumulate(acc1, dt, rates, f_b, va_in)
                if acc1[0] >= prm.covariance_dt_s:
                    _flush_stage1(acc1, x1_start, P1, prm, w1.A, w1.G, w1.F, w1.Q, w1.W, w1.u)
                if stage3_on:
                    _accumulate(acc3, dt, rates, f_b, va_in)
                    if acc3[0] >= prm.covariance_dt_s:
                        _flush_stage3(acc3, x3_start, attitude_start, P1, P2, P3, prm,
                                      w3.A, w3.G, w3.F, w3.Q, w3.W, w3.u, w3.input_var)
                t = t_next
            if not at_event:
                break
            kind = ev_kind[ie]
            values = ev_val[ie]
            for i in range(variances.shape[0]):
                variances[i] = np.maximum(ev_var[ie, i], prm.variance_floor[kind])
            if kind == OUTPUT:
                # divergence check at the output rate: never a non-finite output row (reset to the last healthy)
                _check_health(x1, P1, x1_safe, prm.p1_0, counters)
                _check_health(x2, P2, x2_safe, prm.p2_0, counters)
                if stage3_on:
                    _check_health(x3, P3, x3_safe, prm.p3_0, counters)
                _output_row(t, x1, P1, x2, P2, x3, P3, stage3_on, prm.fixed_wing_nav, height, vertical_speed, row)
                recorder.record_output(out, n_out, row)
                n_out += 1
            elif kind == AIRSPEED:
                va = values[0] if t - va_t > STALE_AFTER_S else _lowpass(va, values[0], t - va_t,
                                                                          prm.airspeed_lpf_s)
                va_t = t
            elif kind == BARO or (kind == GPS_POS and prm.height_from_gps):
                sample = values[0] if kind == BARO else -values[2]
                if height_t == -math.inf:  # first sample
                    height, vertical_speed = sample, 0.0
                else:
                    rate = (sample - height) / prm.baro_lpf_s  # rate of the first-order filter
                    height = _lowpass(height, sample, t - height_t, prm.baro_lpf_s)
                    vertical_speed = _lowpass(vertical_speed, rate, t - height_t, prm.vertical_speed_lpf_s)
                height_t = t
            if kind in (MAG, SUN):
                if abs(x1[1]) > PITCH_GUARD_RAD:
                    counters[C_PITCH_GUARD] += 1
                else:
                    gated, heading = _stage2_update(t, kind, values, variances, prm, x1, P1, x2, P2, w2, mw, diag_f,
                                                    diag_i, counters)
                    if gated:
                        heading_rejected_since = math.inf
                    elif heading_rejected_since == math.inf:
                        heading_rejected_since = t
                    elif t - heading_rejected_since >= prm.gps_reset_after_s and math.isfinite(heading):
                        # heading re-acquisition, the rule of the GPS (math note 2.3): every vector rejected for
                        # T_rej means the heading, not the sensor, is wrong; restart from the measured heading
                        x2[0] = heading
                        P2[0, 0] = P2_reset
                        heading_rejected_since = math.inf
                        counters[C_HEADING_RESETS] += 1
                    _repair(P2, prm.max_var2, w2, counters)
            elif kind == GPS_POS:
                gps_pos_t = t
                gps_pos[:] = values[:2]
                gps_pos_var[:] = variances[:2]
                _flush_stage3(acc3, x3_start, attitude_start, P1, P2, P3, prm,
                              w3.A, w3.G, w3.F, w3.Q, w3.W, w3.u, w3.input_var)
                reset, counted = False, False
                if stage3_on:
                    reset, counted = reacquisition.gps_reset_due(gps_mon, True, t, prm.gps_reset_after_s,
                                                            prm.gps_outage_reset_s)
                if reset:
                    # re-acquisition: position (and velocity, at its event) to GPS, variances to R,
                    # cross-covariances zeroed (math note 2.3)
                    for i in range(2):
                        x3[i] = values[i]
                        for j in range(n3):
                            P3[i, j] = 0.0
                            P3[j, i] = 0.0
                        P3[i, i] = variances[i]
                    if counted:
                        counters[C_GPS_RESETS] += 1
                elif stage3_on:
                    if prm.fixed_wing_nav and t - va_t < STALE_AFTER_S:
                        _stage3_fw_wind(t, va, gps_vel[2], prm, x2, P2, x3, P3, w3, mw, diag_f, diag_i, counters)
                    H3 = w3.H[0]
                    for i in range(2):
                        H3[:] = 0.0
                        H3[i] = 1.0
                        nu = values[i] - x3[i]
                        accepted, s_var, nis = linalg.scalar_update(P3, H3, nu, variances[i], prm.gps_pos_gate,
                                                                      w3.dx, w3.ph)
                        _record(diag_f, diag_i, counters, t, GPS_POS, i, nu, s_var, nis, accepted)
                        reacquisition.gps_record(gps_mon, True, i, t, accepted)
                        if accepted:
                            x3 += w3.dx
                    if prm.fixed_wing_nav:
                        x3[3] = rotations.wrap_pi(x3[3])
                    _repair(P3, prm.max_var3, w3, counters)
            elif kind == GPS_VEL:
                dt_gps = t - gps_vel_t
                if 0.0 < dt_gps < STALE_AFTER_S:
                    for i in range(3):
                        gps_acc[i] = _lowpass(gps_acc[i], (values[i] - gps_vel[i]) / dt_gps, dt_gps,
                                              prm.gps_acceleration_lpf_s)
                else:
                    gps_acc[:] = 0.0
                gps_vel[:] = values[:3]
                gps_vel_t = t
                if not stage3_on:
                    fast = math.hypot(values[0], values[1]) > prm.min_ground_speed_m_s
                    if gps_pos_t == t and (fast or not prm.fixed_wing_nav):
                        # start of stage 3 at this GPS epoch: position (from its GPS_POS event) and velocity
                        x3[:] = 0.0
                        P3[:, :] = prm.p3_0
                        for i in range(2):
                            x3[i] = gps_pos[i]
                            P3[i, i] = max(P3[i, i], gps_pos_var[i])
                        _stage3_init_velocity(values, variances, prm, x3, P3)
                        x3_safe[:] = x3
                        acc3[:] = 0.0
                        stage3_on = True
                        reacquisition.gps_acquired(gps_mon, t)
                else:
                    _flush_stage3(acc3, x3_start, attitude_start, P1, P2, P3, prm,
                                  w3.A, w3.G, w3.F, w3.Q, w3.W, w3.u, w3.input_var)
                    reset, counted = reacquisition.gps_reset_due(gps_mon, False, t, prm.gps_reset_after_s,
                                                            prm.gps_outage_reset_s)
                    if reset:
                        _stage3_init_velocity(values, variances, prm, x3, P3)
                        if counted:
                            counters[C_GPS_RESETS] += 1
                    else:
                        _stage3_gps_velocity(t, values, variances, prm, x3, P3, w3, gps_mon, diag_f, diag_i, counters)
                        _repair(P3, prm.max_var3, w3, counters)
            ie += 1
        # stage 1 at the accelerometer update rate, with the inputs averaged over the interval
        if t >= next_accel_t and acc_meas[0] > 0.0:
            if abs(x1[1]) > PITCH_GUARD_RAD:
                counters[C_PITCH_GUARD] += 1
            else:
                _flush_stage1(acc1, x1_start, P1, prm, w1.A, w1.G, w1.F, w1.Q, w1.W, w1.u)
                use_gps_acc = prm.gps_acceleration and t - gps_vel_t < STALE_AFTER_S
                accel_n = gps_acc if use_gps_acc else mw.no_accel
                mean = mw.mean
                for i in range(8):
                    mean[i] = acc_meas[i] / acc_meas[0]
                _stage1_update(t, mean[4:7], mean[1:4], mean[7], accel_n, prm, x1, P1, x2, w1, mw, diag_f, diag_i,
                               counters)
                _repair(P1, prm.max_var1, w1, counters)
            acc_meas[:] = 0.0
            next_accel_t = max(next_accel_t + prm.accel_update_dt_s, t + 0.5 * prm.accel_update_dt_s)
    counters[C_OUTPUTS] = n_out


# ----------------------------------------------------------------------------------------------------------------
# orchestration


@dataclass(frozen=True)
class KernelSetup:
    """Initial states, covariances and parameters of one run (what :func:`run_kernel` receives)."""

    tables: dict[str, tuple[StateSpec, ...]]
    x1: np.ndarray
    P1: np.ndarray
    x2: np.ndarray
    P2: np.ndarray
    x3: np.ndarray
    P3: np.ndarray
    params: KernelParams
    modes: dict[str, str] = field(default_factory=dict)


def kernel_setup(inputs: ReplayInputs, config: EstimatorConfig, options: ThreeStageOptions) -> KernelSetup:
    """State tables, initial values and kernel parameters of one run (modes from the sensor plan, math note 7)."""
    plan, align, noise = inputs.plan, inputs.alignment, config.noise
    fixed_wing_nav = plan.fixed_wing and plan.has_airspeed
    tables = {"stage1": stage1_states(config),
              "stage2": stage2_states(config, absolute_yaw=align.yaw_source != "none"),
              "stage3": (stage3_fixed_wing_states(config, options) if fixed_wing_nav
                         else stage3_multicopter_states(config))}
    n3 = len(tables["stage3"])
    accel_var = np.full(3, max(noise.accel_noise_m_s2_sqrt_hz ** 2 * options.accel_update_rate_hz,
                               options.accel_sigma_floor_m_s2 ** 2))
    accel_var[1] *= options.accel_tau
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
    params = KernelParams(
        gravity_m_s2=inputs.gravity_m_s2, gyro_bias_rad_s=np.asarray(align.gyro_bias_rad_s, dtype=float),
        gyro_psd=np.full(3, noise.gyro_noise_rad_s_sqrt_hz ** 2), accel_psd=noise.accel_noise_m_s2_sqrt_hz ** 2,
        accel_var=accel_var, variance_floor=variance_floor, accel_update_dt_s=1.0 / options.accel_update_rate_hz,
        covariance_dt_s=1.0 / config.timing.covariance_rate_hz, accel_gate=options.accel_gate,
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
                       P3=params.p3_0.copy(), params=params, modes=modes)


def vector_gate(gate_sigma: float, n_components: int) -> float:
    """Chi-square threshold on ``nu^T S^-1 nu`` of an ``n_components`` vector with the same false-rejection
    probability as the scalar gate ``|nu| / sqrt(S) > gate_sigma`` (math note 2.3); inf stays inf."""
    if not math.isfinite(gate_sigma):
        return math.inf
    return float(chi2.isf(chi2.sf(gate_sigma ** 2, 1), n_components))


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
    kernel_started = time.perf_counter()
    run_kernel(imu.time_s, imu.gyro_rad_s, imu.accel_m_s2, ev.time_s, ev.kind, ev.imu_index, ev.values,
               ev.variances, setup.params, x1, P1, x2, P2, x3, P3, out, diag_f, diag_i, counters)
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
        "accel_tau": options.accel_tau,
        **replay_details(inputs),
    }
    unused = {name: "not part of the three-stage estimator" for name in UNUSED_SENSORS if name in plan.used}
    report = kernel_report(NAME, inputs, counters, diverged="a stage", warnings=warnings, details=details,
                           used=tuple(s for s in plan.used if s not in unused), skipped={**plan.skipped, **unused},
                           timings_s={"kernel": kernel_s, "total": time.perf_counter() - started})
    return EstimatorRun(states=states, diagnostics=diagnostics_frame(diag_f, diag_i, int(counters[C_DIAG])),
                        report=report)
