"""The photocell sun vector against the ephemeris: body-frame azimuth / elevation of the solved and the predicted
sun, their angle, and the state of every cell over time. Pure NumPy / pandas (no Streamlit), tested directly.

Body-frame angles (FRD): azimuth = atan2(s_y, s_x) from the nose towards the right wing, elevation = asin(-s_z)
above the body x-y plane (the sun straight above the wing plane is +90 deg).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from app.comparison import reference_states
from estimators.sun_prediction import sun_ned_at
from ingest import FlightLog, SunDevice
from ingest.frames import euler_to_matrix
from ingest.sun_device import N_CELLS

#: Cell state codes of :func:`cell_states`.
CELL_DARK, CELL_LIT, CELL_FAULTY = 0, 1, 2
CELL_STATE_NAMES = ("dark / unused", "lit (used)", "faulty (excluded)")


def body_angles_deg(sun_body: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth [deg, (-180, 180]] and elevation [deg] of body-frame unit vectors, shape (n, 3)."""
    sun_body = np.asarray(sun_body, dtype=float)
    azimuth = np.degrees(np.arctan2(sun_body[:, 1], sun_body[:, 0]))
    elevation = np.degrees(np.arcsin(np.clip(-sun_body[:, 2], -1.0, 1.0)))
    return azimuth, elevation


def angle_between_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between unit vectors row by row [deg] (NaN where either is NaN)."""
    dot = np.sum(np.asarray(a, float) * np.asarray(b, float), axis=1)
    return np.degrees(np.arccos(np.clip(dot, -1.0, 1.0)))


def predicted_sun_body(log: FlightLog, attitude_source: str, time_s: np.ndarray,
                       origin: tuple[float, float, float]) -> np.ndarray:
    """The sun direction the photocells should see: the NREL SPA sun direction at ``origin`` rotated into the body
    frame by the attitude of ``attitude_source`` (``"truth"`` or ``"onboard"``), shape (n, 3), NaN outside the
    attitude stream. Needs the log's UTC time (:attr:`FlightLog.meta.utc_offset_s`)."""
    time_s = np.asarray(time_s, dtype=float)
    s_ned, _ = sun_ned_at(log, time_s, origin=origin)
    attitude = reference_states(log, attitude_source, time_s)
    r_nb = euler_to_matrix(*(np.radians(attitude[c].to_numpy(float)) for c in ("roll_deg", "pitch_deg", "yaw_deg")))
    return np.einsum("nji,nj->ni", r_nb, s_ned)  # R_nb^T s_ned


def cell_states(solution: pd.DataFrame, device: SunDevice) -> np.ndarray:
    """State of every cell per epoch, shape (n, 7): faulty (excluded by the solver), lit (used and facing the
    solved sun), else dark / unused (codes :data:`CELL_DARK`, :data:`CELL_LIT`, :data:`CELL_FAULTY`).

    Parameters
    ----------
    solution : pandas.DataFrame
        :func:`estimators.sun_vector.solve_sun_log` output (``cells_used``, ``faulty_cells`` bitmasks,
        ``sun_x/y/z``).
    device : SunDevice
        Geometry (cell normals in the body frame).
    """
    bits = 1 << np.arange(N_CELLS)
    used = (solution["cells_used"].to_numpy(np.int64)[:, None] & bits) > 0
    faulty = (solution["faulty_cells"].to_numpy(np.int64)[:, None] & bits) > 0
    facing = solution[["sun_x", "sun_y", "sun_z"]].to_numpy(float) @ device.normals_body.T > 0.0
    states = np.where(used & facing, CELL_LIT, CELL_DARK)
    return np.where(faulty, CELL_FAULTY, states)
