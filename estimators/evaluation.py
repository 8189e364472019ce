"""Accuracy of estimator outputs against a log's ground truth, in the quantities of the paper's Table 2.

Works on the ``states`` table of :func:`estimators.api.run_estimators` and a FlightLog that carries truth streams
(``truth_attitude``, ``truth_global_position``, ``truth_local_position`` and ``truth_wind``; simulator and SITL
logs). Truth is interpolated to the output epochs (angles unwrapped first).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from estimators import environment
from estimators.config import EstimatorConfig, NoiseConfig
from ingest.flightlog import FlightLog

#: Table 2 of the paper: RMS errors per estimator (deg, deg, deg, m, m, m/s, m/s, deg, m/s).
PAPER_TABLE_2 = {
    "three_stage": {"roll_deg": 2.52, "pitch_deg": 3.13, "yaw_deg": 7.19, "position_m": 6.04, "height_m": 5.3,
                    "airspeed_m_s": 2.4, "ground_speed_m_s": 2.9, "course_deg": 10.45, "wind_m_s": 0.3},
    "full_state_direct": {"roll_deg": 1.24, "pitch_deg": 0.4, "yaw_deg": 1.58, "position_m": 2.93,
                          "height_m": 0.98, "airspeed_m_s": 0.8, "ground_speed_m_s": 0.68, "course_deg": 1.62,
                          "wind_m_s": 0.3},
    "full_state_indirect": {"roll_deg": 0.48, "pitch_deg": 0.3, "yaw_deg": 0.61, "position_m": 2.9,
                            "height_m": 0.98, "airspeed_m_s": 0.5, "ground_speed_m_s": 0.37, "course_deg": 1.48,
                            "wind_m_s": 0.15},
}
#: Quantities of Table 2, in order.
QUANTITIES = ("roll_deg", "pitch_deg", "yaw_deg", "position_m", "height_m", "airspeed_m_s", "ground_speed_m_s",
              "course_deg", "wind_m_s")
#: Course, airspeed and wind errors are only meaningful above this true ground speed [m/s] (in flight;
#: docs/estimators.md, 'Sensor plan' and 'Wind on the ground').
MIN_GROUND_SPEED_M_S = 3.0


def _wrap_deg(angle):
    return (np.asarray(angle) + 180.0) % 360.0 - 180.0


def truth_at(flight_log: FlightLog, time_s: np.ndarray, origin_deg_m: tuple[float, float, float]) -> pd.DataFrame:
    """Truth interpolated to ``time_s``: Euler angles [deg], NED position relative to ``origin_deg_m``
    (lat, lon, alt) [m], NED velocity [m/s] and wind [m/s]."""
    att = flight_log["truth_attitude"]
    t_att = att.index.to_numpy(dtype=float)
    out = {"time_s": time_s}
    for column in ("roll_deg", "pitch_deg", "yaw_deg"):
        unwrapped = np.degrees(np.unwrap(np.radians(att[column].to_numpy(dtype=float))))
        out[column] = np.interp(time_s, t_att, unwrapped)
    pos = flight_log["truth_global_position"]
    north, east, _ = environment.geodetic_to_ned(pos["lat_deg"].to_numpy(), pos["lon_deg"].to_numpy(),
                                                 pos["alt_m"].to_numpy(), *origin_deg_m)
    t_pos = pos.index.to_numpy(dtype=float)
    out["north_m"] = np.interp(time_s, t_pos, north)
    out["east_m"] = np.interp(time_s, t_pos, east)
    out["alt_m"] = np.interp(time_s, t_pos, pos["alt_m"].to_numpy(dtype=float))
    local = flight_log["truth_local_position"]
    t_loc = local.index.to_numpy(dtype=float)
    for column, name in (("vx_m_s", "vn_m_s"), ("vy_m_s", "ve_m_s"), ("vz_m_s", "vd_m_s")):
        out[name] = np.interp(time_s, t_loc, local[column].to_numpy(dtype=float))
    if flight_log.has("truth_wind"):
        wind = flight_log["truth_wind"]
        t_wind = wind.index.to_numpy(dtype=float)
        out["wind_n_m_s"] = np.interp(time_s, t_wind, wind["wind_n_m_s"].to_numpy(dtype=float))
        out["wind_e_m_s"] = np.interp(time_s, t_wind, wind["wind_e_m_s"].to_numpy(dtype=float))
    else:
        out["wind_n_m_s"] = out["wind_e_m_s"] = np.zeros(len(time_s))
    return pd.DataFrame(out)


def rms_errors(states: pd.DataFrame, flight_log: FlightLog, *, after_s: float = 60.0) -> pd.DataFrame:
    """RMS error per estimator and Table 2 quantity, over epochs ``after_s`` seconds after the first one.

    Parameters
    ----------
    states : pandas.DataFrame
        :func:`estimators.api.run_estimators` states (``estimator`` column; one estimator's table without it is
        accepted too).
    flight_log : FlightLog
        The log with truth streams.
    after_s : float
        Convergence time excluded at the start [s].

    Returns
    -------
    pandas.DataFrame
        Index estimator, columns :data:`QUANTITIES`; NaN where an estimator lacks the quantity.
    """
    if "estimator" not in states.columns:
        states = states.assign(estimator="estimator")
    rows = {}
    for name, group in states.groupby("estimator", observed=True, sort=False):
        group = group[group["time_s"] >= group["time_s"].iloc[0] + after_s]
        t = group["time_s"].to_numpy(dtype=float)
        lat = group["lat_deg"].to_numpy(dtype=float)
        origin = (float(np.nanmedian(lat)) if np.isfinite(lat).any() else 0.0,
                  float(np.nanmedian(group["lon_deg"])) if np.isfinite(lat).any() else 0.0, 0.0)
        truth = truth_at(flight_log, t, origin)
        rms = lambda e: float(np.sqrt(np.nanmean(np.asarray(e, dtype=float) ** 2)))  # noqa: E731
        row = {c: rms(_wrap_deg(group[c].to_numpy() - truth[c].to_numpy())) for c in ("roll_deg", "pitch_deg",
                                                                                          "yaw_deg")}
        north, east, _ = environment.geodetic_to_ned(lat, group["lon_deg"].to_numpy(), group["alt_m"].to_numpy(),
                                                     *origin)
        row["position_m"] = rms(np.hypot(north - truth["north_m"], east - truth["east_m"]))
        row["height_m"] = rms(group["alt_m"].to_numpy() - truth["alt_m"].to_numpy())
        v = group[["vn_m_s", "ve_m_s", "vd_m_s"]].to_numpy(dtype=float)
        v_true = truth[["vn_m_s", "ve_m_s", "vd_m_s"]].to_numpy()
        w = group[["wind_n_m_s", "wind_e_m_s"]].to_numpy(dtype=float)
        w_true = truth[["wind_n_m_s", "wind_e_m_s"]].to_numpy()
        vg, vg_true = np.hypot(v[:, 0], v[:, 1]), np.hypot(v_true[:, 0], v_true[:, 1])
        row["ground_speed_m_s"] = rms(vg - vg_true)
        # on the ground the wind is unobservable (held, or its prior before the first flight)
        moving = vg_true > MIN_GROUND_SPEED_M_S
        air = np.linalg.norm(v - np.column_stack([w, np.zeros(len(w))]), axis=1)
        air_true = np.linalg.norm(v_true - np.column_stack([w_true, np.zeros(len(w_true))]), axis=1)
        course = np.degrees(np.arctan2(v[:, 1], v[:, 0]))
        course_true = np.degrees(np.arctan2(v_true[:, 1], v_true[:, 0]))
        for quantity, error in (("airspeed_m_s", air - air_true), ("course_deg", _wrap_deg(course - course_true)),
                                ("wind_m_s", np.linalg.norm(w - w_true, axis=1))):
            row[quantity] = rms(error[moving]) if moving.any() else float("nan")
        rows[name] = row
    return pd.DataFrame.from_dict(rows, orient="index").loc[:, list(QUANTITIES)]


#: Random walk of the z accelerometer bias used with simulated fixed-wing flights [m/s^3/sqrt(Hz)]: absorbs the
#: z accelerometer's cross-axis coupling to the forward specific force (Table 1: +-2 %), which changes by
#: 0.02 x ~3 m/s^2 at every climb/cruise/descent transition. Tuned on the paper mission (pitch RMS 0.57 deg
#: with the x/y walk of 1e-3, 0.39 deg with 0.03, 0.37 deg with 0.05; without the simulated cross-axis errors
#: the pitch RMS is 0.17 deg with any of these).
SIM_ACCEL_BIAS_RW_Z = 0.05
#: Random walk of the barometer offset to GPS height for simulated flights [m/sqrt(s)]: the simulated atmosphere
#: is 5 K colder than ISA, which scales barometric heights by ~1.8 %, so the offset changes by ~0.05 m/s in a
#: 3 m/s climb.
SIM_BARO_BIAS_RW = 0.1
#: GPS position noise floors for simulated flights, horizontal and vertical [m]: the receiver's Gauss-Markov
#: increment per 10 Hz sample is only 0.03 / 0.05 m; these floors are the values that bring the position NIS
#: to ~1 (NIS matching, docs/calibration.md, 'Penalty factor tau (eq 52)' (ii)); the slowly varying Gauss-Markov part
#: stays out of R.
SIM_GPS_FLOORS_M = (0.1, 0.3)
#: Air density at the simulated cruise altitude [kg/m^3] (ISA, ~1200 m MSL) for pressure -> height/speed noise.
SIM_AIR_DENSITY_KG_M3 = 1.1


def config_for_simulation(sidecar: str | Path | dict, base: EstimatorConfig | None = None) -> EstimatorConfig:
    """The estimator noise settings that match a simulated log's TRUE sensor grades (its ``*_sim.json`` side
    file written by ``solarnav simulate``): what the consistency tests of docs/estimators.md, 'GPS re-acquisition' call
    "the true noise
    parameters".

    Mapping: IMU white noise (with in-flight vibration) per sample -> density ``sigma / sqrt(rate)``; gyro bias
    walk as simulated; barometer and airspeed pressure noise -> height and speed noise at the cruise density;
    magnetometer noise / field strength, with a bias walk fast enough to follow the solar-panel disturbance
    (``solar_gauss_per_a * panel_current_max_a`` changing over ~50 s); GPS: the receiver's slowly varying
    Gauss-Markov error is unobservable and left out of R (it is the position floor), R keeps small white floors
    (:data:`SIM_GPS_FLOORS_M`), velocity noise as simulated; accelerometer z and barometer offset walks from
    :data:`SIM_ACCEL_BIAS_RW_Z` and :data:`SIM_BARO_BIAS_RW`.
    """
    data = json.loads(Path(sidecar).read_text()) if not isinstance(sidecar, dict) else sidecar
    sensors = data["scenario"]["sensors"]
    imu, mag, baro, air, gps = (sensors[k] for k in ("imu", "mag", "baro", "airspeed", "gps"))
    rate = imu["rate_hz"]
    gyro_sigma = math.sqrt(imu["gyro_noise_rad_s"] ** 2 + np.mean(np.square(imu["gyro_vibration_rad_s"])))
    accel_sigma = math.sqrt(imu["accel_noise_m_s2"] ** 2 + np.mean(np.square(imu["accel_vibration_m_s2"])))
    field = float(np.linalg.norm(data["sensor_errors"]["mag"]["earth_field_ned_gauss"]))
    solar = mag["solar_gauss_per_a"] * mag["panel_current_max_a"] / field
    noise = NoiseConfig(
        gyro_noise_rad_s_sqrt_hz=gyro_sigma / math.sqrt(rate),
        accel_noise_m_s2_sqrt_hz=accel_sigma / math.sqrt(rate),
        gyro_bias_rw_rad_s2_sqrt_hz=imu["gyro_bias_walk_rad_s_sqrt_s"],
        accel_bias_rw_z_m_s3_sqrt_hz=SIM_ACCEL_BIAS_RW_Z,
        baro_bias_rw_m_sqrt_s=SIM_BARO_BIAS_RW,
        baro_sigma_m=baro["noise_pa"] / (SIM_AIR_DENSITY_KG_M3 * environment.STANDARD_GRAVITY_M_S2),
        airspeed_sigma_m_s=air["noise_pa"] / (SIM_AIR_DENSITY_KG_M3 * 12.5),
        mag_sigma=mag["noise_gauss"] / field,
        mag_bias_rw_sqrt_s=solar / math.sqrt(50.0),
        gps_pos_eph_scale=0.0, gps_hgt_epv_scale=0.0,
        gps_pos_sigma_floor_m=SIM_GPS_FLOORS_M[0], gps_hgt_sigma_floor_m=SIM_GPS_FLOORS_M[1],
        gps_vel_sigma_floor_m_s=gps["velocity_noise_m_s"])
    base = EstimatorConfig() if base is None else base
    return EstimatorConfig(noise=noise, gates=base.gates, initial=base.initial, timing=base.timing,
                           accel_bias_states=base.accel_bias_states,
                           accel_cross_axis_states=base.accel_cross_axis_states, mag_bias_states=base.mag_bias_states,
                           baro_bias_state=base.baro_bias_state, gps_velocity_mode=base.gps_velocity_mode)
