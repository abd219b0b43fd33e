"""The gaps family's configuration: the ``[gaps]`` section (distributed maritime
observation paper; degrees in the file, radians here)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.config import Config, ConfigError
from pipeline.filters import particle as pf


@dataclass(frozen=True)
class NamedPolygon:
    name: str
    polygon_lat_lon_deg: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class GapsConfig:
    """The ``[gaps]`` section of the config (angles in degrees there, radians here)."""

    gap_threshold_s: float = 600.0
    forecast_offsets_s: tuple[float, ...] = (300.0, 600.0, 1200.0, 1800.0, 2700.0, 3600.0)
    max_horizon_s: float = 3600.0
    forecast_at_gap_end: bool = True
    particles: int = 2000
    step_s: float = 60.0
    lead_in_s: float = 600.0
    max_lead_in_obs: int = 10
    course_noise_rad_per_sqrt_s: float = math.radians(0.25)
    speed_noise_mps_per_sqrt_s: float = 0.01
    turn_rate_per_s: float = 2.0 / 3600.0
    turn_sigma_rad: float = math.radians(45.0)
    manoeuvre_noise_factor: float = 5.0
    max_speed_mps: float = 15.0
    sigma_cog_rad: float = math.radians(3.0)
    course_min_speed_mps: float = 1.0
    manoeuvre_rate_rad_per_s: float = math.radians(0.2)
    region_probability: float = 0.9
    ess_fraction: float = 0.5
    replenish_rounds: int = 4
    regularise_below: float = 0.1
    min_ess_fraction: float = 0.05
    constrain: bool = True
    constraint_mode: str = "redraw"
    redraw_tries: int = 10
    batch_gaps: int = 32
    admissible: tuple[NamedPolygon, ...] = ()
    islands: tuple[NamedPolygon, ...] = ()
    zones: tuple[NamedPolygon, ...] = ()

    @property
    def lookback_s(self) -> float:
        """How far before a window its inputs are read: a forecast in the window may
        belong to a gap that began ``max_horizon_s`` earlier, after its lead-in."""
        return self.max_horizon_s + self.lead_in_s

    @property
    def noise(self) -> pf.MotionNoise:
        return pf.MotionNoise(
            self.course_noise_rad_per_sqrt_s,
            self.speed_noise_mps_per_sqrt_s,
            self.max_speed_mps,
            self.turn_rate_per_s,
            self.turn_sigma_rad,
        )


def _polygons(raw: Any, what: str) -> tuple[NamedPolygon, ...]:
    out = []
    for i, p in enumerate(raw or []):
        pts = tuple((float(a), float(b)) for a, b in p["polygon"])
        if len(pts) < 3:
            raise ConfigError(f"[gaps] {what} #{i + 1} needs at least 3 vertices")
        out.append(NamedPolygon(str(p.get("name", f"{what}-{i + 1}")), pts))
    if len({p.name for p in out}) != len(out):
        raise ConfigError(f"[gaps] {what} names must be unique")
    return tuple(out)


def gaps_config(cfg: Config) -> GapsConfig:
    """The gaps family's config, parsed when ``cfg`` was loaded."""
    return cfg.family("gaps")


def parse_gaps(raw: Mapping[str, Any], core: Config | None = None) -> GapsConfig:
    """Parse the ``[gaps]`` section (an absent section gives the defaults and no
    geometry: no constraint, no zones). Raises ConfigError on bad values."""
    known = {"admissible", "islands", "zones"}
    simple = {k: v for k, v in raw.items() if k not in known}
    deg = {
        "course_noise_deg_per_sqrt_s": "course_noise_rad_per_sqrt_s",
        "sigma_cog_deg": "sigma_cog_rad",
        "manoeuvre_rate_deg_per_s": "manoeuvre_rate_rad_per_s",
        "turn_sigma_deg": "turn_sigma_rad",
    }
    kw: dict[str, Any] = {}
    fields = GapsConfig.__dataclass_fields__
    for key, value in simple.items():
        if key in deg:
            kw[deg[key]] = math.radians(float(value))
        elif key == "forecast_offsets_s":
            kw[key] = tuple(float(v) for v in value)
        elif key == "turns_per_hour":
            kw["turn_rate_per_s"] = float(value) / 3600.0
        elif key in fields:
            kw[key] = type(getattr(GapsConfig, key))(value)
        else:
            raise ConfigError(f"[gaps] unknown key {key!r}")
    g = GapsConfig(
        **kw,
        admissible=_polygons(raw.get("admissible"), "admissible"),
        islands=_polygons(raw.get("islands"), "islands"),
        zones=_polygons(raw.get("zones"), "zones"),
    )
    _validate(g)
    return g


def _validate(g: GapsConfig) -> None:
    offsets = np.asarray(g.forecast_offsets_s)
    if offsets.size == 0 or np.any(offsets <= 0) or np.any(np.diff(offsets) <= 0):
        raise ConfigError("[gaps] forecast_offsets_s must be positive and increasing")
    if g.max_horizon_s < offsets[-1]:
        raise ConfigError("[gaps] max_horizon_s must be >= the last forecast offset")
    positive = (
        "gap_threshold_s",
        "step_s",
        "lead_in_s",
        "max_speed_mps",
        "course_noise_rad_per_sqrt_s",
        "speed_noise_mps_per_sqrt_s",
        "sigma_cog_rad",
    )
    for name in positive:
        if not getattr(g, name) > 0:
            raise ConfigError(f"[gaps] {name} must be positive")
    if g.particles < 100 or g.max_lead_in_obs < 1 or g.batch_gaps < 1:
        raise ConfigError("[gaps] particles >= 100, max_lead_in_obs >= 1, batch_gaps >= 1")
    if not 0.0 < g.region_probability < 1.0 or not 0.0 < g.ess_fraction <= 1.0:
        raise ConfigError("[gaps] region_probability in (0, 1), ess_fraction in (0, 1]")
    if g.constraint_mode not in ("redraw", "weight") or g.redraw_tries < 0:
        raise ConfigError("[gaps] constraint_mode is 'redraw' or 'weight', redraw_tries >= 0")
    if not 0.0 <= g.min_ess_fraction < 1.0 or not 0.0 <= g.regularise_below <= 1.0:
        raise ConfigError("[gaps] min_ess_fraction in [0, 1), regularise_below in [0, 1]")
