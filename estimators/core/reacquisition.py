"""Re-acquisition policy shared by the three filters (docs/estimators.md, 'GPS re-acquisition').

The rejection rule: a measurement channel whose updates are all rejected for ``T_rej`` means the state, not the
sensor, is wrong, and the state restarts from the measurement. A channel's streak of rejections is one float, its
start time (:func:`rejection_streak`, :func:`rejected_too_long`); the GPS channels and the three-stage filter's
heading (:func:`estimators.three_stage.control.heading_control`) use the same two functions.

GPS: a position or velocity component rejected continuously for ``T_rej``, or GPS back after an outage longer
than ``T_out``, resets position and velocity to the GPS (:func:`gps_reset_due`, :func:`gps_control`); the monitor
is a small float64 array (:func:`gps_monitor`) with the slots ``GM_*``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from estimators.core.recorder import C_GPS_RESETS
from estimators.inputs.records import GPS_POS

# ----------------------------------------------------------------------------------------------------------------
# the rejection rule


@njit(cache=True)
def rejection_streak(start_s, t, accepted):
    """Start [s] of a channel's rejection streak after an update at ``t`` [s] (``start_s`` before it; inf: no
    streak): an acceptance ends the streak, a rejection starts one (or continues it)."""
    if accepted:
        return math.inf
    if start_s == math.inf:
        return t
    return start_s


@njit(cache=True)
def rejected_too_long(start_s, t, reject_s):
    """The rule's trigger: the rejection streak that started at ``start_s`` [s] has lasted ``reject_s`` [s] or
    more at ``t`` [s] (never without a streak, ``start_s`` = inf)."""
    return t - start_s >= reject_s


# ----------------------------------------------------------------------------------------------------------------
# GPS re-acquisition (docs/estimators.md, 'GPS re-acquisition')
#
# The monitor is a float64 array: the last position and velocity event times, a "reset pending" flag per kind
# (a reset triggered at one kind's event resets the other kind's states at its next event; at one GPS epoch the
# position event comes first) and, per GPS channel (position n, e, d, velocity 0, 1, 2; the paper-mode ground
# speed and course use velocity channels 0 and 1), the start of its current rejection streak (inf: the last
# update of that channel was accepted).

GM_POS_SEEN = 0
GM_VEL_SEEN = 1
GM_POS_PENDING = 2
GM_VEL_PENDING = 3
GM_STREAK = 4  # 4..9: rejection streak start per channel
GPS_CHANNELS = 6
GPS_MONITOR_SIZE = GM_STREAK + GPS_CHANNELS


@njit(cache=True)
def gps_monitor():
    """A new monitor: no GPS seen yet, nothing pending, no rejection streak."""
    mon = np.empty(GPS_MONITOR_SIZE)
    mon[GM_POS_SEEN] = -math.inf
    mon[GM_VEL_SEEN] = -math.inf
    mon[GM_POS_PENDING] = 0.0
    mon[GM_VEL_PENDING] = 0.0
    for c in range(GPS_CHANNELS):
        mon[GM_STREAK + c] = math.inf
    return mon


@njit(cache=True)
def gps_channel(position, component):
    """Monitor channel of a GPS scalar update: position n/e/d -> 0..2, velocity components 0..2 -> 3..5,
    the paper-mode ground speed (3) and course (4) -> 3, 4."""
    if position:
        return component
    return 3 + (component if component < 3 else component - 3)


@njit(cache=True)
def gps_record(mon, position, component, t, accepted):
    """Book one gated GPS scalar update at time ``t`` [s]: an acceptance ends the channel's rejection streak, a
    rejection starts one (or continues it)."""
    slot = GM_STREAK + gps_channel(position, component)
    mon[slot] = rejection_streak(mon[slot], t, accepted)


@njit(cache=True)
def gps_acquired(mon, t):
    """Mark position and velocity as (re)acquired at ``t``: seen now, nothing pending, no rejection streak."""
    mon[GM_POS_SEEN] = t
    mon[GM_VEL_SEEN] = t
    mon[GM_POS_PENDING] = 0.0
    mon[GM_VEL_PENDING] = 0.0
    for c in range(GPS_CHANNELS):
        mon[GM_STREAK + c] = math.inf


@njit(cache=True)
def gps_reset_due(mon, position, t, reject_s, outage_s):
    """Decide at a GPS position (``position``) or velocity event at ``t`` [s] whether its states are reset to the
    GPS instead of updated (docs/estimators.md, 'GPS re-acquisition'), and update the monitor.

    A reset is due when a reset triggered at the other kind's event is pending, when this kind returns after an
    outage longer than ``outage_s``, or when any GPS channel (position or velocity) has been rejected
    continuously for ``reject_s`` or more. A new trigger clears every streak and leaves the other kind's reset
    pending, so position and velocity are reset together. The first position event (acquisition) resets the
    position only: the first velocity fixes are fused, so that the velocity drift accumulated before the first
    fix corrects the tilt through its correlation (if they are rejected, the rejection rule resets both).

    Returns
    -------
    reset : bool
        Reset this kind's states to the GPS values (variances to R, cross-covariances zeroed).
    counted : bool
        This is a new reset event to count (not the pending half of one, not the first acquisition).
    """
    seen = GM_POS_SEEN if position else GM_VEL_SEEN
    pending = GM_POS_PENDING if position else GM_VEL_PENDING
    other_pending = GM_VEL_PENDING if position else GM_POS_PENDING
    last = mon[seen]
    mon[seen] = t
    if position and last == -math.inf:
        return True, False
    if mon[pending] > 0.0:
        mon[pending] = 0.0
        return True, False
    outage = last > -math.inf and t - last > outage_s
    rejected = False
    for c in range(GPS_CHANNELS):
        if rejected_too_long(mon[GM_STREAK + c], t, reject_s):
            rejected = True
    if not (outage or rejected):
        return False, False
    for c in range(GPS_CHANNELS):
        mon[GM_STREAK + c] = math.inf
    mon[other_pending] = 1.0
    return True, True


@njit(cache=True)
def gps_control(mon, kind, t, reject_s, outage_s, counters):
    """The GPS control step of every filter at a ``GPS_POS`` or ``GPS_VEL`` event at ``t`` [s]: whether this
    kind's states are reset to the GPS instead of fused (:func:`gps_reset_due`); a new reset event is counted in
    ``counters[C_GPS_RESETS]``."""
    reset, counted = gps_reset_due(mon, kind == GPS_POS, t, reject_s, outage_s)
    if counted:
        counters[C_GPS_RESETS] += 1
    return reset
