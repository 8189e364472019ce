"""Automatic and user segments (calib.segments) on the synthetic log."""

from __future__ import annotations

import numpy as np
import pytest
from test_calib_synthetic import synthetic_log

from calib.segments import auto_segments, find_stationary_segments, find_steady_segments, is_stationary, user_segment
from ingest.errors import InputError

# The synthetic log runs 100 .. 160 s; the vehicle rocks at 0.8 rad/s in 120 .. 130 s.
MOTION = ((120.0, 130.0),)
# The 0.2 s moving average widens the motion by up to 0.1 s on both sides, and the rocking rate
# 0.8 sin(pi t) stays below 0.05 rad/s for |t - k| < 0.02 s: edges within 0.15 s, then moved 1 s away from the
# motion by the trim (StationaryCriteria.trim_s); the log's own start and end are not trimmed.
EDGE_TOL_S = 0.15
TRIM_S = 1.0


def test_stationary_segments_split_by_motion_longest_first():
    segments = find_stationary_segments(synthetic_log(60.0, motion=MOTION))
    assert [s.kind for s in segments] == ["stationary", "stationary"]
    longest, other = segments
    assert longest.start_s == pytest.approx(130.0 + TRIM_S, abs=EDGE_TOL_S)
    assert longest.end_s == pytest.approx(160.0 - 1 / 250, abs=1e-9)
    assert other.start_s == pytest.approx(100.0, abs=1e-9)
    assert other.end_s == pytest.approx(120.0 - TRIM_S, abs=EDGE_TOL_S)
    assert "stationary" in longest.reason and "median GPS ground speed" in longest.reason


def test_short_still_stretches_are_not_segments():
    # Still for 3 s only between two motions: below the 5 s minimum.
    segments = find_stationary_segments(synthetic_log(20.0, motion=((100.0, 108.5), (111.5, 120.0))))
    assert segments == []


def test_unaccelerated_flight_is_steady_not_stationary():
    log = synthetic_log(60.0, motion=MOTION, airspeed_m_s=12.5)
    log.streams["gps"] = log["gps"].assign(vn_m_s=log["gps"]["vn_m_s"] + 12.0)
    assert find_stationary_segments(log) == []
    steady = find_steady_segments(log)
    assert [s.kind for s in steady] == ["steady", "steady"]
    # The 2 s RMS window blurs the motion edge by up to 1 s, the trim adds 1 s: the longest steady stretch
    # starts in 131 .. 132 s and runs to the end of the log (untrimmed).
    assert 131.0 - EDGE_TOL_S <= steady[0].start_s <= 132.0 + EDGE_TOL_S
    assert steady[0].end_s == pytest.approx(160.0, abs=0.2)
    assert "true airspeed" in steady[0].reason and "barometric altitude" in steady[0].reason


def test_standing_vehicle_is_not_steady_cruise():
    assert find_steady_segments(synthetic_log(30.0)) == []  # airspeed 0 < 3 m/s


def test_auto_segments_put_stationary_first():
    log = synthetic_log(60.0, motion=MOTION)
    candidates = auto_segments(log)
    assert candidates[0].kind == "stationary"
    assert candidates[0].duration_s >= candidates[-1].duration_s


def test_user_segment_checks_bounds_and_stationarity():
    log = synthetic_log(60.0, motion=MOTION)
    inside = user_segment(log, 135.0, 150.0)
    assert (inside.kind, inside.reason) == ("user", "user window")
    assert is_stationary(log, inside)
    assert not is_stationary(log, user_segment(log, 110.0, 140.0))
    selected = inside.select(log["imu"])
    assert selected.index[0] >= 135.0 and selected.index[-1] <= 150.0
    assert len(selected) == pytest.approx(15.0 * 250, abs=1)
    for start_s, end_s in ((150.0, 140.0), (np.nan, 140.0), (10.0, 20.0), (170.0, 180.0)):
        with pytest.raises(InputError) as err:
            user_segment(log, start_s, end_s)
        assert err.value.field == "segment"
