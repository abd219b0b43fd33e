"""The place check: do a site's recordings and the config describe the same place?

Issue 35, item 3. Every position the batch computes with in the regional frame (the AIS
reports' WGS-84 positions: the maritime association and integrity, the gaps filter) is
measured against the config's region:

- **inside the region**: within ``[region] radius_m`` of its origin (great-circle
  distance), or inside one of its sectors, its water (``[[gaps.admissible]]`` minus the
  islands) or a radar site's coverage (``max_range_m`` around it);
- **in the sectors**, **in the water**: the shares the reports will be placed in.

When more than ``[region] max_outside_share`` (half) of a site's positions lie outside,
the config describes another place: the positions would be processed silently in a
distorted local frame (the demo origin 46.4 N 30.9 E is 1,964-2,541 km from real AIS
logs of the English Channel: 22 % of a real day's AIS reports flagged by the kinematic
self-test, 3.5 % with a local origin; every gap forecast ``infeasible``; every row in
``(outside sectors)``). :func:`check_places` then refuses the batch, exit 2 before any
work, naming the distance, the share outside and ``surveil config init`` (``--ignore-place``
goes on anyway); the ingest driver warns with the same text (it must not lose data).

Radar reports are not measured: they lie around their declared sites by construction
(a site declared far from the origin is a config check). Own-ship GNSS and airfield
positions are not measured either: those families work in their own frames (the
dead-reckoning origin at the first fix, the airfield reference point).

Pure measurement (:func:`measure`: positions + config -> :class:`Place`) and its reads
(:func:`site_place`, :func:`files_place`) are apart, so tests measure frames directly.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow.dataset as pds
import pymap3d.vincenty as vincenty

from pipeline import frames
from pipeline.config import Config
from pipeline.errors import UsageError
from pipeline.gaps.config import GapsConfig
from pipeline.gaps.geometry import build_geometry
from pipeline.geometry import assign_sectors
from pipeline.warehouse.delta import read_table

EARTH_RADIUS_M = 6_371_008.8  # mean radius (IUGG): great-circle distances to ~0.5 %
MAX_POSITIONS = 200_000
"""Positions measured at most (an even stride over the rows read): shares to ~0.2 %."""
POSITION_TABLES = ("ais_reports",)
"""Raw tables whose WGS-84 positions the batch computes with in the regional frame."""


class PlaceError(UsageError):
    """The config describes another place than a site's recordings (exit 2)."""


@dataclass(frozen=True)
class Place:
    """Where ``positions`` of a site lie against the config's region."""

    site: str
    positions: int  # measured (at most MAX_POSITIONS, a stride over ``rows``)
    rows: int  # position rows read
    centre_lat_deg: float  # median latitude, deg
    centre_lon_deg: float  # median longitude, deg
    distance_m: float  # from the region's origin to the centre (WGS-84, Vincenty), m
    outside: int  # positions outside the region (module docstring)
    in_sectors: int | None  # None: the config has no sector
    in_water: int | None  # None: the config has no water
    region: str = ""
    origin: tuple[float, float] = (0.0, 0.0)
    radius_m: float = 0.0
    max_outside_share: float = 0.5

    @property
    def outside_share(self) -> float:
        return self.outside / self.positions if self.positions else 0.0

    @property
    def refused(self) -> bool:
        """Most positions outside the region: the config describes another place."""
        return self.positions > 0 and self.outside_share > self.max_outside_share

    def describe(self) -> str:
        """One paragraph: where the positions lie, against what."""
        shares = []
        if self.in_sectors is not None:
            shares.append(f"{self.in_sectors / self.positions:.0%} in its sectors")
        if self.in_water is not None:
            shares.append(f"{self.in_water / self.positions:.0%} in its water")
        also = f" ({', '.join(shares)})" if shares else ""
        return (
            f"site {self.site!r}: its {self.rows:,} AIS positions are centred on "
            f"{_latlon(self.centre_lat_deg, self.centre_lon_deg)}, "
            f"{self.distance_m / 1000.0:,.0f} km from the origin of region "
            f"{self.region!r} ({_latlon(*self.origin)}); {self.outside_share:.0%} of them "
            f"lie outside it (farther than {self.radius_m / 1000.0:,.0f} km from the origin "
            f"and in none of its sectors, water or radar coverage){also}"
        )

    def advice(self) -> str:
        if self.distance_m <= self.radius_m:  # centred on the region, spread far beyond it
            return ("the positions spread far beyond the region (a feed of several places, "
                    "a satellite receiver?): declare the area they cover ([region] "
                    "radius_m, sectors) or give each place its own site and config "
                    "(surveil config init), or pass --ignore-place to batch anyway")
        return ("the config describes another place: write one for this site's place "
                "(surveil config init <recordings> --out site.toml, then --config "
                "site.toml), or pass --ignore-place to batch anyway")


def _latlon(lat: float, lon: float) -> str:
    return (f"{abs(lat):.2f} {'N' if lat >= 0 else 'S'} "
            f"{abs(lon):.2f} {'E' if lon >= 0 else 'W'}")


