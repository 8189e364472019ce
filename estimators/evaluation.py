"""The one evaluator: estimator outputs against a reference (the log's ground truth, else the autopilot's onboard
estimate) in the quantities of the paper's Table 2. The dashboard, ``solarnav batch``, the tests and the benchmarks
all call :func:`evaluate`; its convention (docs/evaluation.md) has two explicit parameters:

* the **window**: RMS figures skip the filters' convergence, the first :data:`DEFAULT_CONVERGENCE_S` seconds of the
  estimates, but always keep the last third of a run (a short real log is still evaluated), to the last estimate;
* the **position origin**: the local NED frame of the horizontal position error is tangent at the first good GPS fix
  (else at the first estimate with a position).

The reference is interpolated to the estimates' epochs (yaw unwrapped first; NaN outside its streams). Airspeed,
course and wind errors count only in flight: where the reference's ground speed exceeds
:data:`MIN_GROUND_SPEED_M_S` (on the ground the wind is unobservable, held or at its prior, and the course undefined).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from estimators import environment
from estimators.config import EstimatorConfig, NoiseConfig
from ingest.flightlog import FlightLog
from ingest.frames import wrap_angle_deg

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
#: Quantities of Table 2, in order: the error columns of :class:`Evaluation` and of its RMS table.
QUANTITIES = ("roll_deg", "pitch_deg", "yaw_deg", "position_m", "height_m", "airspeed_m_s", "ground_speed_m_s",
              "course_deg", "wind_m_s")
#: Errors wrapped to [-180, 180) deg.
ANGLE_QUANTITIES = ("roll_deg", "pitch_deg", "yaw_deg", "course_deg")
#: Errors counted only in flight (reference ground speed above :data:`MIN_GROUND_SPEED_M_S`).
IN_FLIGHT_QUANTITIES = ("airspeed_m_s", "course_deg", "wind_m_s")
#: Course, airspeed and wind errors are only meaningful above this ground speed [m/s] (in flight;
#: docs/estimators.md, 'Sensor plan' and 'Wind on the ground'); below it a course is left NaN.
MIN_GROUND_SPEED_M_S = 3.0
#: Convergence excluded at the start of the RMS window [s].
DEFAULT_CONVERGENCE_S = 60.0
#: Reference streams by source, in order of preference: attitude, global position, local position (velocity), wind.
REFERENCE_STREAMS = {
    "truth": ("truth_attitude", "truth_global_position", "truth_local_position", "truth_wind"),
    "onboard": ("onboard_attitude", "onboard_global_position", "onboard_local_position", "onboard_wind"),
}


@dataclass(frozen=True)
class Evaluation:
    """Estimators and references side by side, and the errors of the estimators against the reference.

    Attributes
    ----------
    quantities : dict of str -> pandas.DataFrame
        Source (estimator name, ``"truth"``, ``"onboard"``) -> :func:`quantities` of its states.
    errors : dict of str -> pandas.DataFrame
        Estimator -> ``time_s`` [s] and the error of every :data:`QUANTITIES` column against ``reference`` at every
        epoch (position and wind: horizontal distance [m] / vector difference [m/s]; in-flight quantities NaN on the
        ground).
    reference : str or None
        ``"truth"``, ``"onboard"``, or None (no reference: no errors).
    window_s : tuple of float
        Start and end of the RMS window on the log clock [s] (NaN without estimates).
    origin : tuple of float or None
        Latitude, longitude [deg] and altitude [m] of the local NED origin of the positions.
    """

    quantities: dict[str, pd.DataFrame]
    errors: dict[str, pd.DataFrame]
    reference: str | None
    window_s: tuple[float, float]
    origin: tuple[float, float, float] | None

    def rms(self) -> pd.DataFrame:
        """RMS of every error over :attr:`window_s`: index estimator, columns :data:`QUANTITIES` (NaN where an
        estimator or the reference lacks the quantity)."""
        rows = {}
        for name, frame in self.errors.items():
            t = frame["time_s"].to_numpy(dtype=float)
            inside = (t >= self.window_s[0]) & (t <= self.window_s[1])
            rows[name] = [_rms(frame[column].to_numpy(dtype=float)[inside]) for column in QUANTITIES]
        return pd.DataFrame.from_dict(rows, orient="index", columns=list(QUANTITIES)).rename_axis("estimator")


def _rms(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(np.square(finite)))) if finite.size else math.nan


def rms_window(time_s: np.ndarray, convergence_s: float = DEFAULT_CONVERGENCE_S) -> tuple[float, float]:
    """The RMS window over the epochs ``time_s`` [s]: from ``convergence_s`` after the first (at most two thirds of
    the span, so that the last third is always kept) to the last; NaN for no epochs."""
    if len(time_s) == 0:
        return math.nan, math.nan
    first, last = float(np.min(time_s)), float(np.max(time_s))
    return first + min(convergence_s, 2.0 * (last - first) / 3.0), last


def position_origin(log: FlightLog, states: pd.DataFrame | None = None) -> tuple[float, float, float] | None:
    """Latitude, longitude [deg] and altitude [m] of the first good GPS fix, else of the first estimate with a
    position; None when there is neither."""
    candidates = [log["gps"]] if log.has("gps") else []
    if states is not None:
        candidates.append(states)
    for frame in candidates:
        if not {"lat_deg", "lon_deg", "alt_m"} <= set(frame.columns):
            continue
        fixes = frame[["lat_deg", "lon_deg", "alt_m"]].dropna()
        if not fixes.empty:
            return tuple(float(v) for v in fixes.iloc[0])
    return None


def quantities(states: pd.DataFrame, origin: tuple[float, float, float] | None) -> pd.DataFrame:
    """The compared quantities of one source's states (columns of ``estimators.core.results.STATE_COLUMNS``).

    Returns
    -------
    pandas.DataFrame
        ``time_s`` [s], ``roll_deg``, ``pitch_deg``, ``yaw_deg`` [deg], ``north_m``, ``east_m`` [m] about
        ``origin`` (NaN without one), ``alt_m`` [m], ``ground_speed_m_s``, ``airspeed_m_s`` = |v - wind| [m/s],
        ``course_deg`` [deg] (NaN below :data:`MIN_GROUND_SPEED_M_S`), ``wind_n_m_s``, ``wind_e_m_s`` [m/s].
    """
    def column(name: str) -> np.ndarray:
        return states[name].to_numpy(dtype=float) if name in states else np.full(len(states), np.nan)

    vn, ve, vd = column("vn_m_s"), column("ve_m_s"), column("vd_m_s")
    wind_n, wind_e = column("wind_n_m_s"), column("wind_e_m_s")
    ground_speed = np.hypot(vn, ve)
    course = np.where(ground_speed >= MIN_GROUND_SPEED_M_S, np.degrees(np.arctan2(ve, vn)), np.nan)
    if origin is None:
        north = east = np.full(len(states), np.nan)
    else:
        north, east, _ = environment.geodetic_to_ned(column("lat_deg"), column("lon_deg"), column("alt_m"), *origin)
    return pd.DataFrame({
        "time_s": column("time_s"), "roll_deg": column("roll_deg"), "pitch_deg": column("pitch_deg"),
        "yaw_deg": column("yaw_deg"), "north_m": north, "east_m": east, "alt_m": column("alt_m"),
        "ground_speed_m_s": ground_speed, "airspeed_m_s": np.sqrt((vn - wind_n) ** 2 + (ve - wind_e) ** 2 + vd**2),
        "course_deg": wrap_angle_deg(course), "wind_n_m_s": wind_n, "wind_e_m_s": wind_e,
    })


def reference_states(log: FlightLog, source: str, time_s: np.ndarray) -> pd.DataFrame | None:
    """A reference's states interpolated onto ``time_s`` [s] (NaN outside its streams; yaw unwrapped first).

    Parameters
    ----------
    log : FlightLog
        The flight.
    source : {"truth", "onboard"}
        Which reference (:data:`REFERENCE_STREAMS`).
    time_s : numpy.ndarray
        Times to interpolate to [s], increasing.

    Returns
    -------
    pandas.DataFrame or None
        State columns as the estimators write them; None when the log has none of the source's streams.
    """
    attitude, global_position, local_position, wind = REFERENCE_STREAMS[source]
    if not any(log.has(name) for name in REFERENCE_STREAMS[source]):
        return None
    out = {"time_s": time_s}
    wanted = {attitude: {"roll_deg": "roll_deg", "pitch_deg": "pitch_deg", "yaw_deg": "yaw_deg"},
              global_position: {"lat_deg": "lat_deg", "lon_deg": "lon_deg", "alt_m": "alt_m"},
              local_position: {"vx_m_s": "vn_m_s", "vy_m_s": "ve_m_s", "vz_m_s": "vd_m_s"},
              wind: {"wind_n_m_s": "wind_n_m_s", "wind_e_m_s": "wind_e_m_s"}}
    for stream, columns in wanted.items():
        frame = log.streams.get(stream)
        for column, name in columns.items():
            if frame is None or column not in frame or len(frame) < 2:
                out[name] = np.full(len(time_s), np.nan)
                continue
            values = frame[column].to_numpy(dtype=float)
            if name == "yaw_deg":
                values = np.degrees(np.unwrap(np.radians(values)))
            interpolated = np.interp(time_s, frame.index.to_numpy(dtype=float), values, left=np.nan, right=np.nan)
            out[name] = wrap_angle_deg(interpolated) if name == "yaw_deg" else interpolated
    return pd.DataFrame(out)


def errors(estimate: pd.DataFrame, reference: pd.DataFrame) -> pd.DataFrame:
    """Errors of :func:`quantities` ``estimate`` against ``reference`` on the same times: differences (angles
    wrapped), horizontal position distance [m], height difference [m] and wind vector difference [m/s]; the
    :data:`IN_FLIGHT_QUANTITIES` NaN where the reference's ground speed is not above :data:`MIN_GROUND_SPEED_M_S`."""
    moving = reference["ground_speed_m_s"].to_numpy(dtype=float) > MIN_GROUND_SPEED_M_S
    out = {"time_s": estimate["time_s"].to_numpy(dtype=float)}
    for quantity in QUANTITIES:
        if quantity == "position_m":
            error = np.hypot(estimate["north_m"] - reference["north_m"], estimate["east_m"] - reference["east_m"])
        elif quantity == "wind_m_s":
            error = np.hypot(estimate["wind_n_m_s"] - reference["wind_n_m_s"],
                             estimate["wind_e_m_s"] - reference["wind_e_m_s"])
        else:
            column = "alt_m" if quantity == "height_m" else quantity
            error = estimate[column].to_numpy(dtype=float) - reference[column].to_numpy(dtype=float)
            error = wrap_angle_deg(error) if quantity in ANGLE_QUANTITIES else error
        error = np.asarray(error, dtype=float)
        out[quantity] = np.where(moving, error, np.nan) if quantity in IN_FLIGHT_QUANTITIES else error
    return pd.DataFrame(out)


