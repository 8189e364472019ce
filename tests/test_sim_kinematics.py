"""Kinematic consistency of the simulator's truth and the mission planner."""

from __future__ import annotations

import numpy as np
import pytest

from ingest.frames import quat_to_euler, quat_to_matrix
from sim.kinematics import Site, fly
from sim.mission import ChangeAltitude, Cruise, HandLaunch, Land, Mission, Still, Turn, plan_mission
from sim.wind import WindConfig

RATE_HZ = 250.0
DT = 1.0 / RATE_HZ
#: Every leg type, climbs and descents while circling, in gusty wind: about 100 s.
MISSION = Mission(legs=(Still(5.0), HandLaunch(), ChangeAltitude(60.0, 3.0, turn_radius_m=120.0), Cruise(5.0),
                        Turn(-90.0, radius_m=80.0), ChangeAltitude(0.0, 3.0, turn_radius_m=150.0, clockwise=False),
                        Land(), Still(3.0)), initial_heading_deg=30.0)
GUSTY = WindConfig(speed_m_s=4.0, from_deg=200.0, slow_sigma_m_s=0.5, slow_tau_s=60.0, gust_sigma_m_s=1.5,
                   gust_tau_s=2.0)


@pytest.fixture(scope="module")
def truth():
    return fly(MISSION, Site(), GUSTY, np.random.default_rng(42), rate_hz=RATE_HZ)


def _quat_product(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])


def test_integrating_true_body_rates_reproduces_the_true_attitude(truth):
    # strapdown attitude update with the trapezoidal rotation vector and the coning correction (Savage)
    rates = truth.rates_rad_s
    rotation = 0.5 * DT * (rates[1:] + rates[:-1]) + DT * DT / 12.0 * np.cross(rates[:-1], rates[1:])
    angle = np.linalg.norm(rotation, axis=1)
    half_sinc = 0.5 * np.sinc(angle / (2 * np.pi))  # sin(angle / 2) / angle
    increments = np.column_stack([np.cos(angle / 2), rotation * half_sinc[:, None]])
    q = truth.q_nb[0].copy()
    worst_rad = 0.0
    for k, increment in enumerate(increments, start=1):
        q = _quat_product(q, increment)
        if k % 250 == 0 or k == len(increments):
            q /= np.linalg.norm(q)
            error = quat_to_matrix(q).T @ quat_to_matrix(truth.q_nb[k])
            worst_rad = max(worst_rad, np.arccos(np.clip((np.trace(error) - 1) / 2, -1.0, 1.0)))
    assert worst_rad < 2e-6  # over ~100 s of launch, climbing and descending turns, landing


def test_specific_force_integrates_to_the_true_velocity_and_position(truth):
    accel = np.einsum("nij,nj->ni", quat_to_matrix(truth.q_nb), truth.specific_force_m_s2)
    accel[:, 2] += truth.gravity_m_s2
    velocity = truth.vel_ned_m_s[0] + np.vstack([np.zeros((1, 3)),
                                                 np.cumsum(0.5 * DT * (accel[1:] + accel[:-1]), axis=0)])
    assert np.abs(velocity - truth.vel_ned_m_s).max() < 1e-4  # [m/s]
    position = truth.pos_ned_m[0] + np.vstack([np.zeros((1, 3)),
                                               np.cumsum(0.5 * DT * (velocity[1:] + velocity[:-1]), axis=0)])
    assert np.abs(position - truth.pos_ned_m).max() < 5e-3  # [m]


def test_rest_on_the_ground_reads_gravity_and_no_rotation(truth):
    still = truth.segment_mask("still")
    assert np.abs(truth.rates_rad_s[still]).max() == 0.0
    assert np.abs(truth.vel_ned_m_s[still]).max() == 0.0
    pitch = np.radians(MISSION.manoeuvre.alpha_deg)
    g = truth.gravity_m_s2[still]
    np.testing.assert_allclose(truth.specific_force_m_s2[still],
                               np.column_stack([g * np.sin(pitch), 0 * g, -g * np.cos(pitch)]), atol=1e-12)
    # the air moves past the resting aircraft: airspeed = wind speed
    np.testing.assert_allclose(truth.airspeed_m_s[still], np.linalg.norm(truth.wind_ned_m_s[still], axis=1))


