"""Dryden turbulence, discrete gusts and the aircraft's response (docs/evaluation.md, 'Turbulence (Dryden and
discrete gusts)'): spectra, formulas, gust shape, determinism, exact derivatives and strapdown consistency."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.signal import welch

from app.cli import main
from ingest.frames import quat_to_euler, quat_to_matrix
from sim.kinematics import fly
from sim.mission import plan_mission
from sim.scenarios import SCENARIOS
from sim.turbulence import (
    DiscreteGust,
    TurbulenceConfig,
    dryden_autocorrelation,
    dryden_knots,
    dryden_psd,
    dryden_scales,
    gust_profile,
    turbulence_field,
)
from sim.wind import wind_ned

RATE_HZ = 250.0
DT = 1.0 / RATE_HZ
SPEED_M_S, LENGTH_M = 12.5, 40.0
#: Short correlation (convective boundary layer) for the long statistical draw, at 5 Hz knots.
SHORT = TurbulenceConfig(sigma_m_s=(1.5, 1.5, 1.0), length_scale_m=LENGTH_M, knot_rate_hz=5.0)
N_KNOTS = 100_000  # 20000 s, about 6000 correlation times


@pytest.fixture(scope="module")
def long_draw():
    return dryden_knots(SHORT, np.full(N_KNOTS, SPEED_M_S), np.full(N_KNOTS, 150.0), np.random.default_rng(5))


@pytest.fixture(scope="module")
def turbulent():
    scenario = SCENARIOS["turbulent"]
    flights = {}
    for name, wind in (("turbulent", scenario.wind),
                       ("no_gusts", replace(scenario.wind, turbulence=replace(scenario.wind.turbulence, gusts=()))),
                       ("smooth", replace(scenario.wind, turbulence=None))):
        flights[name] = fly(scenario.mission, scenario.site, wind, np.random.default_rng(scenario.seed))
    return flights


def test_scale_lengths_and_intensities_match_hand_computed_values():
    # h [ft] -> (0.177 + 0.000823 h): 10 -> 0.18523, 100 -> 0.2593, 492.1 -> 0.58202, 1000 -> 1
    length, sigma = dryden_scales([0.0, 30.48, 150.0, 304.8, 457.2, 914.4], 10.0)
    np.testing.assert_allclose(length[:, 0], [75.65 * 0.3048, 505.2 * 0.3048, 942.2 * 0.3048, 304.8, 1375 * 0.3048,
                                              1750 * 0.3048], rtol=2e-4)
    np.testing.assert_array_equal(length[:, 0], length[:, 1])
    np.testing.assert_allclose(length[:, 2], [3.048, 30.48, 150.0, 304.8, 419.1, 533.4])
    np.testing.assert_allclose(sigma[:, 2], 1.0)  # 0.1 W20
    np.testing.assert_allclose(sigma[:, 0], [1.9631, 1.7158, 1.2417, 1.0, 1.0, 1.0], rtol=2e-4)
    np.testing.assert_array_equal(sigma[:, 0], sigma[:, 1])
    scenario_sigma = dryden_scales(150.0, SCENARIOS["turbulent"].wind.turbulence.w20_m_s)[1][0]
    np.testing.assert_allclose(scenario_sigma, [1.49, 1.49, 1.2], atol=0.005)


def test_long_draw_has_the_dryden_variance_autocorrelation_and_spectrum(long_draw):
    tau_s = LENGTH_M / SPEED_M_S
    np.testing.assert_allclose(long_draw.std(axis=0), SHORT.sigma_m_s, rtol=0.04)
    assert np.abs(long_draw.mean(axis=0)).max() < 0.05
    for axis, name in enumerate("uvw"):
        x = long_draw[:, axis]
        sigma = SHORT.sigma_m_s[axis]
        for lag_knots in (4, 8, 16, 32):  # 0.25 .. 2 tau
            empirical = np.mean(x[:-lag_knots] * x[lag_knots:]) / sigma**2
            expected = dryden_autocorrelation(lag_knots / 5.0, 1.0, LENGTH_M, SPEED_M_S, name)
            assert empirical == pytest.approx(expected, abs=0.05), (name, lag_knots)  # ~3 standard errors
        freq_hz, psd = welch(x, fs=5.0, nperseg=1024)
        band = (freq_hz >= 0.02) & (freq_hz <= 0.5)  # aliasing of the sampled spectrum < 2 % below 0.5 Hz
        model = 2 * np.pi * dryden_psd(2 * np.pi * freq_hz[band], sigma, LENGTH_M, SPEED_M_S, name)  # per Hz
        ratio = psd[band] / model
        assert np.mean(ratio) == pytest.approx(1.0, abs=0.05), name
        assert np.all(np.abs(np.convolve(ratio, np.ones(8) / 8, "valid") - 1.0) < 0.2), name
    assert 1.0 / tau_s > 0.02  # the band spans the corner frequency


def test_same_seed_same_turbulence_and_no_turbulence_draws_nothing():
    def draw(seed):
        return dryden_knots(SHORT, np.full(200, SPEED_M_S), np.full(200, 150.0), np.random.default_rng(seed))

    np.testing.assert_array_equal(draw(1), draw(1))
    assert not np.allclose(draw(1), draw(2))
    scenario = SCENARIOS["paper"]
    flown, alone = np.random.default_rng(3), np.random.default_rng(3)
    fly(scenario.mission, scenario.site, scenario.wind, flown, duration_s=70.0)
    wind_ned(scenario.wind, np.arange(round(70.0 * RATE_HZ) + 1) / RATE_HZ, alone)
    assert flown.bit_generator.state == alone.bit_generator.state


def test_one_minus_cosine_gust_peak_duration_and_derivative():
    gust = DiscreteGust(start_s=10.0, amplitude_m_s=-3.0, length_m=40.0, axis="u")
    t = np.arange(8.0, 16.0, 1e-3)
    value, rate = gust_profile(gust, t, SPEED_M_S)
    assert value.min() == pytest.approx(-3.0, abs=1e-6)
    assert t[np.argmin(value)] == pytest.approx(10.0 + 20.0 / SPEED_M_S, abs=1e-3)
    end_s = 10.0 + LENGTH_M / SPEED_M_S  # lasts 3.2 s
    assert np.all(value[(t < 10.0) | (t > end_s + 1e-9)] == 0.0)
    assert np.all(value[(t > 10.0 + 1e-3) & (t < end_s - 1e-3)] < 0.0)
    smooth = (np.abs(t[1:-1] - 10.0) > 2e-3) & (np.abs(t[1:-1] - end_s) > 2e-3)  # the acceleration jumps at the ends
    np.testing.assert_allclose(rate[1:-1][smooth], ((value[2:] - value[:-2]) / 2e-3)[smooth], atol=2e-5)
    assert rate[0] == 0.0 and np.abs(rate[np.abs(t - end_s) < 2e-3]).max() < 2e-2  # continuous rate
    with pytest.raises(ValueError, match="axis"):
        DiscreteGust(0.0, 1.0, 10.0, axis="x")


def test_field_rate_is_the_exact_derivative_and_gusts_point_along_their_axis():
    config = replace(SHORT, knot_rate_hz=20.0, gusts=(DiscreteGust(5.0, 2.0, 30.0, "v"),))
    field = turbulence_field(config, 20.0, lambda t: np.full(np.shape(t), SPEED_M_S),
                             lambda t: np.full(np.shape(t), 150.0), lambda t: 0.3 + 0.1 * np.asarray(t),
                             np.random.default_rng(9))
    t, h = np.arange(0.5, 19.5, 0.0137), 1e-5
    difference = (field.ned_m_s(t + h) - field.ned_m_s(t - h)) / (2 * h)
    np.testing.assert_allclose(field.ned_m_s(t, 1), difference, atol=1e-5)
    peak_s = 5.0 + 15.0 / SPEED_M_S
    gust_only = field.ned_m_s([peak_s]) - field.dryden([peak_s])
    heading = 0.3 + 0.1 * 5.0  # heading at the gust's start; "v" is to the right of it
    np.testing.assert_allclose(gust_only[0], 2.0 * np.array([-np.sin(heading), np.cos(heading), 0.0]), atol=1e-12)


def _strapdown(truth, start: int, stop: int):
    rates, q = truth.rates_rad_s, truth.q_nb[start].copy()
    worst_rad = 0.0
    for k in range(start, stop):
        rotation = 0.5 * DT * (rates[k] + rates[k + 1]) + DT * DT / 12.0 * np.cross(rates[k], rates[k + 1])
        angle = np.linalg.norm(rotation)
        aw, ax, ay, az = q
        bw, (bx, by, bz) = np.cos(angle / 2), rotation * 0.5 * np.sinc(angle / (2 * np.pi))
        q = np.array([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                      aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])
        q /= np.linalg.norm(q)
        error = quat_to_matrix(q).T @ quat_to_matrix(truth.q_nb[k + 1])
        worst_rad = max(worst_rad, np.arccos(np.clip((np.trace(error) - 1) / 2, -1.0, 1.0)))
    window = slice(start, stop + 1)
    accel = np.einsum("nij,nj->ni", quat_to_matrix(truth.q_nb[window]), truth.specific_force_m_s2[window])
    accel[:, 2] += truth.gravity_m_s2[window]
    velocity = truth.vel_ned_m_s[start] + np.vstack([np.zeros((1, 3)),
                                                     np.cumsum(0.5 * DT * (accel[1:] + accel[:-1]), axis=0)])
    return worst_rad, np.abs(velocity - truth.vel_ned_m_s[window]).max()


def test_truth_rates_and_specific_force_integrate_to_the_turbulent_attitude_and_velocity(turbulent):
    truth = turbulent["turbulent"]
    start = round(140.0 * RATE_HZ)  # cruise in turbulence, through the 3 m/s head gust at 150 s
    worst_rad, worst_m_s = _strapdown(truth, start, start + round(20.0 * RATE_HZ))
    assert worst_rad < 1e-5 and worst_m_s < 1e-4
    # rates against finite differences of the quaternion: omega = 2 vec(q* dq/dt)
    q, k = truth.q_nb, np.arange(start, start + 5000)
    dq = (q[k + 1] - q[k - 1]) / (2 * DT)
    w, v = q[k, :1], q[k, 1:]
    dw, dv = dq[:, :1], dq[:, 1:]
    omega = 2 * (w * dv - dw * v - np.cross(v, dv))
    np.testing.assert_allclose(omega, truth.rates_rad_s[k], atol=2e-4)


def test_turbulence_moves_the_aircraft_by_plausible_amounts(turbulent):
    truth, smooth = turbulent["turbulent"], turbulent["smooth"]
    flying = truth.segment_mask("cruise", 10.0) | truth.segment_mask("turn", 10.0)
    sigma_u = dryden_scales(150.0, SCENARIOS["turbulent"].wind.turbulence.w20_m_s)[1][0, 0]
    airspeed_std = truth.airspeed_m_s[flying].std()
    assert 0.25 * sigma_u < airspeed_std < sigma_u
    assert smooth.airspeed_m_s[flying].std() < 1e-6  # the aircraft flies the plan's airspeed without turbulence
    perturbation = np.degrees(np.angle(np.exp(1j * (np.array(quat_to_euler(truth.q_nb))
                                                    - np.array(quat_to_euler(smooth.q_nb))))))[:, flying]
    roll_rms, pitch_rms, yaw_rms = np.sqrt(np.mean(perturbation**2, axis=1))
    assert 1.0 < roll_rms < 5.0 and 0.5 < pitch_rms < 5.0 and 0.5 < yaw_rms < 6.0
    vertical_wind_rms = np.sqrt(np.mean((truth.wind_ned_m_s[flying, 2]) ** 2))
    assert 0.7 < vertical_wind_rms < 1.8  # sigma_w = 1.2 m/s
    height_change = truth.alt_m[flying] - smooth.alt_m[flying]
    assert 1.0 < np.sqrt(np.mean(height_change**2)) < 15.0  # bounded by the altitude hold
    np.testing.assert_allclose(truth.airspeed_m_s, np.linalg.norm(truth.vel_ned_m_s - truth.wind_ned_m_s, axis=1))


def test_discrete_gusts_raise_the_airspeed_and_lift_the_aircraft(turbulent):
    truth, base = turbulent["turbulent"], turbulent["no_gusts"]
    head_peak = round((150.0 + 20.0 / SPEED_M_S) * RATE_HZ)
    assert 1.5 < truth.airspeed_m_s[head_peak] - base.airspeed_m_s[head_peak] < 3.0  # 3 m/s head gust, lagged
    updraft = slice(round(200.0 * RATE_HZ), round(205.0 * RATE_HZ))
    climb = -(truth.vel_ned_m_s[updraft, 2] - base.vel_ned_m_s[updraft, 2])
    assert 0.5 < climb.max() < 2.5  # rises partially with the 2.5 m/s updraft
    heading = plan_mission(SCENARIOS["turbulent"].mission).heading_rad(150.0)
    np.testing.assert_allclose(truth.wind_ned_m_s[head_peak] - base.wind_ned_m_s[head_peak],
                               -3.0 * np.array([np.cos(heading), np.sin(heading), 0.0]), atol=1e-9)


def test_simulate_command_writes_the_turbulent_scenario(tmp_path, capsys):
    assert main(["simulate", "--scenario", "turbulent", "--duration-s", "70", "-o", str(tmp_path)]) == 0
    assert "turbulent" in capsys.readouterr().out
    wind = json.loads((tmp_path / "turbulent_sim.json").read_text())["scenario"]["wind"]
    assert wind["turbulence"]["w20_m_s"] == 12.0 and len(wind["turbulence"]["gusts"]) == 4
    assert wind["turbulence"]["gusts"][0] == {"start_s": 150.0, "amplitude_m_s": -3.0, "length_m": 40.0, "axis": "u"}
