"""Environment models: gravity, ISA, WMM field frame, geodetic <-> NED round trip."""

from __future__ import annotations

import numpy as np
import pytest
from pygeomag import GeoMag

from estimators.environment import (
    earth_field_ned_gauss,
    geodetic_to_ned,
    isa_altitude_m,
    isa_pressure_pa,
    local_gravity_m_s2,
    ned_to_geodetic,
)


def test_local_gravity_matches_math_note_value_at_field_site():
    # docs/estimators.md, 'Frames and attitude identities': ~9.7955 m/s^2 at 35 N / 630 m; equator sea level is the
    # WGS-84 normal gravity 9.7803253359
    assert local_gravity_m_s2(35.0, 630.0) == pytest.approx(9.7955, abs=2e-4)
    assert local_gravity_m_s2(0.0, 0.0) == pytest.approx(9.7803253359, abs=1e-9)


def test_isa_standard_atmosphere_points():
    # ISA tables: 1000 m -> 89875 Pa, 600 m -> 94322 Pa (US Standard Atmosphere 1976)
    assert isa_pressure_pa(1000.0) == pytest.approx(89875.0, rel=5e-4)
    assert isa_pressure_pa(600.0) == pytest.approx(94322.0, rel=5e-4)
    altitudes_m = np.linspace(-100.0, 5000.0, 11)
    np.testing.assert_allclose(isa_altitude_m(isa_pressure_pa(altitudes_m)), altitudes_m, atol=1e-6)


def test_earth_field_is_ned_with_the_model_declination_and_inclination():
    field_ned = earth_field_ned_gauss(34.983, 108.934, 630.0, 2025.8)
    result = GeoMag(base_year=2025).calculate(glat=34.983, glon=108.934, alt=0.63, time=2025.8)
    declination_deg = np.degrees(np.arctan2(field_ned[1], field_ned[0]))
    inclination_deg = np.degrees(np.arctan2(field_ned[2], np.hypot(field_ned[0], field_ned[1])))
    assert declination_deg == pytest.approx(result.d, abs=1e-9)
    assert inclination_deg == pytest.approx(result.i, abs=1e-9)
    assert np.linalg.norm(field_ned) == pytest.approx(result.f * 1e-5, rel=1e-12)  # nT -> gauss
    assert 0.45 < np.linalg.norm(field_ned) < 0.6  # mid-latitude field strength


@pytest.mark.parametrize("spread_deg", [0.05, 1.0])
def test_geodetic_ned_round_trip_is_exact_far_from_the_origin(spread_deg):
    rng = np.random.default_rng(7)
    lat_deg = 35.0 + rng.uniform(-spread_deg, spread_deg, 200)
    lon_deg = 108.9 + rng.uniform(-spread_deg, spread_deg, 200)
    alt_m = 630.0 + rng.uniform(0.0, 3000.0, 200)
    north_m, east_m, down_m = geodetic_to_ned(lat_deg, lon_deg, alt_m, 35.0, 108.9, 630.0)
    np.testing.assert_allclose(down_m, -(alt_m - 630.0))
    lat_back, lon_back, alt_back = ned_to_geodetic(north_m, east_m, down_m, 35.0, 108.9, 630.0)
    np.testing.assert_allclose(lat_back, lat_deg, atol=1e-9)  # ~0.1 mm
    np.testing.assert_allclose(lon_back, lon_deg, atol=1e-9)
    np.testing.assert_allclose(alt_back, alt_m, atol=1e-9)
