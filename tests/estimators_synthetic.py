"""A small exact synthetic flight for estimator tests (independent of the simulator package).

Fixed-wing, constant airspeed, level coordinated flight in constant wind: a straight leg, then a turn at constant
yaw rate, then straight again (yaw rate ramps in and out so the rates stay continuous). Roll follows the
coordinated-turn bank ``tan(phi) = V_a psi_dot / g``, pitch is zero, the air-relative velocity is along body x
(zero sideslip). IMU outputs are exact (body rates ``W(Theta) Theta_dot`` and specific force ``R^T (a - g_n)``)
plus white noise and constant biases; GPS/baro/mag/airspeed are truth plus white noise. Everything is seeded.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from estimators import environment
from ingest.flightlog import FlightLog, LogMetadata
from ingest.frames import euler_to_matrix, euler_to_quat

LAT0, LON0, ALT0 = 35.0, 108.9, 630.0  # the paper's field site
G = float(environment.local_gravity_m_s2(LAT0, ALT0))


def synthetic_flight(duration_s: float = 10.0, *, imu_hz: float = 250.0, airspeed_m_s: float = 15.0,
                     wind_ne_m_s=(2.0, -1.0), turn_rate_deg_s: float = 12.0, seed: int = 0,
                     gyro_noise_density: float = 2e-3, accel_noise_density: float = 0.035,
                     gyro_bias_rad_s=(0.002, -0.001, 0.0015), accel_bias_m_s2=(0.05, -0.03, 0.08),
                     gps_sigma_m: float = 0.5, gps_vel_sigma_m_s: float = 0.1, baro_sigma_m: float = 0.3,
                     mag_sigma: float = 0.01, airspeed_sigma_m_s: float = 0.3, mav_type: int = 1,
                     with_airspeed: bool = True, with_gps: bool = True, still_s: float = 0.0) -> FlightLog:
    """A FlightLog with truth streams (see the module docstring). ``still_s`` > 0 prepends a stationary,
    level period (on the ground, no airspeed events)."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / imu_hz
    t = np.arange(0.0, duration_s + 1e-9, dt)
    t_fly = t - still_s
    # yaw rate profile: 0 for 2 s, ramp 1 s, hold, ramp down in the last 3 s
    rate_max = math.radians(turn_rate_deg_s)
    ramp = np.clip((t_fly - 2.0), 0.0, 1.0) * np.clip((duration_s - still_s - 2.0 - t_fly), 0.0, 1.0)
    psi_dot = rate_max * ramp
    psi_dot[t_fly < 0] = 0.0
    psi = np.radians(30.0) + np.cumsum(psi_dot) * dt
    psi_ddot = np.gradient(psi_dot, dt)
    va = np.where(t_fly < 0, 0.0, airspeed_m_s)
    phi = np.arctan(va * psi_dot / G)
    phi_dot = np.gradient(phi, dt)
    theta = np.zeros_like(t)
    wind = np.array(wind_ne_m_s, dtype=float)
    flying = t_fly >= 0
    v_ned = np.column_stack([va * np.cos(psi), va * np.sin(psi), np.zeros_like(t)])
    v_ned[flying, 0] += wind[0]
    v_ned[flying, 1] += wind[1]
    a_ned = np.column_stack([-va * np.sin(psi) * psi_dot, va * np.cos(psi) * psi_dot, np.zeros_like(t)])
    pos = np.cumsum(v_ned, axis=0) * dt
    pos -= pos[0]
    R = euler_to_matrix(phi, theta, psi)
    # body rates omega = W(Theta) Theta_dot with Theta_dot = (phi_dot, 0, psi_dot), theta = 0
    omega = np.column_stack([phi_dot - np.sin(theta) * psi_dot,
                             np.sin(phi) * np.cos(theta) * psi_dot,
                             np.cos(phi) * np.cos(theta) * psi_dot])
    del psi_ddot
    g_n = np.array([0.0, 0.0, G])
    f_b = np.einsum("kji,kj->ki", R, a_ned - g_n)
    n = len(t)
    gyro = omega + np.asarray(gyro_bias_rad_s) + rng.normal(0, gyro_noise_density * math.sqrt(imu_hz), (n, 3))
    accel = f_b + np.asarray(accel_bias_m_s2) + rng.normal(0, accel_noise_density * math.sqrt(imu_hz), (n, 3))
    t0 = 1000.0
    time_s = t0 + t
    idx = lambda tt: pd.Index(tt, name="time_s")  # noqa: E731
    streams = {"imu": pd.DataFrame(np.column_stack([gyro, accel]), index=idx(time_s),
                                   columns=["gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s", "accel_x_m_s2",
                                            "accel_y_m_s2", "accel_z_m_s2"])}

    def at(rate_hz, offset=0.0):
        return np.arange(int(offset * imu_hz), n, round(imu_hz / rate_hz))

    k_baro = at(50.0)
    alt = ALT0 - pos[k_baro, 2]
    streams["baro"] = pd.DataFrame({"alt_m": alt + 1.5 + rng.normal(0, baro_sigma_m, len(k_baro)),
                                    "pressure_pa": environment.isa_pressure_pa(alt), "temp_c": 20.0},
                                   index=idx(time_s[k_baro]))
    field = environment.earth_field_ned_gauss(LAT0, LON0, ALT0, 2019.5)
    k_mag = at(50.0, 0.004)
    m_b = np.einsum("kji,j->ki", R[k_mag], field) + rng.normal(0, mag_sigma * np.linalg.norm(field), (len(k_mag), 3))
    streams["mag"] = pd.DataFrame(m_b, index=idx(time_s[k_mag]), columns=["mag_x_gauss", "mag_y_gauss", "mag_z_gauss"])
    if with_gps:
        k_gps = at(10.0, 0.01)
        lat, lon, alt_g = environment.ned_to_geodetic(pos[k_gps, 0] + rng.normal(0, gps_sigma_m, len(k_gps)),
                                                      pos[k_gps, 1] + rng.normal(0, gps_sigma_m, len(k_gps)),
                                                      pos[k_gps, 2] + rng.normal(0, gps_sigma_m, len(k_gps)),
                                                      LAT0, LON0, ALT0)
        vel = v_ned[k_gps] + rng.normal(0, gps_vel_sigma_m_s, (len(k_gps), 3))
        streams["gps"] = pd.DataFrame({"lat_deg": lat, "lon_deg": lon, "alt_m": alt_g, "vn_m_s": vel[:, 0],
                                       "ve_m_s": vel[:, 1], "vd_m_s": vel[:, 2],
                                       "eph_m": gps_sigma_m * math.sqrt(2.0), "epv_m": gps_sigma_m, "fix_type": 3,
                                       "time_utc_s": 1.56e9 + time_s[k_gps],
                                       "speed_accuracy_m_s": gps_vel_sigma_m_s}, index=idx(time_s[k_gps]))
    if with_airspeed:
        k_air = at(50.0, 0.008)
        tas = va[k_air] + rng.normal(0, airspeed_sigma_m_s, len(k_air))
        streams["airspeed"] = pd.DataFrame({"ias_m_s": tas, "tas_m_s": tas}, index=idx(time_s[k_air]))
    q = euler_to_quat(phi, theta, psi)
    k_truth = at(50.0)
    streams["truth_attitude"] = pd.DataFrame(
        {"qw": q[k_truth, 0], "qx": q[k_truth, 1], "qy": q[k_truth, 2], "qz": q[k_truth, 3],
         "roll_deg": np.degrees(phi[k_truth]), "pitch_deg": np.degrees(theta[k_truth]),
         "yaw_deg": (np.degrees(psi[k_truth]) + 180) % 360 - 180}, index=idx(time_s[k_truth]))
    streams["truth_local_position"] = pd.DataFrame(
        {"x_m": pos[k_truth, 0], "y_m": pos[k_truth, 1], "z_m": pos[k_truth, 2], "vx_m_s": v_ned[k_truth, 0],
         "vy_m_s": v_ned[k_truth, 1], "vz_m_s": v_ned[k_truth, 2]}, index=idx(time_s[k_truth]))
    streams["truth_wind"] = pd.DataFrame({"wind_n_m_s": wind[0], "wind_e_m_s": wind[1]}, index=idx(time_s[k_truth]))
    meta = LogMetadata(source="synthetic.ulg", vehicle_type=mav_type, parameters={"EKF2_GPS_DELAY": 0.0},
                       utc_offset_s=1.56e9)
    return FlightLog(streams=streams, meta=meta)