def evaluate(states: pd.DataFrame, log: FlightLog, *, reference: str = "auto",
             convergence_s: float = DEFAULT_CONVERGENCE_S,
             origin: tuple[float, float, float] | None = None) -> Evaluation:
    """Every estimator of ``states`` against the log's reference.

    Parameters
    ----------
    states : pandas.DataFrame
        :func:`estimators.api.run_estimators` states (``estimator`` column; one estimator's table without it is
        accepted too and named ``"estimator"``).
    log : FlightLog
        The flight.
    reference : {"auto", "truth", "onboard"}
        The reference; ``"auto"`` takes truth when the log has it, else the onboard estimate.
    convergence_s : float
        Convergence excluded at the start of the RMS window [s] (:func:`rms_window`).
    origin : tuple of float, optional
        The local NED origin (lat, lon [deg], alt [m]); default :func:`position_origin`.

    Returns
    -------
    Evaluation
        With every available reference's quantities (for charts) and the errors against ``reference`` (none when
        the log lacks it).
    """
    if reference not in ("auto", *REFERENCE_STREAMS):
        raise ValueError(f"reference must be 'auto', 'truth' or 'onboard', got {reference!r}")
    if "estimator" not in states.columns:
        states = states.assign(estimator="estimator")
    origin = position_origin(log, states) if origin is None else origin
    names = [str(name) for name in states["estimator"].unique()]
    by_name = {name: states.loc[states["estimator"] == name] for name in names}
    result = {name: quantities(frame, origin) for name, frame in by_name.items()}
    time_s = result[names[0]]["time_s"].to_numpy() if names else np.empty(0)
    available = []
    for source in REFERENCE_STREAMS:
        ref = reference_states(log, source, time_s)
        if ref is not None:
            result[source] = quantities(ref, origin)
            available.append(source)
    chosen = (available[0] if available else None) if reference == "auto" else (
        reference if reference in available else None)
    errs = {}
    if chosen is not None:
        for name in names:
            own_times = by_name[name]["time_s"].to_numpy(dtype=float)
            ref = (result[chosen] if np.array_equal(own_times, time_s)
                   else quantities(reference_states(log, chosen, own_times), origin))
            errs[name] = errors(result[name], ref)
    all_times = states["time_s"].to_numpy(dtype=float)
    return Evaluation(quantities=result, errors=errs, reference=chosen,
                      window_s=rms_window(all_times, convergence_s), origin=origin)


def rms_errors(states: pd.DataFrame, flight_log: FlightLog, *,
               after_s: float = DEFAULT_CONVERGENCE_S) -> pd.DataFrame:
    """RMS error against ground truth per estimator and Table 2 quantity (:func:`evaluate` with ``reference="truth"``
    and ``convergence_s=after_s``): index estimator, columns :data:`QUANTITIES`.

    Raises
    ------
    ValueError
        The log has no ground truth.
    """
    evaluation = evaluate(states, flight_log, reference="truth", convergence_s=after_s)
    if evaluation.reference is None:
        raise ValueError(f"{flight_log.meta.source}: no ground truth to evaluate against")
    return evaluation.rms()


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
