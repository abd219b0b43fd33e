"""A window of the warehouse as one MCAP file in Foxglove's well-known schemas
(protobuf), to look at in Foxglove's Map and 3D panels (docs/foxglove.md).

Topics (one per source; ``log_time`` = the track time):

- ``/fused/location``, ``/radar/<site>/location``, ``/ais/location``,
  ``/airfield/location``: ``foxglove.LocationFix`` per track point (``frame_id`` = the
  track: system track id, ``<site>-<local id>``, MMSI, airfield track id), WGS-84, with
  the ENU position covariance where the table has sigmas;
- ``/geometry``: one ``foxglove.GeoJSON`` at the window start: sectors, fairway legs,
  airfield areas and the coastline ([gaps] admissible area, islands);
- ``/fused/scene``: ``foxglove.SceneUpdate`` per synchronised epoch in the regional ENU
  frame ``region_enu`` (a sphere and a label per fused track), and ``/geometry/scene``:
  the legs and sectors as lines in that frame (once, lifetime 0 = until replaced).

Radar points come from ``associations`` (each radar's synchronised picture, regional
ENU), converted to WGS-84 with :func:`pipeline.frames.enu_to_geodetic`.
"""

from __future__ import annotations

import heapq
import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.GeoJSON_pb2 import GeoJSON
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.Point3_pb2 import Point3
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.SpherePrimitive_pb2 import SpherePrimitive
from foxglove_schemas_protobuf.TextPrimitive_pb2 import TextPrimitive
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.duration_pb2 import Duration
from google.protobuf.timestamp_pb2 import Timestamp
from mcap_protobuf.writer import Writer

from pipeline.config import Config
from pipeline.frames import enu_to_geodetic, geodetic_to_enu
from pipeline.warehouse.delta import read_table

ENU_FRAME = "region_enu"
SCENE_LIFETIME_S = 10.0  # a fused track's sphere outlives its epoch by a few epochs
Message = tuple[int, str, Any]  # (log_time_ns, topic, protobuf message)


@dataclass
class ExportSummary:
    path: Path
    start_ns: int
    end_ns: int
    messages: dict[str, int] = field(default_factory=dict)

    def render(self) -> str:
        lines = [f"export: {self.path} ({sum(self.messages.values())} messages)"]
        lines += [f"  {topic:<28} {n:>9}" for topic, n in sorted(self.messages.items())]
        lines.append("open it in Foxglove: docs/foxglove.md")
        return "\n".join(lines)


