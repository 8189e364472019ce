"""Kinematic response of a small fixed-wing aircraft to turbulence: how a gust moves it, not only the air.

See docs/evaluation.md, 'Turbulence (Dryden and discrete gusts)'. Inputs are the turbulence velocity ``g`` (NED,
Dryden plus discrete gusts) at the spline knots. The aircraft's horizontal ground velocity gains ``airborne * f``
with the first-order lag ``f = g / (1 + T_h s)`` (speed / phugoid mode with the autopilot's energy control); its
height changes by ``-b(h / H_g) z`` with ``z = T_z / ((1 + T_w s)(1 + T_z s)) g_d``: the rate ``f_d = s z`` follows a
vertical gust after ``T_w`` and the altitude hold takes the height change back over ``T_z`` (bounded); the quintic
smoothstep ``b`` blends it out below ``H_g`` above ground (launch, landing: the aircraft touches down on the ground).
The gust relative to the aircraft, ``g - f`` in flight-path axes (``u`` forward, ``v`` right, ``w`` down) over the
airspeed ``V``, perturbs the Euler angles (small-angle, added to the coordinated-flight ones):

* pitch ``dtheta = lag_{T_theta}(k_w w/V - k_u u/V)``: the nose turns part-way toward the relative wind (a downdraft
  raises the air-relative flight path), and a head gust (``u < 0``, more lift) pitches it up;
* yaw ``dpsi = lag_{T_beta}(-v/V)``: weathercocking, so the gust sideslip ``beta = -v/V - dpsi`` decays with
  ``T_beta``;
* roll ``dphi = lag_{T_phi}(-k_phi beta)``: the dihedral effect rolls away from the sideslip and the autopilot
  restores the wings within ``T_phi``.

The lags are discretised at the knot rate (bilinear, :func:`scipy.signal.cont2discrete`), started in their steady
state, multiplied by ``airborne`` (the displacement by ``b``) and joined by cubic splines, so velocity perturbation,
Euler perturbations and their exact derivatives (acceleration, Euler rates) are smooth and mutually consistent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.signal import cont2discrete, lfilter, lfilter_zi

#: Lag of the horizontal ground velocity behind the air [s]: about half the phugoid period
#: ``pi sqrt(2) V / g`` = 5.7 s at 12.5 m/s, and the few-second time constant of the autopilot's energy control.
HORIZONTAL_LAG_S = 3.0
#: Lag of the vertical velocity behind a vertical gust [s] (heave plus pitch response of a light, low wing-loading
#: aircraft, slowed by the pitch damping of the autopilot).
VERTICAL_LAG_S = 1.0
#: Time the altitude hold takes to remove the height change [s].
ALTITUDE_HOLD_S = 5.0
#: Height above ground below which the vertical displacement is blended out [m] (above the largest displacement, so
#: the aircraft never touches the ground early; vertical gusts vanish at the ground and the autopilot holds the
#: height tightly at launch and landing).
GROUND_BLEND_M = 30.0
#: Pitch change per air-relative flight-path change ``w/V`` [-] and per relative airspeed change ``-u/V`` [rad].
PITCH_PER_FLIGHT_PATH = 0.5
PITCH_PER_AIRSPEED = 0.3
#: Pitch response time [s] (short period of a small UAV with its pitch damper, 0.3-0.5 s).
PITCH_LAG_S = 0.5
#: Weathercock time constant of the sideslip [s] (directional stability of a small UAV, about 0.5 s).
WEATHERCOCK_LAG_S = 0.5
#: Roll per sideslip (dihedral effect) [rad/rad] and the roll restoring time of the autopilot [s].
ROLL_PER_SIDESLIP = 3.0
ROLL_LAG_S = 1.0


@dataclass(frozen=True)
class Response:
    """Perturbations of the aircraft's motion by turbulence, smooth functions of the mission time [s].

    Attributes
    ----------
    velocity_ne_m_s : scipy.interpolate.CubicSpline
        Added horizontal ground velocity (north, east) [m/s].
    down_m : scipy.interpolate.CubicSpline
        Added displacement down [m] (its derivative is the added down velocity).
    euler_rad : scipy.interpolate.CubicSpline
        Added (roll, pitch, yaw) [rad] (derivative 1: their rates [rad/s]).
    """

    velocity_ne_m_s: CubicSpline
    down_m: CubicSpline
    euler_rad: CubicSpline

    def velocity_ned_m_s(self, tau_s, derivative: int = 0) -> np.ndarray:
        """Added ground velocity NED [m/s] (``derivative=1``: acceleration [m/s^2]) at mission times [s]."""
        return np.column_stack([self.velocity_ne_m_s(tau_s, derivative), self.down_m(tau_s, derivative + 1)])


def _filter(num, den, dt_s: float, signal: np.ndarray) -> np.ndarray:
    """Continuous transfer function ``num / den`` (polynomials in s) applied to knots ``dt_s`` apart, started in
    the steady state of the first value."""
    b, a, _ = cont2discrete((num, den), dt_s, method="bilinear")
    b = np.ravel(b)
    zi = lfilter_zi(b, a)
    return lfilter(b, a, signal, zi=zi * signal[0])[0]


def _lag(time_constant_s: float, dt_s: float, signal: np.ndarray) -> np.ndarray:
    return _filter([1.0], [time_constant_s, 1.0], dt_s, signal)


def respond(knot_tau_s: np.ndarray, gust_ned_m_s: np.ndarray, speed_m_s: np.ndarray, heading_rad: np.ndarray,
            height_m: np.ndarray, airborne: np.ndarray) -> Response:
    """Aircraft response to the turbulence sampled at equally spaced knots.

    Parameters
    ----------
    knot_tau_s : numpy.ndarray, shape (K,)
        Knot times [s], equally spaced.
    gust_ned_m_s : numpy.ndarray, shape (K, 3)
        Turbulence velocity of the air, NED [m/s].
    speed_m_s : numpy.ndarray, shape (K,)
        Airspeed [m/s] (positive: floor it on the ground).
    heading_rad : numpy.ndarray, shape (K,)
        Air-relative heading [rad].
    height_m : numpy.ndarray, shape (K,)
        Planned height above ground [m].
    airborne : numpy.ndarray, shape (K,)
        0 on the ground, 1 in flight.

    Returns
    -------
    Response
    """
    dt = float(knot_tau_s[1] - knot_tau_s[0])
    vertical = np.polymul([VERTICAL_LAG_S, 1.0], [ALTITUDE_HOLD_S, 1.0])
    rise_m = _filter([ALTITUDE_HOLD_S], vertical, dt, gust_ned_m_s[:, 2])  # z, down
    follow = np.column_stack([_lag(HORIZONTAL_LAG_S, dt, gust_ned_m_s[:, 0]),
                              _lag(HORIZONTAL_LAG_S, dt, gust_ned_m_s[:, 1]),
                              _filter([ALTITUDE_HOLD_S, 0.0], vertical, dt, gust_ned_m_s[:, 2])])
    u_ground = np.clip(height_m / GROUND_BLEND_M, 0.0, 1.0)
    ground = u_ground**3 * (10.0 - 15.0 * u_ground + 6.0 * u_ground**2)
    relative = gust_ned_m_s - follow
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    u, v = c * relative[:, 0] + s * relative[:, 1], -s * relative[:, 0] + c * relative[:, 1]
    w = relative[:, 2]
    yaw = _lag(WEATHERCOCK_LAG_S, dt, -v / speed_m_s)
    sideslip = -v / speed_m_s - yaw
    roll = _lag(ROLL_LAG_S, dt, -ROLL_PER_SIDESLIP * sideslip)
    pitch = _lag(PITCH_LAG_S, dt, (PITCH_PER_FLIGHT_PATH * w - PITCH_PER_AIRSPEED * u) / speed_m_s)
    weight = airborne[:, None]
    return Response(velocity_ne_m_s=CubicSpline(knot_tau_s, weight * follow[:, :2], axis=0),
                    down_m=CubicSpline(knot_tau_s, ground * rise_m),
                    euler_rad=CubicSpline(knot_tau_s, weight * np.column_stack([roll, pitch, yaw]), axis=0))