def test_wind_triangle_and_flight_condition(truth):
    np.testing.assert_allclose(truth.airspeed_m_s, np.linalg.norm(truth.vel_ned_m_s - truth.wind_ned_m_s, axis=1),
                               rtol=0, atol=1e-12)
    cruise = truth.segment_mask("cruise")
    np.testing.assert_allclose(truth.airspeed_m_s[cruise], 12.5, atol=1e-9)
    np.testing.assert_allclose(truth.pos_ned_m[cruise, 2], -60.0, atol=1e-9)
    # the ground moves by the wind: ground speed differs from airspeed in cruise by up to the wind speed
    ground_speed = np.linalg.norm(truth.vel_ned_m_s[cruise], axis=1)
    assert np.abs(ground_speed - 12.5).max() > 1.0
    assert np.abs(truth.q_nb[:, 0] ** 2 + np.sum(truth.q_nb[:, 1:] ** 2, axis=1) - 1).max() < 1e-12


def test_coordinated_turn_bank_and_heading_change(truth):
    turn_legs = [(start, end) for name, start, end in truth.segments if name == "turn"]
    (start, end), = turn_legs
    roll, _, yaw = quat_to_euler(truth.q_nb)
    steady = (truth.tau_s > start + 4.5) & (truth.tau_s < end - 4.5)
    expected_bank = -np.arctan(12.5**2 / (80.0 * 9.80665))  # left turn
    np.testing.assert_allclose(roll[steady], expected_bank, atol=np.radians(0.5))  # + small sideslip coupling
    at = np.searchsorted(truth.tau_s, [start, end])
    heading_change = np.degrees(np.unwrap(yaw)[at[1]] - np.unwrap(yaw)[at[0]])
    assert heading_change == pytest.approx(-90.0, abs=0.01)
    # the aircraft ends at rest on the ground, heights planned exactly
    assert truth.pos_ned_m[-1, 2] == pytest.approx(0.0, abs=1e-9)
    assert truth.alt_m.max() == pytest.approx(Site().ground_alt_m + 60.0, abs=1e-9)


def test_body_rates_and_specific_force_are_continuous(truth):
    # a continuous signal's largest change between samples halves when the rate doubles; a step would not shrink
    fine = fly(MISSION, Site(), GUSTY, np.random.default_rng(42), rate_hz=2 * RATE_HZ)
    for name in ("rates_rad_s", "specific_force_m_s2"):
        coarse_jump = np.abs(np.diff(getattr(truth, name), axis=0)).max()
        fine_jump = np.abs(np.diff(getattr(fine, name), axis=0)).max()
        assert coarse_jump / fine_jump == pytest.approx(2.0, rel=0.1), name


def test_truth_at_other_times(truth):
    on_grid = truth.at(truth.time_us[::7])
    for name in ("pos_ned_m", "q_nb", "rates_rad_s", "lat_deg", "airspeed_m_s", "tau_s"):
        np.testing.assert_array_equal(getattr(on_grid, name), getattr(truth, name)[::7], err_msg=name)
    halfway = truth.at(truth.time_us[:-1] + 2000)
    np.testing.assert_allclose(halfway.pos_ned_m, 0.5 * (truth.pos_ned_m[1:] + truth.pos_ned_m[:-1]), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(halfway.q_nb, axis=1), 1.0, atol=1e-12)
    angle = 2 * np.arccos(np.clip(np.abs(np.sum(halfway.q_nb * truth.q_nb[:-1], axis=1)), 0.0, 1.0))
    assert angle.max() < 0.5 * DT * np.linalg.norm(truth.rates_rad_s, axis=1).max() + 1e-9  # half a step's turn
    with pytest.raises(ValueError, match="outside"):
        truth.at([truth.time_us[-1] + 1])


def test_duration_extends_the_last_leg():
    mission = Mission(legs=(Still(2.0), HandLaunch(), Turn(360.0, radius_m=100.0)))
    truth = fly(mission, Site(), WindConfig(speed_m_s=0.0, slow_sigma_m_s=0.0), np.random.default_rng(0),
                duration_s=200.0, rate_hz=50.0)
    assert truth.tau_s[-1] == pytest.approx(200.0)
    # after the planned circle the aircraft keeps flying straight at its last condition
    late = truth.tau_s > plan_mission(mission).duration_s + 1
    np.testing.assert_allclose(truth.rates_rad_s[late], 0.0, atol=1e-12)
    np.testing.assert_allclose(truth.airspeed_m_s[late], 12.5)


@pytest.mark.parametrize("legs, message", [
    ((Turn(90.0),), "needs the aircraft in flight"),
    ((Still(1.0), HandLaunch(), HandLaunch()), "needs the aircraft on the ground"),
    ((Still(1.0), HandLaunch(), ChangeAltitude(50.0), Cruise(1.0), Land()), "0 m above ground"),
    ((Still(1.0), HandLaunch(), ChangeAltitude(5.0, rate_m_s=3.0)), "too small for two"),
    ((Still(1.0), HandLaunch(), Turn(5.0)), "turn too small"),
])
def test_unflyable_missions_are_rejected(legs, message):
    with pytest.raises(ValueError, match=message):
        plan_mission(Mission(legs=legs))
