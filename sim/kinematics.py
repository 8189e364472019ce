"""Kinematic fixed-wing model: fly a mission plan through the wind and return the true state.

Air-relative velocity ``v_air = (V cos psi, V sin psi, -h_dot)`` from the plan's horizontal airspeed ``V``, heading
``psi`` and climb rate ``h_dot``; ground velocity ``v = v_air + airborne * wind``. Attitude
``R_nb = Rz(psi) Ry(gamma) Rx(mu) Rz(-beta) Ry(alpha)`` with flight-path angle ``gamma = atan2(h_dot, V)``,
coordinated-turn bank ``tan mu = V psi_dot / g``, sideslip ``beta = k mu`` and constant angle of attack ``alpha``.
Velocity, acceleration, attitude and body rates are evaluated analytically from the smooth plan (no numerical
differentiation); only the horizontal position is integrated (fourth-order corrected trapezoid). Specific force
``f_b = R^T (a_n - g_n)`` with local normal gravity. The earth's rotation is ignored (below MEMS gyro resolution).

With turbulence (``WindConfig.turbulence``) the wind gains the Dryden and discrete-gust velocity ``g`` (3-D) and the
aircraft responds (:mod:`sim.response`): ``v = v_air + airborne * (wind + f)`` with ``f`` the lagged ``g``, so the
airspeed ``|v - wind - g|`` carries the high-passed gust; the height gains a bounded displacement (rate ``f_d``); the
Euler angles ``(mu, gamma, psi)`` of the velocity axes gain the response's perturbations and their rates enter
``W(Theta)``, so rates and specific force stay exact (docs/evaluation.md, 'Turbulence (Dryden and discrete gusts)').
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
import pandas as pd

from estimators.environment import STANDARD_GRAVITY_M_S2, local_gravity_m_s2, ned_to_geodetic
from ingest.frames import euler_to_quat
from sim.mission import Mission, plan_mission
from sim.response import Response, respond
from sim.turbulence import TurbulenceField, turbulence_field
from sim.wind import WindConfig, wind_ned


@dataclass(frozen=True)
class Site:
    """Where and when the flight happens, and the day's atmosphere.

    Attributes
    ----------
    lat_deg, lon_deg : float
        Launch point, WGS-84 [deg] (default: the paper's field site).
    ground_alt_m : float
        Ground altitude above MSL at the launch point [m].
    start_utc : str
        UTC time of the first sample, ISO 8601 (default: an autumn morning, sun about 29 deg high).
    log_start_s : float
        Log clock at the first sample [s since autopilot boot].
    sea_level_pressure_pa : float
        The day's true sea-level pressure (QNH) [Pa]; the ISA barometric formula gives the pressure aloft.
    ground_temp_c : float
        Air temperature at the ground [degC]; it falls with the ISA lapse rate aloft.
    """

    lat_deg: float = 34.983
    lon_deg: float = 108.934
    ground_alt_m: float = 630.0
    start_utc: str = "2025-10-15T01:30:00Z"
    log_start_s: float = 20.0
    sea_level_pressure_pa: float = 101325.0
    ground_temp_c: float = 10.0

    @property
    def utc_offset_s(self) -> float:
        """UTC unix time minus log clock [s]."""
        return pd.Timestamp(self.start_utc).timestamp() - self.log_start_s


@dataclass(frozen=True)
class Truth:
    """True state on the IMU time grid (all arrays share the first axis N).

    Attributes
    ----------
    time_us : numpy.ndarray of int64, shape (N,)
        Log clock [us since boot].
    tau_s : numpy.ndarray, shape (N,)
        Mission time [s], 0 at the first sample.
    utc_offset_s : float
        UTC unix time = ``time_us / 1e6 + utc_offset_s`` [s].
    origin : tuple of 3 float
        NED origin = launch point (lat [deg], lon [deg], alt MSL [m]).
    segments : tuple of (str, float, float)
        Mission legs as ``(name, start, end)`` in mission time [s].
    pos_ned_m, vel_ned_m_s, accel_ned_m_s2 : numpy.ndarray, shape (N, 3)
        Position (down = -(alt - origin alt)), ground velocity and acceleration, NED [m, m/s, m/s^2].
    lat_deg, lon_deg, alt_m : numpy.ndarray, shape (N,)
        Geodetic position [deg, deg, m MSL].
    q_nb : numpy.ndarray, shape (N, 4)
        Attitude quaternion (w, x, y, z), body FRD -> NED.
    rates_rad_s : numpy.ndarray, shape (N, 3)
        Body angular rates (p, q, r) [rad/s].
    specific_force_m_s2 : numpy.ndarray, shape (N, 3)
        Specific force in body FRD [m/s^2] (about (0, 0, -g) at rest).
    gravity_m_s2 : numpy.ndarray, shape (N,)
        Local normal gravity [m/s^2].
    wind_ned_m_s : numpy.ndarray, shape (N, 3)
        Wind (velocity of the air mass), NED [m/s]; the down component is nonzero only with turbulence.
    airspeed_m_s : numpy.ndarray, shape (N,)
        True airspeed ``|v - wind|`` (3-D) [m/s].
    airborne : numpy.ndarray, shape (N,)
        0 on the ground, 1 in flight (smooth in between).
    """

    time_us: np.ndarray
    tau_s: np.ndarray
    utc_offset_s: float
    origin: tuple[float, float, float]
    segments: tuple[tuple[str, float, float], ...]
    pos_ned_m: np.ndarray
    vel_ned_m_s: np.ndarray
    accel_ned_m_s2: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    q_nb: np.ndarray
    rates_rad_s: np.ndarray
    specific_force_m_s2: np.ndarray
    gravity_m_s2: np.ndarray
    wind_ned_m_s: np.ndarray
    airspeed_m_s: np.ndarray
    airborne: np.ndarray

    @property
    def time_s(self) -> np.ndarray:
        """Log clock [s]."""
        return self.time_us / 1e6

    def at(self, time_us) -> Truth:
        """The true state at log-clock times ``time_us`` [us] inside the sampled span.

        Linear interpolation between neighbouring samples (exact at the samples themselves; the motion is smooth,
        so the error over one 4 ms step is below 1e-6 of the signal); quaternions are interpolated on one
        hemisphere and renormalised.
        """
        time_us = np.asarray(time_us, dtype=np.int64)
        period_us = self.time_us[1] - self.time_us[0]
        offset_us = time_us - self.time_us[0]
        if len(time_us) and (offset_us.min() < 0 or time_us.max() > self.time_us[-1]):
            raise ValueError("times outside the simulated span")
        last = len(self.time_us) - 1
        i = np.minimum(offset_us // period_us, last)
        j = np.minimum(i + 1, last)
        frac = (offset_us - i * period_us) / period_us
        between = frac > 0

        def lerp(values):
            weight = frac.reshape(-1, *([1] * (values.ndim - 1)))
            return np.where(between.reshape(weight.shape), values[i] + weight * (values[j] - values[i]), values[i])

        arrays = {f.name: lerp(getattr(self, f.name)) for f in fields(self)
                  if isinstance(getattr(self, f.name), np.ndarray) and f.name not in ("time_us", "q_nb")}
        q0, q1 = self.q_nb[i], self.q_nb[j]
        q1 = np.where(np.sum(q0 * q1, axis=1, keepdims=True) < 0, -q1, q1)
        q = q0 + frac[:, None] * (q1 - q0)
        q = np.where(between[:, None], q / np.linalg.norm(q, axis=1, keepdims=True), q0)
        return replace(self, time_us=time_us, q_nb=q, **arrays)

    def segment_mask(self, name: str, margin_s: float = 0.0) -> np.ndarray:
        """Samples inside every leg called ``name`` (``"still"``, ``"turn"`` ...), ``margin_s`` [s] in from its ends."""
        mask = np.zeros(len(self.tau_s), dtype=bool)
        for leg, start, end in self.segments:
            if leg == name:
                mask |= (self.tau_s >= start + margin_s) & (self.tau_s <= end - margin_s)
        return mask


def _quat_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products ``a (x) b`` of (N, 4) quaternions (w, x, y, z)."""
    aw, ax, ay, az = a.T
    bw, bx, by, bz = b.T
    return np.column_stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (N, 3) arrays (``np.cross`` is several times slower on long arrays)."""
    return np.column_stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]])


def _to_body(q_nb: np.ndarray, v_ned: np.ndarray) -> np.ndarray:
    """``R(q)^T v`` for (N, 4) unit quaternions body -> NED and (N, 3) vectors: NED vectors in body axes."""
    w, u = q_nb[:, :1], -q_nb[:, 1:]
    t = 2.0 * _cross(u, v_ned)
    return v_ned + w * t + _cross(u, t)


def _bank_rates(speed, speed_rate, turn, turn_rate):
    """Coordinated-turn bank ``mu = atan(V psi_dot / g0)`` [rad] and its rate [rad/s]."""
    load = speed * turn / STANDARD_GRAVITY_M_S2
    return np.arctan(load), (speed_rate * turn + speed * turn_rate) / STANDARD_GRAVITY_M_S2 / (1.0 + load * load)


def _turbulence(wind: WindConfig, plan, duration_s: float,
                rng: np.random.Generator) -> tuple[TurbulenceField, Response]:
    """Draw the turbulence along the plan and the aircraft's response to it."""
    config = wind.turbulence
    field = turbulence_field(config, duration_s, plan.speed_m_s, plan.height_agl_m, plan.heading_rad, rng)
    knots = field.knot_tau_s
    speed = np.maximum(plan.speed_m_s(knots), config.min_speed_m_s)
    response = respond(knots, field.ned_m_s(knots), speed, plan.heading_rad(knots), plan.height_agl_m(knots),
                       plan.airborne(knots))
    return field, response


def fly(mission: Mission, site: Site, wind: WindConfig, rng: np.random.Generator, *, duration_s: float | None = None,
        rate_hz: float = 250.0) -> Truth:
    """Fly ``mission`` at ``site`` through a wind realisation and return the true state.

    Parameters
    ----------
    mission : Mission
        Flight plan (starts at rest on the ground).
    site : Site
        Location, time and atmosphere.
    wind : WindConfig
        Wind model; its random components are drawn from ``rng`` (turbulence, when configured, after the others).
    rng : numpy.random.Generator
        Source of the wind draws.
    duration_s : float, optional
        Simulated time [s]; default the mission's length. Shorter truncates the mission, longer holds the last
        leg's condition (a loiter keeps circling, a landed aircraft keeps resting).
    rate_hz : float
        Sample rate of the truth [Hz] (the IMU rate).

    Returns
    -------
    Truth
    """
    plan = plan_mission(mission)
    duration_s = plan.duration_s if duration_s is None else float(duration_s)
    if duration_s <= 0:
        raise ValueError(f"duration_s must be positive, got {duration_s}")
    period_us = 1e6 / rate_hz
    if period_us != round(period_us):
        raise ValueError(f"rate_hz={rate_hz} does not give a whole number of microseconds per sample")
    n = round(duration_s * rate_hz) + 1
    if n < 2:
        raise ValueError(f"duration_s={duration_s} is shorter than one sample interval at {rate_hz} Hz")
    time_us = round(site.log_start_s * 1e6) + np.arange(n, dtype=np.int64) * round(period_us)
    tau = np.arange(n) / rate_hz
    dt = 1.0 / rate_hz

    speed, speed_rate = plan.speed_m_s(tau), plan.speed_m_s(tau, 1)
    climb, climb_rate = plan.climb_m_s(tau), plan.climb_m_s(tau, 1)
    turn, turn_rate = plan.turn_rad_s(tau), plan.turn_rad_s(tau, 1)
    airborne, airborne_rate = plan.airborne(tau), plan.airborne(tau, 1)
    heading = plan.heading_rad(tau)
    height = plan.height_agl_m(tau)
    wind_n, wind_rate = wind_ned(wind, tau, rng)

    cos_h, sin_h = np.cos(heading), np.sin(heading)
    vel_air = np.column_stack([speed * cos_h, speed * sin_h, -climb])
    vel = vel_air + airborne[:, None] * wind_n
    accel = (np.column_stack([speed_rate * cos_h - speed * sin_h * turn, speed_rate * sin_h + speed * cos_h * turn,
                              -climb_rate])
             + airborne_rate[:, None] * wind_n + airborne[:, None] * wind_rate)
    if wind.turbulence is not None:
        field, response = _turbulence(wind, plan, tau[-1], rng)
        vel = vel + response.velocity_ned_m_s(tau)
        accel = accel + response.velocity_ned_m_s(tau, 1)
        height = height - response.down_m(tau)
        air_ned = wind_n + field.ned_m_s(tau)
    else:
        response, air_ned = None, wind_n
    # horizontal position: trapezoid corrected with the end-point accelerations (exact for cubic motion)
    step = 0.5 * dt * (vel[1:, :2] + vel[:-1, :2]) + dt * dt / 12.0 * (accel[:-1, :2] - accel[1:, :2])
    pos = np.column_stack([np.vstack([np.zeros((1, 2)), np.cumsum(step, axis=0)]), -height])
    lat, lon, alt = ned_to_geodetic(pos[:, 0], pos[:, 1], pos[:, 2], site.lat_deg, site.lon_deg, site.ground_alt_m)

    # attitude q = q_E(mu, gamma, psi) q_B: E = Rz(psi) Ry(gamma) Rx(mu) (velocity axes), B = Rz(-beta) Ry(alpha)
    man = mission.manoeuvre
    gamma = np.arctan2(climb, speed)
    denom = speed * speed + climb * climb
    gamma_rate = np.divide(speed * climb_rate - climb * speed_rate, denom, out=np.zeros(n), where=denom > 0)
    bank, bank_rate = _bank_rates(speed, speed_rate, turn, turn_rate)
    beta, beta_rate = man.sideslip_per_bank * bank, man.sideslip_per_bank * bank_rate
    if response is not None:  # perturbed Euler angles and rates of the outer rotation
        euler, euler_rate = response.euler_rad(tau), response.euler_rad(tau, 1)
        bank, gamma, heading = bank + euler[:, 0], gamma + euler[:, 1], heading + euler[:, 2]
        bank_rate, gamma_rate = bank_rate + euler_rate[:, 0], gamma_rate + euler_rate[:, 1]
        turn = turn + euler_rate[:, 2]
    alpha = np.radians(man.alpha_deg)
    q_inner = euler_to_quat(np.zeros(n), np.full(n, alpha), -beta)
    q_nb = _quat_product(euler_to_quat(bank, gamma, heading), q_inner)
    q_nb = np.where(q_nb[:, :1] < 0, -q_nb, q_nb)
    # body rate of E from its Euler rates (omega = W(Theta) Theta_dot), carried through B, plus B's own rate
    cb, sb, cg, sg = np.cos(bank), np.sin(bank), np.cos(gamma), np.sin(gamma)
    omega_outer = np.column_stack([bank_rate - sg * turn, cb * gamma_rate + sb * cg * turn,
                                   -sb * gamma_rate + cb * cg * turn])
    rates = _to_body(q_inner, omega_outer) + np.outer(-beta_rate, [-np.sin(alpha), 0.0, np.cos(alpha)])

    gravity = local_gravity_m_s2(lat, alt)
    accel_minus_g = accel - np.column_stack([np.zeros((n, 2)), gravity])
    specific_force = _to_body(q_nb, accel_minus_g)
    return Truth(time_us=time_us, tau_s=tau, utc_offset_s=site.utc_offset_s,
                 origin=(site.lat_deg, site.lon_deg, site.ground_alt_m), segments=plan.segments,
                 pos_ned_m=pos, vel_ned_m_s=vel, accel_ned_m_s2=accel, lat_deg=lat, lon_deg=lon, alt_m=alt,
                 q_nb=q_nb, rates_rad_s=rates, specific_force_m_s2=specific_force, gravity_m_s2=gravity,
                 wind_ned_m_s=air_ned, airspeed_m_s=np.linalg.norm(vel - air_ned, axis=1), airborne=airborne)
