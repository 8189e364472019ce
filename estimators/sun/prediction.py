"""The sun vector the photocells should see, from an attitude reference and the ephemeris, against the solved one.

For a log with a ``sun`` stream (photocell currents) this module answers "how good is the photocell sun vector?"
without running an estimator: the NREL SPA sun direction at the vehicle's GPS position (docs/sun.md, 'Measurement
model') rotated
into the body frame by a reference attitude,

    s_b,pred = C_bn s_n = R_nb^T s_n,

where ``R_nb`` comes from the autopilot's own attitude (``onboard_attitude``, PX4 ``vehicle_attitude``) or from
the ground truth of simulated / SITL logs (``truth_attitude``). The reference's up vector ``R_nb^T (0, 0, -1)``
also feeds the solver's sky-light model (:func:`estimators.sun.solver.solve_sun_log`, ``up_body``).

:func:`sun_vector_table` is the library side of ``solarnav sun``: one row per photocell sample with the solved
vector, the solver's bookkeeping and, per available reference, the predicted vector and its angle to the solved
one.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from estimators.environment import MIN_SUN_ELEVATION_DEG, sun_direction_ned
from estimators.sun.solver import SunSolverConfig, solve_sun_log
from ingest.errors import InputError
from ingest.flightlog import FlightLog
from ingest.frames import quat_to_matrix

#: Attitude references: name -> stream with quaternion columns ``qw, qx, qy, qz`` (body FRD -> NED).
ATTITUDE_STREAMS = {"onboard": "onboard_attitude", "truth": "truth_attitude"}
#: Order in which a reference is chosen for the solver's up vector: the autopilot's estimate (what a real flight
#: has), the ground truth only for logs without one.
UP_VECTOR_PREFERENCE = ("onboard", "truth")
#: The ephemeris is evaluated on this grid [s] and interpolated (the sun moves < 0.005 deg/s, docs/sun.md, 'Measurement
#: model').
EPHEMERIS_STEP_S = 1.0
#: GPS rows used for the observer position: 3D fix or better.
MIN_GPS_FIX_TYPE = 3
#: Columns copied from the solver (:func:`estimators.sun.solver.solve_sun_log`), in output order.
SOLVER_COLUMNS = ("sun_x", "sun_y", "sun_z", "cells_used", "faulty_cells", "residual", "sigma_rad", "k_a",
                  "sky_a", "status")


def attitude_matrices_at(flight_log: FlightLog, source: str, time_s) -> np.ndarray | None:
    """Reference attitude ``R_nb`` (body FRD -> NED) at ``time_s``, shape (n, 3, 3), NaN outside the stream.

    Quaternions are made sign-continuous, interpolated component-wise and renormalised (normalised linear
    interpolation: its angle error is below 1e-4 rad for attitude changes up to 2 deg between samples).

    Parameters
    ----------
    flight_log : FlightLog
        The log.
    source : {"onboard", "truth"}
        Which reference (:data:`ATTITUDE_STREAMS`).
    time_s : array-like, shape (n,)
        Log-clock times [s].

    Returns
    -------
    numpy.ndarray or None
        None when the log has no usable stream for ``source`` (missing, fewer than 2 finite quaternions).
    """
    if source not in ATTITUDE_STREAMS:
        raise InputError(f"unknown attitude reference {source!r} (expected one of {', '.join(ATTITUDE_STREAMS)})",
                         field="source")
    frame = flight_log.streams.get(ATTITUDE_STREAMS[source])
    if frame is None or not {"qw", "qx", "qy", "qz"} <= set(frame.columns):
        return None
    q = frame[["qw", "qx", "qy", "qz"]].to_numpy(dtype=float)
    t = frame.index.to_numpy(dtype=float)
    finite = np.isfinite(q).all(axis=1) & np.isfinite(t)
    q, t = q[finite], t[finite]
    if len(t) < 2:
        return None
    # q and -q are the same rotation: flip each sample to the hemisphere of the previous one
    flips = np.concatenate([[1.0], np.sign(np.einsum("ij,ij->i", q[1:], q[:-1]))])
    q = q * np.cumprod(np.where(flips == 0.0, 1.0, flips))[:, None]
    time_s = np.asarray(time_s, dtype=float)
    q_at = np.column_stack([np.interp(time_s, t, q[:, i], left=np.nan, right=np.nan) for i in range(4)])
    q_at /= np.linalg.norm(q_at, axis=1, keepdims=True)
    return quat_to_matrix(q_at)


def sun_ned_at(flight_log: FlightLog, time_s, origin=None) -> tuple[np.ndarray, np.ndarray]:
    """Unit vector towards the sun in NED and its apparent elevation, at the vehicle's GPS position or at a fixed
    observer position.

    The NREL SPA ephemeris (:func:`estimators.environment.sun_direction_ned`) is evaluated every
    :data:`EPHEMERIS_STEP_S` (the sun moves < 0.005 deg/s, docs/sun.md, 'Measurement model') and interpolated to
    ``time_s``; the
    one place the replay, ``solarnav sun`` and the app evaluate it.

    Parameters
    ----------
    flight_log : FlightLog
        Needs UTC time (``meta.utc_offset_s``) and, without ``origin``, a ``gps`` stream with 3D fixes.
    time_s : array-like, shape (n,)
        Log-clock times [s].
    origin : tuple of (float, float, float), optional
        Fixed observer ``(lat_deg, lon_deg, alt_m)`` (e.g. the replay's NED origin); default: the GPS position
        interpolated to the ephemeris grid.

    Returns
    -------
    s_ned : numpy.ndarray, shape (n, 3)
        Unit vector towards the sun [-]; NaN everywhere when the log has no UTC time or no GPS fix.
    elevation_deg : numpy.ndarray, shape (n,)
        Apparent elevation [deg] (NaN likewise).
    """
    time_s = np.asarray(time_s, dtype=float)
    nan = np.full((len(time_s), 3), np.nan), np.full(len(time_s), np.nan)
    if flight_log.meta.utc_offset_s is None or len(time_s) == 0 or not np.isfinite(time_s).any():
        return nan
    grid = np.arange(np.floor(np.nanmin(time_s)), np.ceil(np.nanmax(time_s)) + EPHEMERIS_STEP_S, EPHEMERIS_STEP_S)
    if origin is not None:
        position = origin
    else:
        if not flight_log.has("gps"):
            return nan
        gps = flight_log["gps"]
        good = np.isfinite(gps[["lat_deg", "lon_deg", "alt_m"]].to_numpy(dtype=float)).all(axis=1)
        if "fix_type" in gps.columns:
            good &= gps["fix_type"].to_numpy(dtype=float) >= MIN_GPS_FIX_TYPE
        if not good.any():
            return nan
        gps = gps[good]
        gps_t = gps.index.to_numpy(dtype=float)
        position = [np.interp(grid, gps_t, gps[c].to_numpy(dtype=float)) for c in ("lat_deg", "lon_deg", "alt_m")]
    s_grid, elevation_grid = sun_direction_ned(flight_log.utc(grid), *position)
    s_ned = np.column_stack([np.interp(time_s, grid, s_grid[:, i]) for i in range(3)])
    s_ned /= np.linalg.norm(s_ned, axis=1, keepdims=True)
    return s_ned, np.interp(time_s, grid, elevation_grid)


def angle_between_deg(a, b) -> np.ndarray:
    """Angle between the rows of two (n, 3) arrays of unit vectors [deg], NaN where either is NaN.

    ``atan2(|a x b|, a . b)``: accurate at small angles, where ``acos`` of the dot product loses precision.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b)))


