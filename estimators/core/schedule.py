"""The one scheduling rule of the three filters (docs/estimators.md, 'Scheduling rule').

:func:`build_schedule` turns the IMU rows and the time-sorted measurement events into a flat list of operations
that every filter's kernel executes in order, so the three filters are stepped identically and a comparison
between them carries no scheduling difference:

* ``PROPAGATE`` (``dt``, ``row``): propagate the state over ``dt`` [s] with IMU row ``row``. Row ``k`` is a
  zero-order-hold rate over ``(time_s[k-1], time_s[k]]``; an event inside that interval splits it, so the state is
  propagated to the event time exactly.
* ``COVARIANCE``: propagate the covariance over the time accumulated since the last ``COVARIANCE`` (mean input,
  transition at the state at the start of the interval). Emitted when the accumulated time reaches the
  covariance interval ``1 / covariance_rate_hz``, **before every measurement update** (every update sees the
  covariance at its own time; the filter names the event kinds it fuses, e.g. the three-stage filter low-passes
  the barometer and the airspeed as inputs instead) and once at the end. Output epochs do not force one: an output
  reports the covariance as last propagated, at most one covariance interval old.
* ``EVENT`` (``event``): the measurement update or the output (``OUTPUT`` kind) of event ``event``.
* ``PERIODIC``: a filter's own update at a fixed period (the three-stage filter's accelerometer update), at the
  end of the first IMU row at or after each period boundary once time has been propagated since the last one,
  preceded by a ``COVARIANCE``; the next boundary is ``max(boundary + period, t + period / 2)``. Not emitted with
  an infinite period.

The schedule is a pure function of the times (numba, allocation of the four output arrays only).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from estimators.inputs.records import OUTPUT, SENSOR_NAMES

PROPAGATE = 0
COVARIANCE = 1
EVENT = 2
PERIODIC = 3

N_KINDS = len(SENSOR_NAMES)
#: Relative tolerance of the covariance interval (an interval of 1/covariance_rate_hz made of float steps counts).
INTERVAL_TOLERANCE = 1e-9


@njit(cache=True)
def _emit(op, dt, index, n, code, step_s, value):
    op[n] = code
    dt[n] = step_s
    index[n] = value
    return n + 1


def build_schedule(imu_time_s, event_time_s, event_kind, event_imu_index, covariance_dt_s, periodic_dt_s,
                   fused_kinds=None):
    """Operations of one replay (see the module docstring).

    Parameters
    ----------
    imu_time_s : float64 (N,)
        IMU row times [s], increasing.
    event_time_s, event_kind, event_imu_index : (M,)
        Events sorted by time (:class:`estimators.inputs.records.MeasurementEvents`); ``event_imu_index[j]`` is the
        IMU row whose interval contains event ``j``.
    covariance_dt_s : float
        Covariance propagation interval [s].
    periodic_dt_s : float
        Period of the filter's own ``PERIODIC`` update [s]; ``inf`` for none.
    fused_kinds : iterable of int, optional
        Event kinds the filter fuses as measurement updates (a ``COVARIANCE`` precedes each); default every kind
        but ``OUTPUT``.

    Returns
    -------
    op : int8 (S,)
        Operation codes.
    dt_s : float64 (S,)
        ``PROPAGATE``: the step [s]; otherwise the time of the operation [s].
    index : int64 (S,)
        ``PROPAGATE``: IMU row; ``EVENT``: event index; otherwise -1.
    """
    fused = np.ones(N_KINDS, dtype=np.bool_)
    if fused_kinds is not None:
        fused[:] = False
        fused[np.asarray(list(fused_kinds), dtype=np.int64)] = True
    fused[OUTPUT] = False
    return _build_schedule(np.ascontiguousarray(imu_time_s, dtype=np.float64),
                           np.ascontiguousarray(event_time_s, dtype=np.float64), np.ascontiguousarray(event_kind),
                           np.ascontiguousarray(event_imu_index), float(covariance_dt_s), float(periodic_dt_s), fused)


@njit(cache=True)
def _build_schedule(imu_time_s, event_time_s, event_kind, event_imu_index, covariance_dt_s, periodic_dt_s, fused):
    n_imu = imu_time_s.shape[0]
    n_events = event_time_s.shape[0]
    # at most two PROPAGATE (+ COVARIANCE) per row and event, one COVARIANCE + EVENT per event, two per period
    capacity = 2 * n_imu + 4 * n_events + 1
    if math.isfinite(periodic_dt_s) and periodic_dt_s > 0.0 and n_imu > 0:
        capacity += 2 * (int((imu_time_s[-1] - imu_time_s[0]) / periodic_dt_s) + 2)
    op = np.empty(capacity, dtype=np.int8)
    dt = np.empty(capacity)
    index = np.empty(capacity, dtype=np.int64)
    n = int(0)  # int(), as the codes below
    if n_imu == 0:
        return op[:0], dt[:0], index[:0]
    # int(): numba compiles a callee once per literal argument value; int64 variables keep _emit to one compile
    propagate, covariance, event, periodic_update, no_index = (int(PROPAGATE), int(COVARIANCE), int(EVENT),
                                                               int(PERIODIC), int(-1))
    threshold = covariance_dt_s * (1.0 - INTERVAL_TOLERANCE)
    periodic = math.isfinite(periodic_dt_s) and periodic_dt_s > 0.0
    next_periodic = imu_time_s[0]
    t = imu_time_s[0]
    last_periodic = t  # a periodic update needs time propagated since the last one (or the start)
    accumulated = 0.0
    j = int(0)
    for k in range(n_imu):
        while True:
            at_event = j < n_events and event_imu_index[j] <= k
            t_next = event_time_s[j] if at_event else imu_time_s[k]
            if t_next > t:
                n = _emit(op, dt, index, n, propagate, t_next - t, k)
                accumulated += t_next - t
                t = t_next
                if accumulated >= threshold:
                    n = _emit(op, dt, index, n, covariance, t, no_index)
                    accumulated = 0.0
            if not at_event:
                break
            if fused[event_kind[j]] and accumulated > 0.0:
                n = _emit(op, dt, index, n, covariance, t, no_index)
                accumulated = 0.0
            n = _emit(op, dt, index, n, event, t, j)
            j += 1
        if periodic and t >= next_periodic and t > last_periodic:
            if accumulated > 0.0:
                n = _emit(op, dt, index, n, covariance, t, no_index)
                accumulated = 0.0
            n = _emit(op, dt, index, n, periodic_update, t, no_index)
            last_periodic = t
            next_periodic = max(next_periodic + periodic_dt_s, t + 0.5 * periodic_dt_s)
    while j < n_events:  # events after the last IMU row (none from build_replay_inputs): handled at the last time
        if fused[event_kind[j]] and accumulated > 0.0:
            n = _emit(op, dt, index, n, covariance, t, no_index)
            accumulated = 0.0
        n = _emit(op, dt, index, n, event, t, j)
        j += 1
    if accumulated > 0.0:
        n = _emit(op, dt, index, n, covariance, t, no_index)
    return op[:n], dt[:n], index[:n]
