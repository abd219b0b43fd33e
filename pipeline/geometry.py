"""Geometry on regional ENU positions: geodetic coordinates, sectors, cross-track deviation.

Works on any frame with x_enu_m / y_enu_m and a position covariance, either as the
fused table's ``sigma_x_m, sigma_y_m, cov_xy_m2`` or as the synchronised/associations
rows' ``P_xx, P_yy, P_xy`` (see :func:`position_covariance`).

Cross-track deviation L_s (multi-radar paper, eq. 1-4). Eq. 1 gives the signed distance
of the ship from the axis of the nearest fairway leg, its sign fixed relative to the
radar post. Our convention, independent of any radar: for a leg from start S to end E
with unit direction d = (E - S)/|E - S| (x east, y north), the starboard normal is
n = (d_y, -d_x) (d rotated 90 deg clockwise), and

.. math:: L_s = (p - S) \\cdot n

positive to starboard (right) of the leg's direction, negative to port. Its sigma is
the covariance form of eq. 2-4 (eq. 2-3 bound the sigma by a linear sum of |terms|):

.. math:: \\sigma_s = \\sqrt{n^T P n}

which for a single radar's polar covariance reduces to
sqrt(sigma_r^2 sin^2 theta + (r sigma_b)^2 cos^2 theta), theta the aspect between the
line of sight and the leg (eq. 4; eq. 5-6 at theta = 0 and 90 deg).

Sector polygons and legs are given in lat/lon and drawn as straight lines in the
regional ENU plane (differences from geodesics are centimetres at VTS scale).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import polars as pl
import shapely

from pipeline import frames
from pipeline.config import FairwayLeg, RegionConfig, Sector


def position_covariance(df: pl.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P_xx, P_yy, P_xy) in m^2 from either P_xx/P_yy/P_xy or sigma_x_m/sigma_y_m/cov_xy_m2."""
    if "P_xx" in df.columns:
        return df["P_xx"].to_numpy(), df["P_yy"].to_numpy(), df["P_xy"].to_numpy()
    return (
        df["sigma_x_m"].to_numpy() ** 2,
        df["sigma_y_m"].to_numpy() ** 2,
        df["cov_xy_m2"].to_numpy(),
    )


def add_geodetic(df: pl.DataFrame, region: RegionConfig) -> pl.DataFrame:
    """Add lat_deg / lon_deg (WGS-84, deg) from x_enu_m / y_enu_m (regional ENU, m)."""
    lat, lon = frames.enu_to_geodetic(
        df["x_enu_m"].to_numpy(),
        df["y_enu_m"].to_numpy(),
        region.origin_lat_deg,
        region.origin_lon_deg,
    )
    return df.with_columns(
        pl.Series("lat_deg", np.atleast_1d(lat), dtype=pl.Float64),
        pl.Series("lon_deg", np.atleast_1d(lon), dtype=pl.Float64),
    )


def sector_polygons(sectors: Sequence[Sector], region: RegionConfig) -> list[shapely.Polygon]:
    """Each sector's lat/lon polygon as a shapely polygon in regional ENU, m."""
    polys = []
    for s in sectors:
        lat, lon = np.array(s.polygon_lat_lon_deg, float).T
        e, n = frames.geodetic_to_enu(lat, lon, region.origin_lat_deg, region.origin_lon_deg)
        polys.append(shapely.Polygon(np.column_stack([e, n])))
    return polys


def assign_sectors(
    df: pl.DataFrame, sectors: Sequence[Sector], region: RegionConfig
) -> pl.DataFrame:
    """Add ``sector``: name of the first sector (config order) whose polygon contains
    (x_enu_m, y_enu_m); null outside every sector. Vectorised ``shapely.contains_xy``."""
    idx = sector_indices(df["x_enu_m"].to_numpy(), df["y_enu_m"].to_numpy(), sectors, region)
    names = np.array([s.name for s in sectors] + [None], dtype=object)
    return df.with_columns(pl.Series("sector", names[idx].tolist(), dtype=pl.String))


