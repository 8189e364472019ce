"""The shared scheduling rule (estimators.core.schedule) on random IMU/event time lines: every IMU interval is
propagated exactly once and split at event times, every measurement update sees a covariance brought up to its
time, covariance intervals never exceed the configured one (unless one IMU step alone is longer), outputs do not
force a covariance propagation, periodic updates keep their period."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.core.schedule import COVARIANCE, EVENT, PERIODIC, PROPAGATE, build_schedule
from estimators.inputs.records import BARO, GPS_POS, MAG, OUTPUT

COV_DT_S = 0.01


def _time_line(seed: int, n_imu: int = 2000, n_events: int = 300):
    rng = np.random.default_rng(seed)
    imu_t = np.cumsum(rng.uniform(0.002, 0.006, n_imu)) + 10.0
    ev_t = np.sort(rng.uniform(imu_t[0] - 0.01, imu_t[-1], n_events))
    ev_t[rng.integers(0, n_events, 20)] = imu_t[rng.integers(0, n_imu, 20)]  # events on IMU sample times
    ev_t.sort()
    ev_kind = rng.choice(np.array([BARO, GPS_POS, MAG, OUTPUT]), n_events)
    ev_imu = np.searchsorted(imu_t, ev_t, side="left").clip(0, n_imu - 1)
    return imu_t, ev_t, ev_kind, ev_imu


@pytest.mark.parametrize("seed", range(5))
def test_every_interval_propagated_once_and_split_at_events(seed):
    imu_t, ev_t, ev_kind, ev_imu = _time_line(seed)
    op, dt, index = build_schedule(imu_t, ev_t, ev_kind, ev_imu, COV_DT_S, math.inf)
    propagate = op == PROPAGATE
    assert np.sum(dt[propagate]) == pytest.approx(imu_t[-1] - imu_t[0], abs=1e-9)
    assert (dt[propagate] > 0).all()
    # the pieces of row k add up to its interval (row 0 holds no interval: the replay starts at its time)
    per_row = np.bincount(index[propagate], weights=dt[propagate], minlength=len(imu_t))
    np.testing.assert_allclose(per_row[1:], np.diff(imu_t), atol=1e-9)
    assert per_row[0] == 0.0
    # every event exactly once, in order
    np.testing.assert_array_equal(index[op == EVENT], np.arange(len(ev_t)))


@pytest.mark.parametrize("seed", range(5))
def test_updates_see_an_up_to_date_covariance_and_intervals_are_bounded(seed):
    imu_t, ev_t, ev_kind, ev_imu = _time_line(seed)
    op, dt, index = build_schedule(imu_t, ev_t, ev_kind, ev_imu, COV_DT_S, math.inf)
    pending = 0.0  # time propagated since the last COVARIANCE
    longest_step = np.max(np.diff(imu_t))
    forced_by_output = 0
    for code, step, i in zip(op, dt, index, strict=True):
        if code == PROPAGATE:
            pending += step
            assert pending <= max(COV_DT_S, longest_step) * (1 + 1e-9) + longest_step
        elif code == COVARIANCE:
            assert pending > 0.0  # never an empty propagation
            pending = 0.0
        elif code == EVENT and ev_kind[i] != OUTPUT:
            assert pending == 0.0, "a measurement update with a stale covariance"
        elif code == EVENT:
            forced_by_output += pending == 0.0
    assert pending == 0.0  # the covariance is brought up to the end
    assert op[-1] == COVARIANCE or op[-1] == EVENT
    assert forced_by_output < (ev_kind == OUTPUT).sum()  # outputs report the last propagated covariance


def test_periodic_update_keeps_its_period_and_follows_a_covariance_propagation():
    imu_t, ev_t, ev_kind, ev_imu = _time_line(0)
    period_s = 0.02
    op, dt, _ = build_schedule(imu_t, ev_t, ev_kind, ev_imu, COV_DT_S, period_s)
    periodic = np.flatnonzero(op == PERIODIC)
    times = dt[periodic]
    gaps = np.diff(times)
    assert 0.5 * period_s <= gaps.min() and gaps.max() <= period_s + np.max(np.diff(imu_t)) + 1e-12
    assert len(times) == pytest.approx((imu_t[-1] - imu_t[0]) / period_s, rel=0.05)
    pending = 0.0
    for code, step in zip(op, dt, strict=True):
        if code == PROPAGATE:
            pending += step
        elif code == COVARIANCE:
            pending = 0.0
        elif code == PERIODIC:
            assert pending == 0.0, "a periodic update with a stale covariance"
    # without a period there is none
    assert not (build_schedule(imu_t, ev_t, ev_kind, ev_imu, COV_DT_S, math.inf)[0] == PERIODIC).any()


def test_empty_and_single_row_inputs():
    empty = np.empty(0)
    op, _, _ = build_schedule(empty, empty, np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64), COV_DT_S,
                              math.inf)
    assert len(op) == 0
    op, _, index = build_schedule(np.array([1.0]), np.array([1.0]), np.array([OUTPUT]), np.array([0]), COV_DT_S,
                                  math.inf)
    assert list(op) == [EVENT] and list(index) == [0]


def test_only_the_fused_kinds_force_a_covariance_propagation():
    imu_t, ev_t, ev_kind, ev_imu = _time_line(1)
    op, dt, index = build_schedule(imu_t, ev_t, ev_kind, ev_imu, COV_DT_S, math.inf, fused_kinds=(MAG, GPS_POS))
    pending, stale_baro = 0.0, 0
    for code, step, i in zip(op, dt, index, strict=True):
        if code == PROPAGATE:
            pending += step
        elif code == COVARIANCE:
            pending = 0.0
        elif code == EVENT and ev_kind[i] in (MAG, GPS_POS):
            assert pending == 0.0
        elif code == EVENT and ev_kind[i] == BARO:
            stale_baro += pending > 0.0
    assert stale_baro > 0  # a kind the filter does not fuse leaves the covariance as it is
    all_kinds = build_schedule(imu_t, ev_t, ev_kind, ev_imu, COV_DT_S, math.inf)[0]
    assert (all_kinds == COVARIANCE).sum() > (op == COVARIANCE).sum()


def test_no_periodic_update_before_time_has_passed():
    imu_t, ev_t, ev_kind, ev_imu = _time_line(2)
    op, dt, _ = build_schedule(imu_t, ev_t, ev_kind, ev_imu, COV_DT_S, 0.02)
    first = np.flatnonzero(op == PERIODIC)[0]
    assert (op[:first] == PROPAGATE).any() and dt[first] > imu_t[0]
