"""Diagnostics and output recorders of the filters' kernels, and the counter slots they share (docs/estimators.md,
'Recorder').

One row per scalar update, :data:`DIAG_FLOAT_COLUMNS` / :data:`DIAG_INT_COLUMNS` (allocated by
:func:`diagnostics_arrays`): ``diag_f[k] = (time_s, innovation, innovation_var, nis)`` and
``diag_i[k] = (sensor kind, component, accepted)``; ``counter[0]`` is the number of rows written. Rows beyond the
preallocated size are dropped and counted in ``counter[1]``. The filters' int64 counter arrays share the slots
``C_*`` below; each filter appends its own after :data:`N_SHARED_COUNTERS`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

#: Columns of the float diagnostics array.
DIAG_FLOAT_COLUMNS = ("time_s", "innovation", "innovation_var", "nis")
#: Columns of the integer diagnostics array.
DIAG_INT_COLUMNS = ("sensor", "component", "accepted")

# counter slots shared by the three filters' kernels (read by estimators.core.results when building the report)
C_DIAG = 0  # diagnostics rows written (record_update)
C_DIAG_DROPPED = 1  # diagnostics rows dropped (record_update)
C_RESETS = 2  # divergence resets
C_GPS_RESETS = 3  # GPS re-acquisition resets (docs/estimators.md, 'GPS re-acquisition')
C_REPAIRS = 4  # covariance eigenvalue repairs
C_UPDATES = 5  # scalar updates attempted
C_OUTPUTS = 6  # output epochs written
C_WIND_INITS = 7  # wind states set from the airspeed along the heading (full-state filters)
N_SHARED_COUNTERS = 8


class Recorder(NamedTuple):
    """The recorder arrays of a kernel run, bundled for the helpers of its loop."""

    diag_f: np.ndarray  # (capacity, len(DIAG_FLOAT_COLUMNS))
    diag_i: np.ndarray  # int64 (capacity, len(DIAG_INT_COLUMNS))
    counters: np.ndarray  # int64 (N_SHARED_COUNTERS + the filter's own,)


def diagnostics_arrays(capacity: int) -> tuple[np.ndarray, np.ndarray]:
    """Zeroed recorder arrays ``(diag_f, diag_i)`` for at most ``capacity`` scalar updates (plain Python)."""
    return (np.zeros((capacity, len(DIAG_FLOAT_COLUMNS))),
            np.zeros((capacity, len(DIAG_INT_COLUMNS)), dtype=np.int64))


@njit(cache=True)
def record_update(diag_f, diag_i, counter, time_s, sensor, component, nu, S, nis, accepted):
    """Append one scalar update to the diagnostics arrays (``counter[0]`` rows used, ``counter[1]`` dropped)."""
    k = counter[0]
    if k >= diag_f.shape[0]:
        counter[1] += 1
        return
    diag_f[k, 0] = time_s
    diag_f[k, 1] = nu
    diag_f[k, 2] = S
    diag_f[k, 3] = nis
    diag_i[k, 0] = sensor
    diag_i[k, 1] = component
    diag_i[k, 2] = 1 if accepted else 0
    counter[0] = k + 1


@njit(cache=True)
def record_output(out, row, values):
    """Write ``values`` into row ``row`` of the output array (the caller advances ``row``)."""
    if row < out.shape[0]:
        for j in range(values.shape[0]):
            out[row, j] = values[j]
