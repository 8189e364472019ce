"""Consistency verdicts judged against each channel's own error model (issue 31, 'Verdicts that are true'):
correlated innovations widen the accepted range, documented bounds are reported as such, and a noise set 10x too
high or too low on one sensor is flagged by name (docs/calibration.md, 'Consistency checks')."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from estimators.api import run_estimators
from estimators.config import NoiseConfig
from estimators.consistency import (
    AT_BOUND,
    CONSERVATIVE,
    CONSISTENT,
    NOT_JUDGED,
    OVERCONFIDENT,
    channel_verdicts,
    estimator_verdict,
    innovation_autocorrelation,
)
from estimators.evaluation import config_for_simulation
from ingest.log_formats import load_flight_log
from tests.conftest import REPO_DIR


def _diagnostics(channels: dict[str, np.ndarray]) -> pd.DataFrame:
    """Diagnostics rows of normalised innovations (S = 1) per ``sensor.component`` channel, interleaved in time."""
    parts = []
    for name, z in channels.items():
        sensor, component = name.split(".")
        parts.append(pd.DataFrame({"time_s": np.arange(len(z)) + 0.5 * len(parts), "sensor": sensor,
                                   "component": component, "innovation": z, "innovation_var": 1.0, "nis": z * z}))
    return pd.concat(parts).sort_values("time_s", kind="stable").reset_index(drop=True)


def _ar1(rng, n: int, rho: float) -> np.ndarray:
    z = np.empty(n)
    z[0] = rng.standard_normal()
    for k in range(1, n):
        z[k] = rho * z[k - 1] + np.sqrt(1 - rho * rho) * rng.standard_normal()
    return z


def test_autocorrelation_per_channel_in_update_order():
    rng = np.random.default_rng(1)
    rho = innovation_autocorrelation(_diagnostics({"baro.alt": rng.standard_normal(4000),
                                                   "gps_pos.n": _ar1(rng, 4000, 0.95)}))
    assert rho["baro.alt"] == pytest.approx(0.0, abs=0.05)
    assert rho["gps_pos.n"] == pytest.approx(0.95, abs=0.02)


def test_white_noise_is_consistent_and_a_10x_noise_error_either_way_is_named():
    rng = np.random.default_rng(2)
    z = rng.standard_normal(3000)
    verdicts = {v.channel: v for v in channel_verdicts("full_state_direct", _diagnostics(
        {"baro.alt": z, "airspeed.tas": 10.0 * z, "mag.x": 0.1 * z, "gps_vel.n": z[:10]}), NoiseConfig())}
    assert verdicts["baro.alt"].verdict == CONSISTENT
    assert verdicts["airspeed.tas"].verdict == OVERCONFIDENT and "10.0x larger" in verdicts["airspeed.tas"].reason
    assert verdicts["mag.x"].verdict == CONSERVATIVE and "10.0x higher" in verdicts["mag.x"].reason
    assert verdicts["gps_vel.n"].verdict == NOT_JUDGED
    summary = estimator_verdict("full_state_direct", tuple(verdicts.values()))
    assert summary.status == "inconsistent"
    assert "airspeed.tas" in summary.summary and "mag.x" in summary.summary and "baro.alt" not in summary.summary


def test_correlated_innovations_widen_the_accepted_range():
    rng = np.random.default_rng(4)
    correlated = 0.45 * _ar1(rng, 200, 0.999)  # a couple of independent updates: a mean NIS of 0.07 says little
    verdict = channel_verdicts("full_state_direct", _diagnostics({"baro.alt": correlated}), NoiseConfig())[0]
    assert verdict.lag1_autocorrelation > 0.95 and verdict.n_effective < 3
    assert verdict.accepted[0] < verdict.mean_nis < 0.2 and verdict.accepted[1] > 3.0
    assert verdict.verdict == CONSISTENT
    white = channel_verdicts("full_state_direct", _diagnostics({"baro.alt": 0.27 * rng.standard_normal(200)}),
                             NoiseConfig())[0]
    assert white.accepted == (0.2, 3.0) and white.verdict == CONSERVATIVE


def test_documented_bounds_excuse_a_small_nis_only_where_the_model_says_so():
    small = 0.05 * np.random.default_rng(4).standard_normal(2000)
    diagnostics = _diagnostics({"sideslip.v": small, "gps_pos.n": small, "accel.y": small})
    direct = {v.channel: v.verdict for v in channel_verdicts("full_state_direct", diagnostics, NoiseConfig())}
    assert direct == {"sideslip.v": AT_BOUND, "gps_pos.n": AT_BOUND, "accel.y": CONSERVATIVE}
    three_stage = {v.channel: v.verdict for v in channel_verdicts("three_stage", diagnostics, NoiseConfig())}
    assert three_stage["accel.y"] == AT_BOUND
    inflated = dataclasses.replace(NoiseConfig(), gps_pos_eph_scale=10 * NoiseConfig().gps_pos_eph_scale)
    assert {v.channel: v.verdict for v in channel_verdicts("full_state_direct", diagnostics, inflated)}[
        "gps_pos.n"] == CONSERVATIVE  # a GPS noise well above the receiver's accuracy is no bound
    big = _diagnostics({"sideslip.v": 5.0 * np.random.default_rng(5).standard_normal(2000)})
    assert channel_verdicts("full_state_direct", big, NoiseConfig())[0].verdict == OVERCONFIDENT


#: One noise setting per sensor kind (NoiseConfig fields scaled together).
SENSOR_NOISE = {"baro": ("baro_sigma_m",), "airspeed": ("airspeed_sigma_m_s",), "mag": ("mag_sigma",),
                "gps_vel": ("gps_vel_accuracy_scale",), "gps_pos": ("gps_pos_sigma_floor_m", "gps_hgt_sigma_floor_m")}


@pytest.fixture(scope="module")
def simulated():
    log = load_flight_log(REPO_DIR / "sample_logs" / "failed_cell.ulg")
    return log, config_for_simulation(REPO_DIR / "sample_logs" / "failed_cell_sim.json")


def _verdict(log, config) -> dict:
    run = run_estimators(log, estimators="full_state_indirect", config=config, rate_hz=1.0)
    return run.reports["full_state_indirect"].details["verdict"]


def test_the_true_noise_of_a_simulated_flight_is_consistent(simulated):
    log, config = simulated
    verdict = _verdict(log, config)
    assert verdict["status"] == "consistent", verdict["summary"]


@pytest.mark.parametrize("factor", [10.0, 0.1])
@pytest.mark.parametrize("sensor", sorted(SENSOR_NOISE))
def test_a_noise_10x_off_on_one_sensor_is_flagged_by_name(simulated, sensor, factor):
    log, config = simulated
    noise = dataclasses.replace(config.noise, **{name: getattr(config.noise, name) * factor
                                                 for name in SENSOR_NOISE[sensor]})
    verdict = _verdict(log, dataclasses.replace(config, noise=noise))
    expected = CONSERVATIVE if factor > 1 else OVERCONFIDENT
    flagged = [c["channel"] for c in verdict["channels"] if c["verdict"] == expected]
    assert any(channel.startswith(f"{sensor}.") for channel in flagged), verdict["summary"]
    assert verdict["status"] == ("conservative" if factor > 1 else "inconsistent")
    assert f"{sensor}." in verdict["summary"]
