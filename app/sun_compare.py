"""Display helpers of the Sun vector page: body-frame azimuth / elevation of a sun vector and the state of every
cell over time (the solved and predicted vectors come from :func:`estimators.sun.prediction.sun_vector_table`).
Pure NumPy / pandas (no Streamlit), tested directly.

Body-frame angles (FRD): azimuth = atan2(s_y, s_x) from the nose towards the right wing, elevation = asin(-s_z)
above the body x-y plane (the sun straight above the wing plane is +90 deg).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ingest.sun_device import N_CELLS, SunDevice

#: Cell state codes of :func:`cell_states`.
CELL_DARK, CELL_LIT, CELL_FAULTY = 0, 1, 2
CELL_STATE_NAMES = ("dark / unused", "lit (used)", "faulty (excluded)")


def body_angles_deg(sun_body: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth [deg, (-180, 180]] and elevation [deg] of body-frame unit vectors, shape (n, 3)."""
    sun_body = np.asarray(sun_body, dtype=float)
    azimuth = np.degrees(np.arctan2(sun_body[:, 1], sun_body[:, 0]))
    elevation = np.degrees(np.arcsin(np.clip(-sun_body[:, 2], -1.0, 1.0)))
    return azimuth, elevation


def cell_states(solution: pd.DataFrame, device: SunDevice) -> np.ndarray:
    """State of every cell per epoch, shape (n, 7): faulty (excluded by the solver), lit (used and facing the
    solved sun), else dark / unused (codes :data:`CELL_DARK`, :data:`CELL_LIT`, :data:`CELL_FAULTY`).

    Parameters
    ----------
    solution : pandas.DataFrame
        :func:`estimators.sun.prediction.sun_vector_table` (or ``solve_sun_log``) output: ``cells_used``,
        ``faulty_cells`` bitmasks, ``sun_x/y/z``.
    device : SunDevice
        Geometry (cell normals in the body frame).
    """
    bits = 1 << np.arange(N_CELLS)
    used = (solution["cells_used"].to_numpy(np.int64)[:, None] & bits) > 0
    faulty = (solution["faulty_cells"].to_numpy(np.int64)[:, None] & bits) > 0
    facing = solution[["sun_x", "sun_y", "sun_z"]].to_numpy(float) @ device.normals_body.T > 0.0
    states = np.where(used & facing, CELL_LIT, CELL_DARK)
    return np.where(faulty, CELL_FAULTY, states)
