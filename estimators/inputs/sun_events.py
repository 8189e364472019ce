"""Sun-vector heading events of the replay (docs/estimators.md, 'Inputs'): the observations of a sun-device CSV or
of the log's photocells, as the ``SUN`` events of :func:`estimators.inputs.build.build_replay_inputs`."""

from __future__ import annotations

import numpy as np
import pandas as pd

from estimators import environment
from estimators.inputs.records import SUN, Origin
from ingest.errors import InputError
from ingest.flightlog import FlightLog


def sun_heading_events(flight_log: FlightLog, heading: str, sun_observations: pd.DataFrame | None, origin: Origin,
                       source: str, warnings: list[str], *, chosen: bool = True):
    """The sun-vector event part ``(time_s, SUN, values, variances)`` when the heading source includes the sun
    (else None): the given observations, else those of the log's photocells (:func:`sun_observations_from_log`).

    Without a single observation it raises when the user ``chosen`` the sun; when the default heading chose it
    (``"auto"`` with sun-device data) the replay goes on with the magnetometer and says so in ``warnings``."""
    if heading not in ("sun", "mag+sun"):
        return None
    if sun_observations is None and flight_log.has("sun"):
        sun_observations = sun_observations_from_log(flight_log, origin, warnings)
    if (sun_observations is None or len(sun_observations) == 0) and not chosen:
        warnings.append("default heading: the sun device gave no sun vector (no GPS fix or UTC time for the "
                        "ephemeris, or the sun below the horizon): magnetometer heading only")
        return None
    if sun_observations is None or len(sun_observations) == 0:
        raise InputError(f"heading {heading!r} needs sun-vector observations (a sun-device CSV with the sun "
                         "above the horizon and a GPS fix for the ephemeris)", source=source, field="heading")
    return _sun_events(sun_observations, source)


def sun_observations_from_log(flight_log: FlightLog, origin: Origin, warnings: list[str]) -> pd.DataFrame | None:
    """Sun-vector observations from the log's photocell currents (:func:`estimators.sun.solver.solve_sun_log`)
    and the sun's NED direction at the origin (NREL SPA on a 1 Hz grid, :func:`estimators.sun.prediction.sun_ned_at`).

    Returns None when the log has no GPS position or no UTC time (the ephemeris needs both). Epochs without a
    solution or with the sun below :data:`estimators.environment.MIN_SUN_ELEVATION_DEG` are dropped.
    """
    from estimators.sun.prediction import sun_ned_at
    from estimators.sun.solver import solve_sun_log

    if origin.source != "gps" or flight_log.meta.utc_offset_s is None:
        warnings.append("sun heading: no GPS position or UTC time for the ephemeris; sun vector not used")
        return None
    solved = solve_sun_log(flight_log["sun"], device=flight_log.meta.sun_device)
    solved = solved[solved["status"] == "ok"]
    if solved.empty:
        warnings.append("sun heading: no epoch with a valid sun-vector solution")
        return None
    time_s = solved["time_s"].to_numpy(dtype=float)
    s_ned, elevation = sun_ned_at(flight_log, time_s, origin=(origin.lat_deg, origin.lon_deg, origin.alt_m))
    keep = elevation > environment.MIN_SUN_ELEVATION_DEG
    if not keep.any():
        warnings.append("sun heading: the sun is below the horizon limit during the whole log")
        return None
    return pd.DataFrame({"sun_x": solved["sun_x"].to_numpy()[keep], "sun_y": solved["sun_y"].to_numpy()[keep],
                         "sun_z": solved["sun_z"].to_numpy()[keep], "sun_n": s_ned[keep, 0], "sun_e": s_ned[keep, 1],
                         "sun_d": s_ned[keep, 2], "sigma_rad": solved["sigma_rad"].to_numpy()[keep]},
                        index=pd.Index(time_s[keep], name="time_s"))


def _sun_events(observations: pd.DataFrame, source: str):
    columns = ("sun_x", "sun_y", "sun_z", "sun_n", "sun_e", "sun_d", "sigma_rad")
    missing = [c for c in columns if c not in observations.columns]
    if missing:
        raise InputError(f"sun observations lack columns {missing}", source=source, field="sun")
    time_s = observations.index.to_numpy(dtype=float)
    data = observations.loc[:, list(columns)].to_numpy(dtype=float)
    keep = np.isfinite(time_s) & np.isfinite(data).all(axis=1) & (data[:, 6] > 0)
    time_s, data = time_s[keep], data[keep]
    variances = np.zeros((len(time_s), 2))
    variances[:, 0] = variances[:, 1] = data[:, 6] ** 2
    return time_s, SUN, data[:, :6], variances
