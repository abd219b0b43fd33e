"""The gaps family's configuration: the ``[gaps]`` section (distributed maritime
observation paper; degrees in the file, radians here). Each value's file key, default
and valid range are declared beside it (:func:`pipeline.configspec.setting`)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

from pipeline.config import Config
from pipeline.configspec import Document, count, polygon, positive, probability, setting
from pipeline.family import FamilyDeclaration
from pipeline.filters import particle as pf


@dataclass(frozen=True)
class NamedPolygon:
    """A polygon of ``[[gaps.admissible]]``, ``[[gaps.islands]]`` or ``[[gaps.zones]]``;
    an unnamed one is called ``<table>-<n>`` (n from 1)."""

    name: str = setting("", unique=True, file_only=True)
    polygon_lat_lon_deg: tuple[tuple[float, float], ...] = polygon()


def _increasing(offsets: tuple[float, ...]) -> str | None:
    ok = all(b > a for a, b in itertools.pairwise(offsets))
    return None if ok else "must be increasing"


@dataclass(frozen=True)
class GapsConfig:
    """The ``[gaps]`` section of the config (angles in degrees there, radians here)."""

    gap_threshold_s: float = positive(600.0)
    forecast_offsets_s: tuple[float, ...] = positive(
        [300.0, 600.0, 1200.0, 1800.0, 2700.0, 3600.0], min_len=1, check=_increasing)
    max_horizon_s: float = positive(3600.0)
    forecast_at_gap_end: bool = setting(True)
    particles: int = setting(2000, ge=100, le=1_000_000, why=(
        "a forecast's memory and time grow with the particles: a million per gap is "
        "past what a batch unit holds"))
    step_s: float = setting(60.0, ge=1.0, le=3600.0, why=(
        "a ship's track between reports is propagated in steps of seconds to an hour"))
    lead_in_s: float = positive(600.0)
    max_lead_in_obs: int = count(10)
    course_noise_rad_per_sqrt_s: float = positive(0.25, unit="deg")
    speed_noise_mps_per_sqrt_s: float = positive(0.01)
    turn_rate_per_s: float = setting(2.0, key="turns_per_hour", ge=0.0,
                                     convert=lambda per_hour: per_hour / 3600.0)
    turn_sigma_rad: float = positive(45.0, unit="deg")
    manoeuvre_noise_factor: float = setting(5.0, ge=1.0)
    max_speed_mps: float = setting(15.0, gt=0.0, le=50.0, why=(
        "a ship sails at most ~25 m/s (50 kn): 50 m/s is no ship's speed"))
    sigma_cog_rad: float = setting(3.0, unit="deg", gt=0.0, le=90.0, why=(
        "an AIS COG sigma is a few degrees (tens when slow); beyond 90 deg the course says "
        "nothing"))
    course_min_speed_mps: float = setting(1.0, ge=0.0)
    manoeuvre_rate_rad_per_s: float = positive(0.2, unit="deg")
    region_probability: float = probability(0.9)
    ess_fraction: float = setting(0.5, gt=0.0, le=1.0)
    replenish_rounds: int = setting(4, ge=0)
    regularise_below: float = setting(0.1, ge=0.0, le=1.0)
    min_ess_fraction: float = setting(0.05, ge=0.0, lt=1.0)
    constrain: bool = setting(True)
    constraint_mode: str = setting("redraw", choices=("redraw", "weight"))
    redraw_tries: int = setting(10, ge=0)
    batch_gaps: int = count(32)
    # a vessel whose last position before a gap lies farther than this outside the
    # admissible area gets no forecast (its particles would start outside the water)
    water_margin_m: float = setting(1000.0, ge=0.0)
    admissible: tuple[NamedPolygon, ...] = setting([])
    islands: tuple[NamedPolygon, ...] = setting([])
    zones: tuple[NamedPolygon, ...] = setting([])

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


def gaps_config(cfg: Config) -> GapsConfig:
    """The gaps family's config, parsed when ``cfg`` was loaded."""
    return cfg.family("gaps")


def parse_gaps(doc: Document, core: Config | None = None) -> GapsConfig | None:
    """The ``[gaps]`` section (an absent section gives the defaults and no geometry: no
    constraint, no zones); the forecast horizon must cover the last offset."""
    g = doc.read(GapsConfig, "gaps")
    if g is None:
        return None
    if g.max_horizon_s < g.forecast_offsets_s[-1]:
        doc.problem(("gaps", "max_horizon_s"),
                    f"must be >= the last forecast offset ({g.forecast_offsets_s[-1]:g} s)")
    named = {k: tuple(p if p.name else replace(p, name=f"{k}-{i + 1}")
                      for i, p in enumerate(getattr(g, k)))
             for k in ("admissible", "islands", "zones")}
    return replace(g, **named)


# what the family's stage reads of the core config, and the tables it writes
DECLARATION = FamilyDeclaration("gaps", ("region", "ais", "sectors"), ("gap_forecasts",))
