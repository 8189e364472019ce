"""The adaptive wind random walk of the full-state filters (docs/estimators.md, 'Wind that follows gusts'): the
moving lag-1 correlation of each wind channel's normalised innovations, its excess over the target integrated in
log into the factor on the wind's walk density. It grows while a lagging wind leaves correlated innovations, falls
back to the configured walk on white ones, stays within its bounds, pairs a channel only with itself and only
across short gaps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.core.full_state import (
    WIND_CORR_TARGET,
    WIND_PAIR_GAP_S,
    WIND_WALK_MAX_SCALE,
    WIND_WALK_RATE_S,
    adapt_wind_walk,
    scaled_wind_walk,
    wind_adaptation,
    wind_walk_scale,
)
from estimators.inputs.records import AIRSPEED, SIDESLIP

STEP_S = 0.1  # airspeed at 10 Hz


def _feed(state, z_values, kinds=None, start_s=0.0, step_s=STEP_S):
    """One update per normalised innovation (innovation variance 4, so nu = 2 z), every ``step_s`` from
    ``start_s``, of the channel in ``kinds`` (airspeed by default); returns the factor after each."""
    diag_f = np.zeros((1, 4))
    diag_i = np.zeros((1, 3), dtype=np.int64)
    scales = []
    for k, z in enumerate(z_values):
        diag_f[0, 1:3] = 2.0 * z, 4.0
        diag_i[0, 0] = AIRSPEED if kinds is None else kinds[k]
        adapt_wind_walk(state, start_s + k * step_s, diag_f, diag_i, 0, 1)
        scales.append(wind_walk_scale(state))
    return np.array(scales)


def _ar1(rho: float, n: int, seed: int = 3) -> np.ndarray:
    """Unit-variance AR(1) innovations with lag-1 correlation ``rho``."""
    rng = np.random.default_rng(seed)
    z = np.empty(n)
    z[0] = rng.standard_normal()
    for k in range(1, n):
        z[k] = rho * z[k - 1] + math.sqrt(1.0 - rho**2) * rng.standard_normal()
    return z


def test_white_innovations_keep_the_configured_walk():
    assert _feed(wind_adaptation(), _ar1(0.0, 6000)).max() < 1.5  # 10 min of white airspeed innovations


def test_a_lagging_wind_opens_the_walk_and_white_innovations_close_it_again():
    state = wind_adaptation()
    scales = _feed(state, _ar1(0.9, 3000))
    assert scales[-1] == pytest.approx(WIND_WALK_MAX_SCALE)  # 5 min at correlation 0.9: the bound
    calm = _feed(state, _ar1(0.0, 12000, seed=4), start_s=400.0)
    assert calm[-1] == pytest.approx(1.0)  # back to the configured walk, never below it
    assert calm.min() >= 1.0


def test_the_rate_is_the_stated_one():
    state = wind_adaptation()
    _feed(state, [1.0] * 600)  # constant innovations: correlation 1
    state[2] = 0.0  # from the configured walk, with the mean settled at 1
    after = _feed(state, [1.0] * int(WIND_WALK_RATE_S / STEP_S), start_s=60.0)[-1]
    assert math.log(after) == pytest.approx((1.0 - WIND_CORR_TARGET) / 0.5, rel=0.03)


def test_a_channel_pairs_only_with_itself_and_only_across_short_gaps():
    alternating = [1.0, -1.0] * 1500  # airspeed always +1, sideslip always -1: each channel fully correlated
    kinds = [AIRSPEED, SIDESLIP] * 1500
    assert _feed(wind_adaptation(), alternating, kinds)[-1] > 100.0  # across channels it would read -1
    sparse = _feed(wind_adaptation(), [3.0] * 300, step_s=2.0 * WIND_PAIR_GAP_S)  # a 2-s gap: no pair
    assert sparse.max() == 1.0


def test_invalid_rows_are_ignored():
    state = wind_adaptation()
    diag_f = np.array([[0.0, np.nan, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0]])  # NaN innovation, zero variance
    diag_i = np.array([[AIRSPEED, 0, 1], [AIRSPEED, 0, 1]])
    for k in range(100):
        adapt_wind_walk(state, k * STEP_S, diag_f, diag_i, 0, 2)
    assert wind_walk_scale(state) == 1.0 and state[0] == 0.0


def test_only_the_two_wind_states_are_scaled():
    walk = np.arange(1.0, 7.0)
    out = np.empty_like(walk)
    assert list(scaled_wind_walk(walk, 2, 10.0, out)) == [1.0, 2.0, 30.0, 40.0, 5.0, 6.0]
    assert list(scaled_wind_walk(walk, -1, 10.0, out)) == list(walk)  # no wind states
