"""Geography of the ``region`` scenario: a regional VTS on a coast, in the regional ENU
frame (x east, y north, m) of the region origin, and the config TOML it needs.

::

        land (y > 0)      R1 ......... R2 ......... R3 ......... R4 ......... R5 ......... R6
      ---- coast ----  port W (-28 km)          port C (0)              port E (+26 km)
                          |  anchorage W (-16, -8)    |   anchorage E (+13, -9)   |
                          |                           |                           |
      westbound lane  <========================= y = -16 km ==========================<
      eastbound lane  >========================= y = -19 km ==========================>
                fishing ground SW          ground S / ferry terminal (+6, -29)     ground SE

Radar sites stand on the coast, spread evenly over x in [-40, 40] km, with overlapping
coverage (~30 km range: a ship in the lanes is seen by three or four of them), each with
its own scan period and error figures. Fairway legs (for cross-track deviation) are the
lane centre lines in three parts each and the three port approaches; sectors cut the
area into lanes (west, central, east), approaches, anchorages and the offshore band.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.frames import enu_to_geodetic

KM = 1000.0
REGION_NAME = "demo-region"
ORIGIN_LAT_DEG = 46.40
ORIGIN_LON_DEG = 30.90

X_EDGE_M = 60 * KM
"""Ships enter and leave the scene at x = +-60 km (lanes) or y = -30 km (from the south)."""
Y_SOUTH_M = -30 * KM
LANE_WB_Y_M = -16 * KM
"""Westbound lane centre (ships heading west)."""
LANE_EB_Y_M = -19 * KM
"""Eastbound lane centre (ships heading east)."""
PORTS: dict[str, tuple[float, float]] = {
    "W": (-28 * KM, 0.5 * KM),
    "C": (0.0, 1.0 * KM),
    "E": (26 * KM, 0.5 * KM),
}
"""Port positions; ships arrive at and leave from the port entrance 0.8 km south of it."""
APPROACH_OFFSET_M = 200.0
"""Inbound ships keep this far east of the approach axis, outbound ships this far west."""
ANCHORAGES: dict[str, tuple[float, float, float]] = {
    "W": (-16 * KM, -8 * KM, 2.0 * KM),
    "E": (13 * KM, -9 * KM, 2.0 * KM),
}
"""Anchorage centre x, y and radius; W serves ports W and C, E serves C and E."""
ANCHORAGE_PORTS = {"W": ("W", "C"), "E": ("C", "E")}
GROUNDS: dict[str, tuple[float, float, float]] = {
    "SW": (-42 * KM, -25 * KM, 5 * KM),
    "S": (-6 * KM, -26 * KM, 5 * KM),
    "SE": (38 * KM, -24 * KM, 5 * KM),
}
"""Fishing grounds (centre, radius) of the small craft."""
FERRY_LINES: dict[str, list[tuple[float, float]]] = {
    # port C <-> offshore terminal, across both lanes (a racetrack 600 m wide)
    "F1": [(-0.3 * KM, 0.2 * KM), (5.7 * KM, -28.8 * KM), (6.3 * KM, -28.7 * KM),
           (0.3 * KM, 0.3 * KM)],
    # coastal line port W <-> port C
    "F2": [(-27.6 * KM, -0.3 * KM), (-26.8 * KM, -3.0 * KM), (-1.2 * KM, -3.0 * KM),
           (-0.4 * KM, -0.3 * KM)],
}

# per-site figures, cycled for more than six sites: scan period (s), range (km),
# sigmas of range (m), azimuth (deg), speed (m/s), course (deg)
_SCAN_S = (3.0, 4.0, 2.5, 3.0, 3.3, 2.8)
_RANGE_KM = (32.0, 30.0, 28.0, 34.0, 30.0, 32.0)
_SIGMA_RANGE_M = (15.0, 20.0, 12.0, 25.0, 15.0, 18.0)
_SIGMA_AZ_DEG = (0.45, 0.5, 0.35, 0.6, 0.4, 0.5)
_SIGMA_SPEED_MPS = (0.25, 0.3, 0.2, 0.35, 0.25, 0.3)
_SIGMA_COURSE_DEG = (2.0, 2.5, 1.5, 3.0, 2.0, 2.5)


@dataclass(frozen=True)
class SiteSpec:
    """One radar site of the region: position (regional ENU, m, and WGS-84), scan period,
    range and the sigmas its tracker reports (the config's units: deg for angles)."""

    site_id: str
    x_m: float
    y_m: float
    lat_deg: float
    lon_deg: float
    scan_period_s: float
    max_range_m: float
    sigma_range_m: float
    sigma_azimuth_deg: float
    sigma_speed_mps: float
    sigma_course_deg: float


@dataclass(frozen=True)
class RegionLayout:
    """Sites, fairway legs (id, start xy, end xy) and sectors (name, polygon xy) in the
    regional ENU frame of (origin_lat_deg, origin_lon_deg)."""

    origin_lat_deg: float
    origin_lon_deg: float
    sites: tuple[SiteSpec, ...]
    legs: tuple[tuple[str, tuple[float, float], tuple[float, float]], ...]
    sectors: tuple[tuple[str, tuple[tuple[float, float], ...]], ...]

    def lat_lon(self, x_m: float, y_m: float) -> tuple[float, float]:
        lat, lon = enu_to_geodetic(np.array([x_m]), np.array([y_m]),
                                   self.origin_lat_deg, self.origin_lon_deg)
        return round(float(lat[0]), 7), round(float(lon[0]), 7)


def region_layout(n_radars: int = 6) -> RegionLayout:
    """The region with ``n_radars`` sites spread along the coast (>= 1)."""
    if n_radars < 1:
        raise ValueError(f"the region needs at least one radar, got {n_radars}")
    xs = np.linspace(-40 * KM, 40 * KM, n_radars) if n_radars > 1 else np.array([0.0])
    sites = []
    for i, x in enumerate(xs):
        k = i % len(_SCAN_S)
        y = (1.5 if i % 2 == 0 else 2.5) * KM
        lat, lon = enu_to_geodetic(np.array([x]), np.array([y]), ORIGIN_LAT_DEG, ORIGIN_LON_DEG)
        sites.append(
            SiteSpec(
                site_id=f"R{i + 1}",
                x_m=float(x),
                y_m=float(y),
                lat_deg=round(float(lat[0]), 7),
                lon_deg=round(float(lon[0]), 7),
                scan_period_s=_SCAN_S[k],
                max_range_m=_RANGE_KM[k] * KM,
                sigma_range_m=_SIGMA_RANGE_M[k],
                sigma_azimuth_deg=_SIGMA_AZ_DEG[k],
                sigma_speed_mps=_SIGMA_SPEED_MPS[k],
                sigma_course_deg=_SIGMA_COURSE_DEG[k],
            )
        )
    legs = []
    thirds = (-X_EDGE_M, -20 * KM, 20 * KM, X_EDGE_M)
    for j, name in enumerate(("W", "C", "E")):
        a, b = thirds[j], thirds[j + 1]
        legs.append((f"EB_{name}", (a, LANE_EB_Y_M), (b, LANE_EB_Y_M)))
        legs.append((f"WB_{name}", (b, LANE_WB_Y_M), (a, LANE_WB_Y_M)))
    for name, (px, py) in PORTS.items():
        legs.append((f"APP_{name}", (px, -12 * KM), (px, py - 0.8 * KM)))
    sectors: list[tuple[str, tuple[tuple[float, float], ...]]] = []

    def box(name: str, x0: float, x1: float, y0: float, y1: float) -> None:
        sectors.append((name, ((x0, y0), (x1, y0), (x1, y1), (x0, y1))))

    for name, (ax, ay, r) in ANCHORAGES.items():
        box(f"anchorage_{name.lower()}", ax - r - 500, ax + r + 500, ay - r - 500, ay + r + 500)
    for name, (px, _) in PORTS.items():
        box(f"approach_{name.lower()}", px - 2 * KM, px + 2 * KM, -13 * KM, 1 * KM)
    box("lanes_w", -X_EDGE_M - 5 * KM, -20 * KM, -21 * KM, -13 * KM)
    box("lanes_c", -20 * KM, 20 * KM, -21 * KM, -13 * KM)
    box("lanes_e", 20 * KM, X_EDGE_M + 5 * KM, -21 * KM, -13 * KM)
    box("coastal", -X_EDGE_M - 5 * KM, X_EDGE_M + 5 * KM, -13 * KM, 1 * KM)
    box("offshore", -X_EDGE_M - 5 * KM, X_EDGE_M + 5 * KM, Y_SOUTH_M - 5 * KM, -21 * KM)
    return RegionLayout(ORIGIN_LAT_DEG, ORIGIN_LON_DEG, tuple(sites), tuple(legs),
                        tuple(sectors))


# -- the config file -----------------------------------------------------------------------


def region_config(layout: RegionLayout) -> dict:
    """The TOML document (as a mapping) that ``surveil --config`` needs for the region:
    region origin, radar sites, sync/association/AIS/validation defaults, fairway legs,
    sectors and SIAP settings (other families' sections take their defaults).

    ``[channel_integrity] unit_settle_s = 0``: the batch's volume units of a regional
    day (~5 min of 1,000 ships seen by 6 radars) do not overlap. Measured on one dense
    hour (docs/scale.md): the 15-min overlap of the default config costs x3.1 CPU and
    x2.6 memory per unit, and the association's pairings in such traffic depend on their
    history beyond it (2.8 % of association rows still grouped differently from the
    hour in one unit, against 4.5 % without it; fused RMS 84.2 m with it, 87.6 m
    without, 80.0 m in one unit of 6.4 GB). Set it back to 300 s for the accuracy."""
    max_range = max(s.max_range_m for s in layout.sites)
    return {
        "region": {"name": REGION_NAME, "origin_lat_deg": layout.origin_lat_deg,
                   "origin_lon_deg": layout.origin_lon_deg, "origin_height_m": 0.0},
        "radar_sites": [
            {"site_id": s.site_id, "lat_deg": s.lat_deg, "lon_deg": s.lon_deg,
             "height_m": 30.0, "north_alignment_deg": 0.0, "scan_period_s": s.scan_period_s,
             "max_range_m": s.max_range_m, "sigma_range_m": s.sigma_range_m,
             "sigma_azimuth_deg": s.sigma_azimuth_deg, "sigma_speed_mps": s.sigma_speed_mps,
             "sigma_course_deg": s.sigma_course_deg}
            for s in layout.sites
        ],
        "sync": {"sigma_dt_s": 0.1,
                 "epoch_period_s": float(math.ceil(max(s.scan_period_s for s in layout.sites)))},
        "association": {"gate_probability": 0.999, "max_course_difference_deg": 30.0,
                        "max_speed_difference_mps": 2.5, "course_gate_min_speed_mps": 1.0,
                        "track_timeout_s": 30.0},
        "ais": {"gate_probability": 0.999, "max_report_age_s": 30.0, "sigma_position_m": 10.0,
                "sigma_sog_mps": 0.3, "identity_window_s": 300.0},
        "validation": {"max_speed_mps": 40.0, "max_range_m": max(60000.0, max_range * 1.5)},
        "fairway_legs": [
            {"leg_id": leg_id, "start": list(layout.lat_lon(*a)), "end": list(layout.lat_lon(*b))}
            for leg_id, a, b in layout.legs
        ],
        "fairway": {"max_cross_track_m": 2000.0},
        "sectors": [
            {"name": name, "polygon": [list(layout.lat_lon(x, y)) for x, y in poly]}
            for name, poly in layout.sectors
        ],
        "siap": {"gate_probability": 0.999, "max_distance_m": 500.0, "swap_window_s": 60.0},
        "radar_bias": {"apply": False},
        "channel_integrity": {"unit_settle_s": 0.0},
        "warehouse": {"path": "warehouse"},
        "execution": {"executor": "process", "max_workers": 2, "threads_per_worker": 1},
    }


def toml_text(doc: dict, header: str = "") -> str:
    """A TOML document from nested dicts/lists of str, bool, int and float (the subset
    :func:`region_config` uses): tables, arrays of tables, inline arrays."""
    lines = [f"# {h}" if h else "#" for h in header.splitlines()]

    def value(v: object) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int | float):
            return repr(v)
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(x) for x in v) + "]"
        raise TypeError(f"cannot write {type(v).__name__} to TOML")

    def table(prefix: str, d: dict, array: bool) -> None:
        lines.append("")
        lines.append(f"[[{prefix}]]" if array else f"[{prefix}]")
        subs = []
        for k, v in d.items():
            if isinstance(v, dict) or (isinstance(v, list) and v and isinstance(v[0], dict)):
                subs.append((k, v))
            else:
                lines.append(f"{k} = {value(v)}")
        for k, v in subs:
            emit(f"{prefix}.{k}", v)

    def emit(prefix: str, v: object) -> None:
        if isinstance(v, dict):
            table(prefix, v, False)
        else:
            for item in v:  # an array of tables
                table(prefix, item, True)

    for k, v in doc.items():
        emit(k, v)
    return "\n".join(lines) + "\n"
