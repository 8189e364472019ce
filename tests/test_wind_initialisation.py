"""Wind from the airspeed (docs/estimators.md, 'Wind initialisation'): both full-state filters start their wind at
the first airspeed along the heading and start again when the estimate has the air flowing backwards through the
airframe (the mirrored solution an airspeed magnitude and a sideslip constraint cannot leave); the truth-free check
:func:`estimators.consistency.reversed_airflow_fraction` that flags such a replay."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from estimators.api import run_estimators
from estimators.consistency import reversed_airflow_fraction
from estimators.direct import kernel as direct_kernel
from estimators.direct import measurements as direct_meas
from estimators.direct.model import I_TH, I_V, L_W, euler_matrices
from estimators.indirect import kernel as indirect_kernel
from estimators.indirect import measurements as indirect_meas
from estimators.indirect import model as m
from tests.estimators_synthetic import synthetic_flight

AIRSPEED_M_S = 15.0
FULL_LAYOUT = np.array([12, 15, 17, 20], dtype=np.int64)  # b_a, wind, mag bias, baro bias (direct filter)


def _direct_state(yaw_deg: float, pitch_deg: float, wind_ne_m_s) -> np.ndarray:
    """Direct-filter state flying at AIRSPEED_M_S along its body x axis through ``wind_ne_m_s`` (NED)."""
    x = np.zeros(21)
    x[I_TH:I_TH + 3] = [math.radians(4.0), math.radians(pitch_deg), math.radians(yaw_deg)]
    R_nb = Rotation.from_euler("ZYX", x[[I_TH + 2, I_TH + 1, I_TH]]).as_matrix()
    wind = np.array([*wind_ne_m_s, 0.0])
    ground_ned = AIRSPEED_M_S * R_nb[:, 0] + wind
    x[I_V:I_V + 3] = R_nb.T @ ground_ned
    x[FULL_LAYOUT[L_W]:FULL_LAYOUT[L_W] + 2] = wind[:2]
    return x


def _mirrored_wind(ground_ned: np.ndarray, body_x_ned: np.ndarray) -> np.ndarray:
    """The wind that has the same ground velocity flying backwards at the same airspeed."""
    return (ground_ned + AIRSPEED_M_S * body_x_ned)[:2]


def test_direct_wind_initialisation_leaves_the_mirrored_solution():
    x = _direct_state(yaw_deg=30.0, pitch_deg=3.0, wind_ne_m_s=(4.0, -2.0))
    true_wind = x[15:17].copy()
    R_nb, S_euler, W_euler = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    euler_matrices(x[I_TH], x[I_TH + 1], x[I_TH + 2], R_nb, S_euler, W_euler)
    x[15:17] = _mirrored_wind(R_nb @ x[I_V:I_V + 3], R_nb[:, 0])
    H = np.empty(21)
    # the mirrored wind fits the airspeed magnitude exactly: no update could tell
    assert direct_meas.h_airspeed(x, FULL_LAYOUT, R_nb, S_euler, W_euler, H) == pytest.approx(AIRSPEED_M_S)
    assert direct_kernel.air_flows_backwards(x, FULL_LAYOUT, R_nb, S_euler, W_euler)
    rng = np.random.default_rng(3)
    P0 = np.diag(rng.uniform(0.5, 2.0, 21))
    P = np.full((21, 21), 0.01) + np.eye(21)
    direct_kernel.initialise_wind(x, P, AIRSPEED_M_S, FULL_LAYOUT, P0, R_nb, S_euler, W_euler, np.empty((2, 2)))
    np.testing.assert_allclose(x[15:17], true_wind, atol=1e-12)
    assert not direct_kernel.air_flows_backwards(x, FULL_LAYOUT, R_nb, S_euler, W_euler)
    np.testing.assert_array_equal(P[15:17, 15:17], P0[15:17, 15:17])
    others = np.r_[0:15, 17:21]
    assert not P[15:17][:, others].any() and not P[others][:, 15:17].any()


def test_indirect_wind_initialisation_leaves_the_mirrored_solution():
    x = np.zeros(m.NX)
    rotation = Rotation.from_euler("ZYX", [math.radians(-120.0), math.radians(5.0), math.radians(-8.0)])
    x[m.X_Q:m.X_Q + 4] = np.roll(rotation.as_quat(), 1)
    body_x_ned = rotation.as_matrix()[:, 0]
    true_wind = np.array([-3.0, 5.0, 0.0])
    ground_ned = AIRSPEED_M_S * body_x_ned + true_wind
    x[m.X_V:m.X_V + 3] = ground_ned
    x[m.X_W:m.X_W + 2] = _mirrored_wind(ground_ned, body_x_ned)
    H = np.zeros(m.NE)
    assert indirect_meas.h_airspeed(x, H) == pytest.approx(AIRSPEED_M_S)
    assert indirect_kernel.air_flows_backwards(x)
    n = 20
    aw = 15  # active index of the wind error state
    P0 = np.diag(np.linspace(1.0, 2.0, n))
    P = np.full((n, n), 0.02) + np.eye(n)
    indirect_kernel.initialise_wind(x, P, AIRSPEED_M_S, aw, P0, np.empty((2, 2)))
    np.testing.assert_allclose(x[m.X_W:m.X_W + 2], true_wind[:2], atol=1e-12)
    assert not indirect_kernel.air_flows_backwards(x)
    np.testing.assert_array_equal(P[aw:aw + 2, aw:aw + 2], P0[aw:aw + 2, aw:aw + 2])
    others = np.r_[0:aw, aw + 2:n]
    assert not P[aw:aw + 2][:, others].any()


@pytest.fixture(scope="module")
def tailwind_flight():
    """A fixed wing with a strong wind (8 m/s, half its airspeed): from a zero wind state the airspeed updates
    alone need tens of seconds to find it."""
    return synthetic_flight(40.0, seed=5, wind_ne_m_s=(-6.0, 5.5), airspeed_m_s=AIRSPEED_M_S)


@pytest.mark.parametrize("estimator", ["full_state_direct", "full_state_indirect"])
def test_first_airspeed_sets_the_wind(tailwind_flight, estimator):
    result = run_estimators(tailwind_flight, estimators=(estimator,), rate_hz=10.0)
    states = result.states
    truth = tailwind_flight.streams["truth_wind"]
    first_airspeed_s = tailwind_flight.streams["airspeed"].index[0]
    early = states[(states.time_s > first_airspeed_s + 0.5) & (states.time_s < first_airspeed_s + 2.0)]
    error = np.hypot(early.wind_n_m_s - truth.wind_n_m_s.iloc[0], early.wind_e_m_s - truth.wind_e_m_s.iloc[0])
    assert error.max() < 1.5, error.max()  # a zero start would still be about 8 m/s off here
    report = result.reports[estimator]
    assert not [w for w in report.warnings if "re-initialised" in w or "backwards" in w], report.warnings
    assert report.details["reversed_airflow_fraction"] == 0.0


def _states(yaw_deg, ground_ne, wind_ne):
    n = len(yaw_deg)
    return pd.DataFrame({"pitch_deg": np.zeros(n), "yaw_deg": yaw_deg, "vn_m_s": ground_ne[:, 0],
                         "ve_m_s": ground_ne[:, 1], "vd_m_s": np.zeros(n), "wind_n_m_s": wind_ne[:, 0],
                         "wind_e_m_s": wind_ne[:, 1]})


def test_reversed_airflow_fraction_counts_backward_epochs():
    yaw = np.linspace(-180.0, 179.0, 100)
    heading = np.column_stack([np.cos(np.radians(yaw)), np.sin(np.radians(yaw))])
    wind = np.tile([3.0, -4.0], (100, 1))
    ground = AIRSPEED_M_S * heading + wind
    assert reversed_airflow_fraction(_states(yaw, ground, wind)) == 0.0
    mirrored = wind.copy()
    mirrored[:30] = ground[:30] + AIRSPEED_M_S * heading[:30]
    assert reversed_airflow_fraction(_states(yaw, ground, mirrored)) == pytest.approx(0.3)
    # on the ground (air speed below the wing-borne threshold) nothing is judged
    assert math.isnan(reversed_airflow_fraction(_states(yaw, wind + 0.1 * heading, wind)))
    assert math.isnan(reversed_airflow_fraction(_states(yaw, ground, wind).drop(columns="wind_n_m_s")))


# ---------------------------------------------------------------------------------------------------------------
# Wind on the ground (docs/estimators.md, 'Wind on the ground')
# ---------------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def paper_log():
    from ingest.log_formats import load_flight_log
    from tests.conftest import SAMPLE_LOGS_DIR

    return load_flight_log(SAMPLE_LOGS_DIR / "paper.ulg")


def _ground_speed_at(flight_log, time_s: np.ndarray) -> np.ndarray:
    truth = flight_log["truth_local_position"]
    t = truth.index.to_numpy(dtype=float)
    return np.interp(time_s, t, np.hypot(truth["vx_m_s"].to_numpy(), truth["vy_m_s"].to_numpy()))


def test_a_pitot_on_the_ground_is_not_fused(paper_log):
    """The bundled mission stands 60 s before the launch and 10 s after the landing in 2.5 m/s wind: with the
    airspeed threshold below that wind, airspeed samples there (the wind on the pitot) still give no events; in
    flight every sample does."""
    from dataclasses import replace

    from estimators.config import EstimatorConfig
    from estimators.inputs.build import build_replay_inputs
    from estimators.inputs.records import AIRSPEED

    config = EstimatorConfig()
    config = replace(config, timing=replace(config.timing, min_airspeed_m_s=1.0))
    events = build_replay_inputs(paper_log, config).events
    fused_t = events.time_s[events.kind == AIRSPEED]
    assert len(fused_t) > 1000
    assert _ground_speed_at(paper_log, fused_t).min() > 2.0
    airspeed = paper_log["airspeed"]
    sample_t = airspeed.index.to_numpy(dtype=float)
    ground_speed = _ground_speed_at(paper_log, sample_t)
    assert (airspeed["tas_m_s"].to_numpy()[ground_speed < 0.1] > 1.0).any(), "no pitot reading on the ground"
    assert len(fused_t) >= 0.99 * (ground_speed > 6.0).sum()


@pytest.mark.parametrize("estimator", ["full_state_direct", "full_state_indirect"])
def test_the_wind_is_held_on_the_ground(paper_log, estimator):
    """With the wind walk of turbulent air (2 m/s/sqrt(s)) the wind after landing stays at its last estimate: its
    sigma does not grow and the estimate moves by less than 0.1 m/s (a walk left running would add 2 sqrt(10) =
    6 m/s of sigma in the 10 s at rest)."""
    from dataclasses import replace

    from estimators.config import EstimatorConfig

    config = EstimatorConfig()
    config = replace(config, noise=replace(config.noise, wind_rw_m_s_sqrt_s=2.0))
    states = run_estimators(paper_log, estimators=[estimator], config=config).states
    t = states["time_s"].to_numpy()
    moving = _ground_speed_at(paper_log, t) > 0.1
    landed = t > t[moving][-1] + 1.5  # after the roll-out and the hold time
    assert landed.sum() > 100
    wind = states.loc[landed, ["wind_n_m_s", "wind_e_m_s"]].to_numpy()
    sigma = states.loc[landed, ["wind_n_m_s_std", "wind_e_m_s_std"]].to_numpy()
    assert np.ptp(wind, axis=0).max() < 0.1
    assert np.ptp(sigma, axis=0).max() < 0.01
