"""Typed, frozen configuration loaded from one TOML file (``config/surveil.toml``).

Angles are degrees in the file and radians here; durations are seconds in the file
and keep the ``_s`` suffix here. Nothing reads configuration from globals: stages
receive the parts they need as arguments.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
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
    ais: AisConfig
    validation: ValidationConfig
    fairway_legs: tuple[FairwayLeg, ...]
    sectors: tuple[Sector, ...]
    warehouse_path: str = "warehouse"
    execution: ExecutionConfig = field(default_factory=ExecutionConfig)
    source: str = ""
    # The whole parsed TOML (raw), and each sensor family's section parsed into its own
    # typed config object when the file loaded ({family name: object}).
    sections: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)
    families: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def section(self, name: str) -> Mapping[str, Any]:
        """A raw TOML section (empty mapping when absent)."""
        return self.sections.get(name, {})

    def family(self, name: str) -> Any:
        """The typed config of sensor family ``name``, parsed when the file loaded."""
        try:
            return self.families[name]
        except KeyError:
            raise ConfigError(
                f"config {self.source or '(in memory)'} was loaded without the {name!r} "
                "family: load it with pipeline.families.load_config"
            ) from None

    def site(self, site_id: str) -> RadarSite:
        for s in self.radar_sites:
            if s.site_id == site_id:
                return s
        raise KeyError(site_id)


DEFAULT_CONFIG_PATH = resource_path("config") / "surveil.toml"


FamilyParser = Callable[[Mapping[str, Any], "Config"], Any]
"""(the whole TOML document, the core config) -> a family's typed config."""


def load_config(
    path: str | Path | None = None, families: Mapping[str, FamilyParser] | None = None
) -> Config:
    """Load and validate a TOML config; ``None`` loads the shipped default.

    ``families`` maps a family name to its parser; every family's sections are parsed
    here, so a bad value fails the load, not a later work unit.
    ``pipeline.families.load_config`` passes every registered family."""
    p = Path(path) if path is not None else DEFAULT_CONFIG_PATH
    try:
        raw = tomllib.loads(p.read_text())
    except FileNotFoundError as exc:
        raise ConfigError(f"config file not found: {p}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {p} is not valid TOML: {exc}") from exc
    return config_from_mapping(raw, str(p), families)


def config_from_mapping(
    raw: Mapping[str, Any], source: str, families: Mapping[str, FamilyParser] | None = None
) -> Config:
    """Validate an already parsed TOML document (see :func:`load_config`)."""
    try:
        core = _parse(dict(raw), source)
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"config file {source}: {exc!r}") from exc
    parsed = {}
    for name, parse in (families or {}).items():
        try:
            parsed[name] = parse(raw, core)
        except ConfigError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"config file {source} ({name} family): {exc!r}") from exc
    return replace(core, families=parsed)


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
        ais=AisConfig(**raw.get("ais", {})),
        validation=ValidationConfig(**raw.get("validation", {})),
        fairway_legs=legs,
        sectors=sectors,
        warehouse_path=raw.get("warehouse", {}).get("path", "warehouse"),
        execution=ExecutionConfig(**raw.get("execution", {})),
        source=source,
        sections=raw,
    )