def assert_same_run(fast, slow_states: pd.DataFrame, slow_diag: pd.DataFrame, slow_final: dict, n_outputs: int,
                    tolerance: float = 1e-9) -> None:
    """A compiled run (an ``EstimatorRun``) equals the same kernel source run uncompiled: states, diagnostics and
    final state within ``tolerance`` (absolute), the same NaN pattern and gate decisions, ``n_outputs`` rows."""
    numeric = [c for c in fast.states.columns if c != "time_s"]
    assert len(fast.states) == len(slow_states) == n_outputs
    a, b = fast.states[numeric].to_numpy(), slow_states[numeric].to_numpy()
    assert np.array_equal(np.isnan(a), np.isnan(b))
    assert np.nanmax(np.abs(a - b)) < tolerance
    assert len(fast.diagnostics) == len(slow_diag) > 0
    for column in ("time_s", "innovation", "innovation_var", "nis"):
        assert np.nanmax(np.abs(fast.diagnostics[column].to_numpy() - slow_diag[column].to_numpy())) < tolerance
    assert (fast.diagnostics["accepted"].to_numpy() == slow_diag["accepted"].to_numpy()).all()
    final = fast.report.details["final_state"]
    assert max(abs(final[k] - slow_final[k]) for k in final) < tolerance
