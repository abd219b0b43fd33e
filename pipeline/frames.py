"""Geodetic and local frames: WGS-84 <-> local ENU, polar <-> Cartesian.

Conventions (used everywhere in surveil):
- ENU: x east, y north, in metres, on the tangent plane at an origin on the WGS-84
  ellipsoid at height 0 (targets at sea level; radar height is not used for range).
- Azimuth and course are clockwise from true north, in radians:
  ``x = r sin(az)``, ``y = r cos(az)``; velocity ``vx = V sin(C)``, ``vy = V cos(C)``.
  (The multi-radar paper writes x* = x + V dt cos C with x to the north; same thing.)
- Radar range is horizontal range in the site's ENU plane, m.

All functions take and return numpy arrays (vectorised through pymap3d).
"""

from __future__ import annotations

import numpy as np
import pymap3d as pm

TWO_PI = 2.0 * np.pi


def geodetic_to_enu(
    lat_deg: np.ndarray, lon_deg: np.ndarray, origin_lat_deg: float, origin_lon_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """WGS-84 (lat, lon, height 0) -> (east_m, north_m) on the tangent plane at the origin."""
    e, n, _ = pm.geodetic2enu(
        np.asarray(lat_deg, float),
        np.asarray(lon_deg, float),
        0.0,
        origin_lat_deg,
        origin_lon_deg,
        0.0,
    )
    return np.asarray(e, float), np.asarray(n, float)


def enu_to_geodetic(
    east_m: np.ndarray, north_m: np.ndarray, origin_lat_deg: float, origin_lon_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """(east_m, north_m) on the origin's tangent plane (up chosen so the point is on the
    ellipsoid to first order) -> WGS-84 (lat_deg, lon_deg)."""
    e = np.asarray(east_m, float)
    n = np.asarray(north_m, float)
    # a point on the tangent plane lies above the ellipsoid by ~ d^2 / 2R; drop it so
    # the round trip with geodetic_to_enu is exact to the millimetre at 30 km.
    up = -(e**2 + n**2) / (2.0 * 6_371_000.0)
    lat, lon, _ = pm.enu2geodetic(e, n, up, origin_lat_deg, origin_lon_deg, 0.0)
    return np.asarray(lat, float), np.asarray(lon, float)


def site_to_region(
    x_site_m: np.ndarray,
    y_site_m: np.ndarray,
    site_lat_deg: float,
    site_lon_deg: float,
    origin_lat_deg: float,
    origin_lon_deg: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Site-frame ENU -> regional-frame ENU (through WGS-84; exact, not a 2-D shift)."""
    lat, lon = enu_to_geodetic(x_site_m, y_site_m, site_lat_deg, site_lon_deg)
    return geodetic_to_enu(lat, lon, origin_lat_deg, origin_lon_deg)


def site_rotation_rad(
    site_lat_deg: float, site_lon_deg: float, origin_lat_deg: float, origin_lon_deg: float
) -> float:
    """Angle by which the site's north is rotated in the regional frame (meridian
    convergence, ~ dlon * sin(lat)); add it to site-frame azimuths/courses to get
    regional-frame ones."""
    e0, n0 = geodetic_to_enu(site_lat_deg, site_lon_deg, origin_lat_deg, origin_lon_deg)
    lat1, lon1 = enu_to_geodetic(np.array([0.0]), np.array([1000.0]), site_lat_deg, site_lon_deg)
    e1, n1 = geodetic_to_enu(lat1, lon1, origin_lat_deg, origin_lon_deg)
    return float(np.arctan2(e1[0] - e0, n1[0] - n0))


def polar_to_enu(range_m: np.ndarray, azimuth_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Range/azimuth (clockwise from north) -> (east_m, north_m)."""
    return range_m * np.sin(azimuth_rad), range_m * np.cos(azimuth_rad)


def enu_to_polar(east_m: np.ndarray, north_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(east_m, north_m) -> (range_m, azimuth_rad in [0, 2pi))."""
    return np.hypot(east_m, north_m), np.mod(np.arctan2(east_m, north_m), TWO_PI)


def polar_covariance(
    range_m: np.ndarray,
    azimuth_rad: np.ndarray,
    sigma_range_m: np.ndarray,
    sigma_azimuth_rad: np.ndarray,
) -> np.ndarray:
    """Cartesian position covariance of a polar measurement, (n, 2, 2) in m^2.

    The covariance form of the multi-radar paper's eq. 3 (which gives the linear
    bound sigma_x = sigma_j |cos b| + j |sin b| sigma_b): J diag(sr^2, sa^2) J^T with
    J = d(x, y)/d(r, az) = [[sin az, r cos az], [cos az, -r sin az]].
    """
    s, c = np.sin(azimuth_rad), np.cos(azimuth_rad)
    vr = np.asarray(sigma_range_m, float) ** 2
    va = (range_m * sigma_azimuth_rad) ** 2
    cov = np.empty((np.size(range_m), 2, 2))
    cov[:, 0, 0] = s * s * vr + c * c * va
    cov[:, 1, 1] = c * c * vr + s * s * va
    cov[:, 0, 1] = cov[:, 1, 0] = s * c * (vr - va)
    return cov


def velocity_enu(speed_mps: np.ndarray, course_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Speed and course (clockwise from north) -> (v_east_mps, v_north_mps)."""
    return speed_mps * np.sin(course_rad), speed_mps * np.cos(course_rad)


def wrap_angle(a_rad: np.ndarray) -> np.ndarray:
    """Wrap an angle difference into [-pi, pi)."""
    return np.mod(np.asarray(a_rad) + np.pi, TWO_PI) - np.pi
