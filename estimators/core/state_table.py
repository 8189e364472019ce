"""The named state table shared by the three filters (conventions practice 3): one row per state with its name,
unit, initial standard deviation and random-walk density; x0's layout, P0 and the random-walk part of the
process noise are built from it, so the table is the one place a state's tuning is read from."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StateSpec:
    """One row of a state table.

    Attributes
    ----------
    name : str
        State name (the three-stage filter's carry their unit as a suffix).
    unit : str
        Unit of the state.
    initial_sigma : float
        Initial 1-sigma [unit].
    process_sigma : float
        Random-walk density [unit/sqrt(s)] (model error beyond the IMU input noise; 0: the state's noise enters
        through the inputs only).
    """

    name: str
    unit: str
    initial_sigma: float
    process_sigma: float


def initial_sigmas(table: tuple[StateSpec, ...]) -> np.ndarray:
    """Initial standard deviations of a table [unit], shape (n,)."""
    return np.array([spec.initial_sigma for spec in table], dtype=float)


def initial_covariance(table: tuple[StateSpec, ...]) -> np.ndarray:
    """P0 = diag(initial_sigma^2) of a table, shape (n, n)."""
    return np.diag(initial_sigmas(table) ** 2)


def random_walk_psd(table: tuple[StateSpec, ...]) -> np.ndarray:
    """Random-walk densities squared [unit^2/s], shape (n,): the variance added over dt is ``psd * dt``."""
    return np.array([spec.process_sigma ** 2 for spec in table], dtype=float)


def process_noise_psd(table: tuple[StateSpec, ...]) -> np.ndarray:
    """Continuous random-walk process-noise density Qc = diag(process_sigma^2) [unit^2/s], shape (n, n)."""
    return np.diag(random_walk_psd(table))