def _stamp(t_ns: int) -> Timestamp:
    return Timestamp(seconds=int(t_ns) // 1_000_000_000, nanos=int(t_ns) % 1_000_000_000)


def _fix(t: int, frame: str, lat: float, lon: float, sx: float | None = None,
         sy: float | None = None, cxy: float | None = None) -> LocationFix:
    msg = LocationFix(timestamp=_stamp(t), frame_id=frame, latitude=lat, longitude=lon)
    if sx is not None and sy is not None:
        c = 0.0 if cxy is None else cxy
        msg.position_covariance.extend([sx * sx, c, 0.0, c, sy * sy, 0.0, 0.0, 0.0, 0.0])
        msg.position_covariance_type = LocationFix.PositionCovarianceType.KNOWN
    return msg


def _col(t: pa.Table, name: str) -> list:
    return t[name].to_pylist()


def location_points(warehouse: Path, cfg: Config, start_ns: int, end_ns: int,
                    site: str | None = None) -> dict[str, dict[str, list]]:
    """Topic -> columns (``time_ns``, ``frame_id``, ``lat_deg``, ``lon_deg``, ``sigma_x_m``,
    ``sigma_y_m``, ``cov_xy_m2``) of every LocationFix the export writes, in time order."""
    out: dict[str, dict[str, list]] = {}
    st = read_table(warehouse, "system_tracks", start_ns=start_ns, end_ns=end_ns, site=site,
                    columns=["time_ns", "system_track_id", "lat_deg", "lon_deg", "sigma_x_m",
                             "sigma_y_m", "cov_xy_m2"])
    out["/fused/location"] = {
        "time_ns": _col(st, "time_ns"), "frame_id": [str(v) for v in _col(st, "system_track_id")],
        "lat_deg": _col(st, "lat_deg"), "lon_deg": _col(st, "lon_deg"),
        "sigma_x_m": _col(st, "sigma_x_m"), "sigma_y_m": _col(st, "sigma_y_m"),
        "cov_xy_m2": _col(st, "cov_xy_m2")}
    assoc = read_table(warehouse, "associations", start_ns=start_ns, end_ns=end_ns, site=site,
                       columns=["time_ns", "site_id", "local_track_id", "x_enu_m", "y_enu_m",
                                "sigma_x_m", "sigma_y_m", "cov_xy_m2"])
    if assoc.num_rows:
        lat, lon = enu_to_geodetic(assoc["x_enu_m"].to_numpy(), assoc["y_enu_m"].to_numpy(),
                                   cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
        sites = np.asarray(_col(assoc, "site_id"), dtype=object)
        for radar in sorted(set(sites)):
            idx = np.flatnonzero(sites == radar)
            sub = assoc.take(pa.array(idx))
            out[f"/radar/{radar}/location"] = {
                "time_ns": _col(sub, "time_ns"),
                "frame_id": [f"{radar}-{v}" for v in _col(sub, "local_track_id")],
                "lat_deg": lat[idx].tolist(), "lon_deg": lon[idx].tolist(),
                "sigma_x_m": _col(sub, "sigma_x_m"), "sigma_y_m": _col(sub, "sigma_y_m"),
                "cov_xy_m2": _col(sub, "cov_xy_m2")}
    ais = read_table(warehouse, "ais_reports", start_ns=start_ns, end_ns=end_ns, site=site,
                     columns=["time_ns", "mmsi", "lat_deg", "lon_deg"])
    n = ais.num_rows
    out["/ais/location"] = {
        "time_ns": _col(ais, "time_ns"), "frame_id": [str(v) for v in _col(ais, "mmsi")],
        "lat_deg": _col(ais, "lat_deg"), "lon_deg": _col(ais, "lon_deg"),
        "sigma_x_m": [None] * n, "sigma_y_m": [None] * n, "cov_xy_m2": [None] * n}
    af = read_table(warehouse, "airfield_tracks", start_ns=start_ns, end_ns=end_ns, site=site,
                    columns=["time_ns", "track_id", "lat_deg", "lon_deg", "sigma_x_m",
                             "sigma_y_m", "cov_xy_m2"])
    out["/airfield/location"] = {
        "time_ns": _col(af, "time_ns"), "frame_id": _col(af, "track_id"),
        "lat_deg": _col(af, "lat_deg"), "lon_deg": _col(af, "lon_deg"),
        "sigma_x_m": _col(af, "sigma_x_m"), "sigma_y_m": _col(af, "sigma_y_m"),
        "cov_xy_m2": _col(af, "cov_xy_m2")}
    return {topic: cols for topic, cols in out.items() if cols["time_ns"]}


def _fixes(topic: str, cols: dict[str, list]) -> Iterator[Message]:
    for t, f, la, lo, sx, sy, c in zip(cols["time_ns"], cols["frame_id"], cols["lat_deg"],
                                       cols["lon_deg"], cols["sigma_x_m"], cols["sigma_y_m"],
                                       cols["cov_xy_m2"], strict=True):
        yield t, topic, _fix(t, f, la, lo, sx, sy, c)


def geometry_geojson(cfg: Config) -> dict[str, Any]:
    """The config's geometry as a GeoJSON FeatureCollection ([lon, lat] order)."""
    def ring(poly: Any) -> list[list[float]]:
        pts = [[p[1], p[0]] for p in poly]
        return [*pts, pts[0]]

    def polygon(poly: Any) -> dict[str, Any]:
        return {"type": "Polygon", "coordinates": [ring(poly)]}

    feats = []
    for s in cfg.sectors:
        feats.append({"type": "Feature", "properties": {"kind": "sector", "name": s.name},
                      "geometry": polygon(s.polygon_lat_lon_deg)})
    for leg in cfg.fairway_legs:
        feats.append({"type": "Feature", "properties": {"kind": "fairway_leg", "name": leg.leg_id},
                      "geometry": {"type": "LineString", "coordinates": [
                          [leg.start_lon_deg, leg.start_lat_deg],
                          [leg.end_lon_deg, leg.end_lat_deg]]}})
    airfield = (cfg.families or {}).get("airfield")
    for s in getattr(airfield, "sectors", ()) or ():
        feats.append({"type": "Feature",
                      "properties": {"kind": "airfield_area", "name": s.name, "area": s.area},
                      "geometry": polygon(s.polygon_lat_lon_deg)})
    gaps = (cfg.families or {}).get("gaps")
    for kind in ("admissible", "islands"):
        for p in getattr(gaps, kind, ()) or ():
            feats.append({"type": "Feature", "properties": {"kind": kind, "name": p.name},
                          "geometry": polygon(p.polygon_lat_lon_deg)})
    return {"type": "FeatureCollection", "features": feats}


_POSE = Pose(position=Vector3(x=0, y=0, z=0), orientation=Quaternion(x=0, y=0, z=0, w=1))


def _colour(hex_rgb: str, a: float = 1.0) -> Color:
    r, g, b = (int(hex_rgb[i:i + 2], 16) / 255 for i in (1, 3, 5))
    return Color(r=r, g=g, b=b, a=a)


def geometry_scene(cfg: Config, t_ns: int) -> SceneUpdate:
    """Legs and sectors as lines in the regional ENU frame (lifetime 0: kept)."""
    o = cfg.region
    entity = SceneEntity(timestamp=_stamp(t_ns), frame_id=ENU_FRAME, id="geometry",
                         frame_locked=True)
    for leg in cfg.fairway_legs:
        e, n = geodetic_to_enu(np.array([leg.start_lat_deg, leg.end_lat_deg]),
                               np.array([leg.start_lon_deg, leg.end_lon_deg]),
                               o.origin_lat_deg, o.origin_lon_deg)
        entity.lines.append(LinePrimitive(
            type=LinePrimitive.Type.LINE_STRIP, pose=_POSE, thickness=4, scale_invariant=True,
            points=[Point3(x=float(x), y=float(y), z=0) for x, y in zip(e, n, strict=True)],
            color=_colour("#d4a017")))
    for s in cfg.sectors:
        lat = np.array([p[0] for p in s.polygon_lat_lon_deg])
        lon = np.array([p[1] for p in s.polygon_lat_lon_deg])
        e, n = geodetic_to_enu(lat, lon, o.origin_lat_deg, o.origin_lon_deg)
        entity.lines.append(LinePrimitive(
            type=LinePrimitive.Type.LINE_LOOP, pose=_POSE, thickness=2, scale_invariant=True,
            points=[Point3(x=float(x), y=float(y), z=0) for x, y in zip(e, n, strict=True)],
            color=_colour("#555555")))
        entity.texts.append(TextPrimitive(
            pose=Pose(position=Vector3(x=float(e.mean()), y=float(n.max()), z=0),
                      orientation=_POSE.orientation),
            billboard=True, font_size=14, scale_invariant=True, text=s.name,
            color=_colour("#333333")))
    return SceneUpdate(entities=[entity])


def _scenes(warehouse: Path, start_ns: int, end_ns: int, site: str | None = None
            ) -> Iterator[Message]:
    st = read_table(warehouse, "system_tracks", start_ns=start_ns, end_ns=end_ns, site=site,
                    columns=["time_ns", "system_track_id", "x_enu_m", "y_enu_m", "mmsi"])
    if st.num_rows == 0:
        return
    times = st["time_ns"].to_numpy()
    ids = st["system_track_id"].to_numpy()
    xs, ys = st["x_enu_m"].to_numpy(), st["y_enu_m"].to_numpy()
    mmsi = _col(st, "mmsi")
    cuts = np.flatnonzero(np.diff(times)) + 1
    life = Duration(seconds=int(SCENE_LIFETIME_S))
    blue = _colour("#1f4e9c")
    for rows in np.split(np.arange(len(times)), cuts):
        t = int(times[rows[0]])
        update = SceneUpdate()
        for i in rows:
            pose = Pose(position=Vector3(x=float(xs[i]), y=float(ys[i]), z=0),
                        orientation=_POSE.orientation)
            label = str(ids[i]) + (f" ({mmsi[i]})" if mmsi[i] is not None else "")
            update.entities.append(SceneEntity(
                timestamp=_stamp(t), frame_id=ENU_FRAME, id=f"fused/{ids[i]}", lifetime=life,
                spheres=[SpherePrimitive(pose=pose, size=Vector3(x=150, y=150, z=150),
                                         color=blue)],
                texts=[TextPrimitive(pose=pose, billboard=True, font_size=12,
                                     scale_invariant=True, text=label, color=blue)]))
        yield t, "/fused/scene", update


def write_export(cfg: Config, warehouse: Path, out: Path, *, start_ns: int, end_ns: int,
                 site: str | None = None) -> ExportSummary:
    """Write the window's tracks (of ``site``; None: every row) and the config's geometry
    to ``out`` (see the module)."""
    summary = ExportSummary(out, start_ns, end_ns)
    points = location_points(warehouse, cfg, start_ns, end_ns, site)
    first = [(start_ns, "/geometry", GeoJSON(geojson=json.dumps(geometry_geojson(cfg)))),
             (start_ns, "/geometry/scene", geometry_scene(cfg, start_ns))]
    streams = [iter(first), *(_fixes(topic, cols) for topic, cols in points.items()),
               _scenes(warehouse, start_ns, end_ns, site)]
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    with open(tmp, "wb") as f:
        writer = Writer(f)
        for t, topic, msg in heapq.merge(*streams, key=lambda m: m[0]):
            writer.write_message(topic, msg, log_time=int(t), publish_time=int(t))
            summary.messages[topic] = summary.messages.get(topic, 0) + 1
        writer.finish()
    tmp.replace(out)
    return summary
