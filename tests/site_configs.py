"""Site configs written for a place, for tests on recordings that are not the demo's.

Until ``surveil config init`` (issue 35, item 1) writes a site config from a folder of
recordings, these helpers write the few lines a site needs by hand: the demo config with
its region origin at the data's centroid (:func:`local_config`), or the whole demo config
carried to another place (:func:`moved_config`: every latitude and longitude shifted).
"""

from __future__ import annotations

import copy
import math
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.config import Config
from pipeline.families import config_from_mapping
from pipeline.resources import resource_path
from pipeline.simulate.region_layout import toml_text


def demo_raw() -> dict[str, Any]:
    """The shipped config as a TOML mapping."""
    return tomllib.loads((resource_path("config") / "surveil.toml").read_text())


def local_config(lat_deg: float, lon_deg: float, **kw: Any) -> Config:
    """:func:`local_raw`, loaded."""
    return config_from_mapping(local_raw(lat_deg, lon_deg, **kw),
                               f"local config at {lat_deg:.3f}, {lon_deg:.3f}")


def local_raw(lat_deg: float, lon_deg: float, *, name: str = "local",
              radars_at_data: bool = False, sector_half_deg: float = 0.5) -> dict[str, Any]:
    """The demo config written for the place (lat, lon): the region's origin there, one
    sector of +-``sector_half_deg`` around it, no fairway legs, water, zones or fault
    schedules (nothing known of that place). The demo's two radars stay declared (the
    config needs one), at the demo estuary; with ``radars_at_data`` at the data, 1 km
    apart (declared radars without any radar data: issue 35, item 4). A TOML mapping."""
    raw = demo_raw()
    raw["region"] = {"name": name, "origin_lat_deg": lat_deg, "origin_lon_deg": lon_deg}
    d = sector_half_deg
    raw["sectors"] = [{"name": "local", "polygon": [[lat_deg - d, lon_deg - d],
                                                    [lat_deg - d, lon_deg + d],
                                                    [lat_deg + d, lon_deg + d],
                                                    [lat_deg + d, lon_deg - d]]}]
    raw.pop("fairway_legs", None)
    raw.pop("channel_faults", None)
    for key in ("admissible", "islands", "zones"):
        raw["gaps"].pop(key, None)
    if radars_at_data:
        for i, site in enumerate(raw["radar_sites"]):
            site.update(lat_deg=lat_deg + 0.01, lon_deg=lon_deg + (0.01 if i else -0.01))
    return raw


def centroid(lat_deg: np.ndarray, lon_deg: np.ndarray) -> tuple[float, float]:
    """The data's centre (median latitude and longitude)."""
    return float(np.nanmedian(lat_deg)), float(np.nanmedian(lon_deg))


def _shift(value: Any, key: str, dlat: float, dlon: float) -> Any:
    """``value`` with every ``polygon``, ``start`` / ``end`` [lat, lon] pair and
    ``*lat_deg`` / ``*lon_deg`` key shifted."""
    if isinstance(value, Mapping):
        return {k: _shift(v, k, dlat, dlon) for k, v in value.items()}
    if isinstance(value, list):
        if (len(value) >= 2 and all(isinstance(v, int | float) for v in value)
                and key in ("start", "end")):
            return [value[0] + dlat, value[1] + dlon, *value[2:]]
        if key == "polygon":
            return [[a + dlat, b + dlon] for a, b in value]
        return [_shift(v, key, dlat, dlon) for v in value]
    if isinstance(value, int | float) and not isinstance(value, bool):
        if key.endswith("lat_deg"):
            return value + dlat
        if key.endswith("lon_deg"):
            return value + dlon
    return value


def moved_raw(dlat_deg: float, dlon_deg: float, raw: Mapping[str, Any] | None = None
              ) -> dict[str, Any]:
    """The demo config (or ``raw``) carried ``dlat_deg``, ``dlon_deg`` away: region origin,
    radar sites, legs, sectors, water, zones, airfield and own-ship places all shifted
    (a config for another place, whole and valid), as a TOML mapping."""
    return _shift(copy.deepcopy(dict(raw or demo_raw())), "", dlat_deg, dlon_deg)


def moved_config(dlat_deg: float, dlon_deg: float, raw: Mapping[str, Any] | None = None
                 ) -> Config:
    """:func:`moved_raw`, loaded."""
    return config_from_mapping(moved_raw(dlat_deg, dlon_deg, raw),
                               f"demo config moved by {dlat_deg}, {dlon_deg} deg")


def write_config(raw: Mapping[str, Any], path: Path) -> Path:
    """``raw`` as a TOML file (for the command line's ``--config``)."""
    path.write_text(toml_text(dict(raw), header="test config (tests/site_configs.py)"))
    return path


def expected_km(cfg, lat: float, lon: float) -> float:
    """Oracle: the great-circle distance from the region origin on the mean sphere
    (haversine, written here; the check's own is WGS-84 Vincenty: they agree to 0.5 %)."""
    p1, p2 = math.radians(cfg.region.origin_lat_deg), math.radians(lat)
    dl = math.radians(lon - cfg.region.origin_lon_deg)
    h = math.sin((p2 - p1) / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * 6371.0088 * math.asin(math.sqrt(h))
