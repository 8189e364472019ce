"""Sun direction in local NED (estimators.environment.sun_direction_ned, NREL SPA via pvlib),
docs/sun.md, 'Measurement model'."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from estimators.environment import sun_direction_ned


def azimuth_deg(s_ned: np.ndarray) -> np.ndarray:
    return np.degrees(np.arctan2(s_ned[:, 1], s_ned[:, 0])) % 360.0


def test_nrel_spa_report_example():
    # Reda & Andreas 2004 (NREL/TP-560-34302) example: apparent zenith 50.111622 deg, azimuth 194.340241 deg with
    # delta_t = 67 s. sun_direction_ned lets pvlib compute delta_t (64.5 s for Oct 2003); 2.5 s of delta_t move the
    # sun by ~3e-5 deg (docs/sun.md, 'Measurement model'), hence 1e-4 deg here instead of the report's 1e-5.
    times = pd.DatetimeIndex(["2003-10-17 19:30:30"], tz="UTC")
    s_ned, elevation_deg = sun_direction_ned(times, 39.742476, -105.1786, 1830.14, pressure_pa=82000.0,
                                             temp_c=11.0)
    assert elevation_deg[0] == pytest.approx(90.0 - 50.111622, abs=1e-4)
    assert azimuth_deg(s_ned)[0] == pytest.approx(194.340241, abs=1e-4)
    np.testing.assert_allclose(np.linalg.norm(s_ned, axis=1), 1.0, atol=1e-12)
    assert s_ned[0, 2] == pytest.approx(-np.sin(np.radians(elevation_deg[0])), abs=1e-12)


def almanac_sun_ned(times: pd.DatetimeIndex, lat_deg: np.ndarray, lon_deg: np.ndarray) -> np.ndarray:
    """Low-precision geocentric, unrefracted sun direction (oracle of docs/sun.md, 'Measurement model'; Astronomical
    Almanac formulas)."""
    d = (times.to_julian_date().to_numpy() - 2451545.0)
    mean_longitude = 280.460 + 0.9856474 * d
    anomaly = np.radians(357.528 + 0.9856003 * d)
    ecliptic = np.radians(mean_longitude + 1.915 * np.sin(anomaly) + 0.020 * np.sin(2 * anomaly))
    obliquity = np.radians(23.439 - 4.0e-7 * d)
    right_ascension = np.arctan2(np.cos(obliquity) * np.sin(ecliptic), np.cos(ecliptic))
    declination = np.arcsin(np.sin(obliquity) * np.sin(ecliptic))
    gmst_h = 18.697374558 + 24.06570982441908 * d
    hour_angle = np.radians(15.0 * gmst_h + lon_deg) - right_ascension
    lat = np.radians(lat_deg)
    elevation = np.arcsin(np.sin(lat) * np.sin(declination)
                          + np.cos(lat) * np.cos(declination) * np.cos(hour_angle))
    azimuth = np.arctan2(-np.sin(hour_angle), np.tan(declination) * np.cos(lat) - np.sin(lat) * np.cos(hour_angle))
    return np.column_stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                            -np.sin(elevation)])


def test_agrees_with_the_low_precision_oracle():
    # Random instants 2000-2050 and |lat| < 70 deg; pressure 0 switches SPA's refraction off, leaving the
    # geometric topocentric direction; the oracle lacks the 0.0024 deg parallax: bound 0.02 deg (docs/sun.md,
    # 'Measurement model' [FLAG]).
    rng = np.random.default_rng(8)
    n = 400
    start, end = pd.Timestamp("2000-01-01", tz="UTC"), pd.Timestamp("2050-12-31", tz="UTC")
    times = pd.DatetimeIndex(start + (end - start) * rng.uniform(0.0, 1.0, n)).round("s")
    lat, lon = rng.uniform(-70.0, 70.0, n), rng.uniform(-180.0, 180.0, n)
    s_spa, _ = sun_direction_ned(times, lat, lon, 0.0, pressure_pa=0.0, temp_c=12.0)
    s_oracle = almanac_sun_ned(times, lat, lon)
    angle_deg = np.degrees(np.arccos(np.clip(np.sum(s_spa * s_oracle, axis=1), -1.0, 1.0)))
    assert np.max(angle_deg) < 0.02  # measured max ~0.01 deg


def test_refraction_raises_the_apparent_elevation():
    times = pd.DatetimeIndex(["2024-06-21 18:00:00"], tz="UTC")
    _, apparent = sun_direction_ned(times, 47.0, 8.0, 500.0)  # ISA pressure: refraction on
    _, geometric = sun_direction_ned(times, 47.0, 8.0, 500.0, pressure_pa=0.0)
    assert 5.0 < geometric[0] < 20.0
    # About 0.1 deg near 10 deg elevation (docs/sun.md, 'Measurement model').
    assert 0.04 < apparent[0] - geometric[0] < 0.15


def test_interpolated_ephemeris_at_a_fixed_observer():
    """``sun_prediction.sun_ned_at`` with a fixed observer (what the replay and the app use): the SPA direction
    on the 1 Hz grid, interpolated in between well inside the 0.01 deg budget; NaN without the log's UTC time."""
    from dataclasses import replace

    from estimators.sun.prediction import sun_ned_at
    from ingest.flightlog import FlightLog
    from tests.estimators_synthetic import ALT0, LAT0, LON0, synthetic_flight

    log = synthetic_flight(5.0)
    time_s = np.array([1000.0, 1000.25, 1001.5, 1003.0, 1004.75])
    origin = (LAT0, LON0 + 1.0, ALT0)
    s_ned, elevation = sun_ned_at(log, time_s, origin=origin)
    exact, exact_elevation = sun_direction_ned(log.utc(time_s), *origin)
    angle = np.degrees(np.arccos(np.clip(np.sum(s_ned * exact, axis=1), -1.0, 1.0)))
    assert angle.max() < 1e-4
    np.testing.assert_allclose(elevation, exact_elevation, atol=1e-4)
    np.testing.assert_allclose(s_ned[[0, 3]], exact[[0, 3]], atol=1e-12)  # grid points
    no_utc = FlightLog(streams=log.streams, meta=replace(log.meta, utc_offset_s=None))
    assert np.isnan(sun_ned_at(no_utc, time_s, origin=origin)[0]).all()
