"""Missions as data: a tuple of legs, turned into smooth command profiles for the kinematic fixed-wing model.

A mission drives four command channels, functions of the mission time ``tau`` [s] (0 at the start of the first
leg):

``speed_m_s``
    horizontal speed of the aircraft through the air [m/s];
``climb_m_s``
    climb rate [m/s], up positive;
``turn_rad_s``
    rate of the air-relative heading [rad/s], clockwise seen from above positive (right turn);
``airborne``
    0 while the aircraft rests on the ground (or in the launcher's hand), 1 in flight: the fraction of the wind
    that carries it.

Every change of a channel is a quintic smoothstep ``s(u) = 10u^3 - 15u^4 + 6u^5`` (continuous up to the second
derivative), so attitude, body rates and specific force stay continuous. The channels are
:class:`scipy.interpolate.PPoly` objects: their derivatives and integrals (heading, height) are exact.
A loiter circle is a :class:`Turn` of ``n x 360`` deg; a descent is a :class:`ChangeAltitude` to a lower height.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PPoly


@dataclass(frozen=True)
class Still:
    """Rest on the ground (engine off, no motion).

    Attributes
    ----------
    duration_s : float
        Length of the leg [s].
    """

    duration_s: float


@dataclass(frozen=True)
class HandLaunch:
    """Throw the aircraft from rest to flying speed (the air starts to carry it).

    Attributes
    ----------
    airspeed_m_s : float
        Horizontal airspeed reached at the end of the throw [m/s].
    duration_s : float
        Length of the throw [s].
    """

    airspeed_m_s: float = 12.5
    duration_s: float = 1.5


@dataclass(frozen=True)
class Cruise:
    """Straight and level flight.

    Attributes
    ----------
    duration_s : float
        Length of the leg [s].
    """

    duration_s: float


@dataclass(frozen=True)
class Turn:
    """Level coordinated turn at constant air-relative turn rate (a loiter circle is ``360 x n`` deg).

    Attributes
    ----------
    heading_change_deg : float
        Heading change [deg]; positive turns right (clockwise seen from above).
    radius_m : float
        Radius of the air-relative circle [m] (with wind the ground track is a trochoid).
    """

    heading_change_deg: float
    radius_m: float = 100.0


@dataclass(frozen=True)
class ChangeAltitude:
    """Climb or descend at a constant rate to a height above ground, straight or circling.

    Attributes
    ----------
    to_agl_m : float
        Height above the ground at the end of the leg [m].
    rate_m_s : float
        Magnitude of the climb or descent rate [m/s].
    turn_radius_m : float
        0 for a straight climb; otherwise circle with this air-relative radius [m] while climbing.
    clockwise : bool
        Direction of the circle (True: right turn).
    """

    to_agl_m: float
    rate_m_s: float = 2.5
    turn_radius_m: float = 0.0
    clockwise: bool = True


@dataclass(frozen=True)
class Land:
    """Touch down (the height must already be 0 above ground) and slide to rest.

    Attributes
    ----------
    duration_s : float
        Time from touchdown to rest [s].
    """

    duration_s: float = 4.0


Leg = Still | HandLaunch | Cruise | Turn | ChangeAltitude | Land


@dataclass(frozen=True)
class Manoeuvre:
    """How fast the kinematic aircraft changes its flight condition, and its trim angles.

    Attributes
    ----------
    roll_in_s : float
        Duration of every turn-rate change (bank in / bank out) [s].
    pitch_transition_s : float
        Duration of every climb-rate change (pitch up / pitch over) [s].
    alpha_deg : float
        Angle of attack, constant [deg]; also the nose-up pitch of the aircraft resting on the ground.
    sideslip_per_bank : float
        Sideslip angle per bank angle [-] (a rudder-only airframe skids a little in turns).
    """

    roll_in_s: float = 4.0
    pitch_transition_s: float = 6.0
    alpha_deg: float = 3.0
    sideslip_per_bank: float = 0.05


@dataclass(frozen=True)
class Mission:
    """A flight plan: legs flown in order from rest on the ground.

    Attributes
    ----------
    legs : tuple of Leg
        The legs (:class:`Still`, :class:`HandLaunch`, :class:`Cruise`, :class:`Turn`, :class:`ChangeAltitude`,
        :class:`Land`).
    initial_heading_deg : float
        Heading of the aircraft on the ground and at launch [deg, clockwise from north].
    manoeuvre : Manoeuvre
        Transition durations and trim angles.
    """

    legs: tuple[Leg, ...]
    initial_heading_deg: float = 0.0
    manoeuvre: Manoeuvre = Manoeuvre()


@dataclass(frozen=True)
class Plan:
    """Smooth command channels of a mission (see the module docstring).

    Attributes
    ----------
    speed_m_s, climb_m_s, turn_rad_s, airborne : scipy.interpolate.PPoly
        Command channels of the mission time ``tau`` [s].
    heading0_rad : float
        Air-relative heading at ``tau = 0`` [rad].
    segments : tuple of (str, float, float)
        ``(leg name, start, end)`` [s] of every leg in mission time.
    duration_s : float
        End of the last leg [s].
    """

    speed_m_s: PPoly
    climb_m_s: PPoly
    turn_rad_s: PPoly
    airborne: PPoly
    heading0_rad: float
    segments: tuple[tuple[str, float, float], ...]
    duration_s: float

    def heading_rad(self, tau_s) -> np.ndarray:
        """Air-relative heading [rad] (unwrapped) at mission times ``tau_s`` [s]."""
        return self.heading0_rad + self.turn_rad_s.antiderivative()(tau_s)

    def height_agl_m(self, tau_s) -> np.ndarray:
        """Height above the launch ground [m] at mission times ``tau_s`` [s]."""
        return self.climb_m_s.antiderivative()(tau_s)


def smooth_channel(initial: float, ramps: list[tuple[float, float, float]]) -> PPoly:
    """A channel that holds its value between quintic smoothstep ramps.

    Parameters
    ----------
    initial : float
        Value before the first ramp.
    ramps : list of (start_s, duration_s, target)
        Non-overlapping ramps in time order; each moves the value to ``target`` over ``duration_s``.

    Returns
    -------
    scipy.interpolate.PPoly
        Piecewise quintic starting at ``tau = 0``; constant (extrapolated) after the last ramp.
    """
    breaks, coefs = [0.0], []
    value, t = float(initial), 0.0
    for start, duration, target in ramps:
        if start < t - 1e-9 or duration <= 0:
            raise ValueError(f"ramp at {start} s (duration {duration} s) overlaps the previous one ending at {t} s")
        if start > t:
            breaks.append(start)
            coefs.append([0.0, 0.0, 0.0, 0.0, 0.0, value])
        step = target - value
        breaks.append(start + duration)
        coefs.append([6 * step / duration**5, -15 * step / duration**4, 10 * step / duration**3, 0.0, 0.0, value])
        value, t = float(target), start + duration
    breaks.append(t + 1.0)
    coefs.append([0.0, 0.0, 0.0, 0.0, 0.0, value])
    return PPoly(np.array(coefs).T, np.array(breaks))


def plan_mission(mission: Mission) -> Plan:
    """Turn a :class:`Mission` into smooth command channels.

    Raises
    ------
    ValueError
        When a leg cannot be flown from the state the previous legs leave (a turn on the ground, a launch in flight,
        a landing above the ground, a climb or turn too short for its transitions).
    """
    man = mission.manoeuvre
    ramps: dict[str, list[tuple[float, float, float]]] = {"speed": [], "climb": [], "turn": [], "airborne": []}
    t, speed, agl, flying = 0.0, 0.0, 0.0, False
    segments = []

    def need(condition: bool, leg, what: str):
        if not condition:
            raise ValueError(f"mission leg {len(segments) + 1} ({leg}): {what}")

    for leg in mission.legs:
        if isinstance(leg, Still):
            need(not flying and leg.duration_s > 0, leg, "needs the aircraft on the ground and a positive duration")
            duration = leg.duration_s
        elif isinstance(leg, HandLaunch):
            need(not flying and leg.airspeed_m_s > 0 and leg.duration_s > 0, leg,
                 "needs the aircraft on the ground, a positive airspeed and duration")
            ramps["speed"].append((t, leg.duration_s, leg.airspeed_m_s))
            ramps["airborne"].append((t, leg.duration_s, 1.0))
            speed, flying, duration = leg.airspeed_m_s, True, leg.duration_s
        elif isinstance(leg, Cruise):
            need(flying and leg.duration_s > 0, leg, "needs the aircraft in flight and a positive duration")
            duration = leg.duration_s
        elif isinstance(leg, Turn):
            need(flying and leg.radius_m > 0, leg, "needs the aircraft in flight and a positive radius")
            rate = np.sign(leg.heading_change_deg) * speed / leg.radius_m
            # heading change of ramp-in + hold + ramp-out = rate * (roll_in + hold)
            hold = abs(np.radians(leg.heading_change_deg) / rate) - man.roll_in_s
            need(hold >= 0, leg, f"turn too small for two {man.roll_in_s} s roll transitions")
            ramps["turn"] += [(t, man.roll_in_s, rate), (t + man.roll_in_s + hold, man.roll_in_s, 0.0)]
            duration = 2 * man.roll_in_s + hold
        elif isinstance(leg, ChangeAltitude):
            need(flying and leg.rate_m_s > 0 and leg.to_agl_m >= 0, leg,
                 "needs the aircraft in flight, a positive rate and a target height >= 0")
            rate = np.sign(leg.to_agl_m - agl) * leg.rate_m_s
            need(rate != 0, leg, f"already at {agl} m above ground")
            # height change of ramp-in + hold + ramp-out = rate * (transition + hold)
            hold = (leg.to_agl_m - agl) / rate - man.pitch_transition_s
            need(hold >= 0, leg, f"height change too small for two {man.pitch_transition_s} s pitch transitions")
            duration = 2 * man.pitch_transition_s + hold
            ramps["climb"] += [(t, man.pitch_transition_s, rate),
                               (t + man.pitch_transition_s + hold, man.pitch_transition_s, 0.0)]
            if leg.turn_radius_m > 0:
                need(duration > 2 * man.roll_in_s, leg, "too short to circle")
                turn = (1.0 if leg.clockwise else -1.0) * speed / leg.turn_radius_m
                ramps["turn"] += [(t, man.roll_in_s, turn), (t + duration - man.roll_in_s, man.roll_in_s, 0.0)]
            agl = leg.to_agl_m
        elif isinstance(leg, Land):
            need(flying and abs(agl) < 1e-6 and leg.duration_s > 0, leg,
                 f"needs the aircraft flying at 0 m above ground (it is at {agl:.3f} m) and a positive duration")
            ramps["speed"].append((t, leg.duration_s, 0.0))
            ramps["airborne"].append((t, leg.duration_s, 0.0))
            speed, flying, duration = 0.0, False, leg.duration_s
        else:
            raise TypeError(f"unknown mission leg {leg!r}")
        segments.append((type(leg).__name__.lower(), float(t), float(t + duration)))
        t = float(t + duration)

    return Plan(speed_m_s=smooth_channel(0.0, ramps["speed"]), climb_m_s=smooth_channel(0.0, ramps["climb"]),
                turn_rad_s=smooth_channel(0.0, ramps["turn"]), airborne=smooth_channel(0.0, ramps["airborne"]),
                heading0_rad=float(np.radians(mission.initial_heading_deg)), segments=tuple(segments),
                duration_s=t)
