"""Environment models shared by the estimators and the simulator: the earth's magnetic field (World Magnetic
Model) and the sun's direction (NREL SPA), plus re-exports of the lower-layer gravity, ISA and geodesy helpers
(:mod:`ingest.atmosphere`, :mod:`ingest.geodesy`) so model code has one import for its environment.
"""

from __future__ import annotations

import warnings
from datetime import datetime
from functools import lru_cache

import numpy as np
import pandas as pd
from pygeomag import GeoMag

from ingest.atmosphere import AIR_GAS_CONSTANT_J_KG_K, STANDARD_GRAVITY_M_S2
from ingest.atmosphere import ISA_LAPSE_RATE_K_M as ISA_LAPSE_K_M
from ingest.atmosphere import ISA_SEA_LEVEL_PRESSURE_PA as ISA_P0_PA
from ingest.atmosphere import altitude_pressure_pa as isa_pressure_pa
from ingest.atmosphere import pressure_altitude_m as isa_altitude_m
from ingest.geodesy import geodetic_to_ned, local_gravity_m_s2, ned_to_geodetic

__all__ = ["ISA_LAPSE_K_M", "ISA_P0_PA", "MIN_SUN_ELEVATION_DEG", "STANDARD_GRAVITY_M_S2", "air_density_kg_m3",
           "decimal_year", "earth_field_ned_gauss", "geodetic_to_ned", "isa_altitude_m", "isa_pressure_pa",
           "local_gravity_m_s2", "ned_to_geodetic", "sun_direction_ned"]

#: Sun elevation below which photocell measurements are not used [deg].
MIN_SUN_ELEVATION_DEG = 5.0


def air_density_kg_m3(pressure_pa, temp_c):
    """Dry-air density [kg/m^3] from static pressure [Pa] and temperature [degC]."""
    return np.asarray(pressure_pa, dtype=float) / (AIR_GAS_CONSTANT_J_KG_K * (np.asarray(temp_c, dtype=float) + 273.15))


def decimal_year(when: datetime | pd.Timestamp) -> float:
    """Decimal year of a (UTC) date, as the WMM expects it."""
    stamp = pd.Timestamp(when)
    if stamp.tzinfo is not None:
        stamp = stamp.tz_convert("UTC").tz_localize(None)
    start = pd.Timestamp(year=stamp.year, month=1, day=1)
    end = pd.Timestamp(year=stamp.year + 1, month=1, day=1)
    return stamp.year + (stamp - start) / (end - start)


@lru_cache(maxsize=8)
def _geomag_for_year(year: int) -> GeoMag:
    # WMM coefficient sets are 5-year epochs; pygeomag picks the set covering the year.
    clamped = min(max(year, 2010), 2029)
    return GeoMag(base_year=clamped)


def earth_field_ned_gauss(lat_deg: float, lon_deg: float, alt_m: float, when) -> np.ndarray:
    """Main geomagnetic field vector in local NED [gauss] from the World Magnetic Model.

    Parameters
    ----------
    lat_deg, lon_deg : float
        Geodetic position [deg] (north, east positive).
    alt_m : float
        Altitude [m].
    when : datetime-like or float
        Date (UTC) or decimal year.

    Returns
    -------
    numpy.ndarray, shape (3,)
        (north, east, down) field [gauss]; 1 gauss = 1e5 nT.
    """
    year = float(when) if isinstance(when, (int, float)) else decimal_year(when)
    geomag = _geomag_for_year(int(year))
    with warnings.catch_warnings():
        # Outside a model's 5-year lifespan the field is extrapolated (error grows ~100 nT/yr): acceptable here.
        warnings.simplefilter("ignore")
        result = geomag.calculate(glat=float(lat_deg), glon=float(lon_deg), alt=float(alt_m) / 1000.0, time=year,
                                  allow_date_outside_lifespan=True)
    return np.array([result.x, result.y, result.z]) * 1e-5


def sun_direction_ned(times_utc, lat_deg, lon_deg, alt_m, pressure_pa=None, temp_c=None):
    """Unit vector towards the sun in local NED and its apparent elevation (NREL SPA via pvlib).

    Parameters
    ----------
    times_utc : pandas.DatetimeIndex
        Time stamps, timezone-aware UTC (or naive, taken as UTC).
    lat_deg, lon_deg, alt_m : numeric or array-like
        Observer position [deg, deg, m]; scalars or arrays of the same length as ``times_utc``.
    pressure_pa : numeric, optional
        Static pressure [Pa] for refraction; ISA at ``alt_m`` when omitted.
    temp_c : numeric, optional
        Air temperature [degC] for refraction; 12 degC when omitted.

    Returns
    -------
    s_ned : numpy.ndarray, shape (N, 3)
        (cos e cos A, cos e sin A, -sin e) with e the apparent elevation and A the azimuth east of north.
    elevation_deg : numpy.ndarray, shape (N,)
        Apparent (refracted) elevation [deg]; below :data:`MIN_SUN_ELEVATION_DEG` the sun is not usable.
    """
    times = pd.DatetimeIndex(times_utc)
    times = times.tz_localize("UTC") if times.tz is None else times.tz_convert("UTC")
    n = len(times)
    pressure = isa_pressure_pa(alt_m) if pressure_pa is None else pressure_pa
    temperature = 12.0 if temp_c is None else temp_c
    import pvlib  # here, not at the top: pvlib costs every CLI command a third of a second to import

    position = pvlib.solarposition.spa_python(
        times, np.broadcast_to(lat_deg, n), np.broadcast_to(lon_deg, n), altitude=np.broadcast_to(alt_m, n),
        pressure=np.broadcast_to(pressure, n), temperature=np.broadcast_to(temperature, n), delta_t=None)
    elevation_deg = position["apparent_elevation"].to_numpy(dtype=float)
    azimuth = np.radians(position["azimuth"].to_numpy(dtype=float))
    elevation = np.radians(elevation_deg)
    s_ned = np.column_stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                             -np.sin(elevation)])
    return s_ned, elevation_deg
