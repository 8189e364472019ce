"""Sensor models of the low-cost autopilot (paper section 2, eqs 1-9 as corrected in docs/evaluation.md, Table 1).

Every grade is a frozen dataclass whose fields are documented with units. Datasheet tolerances (Table 1: offsets,
scale and cross-axis errors) are bounds, so a realisation draws each error uniformly within +/- the bound; noise
figures are per-sample standard deviations at the sensor's rate. Each model returns the measurement stream in the
canonical :mod:`ingest.flightlog` layout (indexed by ``time_s``, the publication time on the log clock) and a flat
dict of the error realisation (JSON-ready, units in the keys) so tests and calibration can compare against it.
Sensors sample the truth grid: their rates must divide the IMU rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from estimators.environment import (
    ISA_LAPSE_K_M,
    ISA_P0_PA,
    air_density_kg_m3,
    earth_field_ned_gauss,
    isa_altitude_m,
    isa_pressure_pa,
    ned_to_geodetic,
    sun_direction_ned,
)
from ingest.frames import quat_to_matrix
from sim.kinematics import Site, Truth
from sim.processes import gauss_markov, uniform_within

#: Sea-level density used by the indicated-airspeed formula [kg/m^3].
RHO_SEA_LEVEL_KG_M3 = 1.225
#: Interval of the solar-position evaluations that are interpolated to the sensor times [s].
SUN_EPHEMERIS_STEP_S = 1.0


@dataclass(frozen=True)
class ImuGrade:
    """MPU6050-class IMU (Table 1; noise and vibration from the datasheet and Table 4).

    Attributes
    ----------
    rate_hz : float
        Sample rate [Hz]; also the rate of the simulated truth.
    gyro_noise_rad_s : float
        White noise per sample [rad/s] (Table 1: 0.05 deg/s rms).
    gyro_vibration_rad_s : tuple of 3 float
        Extra white noise per axis while flying (motor vibration) [rad/s]; Table 4 in-cruise half-ranges / 3.6.
    gyro_bias_limit_rad_s : float
        Bound of the turn-on bias per axis [rad/s] (our choice: 0.5 deg/s residual after calibration; Table 1
        gives none).
    gyro_bias_walk_rad_s_sqrt_s : float
        Rate random walk of the bias [rad/s/sqrt(s)].
    gyro_scale_limit : float
        Bound of the scale-factor error per axis [-] (Table 1 nonlinearity 0.2 %).
    gyro_cross_axis_limit : float
        Bound of each cross-axis coupling [-] (Table 1: 2 %).
    accel_noise_m_s2 : float
        White noise per sample [m/s^2] (datasheet 400 ug/sqrt(Hz) over ~100 Hz).
    accel_vibration_m_s2 : tuple of 3 float
        Extra white noise per axis while flying [m/s^2]; Table 4 in-cruise half-ranges / 3.6.
    accel_bias_limit_m_s2 : tuple of 3 float
        Bound of the bias per axis [m/s^2] (Table 1 zero-g offset 50/50/80 mg).
    accel_scale_limit : float
        Bound of the scale-factor error per axis [-] (Table 1 nonlinearity 0.5 %).
    accel_cross_axis_limit : float
        Bound of each cross-axis coupling [-] (Table 1: 2 %).
    """

    rate_hz: float = 250.0
    gyro_noise_rad_s: float = float(np.radians(0.05))
    gyro_vibration_rad_s: tuple[float, float, float] = tuple(float(v) for v in np.radians((1.15, 1.64, 1.43)))
    gyro_bias_limit_rad_s: float = float(np.radians(0.5))
    gyro_bias_walk_rad_s_sqrt_s: float = 2e-5
    gyro_scale_limit: float = 0.002
    gyro_cross_axis_limit: float = 0.02
    accel_noise_m_s2: float = 0.04
    accel_vibration_m_s2: tuple[float, float, float] = (0.023, 0.0054, 0.070)
    accel_bias_limit_m_s2: tuple[float, float, float] = (0.49, 0.49, 0.78)
    accel_scale_limit: float = 0.005
    accel_cross_axis_limit: float = 0.02


@dataclass(frozen=True)
class MagGrade:
    """LSM303D-class magnetometer (Table 1) with the solar-panel current disturbance of the paper.

    Attributes
    ----------
    rate_hz : float
        Sample rate [Hz].
    noise_gauss : float
        White noise per sample [gauss].
    hard_iron_limit_gauss : float
        Bound of the residual hard-iron bias per axis after calibration [gauss] (our choice).
    scale_limit : float
        Bound of the scale-factor error per axis [-] (Table 1 nonlinearity 0.5 %).
    cross_axis_limit : float
        Bound of each cross-axis coupling [-] (Table 1: 1 %).
    solar_gauss_per_a : float
        Disturbance field per ampere of solar-panel current [gauss/A]; 0 disables it.
    solar_direction_body : tuple of 3 float
        Direction of the disturbance field in body FRD [-] (normalised).
    panel_current_max_a : float
        Panel current with the sun normal to the wing [A]; it scales with the cosine of the sun's incidence on
        the wing (body -z) and is 0 with the sun behind the wing.
    """

    rate_hz: float = 50.0
    noise_gauss: float = 0.005
    hard_iron_limit_gauss: float = 0.02
    scale_limit: float = 0.005
    cross_axis_limit: float = 0.01
    solar_gauss_per_a: float = 0.005
    solar_direction_body: tuple[float, float, float] = (0.3, 0.5, 0.81)
    panel_current_max_a: float = 4.0


@dataclass(frozen=True)
class BaroGrade:
    """MS5611-class barometer (eq. 4 with the ISA barometric formula, docs/direct.md, 'Corrections to the paper').

    Attributes
    ----------
    rate_hz : float
        Sample rate [Hz].
    noise_pa : float
        White noise per sample [Pa].
    offset_limit_pa : float
        Bound of the constant pressure offset [Pa] (Table 1 accuracy +/- 1.5 mbar).
    drift_limit_pa_s : float
        Bound of the linear drift rate of the offset [Pa/s].
    temperature_c : float
        Sensor (controller) temperature [degC], constant as in the paper's simulation.
    temperature_noise_c : float
        White noise of the temperature reading [degC].
    qnh_setting_pa : float
        Sea-level pressure the autopilot assumes for ``baro_alt_meter`` (PX4 ``SENS_BARO_QNH``) [Pa].
    """

    rate_hz: float = 50.0
    noise_pa: float = 1.5
    offset_limit_pa: float = 150.0
    drift_limit_pa_s: float = 0.02
    temperature_c: float = 25.0
    temperature_noise_c: float = 0.02
    qnh_setting_pa: float = ISA_P0_PA


@dataclass(frozen=True)
class AirspeedGrade:
    """MPXV7002-class differential-pressure airspeed sensor (eq. 5).

    Attributes
    ----------
    rate_hz : float
        Sample rate [Hz].
    noise_pa : float
        White noise per sample of the differential pressure [Pa].
    offset_limit_pa : float
        Bound of the residual offset after zeroing at power-up [Pa] (the raw +/-2.5 % V_FS is ~100 Pa, more than
        the 96 Pa dynamic pressure at 12.5 m/s: docs/evaluation.md, 'Plausibility floors').
    air_temp_noise_c : float
        White noise of the outside-air temperature reading [degC].
    """

    rate_hz: float = 20.0
    noise_pa: float = 1.0
    offset_limit_pa: float = 5.0
    air_temp_noise_c: float = 0.1


@dataclass(frozen=True)
class GpsGrade:
    """u-blox NEO-M8N-class receiver (eqs 6-9, docs/evaluation.md, 'Table 2 set-up').

    Attributes
    ----------
    rate_hz : float
        Solution rate [Hz].
    position_sigma_m : tuple of 3 float
        Steady-state std of the Gauss-Markov position error (north, east, down) [m]: 2.5 m CEP -> 2.12 m per
        horizontal axis; vertical 1.9 x horizontal (ratio of Beard & McLain's numbers).
    position_tau_s : float
        Correlation time of the position error [s] (1 / k_GPS = 1100 s, Beard & McLain).
    stationary_start : bool
        Start the position error from its stationary distribution (True) or from 0 (Beard & McLain).
    velocity_noise_m_s : float
        White noise of each NED velocity component [m/s].
    latency_s : float
        Receiver latency: ``timestamp = timestamp_sample + latency`` [s]; also the ``EKF2_GPS_DELAY`` parameter.
    time_to_first_fix_s : float
        No solution before this time after the first sample [s] (Table 1 start time 26 s).
    satellites_used : int
        Reported number of satellites.
    """

    rate_hz: float = 10.0
    position_sigma_m: tuple[float, float, float] = (2.12, 2.12, 4.04)
    position_tau_s: float = 1100.0
    stationary_start: bool = True
    velocity_noise_m_s: float = 0.05
    latency_s: float = 0.1
    time_to_first_fix_s: float = 26.0
    satellites_used: int = 12


def sample_times_us(truth: Truth, rate_hz: float, start_s: float = 0.0) -> np.ndarray:
    """A sensor's sample times [us, log clock]: every ``1 / rate_hz`` from ``start_s`` [s after the first truth
    sample] to the end of the truth (rounded to the microsecond)."""
    period_us = 1e6 / rate_hz
    span_us = truth.time_us[-1] - truth.time_us[0]
    k = np.arange(np.ceil(start_s * rate_hz - 1e-9), np.floor(span_us / period_us + 1e-9) + 1)
    return truth.time_us[0] + np.round(k * period_us).astype(np.int64)


def _frame(time_us: np.ndarray, columns: dict[str, np.ndarray]) -> pd.DataFrame:
    return pd.DataFrame(columns, index=pd.Index(time_us / 1e6, name="time_s"))


def _misalignment(scale_limit: float, cross_limit: float, rng: np.random.Generator) -> np.ndarray:
    """``I + M``: scale errors on the diagonal, cross-axis couplings off it (uniform within the bounds)."""
    matrix = uniform_within(cross_limit, rng, (3, 3))
    matrix[np.diag_indices(3)] = 1.0 + uniform_within(scale_limit, rng, (3,))
    return matrix


def _air_temperature_c(truth: Truth, site: Site) -> np.ndarray:
    return site.ground_temp_c - ISA_LAPSE_K_M * (truth.alt_m - site.ground_alt_m)


def _static_pressure_pa(truth: Truth, site: Site) -> np.ndarray:
    return isa_pressure_pa(truth.alt_m, site.sea_level_pressure_pa)


def sun_ned(truth: Truth, site: Site, time_us: np.ndarray) -> np.ndarray:
    """Unit vector towards the sun in NED at log-clock times ``time_us`` [us], shape (N, 3): NREL SPA every
    second at the true position, interpolated (the sun moves < 0.005 deg/s)."""
    coarse = truth.at(np.unique(np.append(sample_times_us(truth, 1.0 / SUN_EPHEMERIS_STEP_S), truth.time_us[-1])))
    times = pd.to_datetime(coarse.time_s + truth.utc_offset_s, unit="s", utc=True)
    s_coarse, _ = sun_direction_ned(times, coarse.lat_deg, coarse.lon_deg, coarse.alt_m,
                                    pressure_pa=_static_pressure_pa(coarse, site),
                                    temp_c=_air_temperature_c(coarse, site))
    s = np.column_stack([np.interp(time_us, coarse.time_us, s_coarse[:, axis]) for axis in range(3)])
    return s / np.linalg.norm(s, axis=1, keepdims=True)


def simulate_imu(truth: Truth, grade: ImuGrade, rng: np.random.Generator) -> tuple[pd.DataFrame, dict]:
    """Gyro and accelerometer at every truth sample: ``y = (I + M) x + b + noise (+ vibration in flight)``.

    The gyro bias starts uniform within its bound and random-walks; the accelerometer bias is constant. The
    accelerometer measures the specific force (corrected eq. 1).

    Returns
    -------
    frame : pandas.DataFrame
        Canonical ``imu`` stream with ``dt_s``.
    errors : dict
        ``gyro_bias_start_rad_s``, ``gyro_bias_end_rad_s``, ``gyro_matrix``, ``accel_bias_m_s2``,
        ``accel_matrix`` and the configured noise figures.
    """
    n = len(truth.time_us)
    dt = 1.0 / grade.rate_hz
    gyro_bias0 = uniform_within(grade.gyro_bias_limit_rad_s, rng, (3,))
    gyro_matrix = _misalignment(grade.gyro_scale_limit, grade.gyro_cross_axis_limit, rng)
    accel_bias = uniform_within(grade.accel_bias_limit_m_s2, rng)
    accel_matrix = _misalignment(grade.accel_scale_limit, grade.accel_cross_axis_limit, rng)
    walk = np.cumsum(rng.standard_normal((n, 3)) * (grade.gyro_bias_walk_rad_s_sqrt_s * np.sqrt(dt)), axis=0)
    gyro_bias = gyro_bias0 + walk - walk[0]
    flying = truth.airborne[:, None]
    gyro_sigma = np.sqrt(grade.gyro_noise_rad_s**2 + flying * np.square(grade.gyro_vibration_rad_s))
    accel_sigma = np.sqrt(grade.accel_noise_m_s2**2 + flying * np.square(grade.accel_vibration_m_s2))
    gyro = truth.rates_rad_s @ gyro_matrix.T + gyro_bias + rng.standard_normal((n, 3)) * gyro_sigma
    accel = truth.specific_force_m_s2 @ accel_matrix.T + accel_bias + rng.standard_normal((n, 3)) * accel_sigma
    frame = _frame(truth.time_us, {
        "gyro_x_rad_s": gyro[:, 0], "gyro_y_rad_s": gyro[:, 1], "gyro_z_rad_s": gyro[:, 2],
        "accel_x_m_s2": accel[:, 0], "accel_y_m_s2": accel[:, 1], "accel_z_m_s2": accel[:, 2],
        "dt_s": np.full(n, dt)})
    errors = {"gyro_bias_start_rad_s": gyro_bias[0], "gyro_bias_end_rad_s": gyro_bias[-1],
              "gyro_matrix": gyro_matrix, "gyro_noise_rad_s": grade.gyro_noise_rad_s,
              "gyro_vibration_rad_s": grade.gyro_vibration_rad_s,
              "gyro_bias_walk_rad_s_sqrt_s": grade.gyro_bias_walk_rad_s_sqrt_s,
              "accel_bias_m_s2": accel_bias, "accel_matrix": accel_matrix, "accel_noise_m_s2": grade.accel_noise_m_s2,
              "accel_vibration_m_s2": grade.accel_vibration_m_s2}
    return frame, errors


def panel_current_a(truth: Truth, site: Site, time_us: np.ndarray, panel_current_max_a: float) -> np.ndarray:
    """Solar-panel current [A] at ``time_us`` [us]: maximum current times the cosine of the sun's incidence on the
    wing (body -z)."""
    up_ned = -quat_to_matrix(truth.at(time_us).q_nb)[:, :, 2]
    return panel_current_max_a * np.maximum(0.0, np.einsum("ni,ni->n", up_ned, sun_ned(truth, site, time_us)))


def simulate_mag(truth: Truth, site: Site, grade: MagGrade, rng: np.random.Generator) -> tuple[pd.DataFrame, dict]:
    """Magnetometer ``m_b = (I + M) (C_bn m_n + d_solar) + b_hard + noise``.

    ``m_n`` is the World Magnetic Model field at the launch point and date; ``d_solar`` the solar-panel current
    disturbance along ``solar_direction_body``.

    Returns
    -------
    frame : pandas.DataFrame
        Canonical ``mag`` stream with ``sample_time_s``.
    errors : dict
        ``earth_field_ned_gauss``, ``hard_iron_gauss``, ``mag_matrix``, ``solar_disturbance_max_gauss`` (largest
        disturbance magnitude of the flight), ``noise_gauss``.
    """
    time_us = sample_times_us(truth, grade.rate_hz)
    n = len(time_us)
    field_ned = earth_field_ned_gauss(*truth.origin, pd.Timestamp(truth.time_s[0] + truth.utc_offset_s, unit="s"))
    hard_iron = uniform_within(grade.hard_iron_limit_gauss, rng, (3,))
    matrix = _misalignment(grade.scale_limit, grade.cross_axis_limit, rng)
    field_body = np.einsum("nji,j->ni", quat_to_matrix(truth.at(time_us).q_nb), field_ned)
    direction = np.asarray(grade.solar_direction_body) / np.linalg.norm(grade.solar_direction_body)
    disturbance = np.zeros((n, 3))
    if grade.solar_gauss_per_a > 0:
        current = panel_current_a(truth, site, time_us, grade.panel_current_max_a)
        disturbance = np.outer(grade.solar_gauss_per_a * current, direction)
    mag = (field_body + disturbance) @ matrix.T + hard_iron + rng.standard_normal((n, 3)) * grade.noise_gauss
    frame = _frame(time_us, {"mag_x_gauss": mag[:, 0], "mag_y_gauss": mag[:, 1], "mag_z_gauss": mag[:, 2],
                             "sample_time_s": time_us / 1e6})
    errors = {"earth_field_ned_gauss": field_ned, "hard_iron_gauss": hard_iron, "mag_matrix": matrix,
              "solar_disturbance_max_gauss": float(np.linalg.norm(disturbance, axis=1).max(initial=0.0)),
              "noise_gauss": grade.noise_gauss}
    return frame, errors


def simulate_baro(truth: Truth, site: Site, grade: BaroGrade, rng: np.random.Generator) -> tuple[pd.DataFrame, dict]:
    """Barometer: true ISA static pressure + offset + linear drift + noise; ``alt_m`` = ISA altitude of the reading
    for the autopilot's QNH setting (PX4 ``baro_alt_meter``).

    Returns
    -------
    frame : pandas.DataFrame
        Canonical ``baro`` stream with ``sample_time_s``.
    errors : dict
        ``offset_pa``, ``drift_pa_s`` (the offset at time t after the first sample is offset + drift t),
        ``noise_pa``, ``qnh_setting_pa``, ``sea_level_pressure_pa``.
    """
    time_us = sample_times_us(truth, grade.rate_hz)
    state, n = truth.at(time_us), len(time_us)
    offset = float(uniform_within(grade.offset_limit_pa, rng))
    drift = float(uniform_within(grade.drift_limit_pa_s, rng))
    pressure = (_static_pressure_pa(state, site) + offset + drift * state.tau_s
                + rng.standard_normal(n) * grade.noise_pa)
    temperature = grade.temperature_c + rng.standard_normal(n) * grade.temperature_noise_c
    frame = _frame(time_us, {"alt_m": isa_altitude_m(pressure, grade.qnh_setting_pa), "pressure_pa": pressure,
                             "temp_c": temperature, "sample_time_s": time_us / 1e6})
    errors = {"offset_pa": offset, "drift_pa_s": drift, "noise_pa": grade.noise_pa,
              "qnh_setting_pa": grade.qnh_setting_pa, "sea_level_pressure_pa": site.sea_level_pressure_pa}
    return frame, errors


def simulate_airspeed(truth: Truth, site: Site, grade: AirspeedGrade,
                      rng: np.random.Generator) -> tuple[pd.DataFrame, dict, np.ndarray]:
    """Airspeed from differential pressure ``dp = rho V_a^2 / 2 + offset + noise`` (eq. 5).

    Indicated airspeed ``sign(dp) sqrt(2 |dp| / rho0)`` (signed, as PX4 logs it); true airspeed
    ``IAS sqrt(rho0 / rho)`` with ``rho`` from the static pressure and the measured air temperature.

    Returns
    -------
    frame : pandas.DataFrame
        Canonical ``airspeed`` stream with ``sample_time_s``.
    errors : dict
        ``offset_pa``, ``noise_pa``, ``air_temp_noise_c``.
    air_temp_c : numpy.ndarray
        Measured outside-air temperature per row [degC] (PX4 ``air_temperature_celsius``).
    """
    time_us = sample_times_us(truth, grade.rate_hz)
    state, n = truth.at(time_us), len(time_us)
    offset = float(uniform_within(grade.offset_limit_pa, rng))
    static = _static_pressure_pa(state, site)
    rho = air_density_kg_m3(static, _air_temperature_c(state, site))
    diff_pressure = 0.5 * rho * state.airspeed_m_s**2 + offset + rng.standard_normal(n) * grade.noise_pa
    air_temp = _air_temperature_c(state, site) + rng.standard_normal(n) * grade.air_temp_noise_c
    ias = np.sign(diff_pressure) * np.sqrt(2.0 * np.abs(diff_pressure) / RHO_SEA_LEVEL_KG_M3)
    tas = ias * np.sqrt(RHO_SEA_LEVEL_KG_M3 / air_density_kg_m3(static, air_temp))
    frame = _frame(time_us, {"ias_m_s": ias, "tas_m_s": tas, "sample_time_s": time_us / 1e6})
    errors = {"offset_pa": offset, "noise_pa": grade.noise_pa, "air_temp_noise_c": grade.air_temp_noise_c}
    return frame, errors, air_temp


def simulate_gps(truth: Truth, grade: GpsGrade, rng: np.random.Generator) -> tuple[pd.DataFrame, dict]:
    """GPS fixes: true position + Gauss-Markov error (eqs 6-7), NED velocity + white noise, UTC time.

    Rows are published ``latency_s`` after their measurement time (``sample_time_s``) and only once published
    before the last truth sample. Ground speed and course (eqs 8-9) follow from the velocity.

    Returns
    -------
    frame : pandas.DataFrame
        Canonical ``gps`` stream with ``sample_time_s``, ``speed_accuracy_m_s`` and ``satellites_used``.
    errors : dict
        ``position_error_rms_ned_m`` and ``position_error_rms_horizontal_m`` of the realisation (the position-error
        floor of any estimator), the configured ``position_sigma_m``, ``position_tau_s``,
        ``velocity_noise_m_s`` and ``latency_s``.
    """
    latency_us = round(grade.latency_s * 1e6)
    time_us = sample_times_us(truth, grade.rate_hz, grade.time_to_first_fix_s)
    time_us = time_us[time_us + latency_us <= truth.time_us[-1]]
    state, n = truth.at(time_us), len(time_us)
    error = gauss_markov(n, 1.0 / grade.rate_hz, grade.position_tau_s, grade.position_sigma_m, rng,
                         stationary_start=grade.stationary_start)
    velocity = state.vel_ned_m_s + rng.standard_normal((n, 3)) * grade.velocity_noise_m_s
    position = state.pos_ned_m + error
    lat, lon, alt = ned_to_geodetic(position[:, 0], position[:, 1], position[:, 2], *truth.origin)
    sigma = np.asarray(grade.position_sigma_m)
    utc_us = time_us + round(truth.utc_offset_s * 1e6)
    frame = _frame(time_us + latency_us, {
        "lat_deg": lat, "lon_deg": lon, "alt_m": alt,
        "vn_m_s": velocity[:, 0], "ve_m_s": velocity[:, 1], "vd_m_s": velocity[:, 2],
        "eph_m": np.full(n, np.hypot(sigma[0], sigma[1])), "epv_m": np.full(n, sigma[2]),
        "fix_type": np.full(n, 3), "time_utc_s": utc_us / 1e6, "sample_time_s": time_us / 1e6,
        "speed_accuracy_m_s": np.full(n, grade.velocity_noise_m_s),
        "satellites_used": np.full(n, grade.satellites_used)})
    rms = np.sqrt(np.mean(error**2, axis=0)) if n else np.full(3, np.nan)
    errors = {"position_error_rms_ned_m": rms,
              "position_error_rms_horizontal_m": float(np.hypot(rms[0], rms[1])),
              "position_sigma_m": grade.position_sigma_m, "position_tau_s": grade.position_tau_s,
              "velocity_noise_m_s": grade.velocity_noise_m_s, "latency_s": grade.latency_s}
    return frame, errors
