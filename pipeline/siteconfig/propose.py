"""What ``surveil config init`` proposes for a site, from the :class:`Survey` of its
recordings: the region's origin and extent, sectors over the traffic, the radar sites and
airfield sensors with their positions (from the data where it carries them, estimated
against another source where it does not: :mod:`pipeline.siteconfig.register`), and the
water from a coastline file. Every decision carries the note the config prints beside it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import polars as pl

from pipeline.frames import enu_to_geodetic, geodetic_to_enu
from pipeline.siteconfig.coastline import Water, water_from_file
from pipeline.siteconfig.register import ais_at_seconds, frame_offset, local_xy
from pipeline.siteconfig.survey import AirfieldSource, RadarSource, Survey
from pipeline.units import NS
from pipeline.warehouse.delta import read_table

CELL_M = 10_000.0  # proposed sector grid: cells of about this side...
MAX_CELLS = 4  # ...at most this many along each axis
MIN_CELL_SHARE = 0.005  # a cell with less of the traffic is left out (its rows: no sector)
FUSED_KINDS = ("smr", "mlat", "vasn")  # the airfield family fuses these (one of each)
GEODETIC_SHARE = 0.5  # a source whose reports carry WGS-84 this often is "located"


@dataclass(frozen=True)
class Sector:
    name: str
    polygon: list[tuple[float, float]]
    note: str


@dataclass(frozen=True)
class RadarProposal:
    source: RadarSource
    lat_deg: float | None  # None: not located (the block is written commented out)
    lon_deg: float | None
    note: str


@dataclass(frozen=True)
class SensorProposal:
    sensor_id: str
    source: AirfieldSource
    lat_deg: float
    lon_deg: float
    located: bool
    note: str


@dataclass
class AirfieldProposal:
    reference_lat_deg: float
    reference_lon_deg: float
    reference_note: str
    sensors: list[SensorProposal] = field(default_factory=list)
    other: list[tuple[AirfieldSource, str]] = field(default_factory=list)  # not declared


@dataclass
class Proposal:
    name: str
    survey: Survey
    origin: tuple[float, float]
    origin_note: str
    origin_known: bool
    extent: tuple[float, float, float, float] | None  # lat_min, lon_min, lat_max, lon_max
    sectors: list[Sector] = field(default_factory=list)
    sectors_note: str = ""
    radars: list[RadarProposal] = field(default_factory=list)
    airfield: AirfieldProposal | None = None
    water: Water | None = None
    warnings: list[str] = field(default_factory=list)


def _percentile_box(ll: np.ndarray) -> tuple[float, float, float, float]:
    lo = np.percentile(ll, 1, axis=0)
    hi = np.percentile(ll, 99, axis=0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def _padded(box: tuple[float, float, float, float], origin: tuple[float, float],
            pad_share: float = 0.1, min_pad_m: float = 500.0) -> tuple[float, float, float, float]:
    lat0, lon0 = origin
    (x0, x1), (y0, y1) = (geodetic_to_enu(np.array([box[0], box[2]]),
                                          np.array([box[1], box[3]]), lat0, lon0))
    px = max(min_pad_m, pad_share * (x1 - x0))
    py = max(min_pad_m, pad_share * (y1 - y0))
    la, lo = enu_to_geodetic(np.array([x0 - px, x1 + px]), np.array([y0 - py, y1 + py]),
                             lat0, lon0)
    return float(la[0]), float(lo[0]), float(la[1]), float(lo[1])


def propose(survey: Survey, warehouse: Path, *, name: str,
            origin: tuple[float, float] | None = None, coastline: Path | None = None
            ) -> Proposal:
    """The :class:`Proposal` for ``survey`` (of ``warehouse``)."""
    ll = survey.all_positions
    if origin is not None:
        org, note, known = origin, "the point given (--origin)", True
    elif len(ll):
        org = (float(np.median(ll[:, 0])), float(np.median(ll[:, 1])))
        tables = ", ".join(f"{t} {len(p):,}" for t, p in survey.positions.items() if len(p))
        note = f"the median of the recordings' positions ({tables})"
        known = True
    else:
        org, known = (0.0, 0.0), False
        note = ("UNKNOWN: the recordings carry no geodetic position (range/azimuth and x/y "
                "are relative to the sensors); set your site's reference point here, or run "
                "`surveil config init` again with --origin LAT,LON")
    prop = Proposal(name, survey, org, note, known, None)
    if not known:
        prop.warnings.append("the recordings carry no geodetic position: the origin is "
                             "written as 0, 0 (UNKNOWN); give --origin LAT,LON")
    if len(ll):
        prop.extent = _padded(_percentile_box(ll), org)
    maritime = bool(survey.ais or survey.radars)
    if maritime and prop.extent is not None:
        mar = np.concatenate([p for t, p in survey.positions.items()
                              if t in ("ais_reports",) and len(p)] or [ll])
        prop.sectors, prop.sectors_note = _grid(mar, org)
    if survey.radars:
        prop.radars = _radars(survey, warehouse, org)
    if survey.airfield:
        prop.airfield = _airfield(survey, warehouse, org, known)
    if coastline is not None:
        box = prop.extent or (org[0], org[1], org[0], org[1])
        prop.water = water_from_file(coastline, survey.vessel_positions, box, org)
    return prop


def _grid(ll: np.ndarray, origin: tuple[float, float]) -> tuple[list[Sector], str]:
    """A grid over the traffic's extent (the 1st-99th percentile box, padded 10 %),
    cells of about ``CELL_M``, at most ``MAX_CELLS`` a side; cells without traffic are
    left out. One cell: the extent itself."""
    box = _padded(_percentile_box(ll), origin)
    lat0, lon0 = origin
    (x0, x1), (y0, y1) = geodetic_to_enu(np.array([box[0], box[2]]),
                                         np.array([box[1], box[3]]), lat0, lon0)
    nx = int(min(MAX_CELLS, max(1, math.ceil((x1 - x0) / CELL_M))))
    ny = int(min(MAX_CELLS, max(1, math.ceil((y1 - y0) / CELL_M))))
    lat_edges = np.linspace(box[0], box[2], ny + 1)
    lon_edges = np.linspace(box[1], box[3], nx + 1)
    ix = np.clip(np.searchsorted(lon_edges, ll[:, 1]) - 1, 0, nx - 1)
    iy = np.clip(np.searchsorted(lat_edges, ll[:, 0]) - 1, 0, ny - 1)
    counts = np.bincount(iy * nx + ix, minlength=nx * ny)
    out = []
    w_km, h_km = (x1 - x0) / 1000.0, (y1 - y0) / 1000.0
    for r in range(ny):
        for c in range(nx):
            n = int(counts[r * nx + c])
            if n < max(1, MIN_CELL_SHARE * len(ll)):
                continue
            a, b = float(lat_edges[r]), float(lat_edges[r + 1])
            lo, hi = float(lon_edges[c]), float(lon_edges[c + 1])
            poly = [(round(a, 6), round(lo, 6)), (round(a, 6), round(hi, 6)),
                    (round(b, 6), round(hi, 6)), (round(b, 6), round(lo, 6))]
            name = "traffic_extent" if nx * ny == 1 else f"cell_r{r + 1}c{c + 1}"
            where = ("" if nx * ny == 1
                     else f"row {r + 1} from the south, column {c + 1} from the west; ")
            out.append(Sector(name, poly,
                              f"PROPOSED: {where}{100 * n / len(ll):.1f} % of the positions"))
    grid = "the traffic extent" if nx * ny == 1 else f"a {ny} x {nx} grid"
    note = (f"PROPOSED sectors: {grid} "
            f"over the 1st-99th percentile box of {len(ll):,} positions, padded 10 % "
            f"({w_km:.1f} km east-west x {h_km:.1f} km north-south); cells with less than "
            f"{100 * MIN_CELL_SHARE:g} % of the traffic left out. Rename and redraw them: "
            "reports group by sector, the first polygon holding a position names it")
    return out, note


def _radars(survey: Survey, warehouse: Path, origin: tuple[float, float]
            ) -> list[RadarProposal]:
    """Each radar site of the recordings, located against AIS when the data allow."""
    ais = pl.from_arrow(read_table(warehouse, "ais_reports", columns=[
        "time_ns", "mmsi", "lat_deg", "lon_deg"], site=survey.site, sort=False))
    out = []
    for r in survey.radars:
        lat = lon = None
        note = ("POSITION UNKNOWN: its reports (range/azimuth from the antenna) carry no "
                "position and no AIS ship was seen with it to locate it: set lat_deg/lon_deg "
                "and uncomment this block; until then its reports are batch rejects "
                "(unknown_site)")
        if ais.height:
            rep = pl.from_arrow(read_table(warehouse, "radar_tracks", columns=[
                "time_ns", "site_id", "range_m", "azimuth_rad"], site=survey.site, sort=False)
            ).filter(pl.col("site_id") == r.site_id)
            rxy = local_xy(rep)
            seconds = rxy["second"].unique().to_numpy()
            if seconds.size > 3600:
                seconds = np.sort(seconds)[:: int(np.ceil(seconds.size / 3600))]
                rxy = rxy.filter(pl.col("second").is_in(seconds))
            axy = ais_at_seconds(ais, seconds, *origin)
            off = frame_offset(axy, rxy, max_offset_m=max(20_000.0, 1.2 * r.max_range_m))
            if off is not None:
                la, lo = enu_to_geodetic(np.array([off.east_m]), np.array([off.north_m]),
                                         *origin)
                lat, lon = float(la[0]), float(lo[0])
                note = (f"PROPOSED: estimated from its reports against AIS ships ({off.pairs:,} "
                        f"pairs, {off.matched_share:.0%} of its reports matched); check it")
        out.append(RadarProposal(r, lat, lon, note))
    return out


def _airfield(survey: Survey, warehouse: Path, origin: tuple[float, float], origin_known: bool
              ) -> AirfieldProposal:
    """The airfield's reference point and sensors (module docstring of
    :mod:`pipeline.siteconfig.register` for the positions)."""
    obs = pl.from_arrow(read_table(warehouse, "airfield_obs", columns=[
        "time_ns", "sensor_id", "message_type", "range_m", "azimuth_rad", "x_m", "y_m",
        "lat_deg", "lon_deg"], site=survey.site, sort=False)).filter(
        pl.col("message_type").is_null() | (pl.col("message_type") == "target report"))
    by_id = {s.sensor_id: obs.filter(pl.col("sensor_id") == s.sensor_id)
             for s in survey.airfield}
    chosen: dict[str, AirfieldSource] = {}
    other: list[tuple[AirfieldSource, str]] = []
    for s in survey.airfield:  # most reports first
        if s.kind not in FUSED_KINDS:
            other.append((s, f"{s.kind} reports: the airfield family fuses smr, mlat and vasn "
                             "only; its rows stay in airfield_obs (surveil sql)"))
        elif s.kind in chosen:
            other.append((s, f"a second {s.kind} ({chosen[s.kind].sensor_id} has more "
                             "reports): the airfield family fuses one sensor of each kind"))
        else:
            chosen[s.kind] = s

    def geodetic(s: AirfieldSource) -> bool:
        return s.geodetic >= GEODETIC_SHARE * s.reports

    anchors = [s for s in survey.airfield if geodetic(s)]
    frames: dict[str, pl.DataFrame] = {}
    lat0, lon0 = origin

    def xy(s: AirfieldSource, with_ll: bool) -> pl.DataFrame:
        key = f"{s.sensor_id}/{with_ll}"
        if key not in frames:
            d = by_id[s.sensor_id]
            frames[key] = local_xy(d if with_ll else d.drop("lat_deg", "lon_deg"),
                                   lat0 if with_ll else None, lon0 if with_ll else None)
        return frames[key]

    anchor_xy = (pl.concat([xy(a, True) for a in anchors]) if anchors else None)
    positions: dict[str, tuple[float, float, bool, str]] = {}

    def locate(s: AirfieldSource, against: pl.DataFrame, against_origin: tuple[float, float],
               what: str) -> tuple[float, float, bool, str] | None:
        off = frame_offset(against, xy(s, False))
        if off is None:
            return None
        la, lo = enu_to_geodetic(np.array([off.east_m]), np.array([off.north_m]),
                                 *against_origin)
        return (float(la[0]), float(lo[0]), True,
                f"PROPOSED: estimated from its reports against {what} ({off.pairs:,} pairs, "
                f"{off.matched_share:.0%} of its reports matched); check it")

    mlat = chosen.get("mlat")
    if mlat is not None:
        if geodetic(mlat):
            ll = by_id[mlat.sensor_id].select("lat_deg", "lon_deg").drop_nulls().to_numpy()
            positions[mlat.sensor_id] = (float(np.median(ll[:, 0])), float(np.median(ll[:, 1])),
                                         True, "its reports carry WGS-84 positions (used as "
                                         "they are); this point is their median")
        elif anchor_xy is not None:
            found = locate(mlat, anchor_xy, origin,
                           " + ".join(f"{a.sensor_id} ({a.kind})" for a in anchors))
            if found:
                positions[mlat.sensor_id] = found
        if mlat.sensor_id not in positions:
            positions[mlat.sensor_id] = (lat0, lon0, origin_known,
                                         "its x/y origin (the airfield reference point): "
                                         + ("the point given (--origin)" if origin_known
                                            else "UNKNOWN, set it"))
    ref_lat, ref_lon = (positions[mlat.sensor_id][:2] if mlat is not None else origin)
    ref_note = ("the MLAT's x/y origin" if mlat is not None else
                "the region origin") + " (the common frame's tangent point; MLAT and VASN x/y "
    ref_note += "are from it)"
    for kind in ("smr", "vasn"):
        s = chosen.get(kind)
        if s is None:
            continue
        if geodetic(s):
            ll = by_id[s.sensor_id].select("lat_deg", "lon_deg").drop_nulls().to_numpy()
            positions[s.sensor_id] = (float(np.median(ll[:, 0])), float(np.median(ll[:, 1])),
                                      True, "its reports carry WGS-84 positions (used as they "
                                      "are); this point is their median")
            continue
        found = None
        if anchor_xy is not None:
            found = locate(s, anchor_xy, origin,
                           " + ".join(f"{a.sensor_id} ({a.kind})" for a in anchors))
        if found is None and mlat is not None:  # relative to the MLAT's frame (even when
            found = locate(s, xy(mlat, False), (ref_lat, ref_lon),  # that one is unknown)
                           f"the MLAT {mlat.sensor_id}")
            if found is not None and not positions[mlat.sensor_id][2]:
                found = (found[0], found[1], False,
                         found[3] + " (so it is placed right relative to the reference point, "
                         "which is UNKNOWN)")
        if found is None and kind == "vasn":
            found = (ref_lat, ref_lon, mlat is not None or origin_known,
                     "its x/y origin, taken as the airfield reference point")
        positions[s.sensor_id] = found or (
            ref_lat, ref_lon, False,
            "POSITION UNKNOWN: its range/azimuth are from an antenna the data do not place "
            "and no located sensor saw its targets; set lat_deg/lon_deg (until then its "
            "plots are placed as if it stood at the reference point)")
    prop = AirfieldProposal(ref_lat, ref_lon, ref_note, other=other)
    for kind in FUSED_KINDS:
        s = chosen.get(kind)
        if s is None:
            continue
        lat, lon, located, note = positions[s.sensor_id]
        sid = (f"{kind.upper()}_{s.sac}_{s.sic}" if s.sac is not None and s.sic is not None
               else s.sensor_id)
        prop.sensors.append(SensorProposal(sid, s, lat, lon, located, note))
    return prop


def seconds_span(survey: Survey) -> float:
    """Length of the recordings, s."""
    if survey.start_ns is None or survey.end_ns is None:
        return 0.0
    return (survey.end_ns - survey.start_ns) / NS