def sun_vector_table(flight_log: FlightLog, *, config: SunSolverConfig | None = None) -> pd.DataFrame:
    """Solved and predicted sun vectors of every photocell sample of a log.

    Parameters
    ----------
    flight_log : FlightLog
        A log with a ``sun`` stream (:func:`ingest.sun_log.with_sun`); its ``meta.sun_device`` gives the geometry.
    config : SunSolverConfig, optional
        Solver thresholds.

    Returns
    -------
    pandas.DataFrame
        One row per photocell sample:

        * ``time_s`` [s]; ``sun_x, sun_y, sun_z``: solved unit vector towards the sun, body FRD [-], NaN without
          a solution; ``cells_used``, ``faulty_cells`` (bitmasks, bit j = cell j+1), ``residual`` [-],
          ``sigma_rad`` [rad], ``k_a``, ``sky_a`` [A], ``status``: as
          :func:`estimators.sun.solver.solve_sun_log`;
        * ``sun_elevation_deg``: apparent sun elevation from the ephemeris [deg];
        * per reference ``r`` in ``onboard``, ``truth``: ``pred_r_x, pred_r_y, pred_r_z`` (predicted unit
          vector, body FRD [-]) and ``angle_r_deg`` (angle solved vs predicted [deg]); NaN where the log has no
          such attitude, no UTC time or no GPS fix.

        ``attrs["up_reference"]`` names the attitude whose up vector the solver used (``"level"``: none).

    Raises
    ------
    InputError
        The log has no ``sun`` stream.
    """
    if not flight_log.has("sun"):
        raise InputError("the log has no sun-device currents: attach a sun-device CSV", source=flight_log.meta.source,
                         field="sun")
    sun = flight_log["sun"]
    time_s = sun.index.to_numpy(dtype=float)
    attitudes = {name: attitude_matrices_at(flight_log, name, time_s) for name in ATTITUDE_STREAMS}
    up_reference = next((name for name in UP_VECTOR_PREFERENCE if attitudes[name] is not None), "level")
    up_body = None
    if up_reference != "level":
        up_body = -attitudes[up_reference][:, 2, :]
        # outside the reference's time span: level flight (the solver's default)
        up_body[~np.isfinite(up_body).all(axis=1)] = (0.0, 0.0, -1.0)
    solved = solve_sun_log(sun, device=flight_log.meta.sun_device, up_body=up_body, config=config)
    s_ned, elevation_deg = sun_ned_at(flight_log, time_s)
    table = {"time_s": time_s, **{c: solved[c].to_numpy() for c in SOLVER_COLUMNS},
             "sun_elevation_deg": elevation_deg}
    s_body = solved[["sun_x", "sun_y", "sun_z"]].to_numpy(dtype=float)
    for name, r_nb in attitudes.items():
        predicted = np.full((len(time_s), 3), np.nan) if r_nb is None else np.einsum("nji,nj->ni", r_nb, s_ned)
        for i, axis in enumerate("xyz"):
            table[f"pred_{name}_{axis}"] = predicted[:, i]
        table[f"angle_{name}_deg"] = angle_between_deg(s_body, predicted)
    out = pd.DataFrame(table)
    out.attrs["up_reference"] = up_reference
    return out


def usable_sun(table: pd.DataFrame) -> np.ndarray:
    """Rows of :func:`sun_vector_table` with a solution and the sun above
    :data:`estimators.environment.MIN_SUN_ELEVATION_DEG` (the estimators' criterion), bool (n,)."""
    return (table["status"].to_numpy() == "ok") & (table["sun_elevation_deg"].to_numpy() > MIN_SUN_ELEVATION_DEG)