def sector_indices(x: np.ndarray, y: np.ndarray, sectors: Sequence[Sector],
                   region: RegionConfig) -> np.ndarray:
    """Index (config order) of the first sector whose polygon contains each (x, y)
    (regional ENU, m); ``len(sectors)`` outside every sector."""
    idx = np.full(x.size, -1)
    for k, poly in enumerate(sector_polygons(sectors, region)):
        # only the points inside the polygon's bounding box go to GEOS (same answer)
        x0, y0, x1, y1 = poly.bounds
        cand = np.flatnonzero((idx < 0) & (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1))
        idx[cand[shapely.contains_xy(poly, x[cand], y[cand])]] = k
    return np.where(idx < 0, len(sectors), idx)


def leg_endpoints(
    legs: Sequence[FairwayLeg], region: RegionConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Start and end of each leg in regional ENU, two (n_legs, 2) arrays, m."""

    def enu(lat: list[float], lon: list[float]) -> np.ndarray:
        e, n = frames.geodetic_to_enu(
            np.array(lat), np.array(lon), region.origin_lat_deg, region.origin_lon_deg
        )
        return np.column_stack([e, n]).reshape(-1, 2)

    start = enu([g.start_lat_deg for g in legs], [g.start_lon_deg for g in legs])
    end = enu([g.end_lat_deg for g in legs], [g.end_lon_deg for g in legs])
    return start, end


def cross_track_xy(
    x: np.ndarray,
    y: np.ndarray,
    P_xx: np.ndarray,
    P_yy: np.ndarray,
    P_xy: np.ndarray,
    start: np.ndarray,
    end: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nearest leg SEGMENT and the cross-track deviation from its axis.

    Points (n,), legs as (L, 2) start/end arrays (m). Returns (leg index (n,),
    distance to that segment m, signed cross-track L_s m (+ starboard), sigma_s m).
    """
    d = end - start  # (L, 2)
    length2 = np.einsum("lk,lk->l", d, d)
    px, py = x[:, None] - start[:, 0], y[:, None] - start[:, 1]  # (n, L)
    t = np.clip((px * d[:, 0] + py * d[:, 1]) / length2, 0.0, 1.0)
    dist = np.hypot(px - t * d[:, 0], py - t * d[:, 1])
    leg = np.argmin(dist, axis=1)
    rows = np.arange(x.size)
    u = d[leg] / np.sqrt(length2[leg])[:, None]
    nx, ny = u[:, 1], -u[:, 0]  # starboard normal: direction rotated 90 deg clockwise
    cross = px[rows, leg] * nx + py[rows, leg] * ny
    sigma = np.sqrt(nx * nx * P_xx + 2.0 * nx * ny * P_xy + ny * ny * P_yy)
    return leg, dist[rows, leg], cross, sigma


def cross_track(
    df: pl.DataFrame, legs: Sequence[FairwayLeg], region: RegionConfig, max_cross_track_m: float
) -> pl.DataFrame:
    """Add leg_id, cross_track_m and sigma_cross_track_m (m, multi-radar paper eq. 1-4;
    sign: + to starboard of the leg's direction). All three are null when the point is
    farther than ``max_cross_track_m`` from every leg segment (or there are no legs)."""
    n = df.height
    if not legs or n == 0:
        return df.with_columns(
            pl.lit(None, pl.String).alias("leg_id"),
            pl.lit(None, pl.Float64).alias("cross_track_m"),
            pl.lit(None, pl.Float64).alias("sigma_cross_track_m"),
        )
    start, end = leg_endpoints(legs, region)
    P_xx, P_yy, P_xy = position_covariance(df)
    leg, dist, cross, sigma = cross_track_xy(
        df["x_enu_m"].to_numpy(), df["y_enu_m"].to_numpy(), P_xx, P_yy, P_xy, start, end
    )
    near = dist <= max_cross_track_m
    ids = np.array([g.leg_id for g in legs], dtype=object)[leg]
    ids[~near] = None
    return df.with_columns(
        pl.Series("leg_id", ids.tolist(), dtype=pl.String),
        pl.Series("cross_track_m", np.where(near, cross, np.nan)).fill_nan(None),
        pl.Series("sigma_cross_track_m", np.where(near, sigma, np.nan)).fill_nan(None),
    )
