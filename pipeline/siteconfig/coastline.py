"""The water and land of a site from a polygon file the user has (``surveil config init
--coastline FILE``): GeoJSON (a FeatureCollection, a Feature or a bare geometry;
Polygon / MultiPolygon, coordinates ``[lon, lat]`` as RFC 7946 says) or WKT (POLYGON,
MULTIPOLYGON, GEOMETRYCOLLECTION).

Whether the polygons are water or land is read from the data, not asked: when most of
the vessels' positions (AIS, own ship) lie inside them they are water, else land. Both
become the gaps family's admissible area (``[[gaps.admissible]]`` minus
``[[gaps.islands]]``, docs/gaps.md), clipped to the site's extent padded by
:data:`PAD_M` (beyond it a polygon would only cost time) and simplified to
:data:`TOLERANCE_M` in the local tangent plane:

- water: each water polygon clipped to the extent is admissible, its holes islands;
- land: the extent box is admissible, each land polygon inside it an island.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
from shapely import wkt
from shapely.geometry import shape

from pipeline.errors import UsageError
from pipeline.frames import enu_to_geodetic, geodetic_to_enu

PAD_M = 40_000.0
TOLERANCE_M = 20.0
MIN_AREA_M2 = 2_500.0  # islands smaller than 50 m x 50 m are left out
MAX_POLYGONS = 200


@dataclass(frozen=True)
class Water:
    """The admissible area: ``admissible`` and ``islands`` as [lat_deg, lon_deg] rings."""

    kind: str  # the file's polygons are "water" or "land"
    inside_share: float  # share of the vessels' positions inside the file's polygons
    admissible: list[list[tuple[float, float]]]
    islands: list[list[tuple[float, float]]]
    source: str


def read_polygons(path: Path) -> shapely.Geometry:
    """The (multi)polygon of a GeoJSON or WKT file, in lon/lat; UsageError when the file
    holds none."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"--coastline {path}: cannot be read ({exc})") from None
    geoms: list[shapely.Geometry] = []
    stripped = text.lstrip()
    try:
        if stripped.startswith(("{", "[")):
            doc = json.loads(text)
            features = (doc.get("features", []) if doc.get("type") == "FeatureCollection"
                        else [doc])
            for f in features:
                g = f.get("geometry", f) if isinstance(f, dict) else None
                if g:
                    geoms.append(shape(g))
        else:
            geoms.append(wkt.loads(text))
    except (ValueError, TypeError, AttributeError, shapely.errors.GEOSException) as exc:
        raise UsageError(f"--coastline {path}: neither GeoJSON nor WKT polygons ({exc})"
                         ) from None
    polys = [p for g in geoms for p in _polygons(g)]
    if not polys:
        raise UsageError(f"--coastline {path}: holds no Polygon or MultiPolygon")
    return shapely.make_valid(shapely.MultiPolygon(polys))


def _polygons(g: shapely.Geometry) -> list[shapely.Polygon]:
    if isinstance(g, shapely.Polygon):
        return [g]
    if hasattr(g, "geoms"):
        return [p for part in g.geoms for p in _polygons(part)]
    return []


def water_from_file(path: Path, vessels_lat_lon: np.ndarray, extent: tuple[float, float,
                    float, float], origin: tuple[float, float]) -> Water:
    """The admissible area from ``path`` (module docstring). ``vessels_lat_lon``: (n, 2)
    positions of the vessels; ``extent``: (lat_min, lon_min, lat_max, lon_max) of the
    traffic; ``origin``: the tangent plane's (lat, lon)."""
    lonlat = read_polygons(path)
    lat0, lon0 = origin

    def to_xy(g: shapely.Geometry) -> shapely.Geometry:
        return shapely.transform(g, lambda c: np.column_stack(
            geodetic_to_enu(c[:, 1], c[:, 0], lat0, lon0)))

    area = to_xy(lonlat).buffer(0)
    if len(vessels_lat_lon):
        vx, vy = geodetic_to_enu(vessels_lat_lon[:, 0], vessels_lat_lon[:, 1], lat0, lon0)
        share = float(np.mean(shapely.contains_xy(area, np.atleast_1d(vx), np.atleast_1d(vy))))
    else:
        share = 0.0
    kind = "water" if share > 0.5 else "land"
    (x0, y0), (x1, y1) = (np.column_stack(geodetic_to_enu(
        np.array([extent[0], extent[2]]), np.array([extent[1], extent[3]]), lat0, lon0)))
    box = shapely.box(x0 - PAD_M, y0 - PAD_M, x1 + PAD_M, y1 + PAD_M)
    clipped = area.intersection(box)
    admissible, islands = [], []
    if kind == "water":
        for p in _polygons(clipped):
            p = p.simplify(TOLERANCE_M)
            if p.is_empty:
                continue
            admissible.append(p.exterior)
            islands += [r for r in p.interiors if shapely.Polygon(r).area >= MIN_AREA_M2]
    else:
        admissible.append(box.exterior)
        for p in _polygons(clipped):
            p = p.simplify(TOLERANCE_M)
            if not p.is_empty and p.area >= MIN_AREA_M2:
                islands.append(p.exterior)
    islands = sorted(islands, key=lambda r: -shapely.Polygon(r).area)[:MAX_POLYGONS]

    def rings(rs: list) -> list[list[tuple[float, float]]]:
        out = []
        for r in rs:
            xy = np.asarray(r.coords)[:-1]  # closed ring: drop the repeated vertex
            lat, lon = enu_to_geodetic(xy[:, 0], xy[:, 1], lat0, lon0)
            out.append([(round(float(a), 6), round(float(b), 6))
                        for a, b in zip(np.atleast_1d(lat), np.atleast_1d(lon), strict=True)])
        return [r for r in out if len(r) >= 3]

    return Water(kind, share, rings(admissible), rings(islands), str(path))
