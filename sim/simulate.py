"""Run a scenario: fly it, sample every sensor, and assemble the canonical flight log with its ground truth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ingest.flightlog import FlightLog, LogMetadata, stream_info
from ingest.frames import quat_to_euler
from ingest.px4_topics import TRUTH_WIND_TOPIC
from sim.kinematics import Truth, fly
from sim.photocells import simulate_sun_device
from sim.scenarios import Scenario
from sim.sensors import sample_times_us, simulate_airspeed, simulate_baro, simulate_gps, simulate_imu, simulate_mag

#: ``ver_hw`` / ``LogMetadata.hardware`` of simulated logs.
HARDWARE = "SOLARNAV_SIM"
#: MAVLink MAV_TYPE of the simulated aircraft (fixed wing).
MAV_TYPE_FIXED_WING = 1

#: PX4 topic each canonical stream is written to (:mod:`sim.px4_export`).
STREAM_TOPICS = {
    "imu": "sensor_combined", "mag": "vehicle_magnetometer", "baro": "vehicle_air_data", "airspeed": "airspeed",
    "gps": "vehicle_gps_position", "truth_attitude": "vehicle_attitude_groundtruth",
    "truth_local_position": "vehicle_local_position_groundtruth",
    "truth_global_position": "vehicle_global_position_groundtruth", "truth_wind": TRUTH_WIND_TOPIC,
}


@dataclass(frozen=True)
class SimResult:
    """Output of :func:`simulate`.

    Attributes
    ----------
    scenario : Scenario
        What was simulated.
    seed : int or None
        Seed of the generator when known (recorded in the side file).
    log : FlightLog
        The sensor streams as a log reader would return them, the ground-truth streams at
        ``scenario.truth_rate_hz`` and the ``sun`` stream (currents [A] on the log clock).
    truth : Truth
        Full-rate true state.
    errors : dict of str -> dict
        Error realisation per sensor (``imu``, ``mag``, ``baro``, ``airspeed``, ``gps``, ``sun``).
    airspeed_air_temp_c : numpy.ndarray
        Measured outside-air temperature of each ``airspeed`` row [degC].
    """

    scenario: Scenario
    seed: int | None
    log: FlightLog
    truth: Truth
    errors: dict[str, dict]
    airspeed_air_temp_c: np.ndarray


def _truth_streams(truth: Truth) -> dict[str, pd.DataFrame]:
    index = pd.Index(truth.time_us / 1e6, name="time_s")
    q = truth.q_nb
    roll, pitch, yaw = (np.degrees(angle) for angle in quat_to_euler(q))
    pos, vel, wind = truth.pos_ned_m, truth.vel_ned_m_s, truth.wind_ned_m_s
    return {
        "truth_attitude": pd.DataFrame({"qw": q[:, 0], "qx": q[:, 1], "qy": q[:, 2], "qz": q[:, 3],
                                        "roll_deg": roll, "pitch_deg": pitch, "yaw_deg": yaw}, index=index),
        "truth_local_position": pd.DataFrame({"x_m": pos[:, 0], "y_m": pos[:, 1], "z_m": pos[:, 2],
                                              "vx_m_s": vel[:, 0], "vy_m_s": vel[:, 1], "vz_m_s": vel[:, 2]},
                                             index=index),
        "truth_global_position": pd.DataFrame({"lat_deg": truth.lat_deg, "lon_deg": truth.lon_deg,
                                               "alt_m": truth.alt_m}, index=index),
        "truth_wind": pd.DataFrame({"wind_n_m_s": wind[:, 0], "wind_e_m_s": wind[:, 1]}, index=index),
    }


def simulate(scenario: Scenario, rng: np.random.Generator, *, duration_s: float | None = None,
             seed: int | None = None) -> SimResult:
    """Simulate ``scenario`` with draws from ``rng`` (wind, then IMU, mag, baro, airspeed, GPS, sun device).

    Parameters
    ----------
    scenario : Scenario
        Mission, site, wind, sensors.
    rng : numpy.random.Generator
        Source of every random draw; the same generator state gives the same result bit for bit.
    duration_s : float, optional
        Simulated time [s]; default the mission's length (see :func:`sim.kinematics.fly`).
    seed : int, optional
        The seed ``rng`` was made from, recorded in the result (informational).

    Returns
    -------
    SimResult
    """
    sensors = scenario.sensors
    imu_rate = sensors.imu.rate_hz
    truth = fly(scenario.mission, scenario.site, scenario.wind, rng, duration_s=duration_s, rate_hz=imu_rate)
    site = scenario.site
    streams, errors = {}, {}
    streams["imu"], errors["imu"] = simulate_imu(truth, sensors.imu, rng)
    streams["mag"], errors["mag"] = simulate_mag(truth, site, sensors.mag, rng)
    streams["baro"], errors["baro"] = simulate_baro(truth, site, sensors.baro, rng)
    streams["airspeed"], errors["airspeed"], air_temp = simulate_airspeed(truth, site, sensors.airspeed, rng)
    streams["gps"], errors["gps"] = simulate_gps(truth, sensors.gps, rng)
    sun, errors["sun"] = simulate_sun_device(truth, site, sensors.sun, sensors.device, rng)
    streams.update(_truth_streams(truth.at(sample_times_us(truth, scenario.truth_rate_hz))))
    streams = {name: frame for name, frame in streams.items() if len(frame)}
    infos = {name: stream_info(STREAM_TOPICS[name], frame.index.to_numpy()) for name, frame in streams.items()}
    streams["sun"] = sun
    infos["sun"] = stream_info(f"{scenario.name}_sun.csv", sun.index.to_numpy())
    time_s = truth.time_s
    meta = LogMetadata(
        source=f"simulated:{scenario.name}", vehicle_type=MAV_TYPE_FIXED_WING, hardware=HARDWARE,
        ver_data_format=2, start_time_s=float(time_s[0]), end_time_s=float(time_s[-1]),
        duration_s=float(time_s[-1] - time_s[0]), utc_offset_s=truth.utc_offset_s,
        parameters={"MAV_TYPE": MAV_TYPE_FIXED_WING, "EKF2_GPS_DELAY": float(sensors.gps.latency_s * 1e3),
                    "SENS_BARO_QNH": float(sensors.baro.qnh_setting_pa / 100.0)},
        streams=infos)
    return SimResult(scenario=scenario, seed=seed, log=FlightLog(streams=streams, meta=meta), truth=truth,
                     errors=errors, airspeed_air_temp_c=air_temp)
