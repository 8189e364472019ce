"""GPS re-acquisition policy shared by the three filters (docs/estimators.md, 'GPS re-acquisition').

A position or velocity component rejected continuously for ``T_rej``, or GPS back after an outage longer than
``T_out``, resets position and velocity to the GPS (:func:`gps_reset_due`); the monitor is a small float64 array
(:func:`gps_monitor`) with the slots ``GM_*``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

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
    if accepted:
        mon[slot] = math.inf
    elif mon[slot] == math.inf:
        mon[slot] = t


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
        if t - mon[GM_STREAK + c] >= reject_s:
            rejected = True
    if not (outage or rejected):
        return False, False
    for c in range(GPS_CHANNELS):
        mon[GM_STREAK + c] = math.inf
    mon[other_pending] = 1.0
    return True, True
