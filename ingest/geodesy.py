"""Geodesy shared by every layer: WGS-84 normal gravity and geodetic <-> local NED coordinates.

Local NED: north/east are WGS-84 tangent-plane coordinates at a reference point (pymap3d); down is
-(altitude - reference altitude), so GPS and barometric heights stay consistent (math note 1.5).
"""

from __future__ import annotations

import numpy as np
import pymap3d


def local_gravity_m_s2(lat_deg, alt_m):
    """Normal gravity [m/s^2] on the WGS-84 ellipsoid (Somigliana) with a free-air height correction.

    Parameters
    ----------
    lat_deg : numeric
        Geodetic latitude [deg], positive north.
    alt_m : numeric
        Height above the ellipsoid / MSL [m] (the difference is irrelevant at this precision).
    """
    s2 = np.sin(np.radians(lat_deg)) ** 2
    return 9.7803253359 * (1 + 0.00193185265241 * s2) / np.sqrt(1 - 0.00669437999013 * s2) - 3.086e-6 * alt_m


def geodetic_to_ned(lat_deg, lon_deg, alt_m, lat0_deg, lon0_deg, alt0_m):
    """Local NED coordinates [m] of geodetic points relative to a reference point.

    North/east from the WGS-84 tangent plane (pymap3d); down = -(alt - alt0) so it matches barometric height.
    """
    north, east, _ = pymap3d.geodetic2ned(lat_deg, lon_deg, alt_m, lat0_deg, lon0_deg, alt0_m)
    return np.asarray(north), np.asarray(east), -(np.asarray(alt_m, dtype=float) - alt0_m)


def ned_to_geodetic(north_m, east_m, down_m, lat0_deg, lon0_deg, alt0_m):
    """Geodetic latitude, longitude [deg] and altitude [m] of local NED points (exact inverse of
    :func:`geodetic_to_ned`).

    North/east are tangent-plane coordinates of the point at its own altitude, so the tangent-plane down
    coordinate (altitude plus earth curvature) is found by fixed-point iteration; two passes reach < 1 mm at 10 km,
    the third refines latitude and longitude.
    """
    alt_m = alt0_m - np.asarray(down_m, dtype=float)
    tangent_down_m = -(alt_m - alt0_m)
    for _ in range(2):
        lat, lon, _ = pymap3d.ned2geodetic(north_m, east_m, tangent_down_m, lat0_deg, lon0_deg, alt0_m)
        _, _, tangent_down_m = pymap3d.geodetic2ned(lat, lon, alt_m, lat0_deg, lon0_deg, alt0_m)
    lat, lon, _ = pymap3d.ned2geodetic(north_m, east_m, tangent_down_m, lat0_deg, lon0_deg, alt0_m)
    return np.asarray(lat), np.asarray(lon), alt_m