def great_circle_m(lat_deg: np.ndarray, lon_deg: np.ndarray, lat0_deg: float,
                   lon0_deg: float) -> np.ndarray:
    """Haversine distance of each position from (lat0, lon0), m (sphere of the mean
    radius)."""
    p1, p2 = np.radians(lat_deg), np.radians(lat0_deg)
    dl = np.radians(np.asarray(lon_deg) - lon0_deg)
    h = np.sin((p2 - p1) / 2.0) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dl / 2.0) ** 2
    return 2.0 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(h, 0.0, 1.0)))


def measure(lat_deg: np.ndarray, lon_deg: np.ndarray, cfg: Config, *, site: str = "",
            rows: int | None = None) -> Place:
    """Where the positions (WGS-84, deg; NaN ignored) lie against ``cfg``'s region,
    sectors, water and radar coverage (module docstring)."""
    lat, lon = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
    ok = np.isfinite(lat) & np.isfinite(lon)
    lat, lon = lat[ok], lon[ok]
    r = cfg.region
    common = dict(site=site, region=r.name, origin=(r.origin_lat_deg, r.origin_lon_deg),
                  radius_m=r.radius_m, max_outside_share=r.max_outside_share)
    n = lat.size
    if n == 0:
        return Place(positions=0, rows=rows or 0, centre_lat_deg=np.nan,
                     centre_lon_deg=np.nan, distance_m=np.nan, outside=0, in_sectors=None,
                     in_water=None, **common)  # type: ignore[arg-type]
    inside = great_circle_m(lat, lon, r.origin_lat_deg, r.origin_lon_deg) <= r.radius_m
    for s in cfg.radar_sites:
        inside |= great_circle_m(lat, lon, s.lat_deg, s.lon_deg) <= s.max_range_m
    x, y = frames.geodetic_to_enu(lat, lon, r.origin_lat_deg, r.origin_lon_deg)
    x, y = np.atleast_1d(x), np.atleast_1d(y)
    in_sectors = None
    if cfg.sectors:
        sector = assign_sectors(pl.DataFrame({"x_enu_m": x, "y_enu_m": y}), cfg.sectors,
                                r)["sector"].is_not_null().to_numpy()
        inside |= sector
        in_sectors = int(sector.sum())
    in_water = None
    gaps = (cfg.families or {}).get("gaps")
    if isinstance(gaps, GapsConfig) and gaps.admissible:
        water = build_geometry(gaps, r).inside(x, y)
        inside |= water
        in_water = int(water.sum())
    clat, clon = float(np.median(lat)), float(np.median(lon))
    return Place(positions=n, rows=n if rows is None else rows, centre_lat_deg=clat,
                 centre_lon_deg=clon,
                 distance_m=float(vincenty.vdist(r.origin_lat_deg, r.origin_lon_deg, clat,
                                                 clon)[0]),
                 outside=int(n - inside.sum()), in_sectors=in_sectors, in_water=in_water,
                 **common)  # type: ignore[arg-type]


def _positions(warehouse: Path, site: str | None, start_ns: int | None, end_ns: int | None,
               predicate: pds.Expression | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """(lat, lon, rows read) of the position tables, an even stride of at most
    MAX_POSITIONS of them."""
    lats, lons = [], []
    for name in POSITION_TABLES:
        t = read_table(warehouse, name, start_ns=start_ns, end_ns=end_ns, site=site,
                       columns=["lat_deg", "lon_deg"], predicate=predicate, sort=False)
        lats.append(t["lat_deg"].to_numpy(zero_copy_only=False))
        lons.append(t["lon_deg"].to_numpy(zero_copy_only=False))
    lat, lon = np.concatenate(lats), np.concatenate(lons)
    step = max(1, -(-lat.size // MAX_POSITIONS))
    return lat[::step], lon[::step], int(lat.size)


def site_place(warehouse: Path, cfg: Config, site: str, start_ns: int, end_ns: int) -> Place:
    """The place of ``site``'s positions in ``[start_ns, end_ns)``."""
    lat, lon, rows = _positions(warehouse, site, start_ns, end_ns)
    return measure(lat, lon, cfg, site=site, rows=rows)


def files_place(warehouse: Path, cfg: Config, site: str, files: Sequence[str]) -> Place:
    """The place of the positions ``files`` (source files of ``site``) brought in."""
    lat, lon, rows = _positions(warehouse, site, None, None,
                                pds.field("source_file").isin(list(files)))
    return measure(lat, lon, cfg, site=site, rows=rows)


def check_places(warehouse: Path, cfg: Config, sites: Sequence[str], start_ns: int,
                 end_ns: int) -> list[Place]:
    """Every site's place in the window; :class:`PlaceError` naming each refused site
    (their distance, the share outside, what to do) before any work."""
    places = [site_place(warehouse, cfg, s, start_ns, end_ns) for s in sites]
    refused = [p for p in places if p.refused]
    if refused:
        raise PlaceError("; ".join(p.describe() for p in refused) + ": " + refused[0].advice())
    return places
