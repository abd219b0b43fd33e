"""Typed, frozen configuration loaded from one TOML file (``config/surveil.toml``).

Angles are degrees in the file and radians here; durations are seconds in the file
and keep the ``_s`` suffix here. Nothing reads configuration from globals: stages
receive the parts they need as arguments.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.resources import resource_path


class ConfigError(ValueError):
    """The configuration file is missing, malformed or inconsistent (exit code 2)."""


@dataclass(frozen=True)
class RegionConfig:
    name: str
    origin_lat_deg: float
    origin_lon_deg: float
    origin_height_m: float = 0.0


@dataclass(frozen=True)
class RadarSite:
    site_id: str
    lat_deg: float
    lon_deg: float
    height_m: float
    north_alignment_rad: float
    scan_period_s: float
    max_range_m: float
    sigma_range_m: float
    sigma_azimuth_rad: float
    sigma_speed_mps: float
    sigma_course_rad: float


@dataclass(frozen=True)
class SyncConfig:
    sigma_dt_s: float = 0.1
    epoch_period_s: float = 4.0


@dataclass(frozen=True)
class AssociationConfig:
    gate_probability: float = 0.999
    max_course_difference_rad: float = math.radians(30.0)
    max_speed_difference_mps: float = 2.5
    course_gate_min_speed_mps: float = 1.0
    track_timeout_s: float = 30.0


@dataclass(frozen=True)
class AisConfig:
    gate_probability: float = 0.999
    max_report_age_s: float = 30.0
    sigma_position_m: float = 10.0
    sigma_sog_mps: float = 0.3
    identity_window_s: float = 300.0
    min_identity_matches: int = 3


@dataclass(frozen=True)
class ValidationConfig:
    max_speed_mps: float = 40.0
    max_range_m: float = 60000.0


@dataclass(frozen=True)
class FairwayLeg:
    leg_id: str
    start_lat_deg: float
    start_lon_deg: float
    end_lat_deg: float
    end_lon_deg: float


@dataclass(frozen=True)
class Sector:
    name: str
    polygon_lat_lon_deg: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class ExecutionConfig:
    executor: str = "process"
    max_workers: int = 2
    threads_per_worker: int = 1


@dataclass(frozen=True)
class Config:
    region: RegionConfig
    radar_sites: tuple[RadarSite, ...]
    sync: SyncConfig
    association: AssociationConfig
    ais: AisConfig
    validation: ValidationConfig
    fairway_legs: tuple[FairwayLeg, ...]
    max_cross_track_m: float
    sectors: tuple[Sector, ...]
    warehouse_path: str = "warehouse"
    execution: ExecutionConfig = field(default_factory=ExecutionConfig)
    source: str = ""
    # The whole parsed TOML, for sensor-family sections (e.g. [ownship], [airfield])
    # that their own modules parse into their own frozen dataclasses.
    sections: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def section(self, name: str) -> Mapping[str, Any]:
        """A family's raw TOML section (empty mapping when absent)."""
        return self.sections.get(name, {})

    def site(self, site_id: str) -> RadarSite:
        for s in self.radar_sites:
            if s.site_id == site_id:
                return s
        raise KeyError(site_id)


DEFAULT_CONFIG_PATH = resource_path("config") / "surveil.toml"


def load_config(path: str | Path | None = None) -> Config:
    """Load and validate a TOML config; ``None`` loads the shipped default."""
    p = Path(path) if path is not None else DEFAULT_CONFIG_PATH
    try:
        raw = tomllib.loads(p.read_text())
    except FileNotFoundError as exc:
        raise ConfigError(f"config file not found: {p}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {p} is not valid TOML: {exc}") from exc
    try:
        return _parse(raw, str(p))
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"config file {p}: {exc!r}") from exc


def _parse(raw: dict, source: str) -> Config:
    region = RegionConfig(**raw["region"])
    sites = tuple(
        RadarSite(
            site_id=s["site_id"],
            lat_deg=float(s["lat_deg"]),
            lon_deg=float(s["lon_deg"]),
            height_m=float(s.get("height_m", 0.0)),
            north_alignment_rad=math.radians(s.get("north_alignment_deg", 0.0)),
            scan_period_s=float(s["scan_period_s"]),
            max_range_m=float(s["max_range_m"]),
            sigma_range_m=float(s["sigma_range_m"]),
            sigma_azimuth_rad=math.radians(s["sigma_azimuth_deg"]),
            sigma_speed_mps=float(s["sigma_speed_mps"]),
            sigma_course_rad=math.radians(s["sigma_course_deg"]),
        )
        for s in raw["radar_sites"]
    )
    if len({s.site_id for s in sites}) != len(sites):
        raise ValueError("radar site ids must be unique")
    a = raw.get("association", {})
    assoc = AssociationConfig(
        gate_probability=a.get("gate_probability", 0.999),
        max_course_difference_rad=math.radians(a.get("max_course_difference_deg", 30.0)),
        max_speed_difference_mps=a.get("max_speed_difference_mps", 2.5),
        course_gate_min_speed_mps=a.get("course_gate_min_speed_mps", 1.0),
        track_timeout_s=a.get("track_timeout_s", 30.0),
    )
    legs = tuple(
        FairwayLeg(
            leg_id=leg["leg_id"],
            start_lat_deg=leg["start"][0],
            start_lon_deg=leg["start"][1],
            end_lat_deg=leg["end"][0],
            end_lon_deg=leg["end"][1],
        )
        for leg in raw.get("fairway_legs", [])
    )
    sectors = tuple(
        Sector(name=s["name"], polygon_lat_lon_deg=tuple((p[0], p[1]) for p in s["polygon"]))
        for s in raw.get("sectors", [])
    )
    for s in sectors:
        if len(s.polygon_lat_lon_deg) < 3:
            raise ValueError(f"sector {s.name} needs at least 3 vertices")
    return Config(
        region=region,
        radar_sites=sites,
        sync=SyncConfig(**raw.get("sync", {})),
        association=assoc,
        ais=AisConfig(**raw.get("ais", {})),
        validation=ValidationConfig(**raw.get("validation", {})),
        fairway_legs=legs,
        max_cross_track_m=raw.get("fairway", {}).get("max_cross_track_m", 2000.0),
        sectors=sectors,
        warehouse_path=raw.get("warehouse", {}).get("path", "warehouse"),
        execution=ExecutionConfig(**raw.get("execution", {})),
        source=source,
        sections=raw,
    )
