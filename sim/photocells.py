"""The 7-photocell sun device: cell currents from the true attitude and the sun's position (docs/sun.md, 'Current
model').

The current model is :func:`estimators.sun.photocells.photocell_currents` (direct sun on lit cells plus isotropic sky
light weighted by each cell's view of the sky); the sun direction comes from NREL SPA at the true position and
time. Faults: one cell stuck at 0 A over a time window, and a cloud that dims the direct sun over a window.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from estimators.sun.photocells import CURRENT_COLUMNS, device_sun_and_up, photocell_currents
from ingest.frames import quat_to_matrix
from ingest.sun_device import N_CELLS, SunDevice
from sim.kinematics import Site, Truth
from sim.sensors import sample_times_us, sun_ned


@dataclass(frozen=True)
class SunCellGrade:
    """Sun-device currents, noise and faults.

    Attributes
    ----------
    rate_hz : float
        Sample rate [Hz].
    k_a : float
        Current of a cell facing the sun in clear sky [A].
    sky_a : float
        Sky-light current of a cell facing the zenith [A].
    noise_a : float
        White noise per sample and cell [A].
    failed_cell : int or None
        Cell (1 = top, 2..7 = sides) stuck at 0 A during ``failed_window_s``; None: all healthy.
    failed_window_s : tuple of 2 float
        Start and end of the failure [s of mission time].
    cloud_window_s : tuple of 2 float or None
        Start and end of a cloud passage [s of mission time]; None: clear sky.
    cloud_transmittance : float
        Fraction of the direct sun that passes the cloud [-].
    cloud_edge_s : float
        Duration of the cloud's fade in and out (half-cosine) [s].
    """

    rate_hz: float = 10.0
    k_a: float = 0.100
    sky_a: float = 0.010
    noise_a: float = 0.0005
    failed_cell: int | None = None
    failed_window_s: tuple[float, float] = (0.0, 0.0)
    cloud_window_s: tuple[float, float] | None = None
    cloud_transmittance: float = 0.3
    cloud_edge_s: float = 10.0

    def __post_init__(self):
        if self.failed_cell is not None and not 1 <= self.failed_cell <= N_CELLS:
            raise ValueError(f"failed_cell must be 1..{N_CELLS} or None, got {self.failed_cell}")


def _cloud_factor(tau_s: np.ndarray, grade: SunCellGrade) -> np.ndarray:
    """Direct-sun transmittance over time: 1 in clear sky, ``cloud_transmittance`` under the cloud."""
    if grade.cloud_window_s is None:
        return np.ones_like(tau_s)
    start, end = grade.cloud_window_s
    edge = max(grade.cloud_edge_s, 1e-9)
    inside = np.clip(np.minimum(tau_s - start, end - tau_s) / edge, 0.0, 1.0)
    cover = 0.5 - 0.5 * np.cos(np.pi * inside)
    return 1.0 - (1.0 - grade.cloud_transmittance) * cover


def simulate_sun_device(truth: Truth, site: Site, grade: SunCellGrade, device: SunDevice,
                        rng: np.random.Generator) -> tuple[pd.DataFrame, dict]:
    """Photocell currents at ``grade.rate_hz``; no direct sun with the sun below the horizon.

    Returns
    -------
    frame : pandas.DataFrame
        Canonical ``sun`` stream (currents [A], indexed by the log clock ``time_s``).
    errors : dict
        ``k_a``, ``sky_a``, ``noise_a``, ``failed_cell``, ``failed_window_s``, ``cloud_window_s``,
        ``cloud_transmittance``.
    """
    time_us = sample_times_us(truth, grade.rate_hz)
    state, n = truth.at(time_us), len(time_us)
    s_ned = sun_ned(truth, site, time_us)
    s_device, up_device = device_sun_and_up(quat_to_matrix(state.q_nb), s_ned, device)
    k = grade.k_a * _cloud_factor(state.tau_s, grade) * (s_ned[:, 2] < 0)
    currents = (photocell_currents(s_device, k, np.full(n, grade.sky_a), device, up_device)
                + rng.standard_normal((n, N_CELLS)) * grade.noise_a)
    if grade.failed_cell is not None:
        start, end = grade.failed_window_s
        failed = (state.tau_s >= start) & (state.tau_s < end)
        currents[failed, grade.failed_cell - 1] = 0.0
    frame = pd.DataFrame(currents, columns=list(CURRENT_COLUMNS), index=pd.Index(time_us / 1e6, name="time_s"))
    errors = {"k_a": grade.k_a, "sky_a": grade.sky_a, "noise_a": grade.noise_a, "failed_cell": grade.failed_cell,
              "failed_window_s": grade.failed_window_s, "cloud_window_s": grade.cloud_window_s,
              "cloud_transmittance": grade.cloud_transmittance}
    return frame, errors
