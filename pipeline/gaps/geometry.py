"""The gaps family's geometry in the regional ENU frame: the admissible area (water
minus islands, the exogenous constraint of the distributed maritime observation paper)
and the named zones."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely

from pipeline import frames
from pipeline.config import RegionConfig
from pipeline.gaps.config import GapsConfig, NamedPolygon


@dataclass(frozen=True, eq=False)
class GapsGeometry:
    """The exogenous constraint and the named zones in the regional ENU plane (m).

    ``water``: the admissible area (union of the admissible polygons minus the
    islands), or ``None`` when the config gives no geometry (no constraint).
    ``zones``: (name, polygon) in config order; a point belongs to the first zone that
    contains it, so zone probabilities add up to at most 1.
    """

    water: shapely.Geometry | None
    zones: tuple[tuple[str, shapely.Geometry], ...] = field(default=())

    def inside(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """u_k(x) > 0: the points (any shape) lie in the admissible area."""
        if self.water is None:
            return np.ones(np.shape(x), bool)
        return shapely.contains_xy(self.water, x, y)

    def near(self, x: np.ndarray, y: np.ndarray, margin_m: float) -> np.ndarray:
        """The points (1-d) lie in the admissible area or at most ``margin_m`` outside it
        (every point when there is no constraint)."""
        if self.water is None:
            return np.ones(np.shape(x), bool)
        inside = shapely.contains_xy(self.water, x, y)
        out = np.flatnonzero(~inside)
        if out.size:
            inside[out] = shapely.dwithin(self.water, shapely.points(x[out], y[out]), margin_m)
        return inside

    def zone_index(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Index of the first zone containing each point, ``len(zones)`` when none."""
        idx = np.full(np.shape(x), len(self.zones))
        for k, (_, poly) in enumerate(self.zones):
            free = idx == len(self.zones)
            idx[free & shapely.contains_xy(poly, x, y)] = k
        return idx


def _enu_polygon(p: NamedPolygon, region: RegionConfig) -> shapely.Polygon:
    lat, lon = np.array(p.polygon_lat_lon_deg, float).T
    e, n = frames.geodetic_to_enu(lat, lon, region.origin_lat_deg, region.origin_lon_deg)
    return shapely.make_valid(shapely.Polygon(np.column_stack([e, n])))


def build_geometry(g: GapsConfig, region: RegionConfig) -> GapsGeometry:
    """Shapely geometry (prepared for ``contains_xy``) of the constraint and the zones."""
    water = None
    if g.admissible or g.islands:
        if g.admissible:
            water = shapely.union_all([_enu_polygon(p, region) for p in g.admissible])
        else:  # islands only: everything but the islands is admissible
            water = shapely.box(-1e8, -1e8, 1e8, 1e8)
        if g.islands:
            water = water.difference(
                shapely.union_all([_enu_polygon(p, region) for p in g.islands])
            )
        shapely.prepare(water)
    zones = []
    for z in g.zones:
        poly = _enu_polygon(z, region)
        shapely.prepare(poly)
        zones.append((z.name, poly))
    return GapsGeometry(water, tuple(zones))


