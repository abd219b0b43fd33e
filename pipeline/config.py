"""Typed, frozen configuration loaded from one TOML file (``config/surveil.toml``).

Angles are degrees in the file and radians here; durations are seconds in the file
and keep the ``_s`` suffix here. Each value's file key, default and valid range are
declared beside its field (:func:`pipeline.configspec.setting`); one reader checks
them all when the file loads and reports every problem at once. Nothing reads
configuration from globals: stages receive the parts they need as arguments.
"""

from __future__ import annotations

import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

from pipeline.configspec import (
    ConfigError,
    Document,
    count,
    height,
    latitude,
    longitude,
    polygon,
    positive,
    probability,
    setting,
    text,
)
from pipeline.resources import resource_path

__all__ = ["Config", "ConfigError", "load_config"]


@dataclass(frozen=True)
class RegionConfig:
    """The site's place: its name and the origin of the regional frame (local ENU).
    ``radius_m``: positions farther than this from the origin and in none of the site's
    declared areas (sectors, water, radar coverage) lie outside the region; batch
    refuses a site whose positions are more than ``max_outside_share`` outside
    (``pipeline.batch.place``): the config then describes another place (the tangent
    plane's north deviates from true north by about 0.9 deg at 100 km east at 46 N)."""

    name: str = text()
    origin_lat_deg: float = latitude()
    origin_lon_deg: float = longitude()
    origin_height_m: float = height(0.0)
    radius_m: float = positive(100_000.0)
    max_outside_share: float = setting(0.5, ge=0.0, le=1.0)


@dataclass(frozen=True)
class RadarSite:
    site_id: str = text(unique=True)
    lat_deg: float = latitude()
    lon_deg: float = longitude()
    height_m: float = height(0.0, file_only=True)
    north_alignment_rad: float = setting(0.0, unit="deg", ge=-180.0, le=180.0, file_only=True)
    scan_period_s: float = positive()
    max_range_m: float = positive()
    sigma_range_m: float = positive()
    sigma_azimuth_rad: float = setting(unit="deg", gt=0.0, lt=180.0)
    sigma_speed_mps: float = positive()
    sigma_course_rad: float = setting(unit="deg", gt=0.0, lt=180.0)


@dataclass(frozen=True)
class AisConfig:
    gate_probability: float = probability(0.999)
    max_report_age_s: float = positive(30.0)
    sigma_position_m: float = positive(10.0)
    sigma_sog_mps: float = positive(0.3)
    identity_window_s: float = positive(300.0)
    min_identity_matches: int = count(3)


@dataclass(frozen=True)
class ValidationConfig:
    max_speed_mps: float = positive(40.0)
    max_range_m: float = positive(60000.0)


@dataclass(frozen=True)
class FairwayLeg:
    """``start = [lat_deg, lon_deg]``, ``end = [lat_deg, lon_deg]`` in the file."""

    leg_id: str = text(unique=True)
    start_lat_deg: float = latitude(key=("start", 0))
    start_lon_deg: float = longitude(key=("start", 1))
    end_lat_deg: float = latitude(key=("end", 0))
    end_lon_deg: float = longitude(key=("end", 1))


@dataclass(frozen=True)
class Sector:
    name: str = text(unique=True)
    polygon_lat_lon_deg: tuple[tuple[float, float], ...] = polygon()


@dataclass(frozen=True)
class ExecutionConfig:
    executor: str = setting("process", choices=("serial", "process", "ray"))
    max_workers: int = count(2)
    threads_per_worker: int = count(1)
    # the longest batch/reprocess window, after clipping it to the data the ledger knows
    max_window_days: float = positive(31.0)
    # memory a batch may plan for (MB; 0: 80% of the machine's memory): above, exit 2
    memory_budget_mb: int = setting(0, ge=0)


def _folder_names(folders: tuple[str, ...]) -> str | None:
    """``[archive] folders``: non-empty, distinct paths."""
    if any(not str(f).strip() for f in folders):
        return "a folder name is empty"
    if len(set(folders)) != len(folders):
        return "a folder is named twice"
    return None


def _storage_options(options: Mapping[str, str]) -> str | None:
    """``[warehouse] storage_options``: option names and string values."""
    if any(not str(k).strip() for k in options):
        return "an option name is empty"
    return None


_SECRET_WORDS = ("secret", "token", "password", "key_id", "access_key", "credential")


def is_secret_option(key: str) -> bool:
    """Whether a storage option's value is a credential (masked wherever it is shown)."""
    return any(w in key.lower() for w in _SECRET_WORDS)


def _masked_options(options: Mapping[str, str]) -> dict[str, str]:
    """``[warehouse] storage_options`` as ``config check`` shows them: credentials
    masked (:func:`is_secret_option`)."""
    return {k: "***" if is_secret_option(k) else v for k, v in options.items()}


def _unshown(f: Any) -> Any:
    """A field left out of ``repr`` (it may hold credentials), equality and hashing."""
    f.repr = f.compare = False
    return f


@dataclass(frozen=True)
class Config:
    region: RegionConfig = setting()
    radar_sites: tuple[RadarSite, ...] = setting(min_len=1)
    ais: AisConfig = setting({})
    validation: ValidationConfig = setting({})
    fairway_legs: tuple[FairwayLeg, ...] = setting([], file_only=True)
    sectors: tuple[Sector, ...] = setting([], file_only=True)
    warehouse_path: str = text("warehouse", key=("warehouse", "path"))
    # object-store options of an s3:// warehouse (endpoint, region, credentials: deltalake's
    # names; over the AWS_* environment variables): never printed (docs/scale.md)
    warehouse_storage_options: Mapping[str, str] = _unshown(setting(
        {}, key=("warehouse", "storage_options"), factory=dict, check=_storage_options,
        mask=_masked_options))
    # folders `surveil run` scans for MCAP files (absolute, or relative to the working
    # folder); empty: `surveil run FOLDER...` names them
    archive_folders: tuple[str, ...] = setting([], key=("archive", "folders"),
                                               check=_folder_names)
    # a file `surveil run` finds still being written (an MCAP without its footer, a raw
    # recording just modified) is read once it has not changed for this long, s
    archive_settle_s: float = setting(300.0, key=("archive", "settle_s"), ge=0.0)
    execution: ExecutionConfig = setting({}, factory=ExecutionConfig)
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


FamilyParser = Callable[[Document, "Config | None"], Any]
"""(the document being read, the core config or None when the core sections are invalid)
-> a family's typed config; problems go to the document (``Document.read``/``problem``)."""


class FamilySections(Protocol):
    """What the loader needs of a :class:`~pipeline.family.Family`."""

    name: str
    sections: tuple[str, ...]
    parse_config: FamilyParser


def load_config(path: str | Path | None, families: Sequence[FamilySections]) -> Config:
    """Load and validate a TOML config; ``None`` loads the shipped default.

    Every family's sections are parsed here, so a bad value fails the load (one
    :class:`ConfigError` listing every problem), not a later work unit; a section no
    family claims is an unknown section. ``pipeline.families.load_config`` passes every
    registered family."""
    cfg, doc = read_config(path, families)
    doc.finish()
    assert cfg is not None  # finish raised otherwise
    return cfg


def read_config(path: str | Path | None, families: Sequence[FamilySections]
                ) -> tuple[Config | None, Document]:
    """The config and its :class:`Document` (``Document.finish`` not yet called: the
    caller raises the problems, or renders ``Document.resolved``). ConfigError when the
    file cannot be read as TOML at all."""
    p = Path(path) if path is not None else DEFAULT_CONFIG_PATH
    try:
        text = p.read_bytes().decode("utf-8")
        raw = tomllib.loads(text)
    except FileNotFoundError as exc:
        raise ConfigError(f"config file not found: {p}") from exc
    except OSError as exc:
        raise ConfigError(f"config file {p} cannot be read: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"config file {p} is not a UTF-8 TOML file ({exc.reason} "
                          f"at byte {exc.start})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {p} is not valid TOML: {exc}") from exc
    doc = Document(raw, str(p), text)
    return _read(doc, families), doc


def config_from_mapping(raw: Mapping[str, Any], source: str,
                        families: Sequence[FamilySections]) -> Config:
    """Validate an already parsed TOML document (see :func:`load_config`)."""
    doc = Document(raw, source)
    cfg = _read(doc, families)
    doc.finish()
    assert cfg is not None
    return cfg


def _read(doc: Document, families: Sequence[FamilySections]) -> Config | None:
    """The core sections, then every family's (each reports its problems to ``doc``);
    then the keys nobody read (``doc.finish``, by the caller)."""
    core = doc.read(Config)
    if core is not None:
        for i, leg in enumerate(core.fairway_legs):
            if (leg.start_lat_deg, leg.start_lon_deg) == (leg.end_lat_deg, leg.end_lon_deg):
                doc.problem(("fairway_legs", i, "end"), "equals start (a leg needs two points)")
        core = replace(core, source=doc.source, sections=doc.raw)
    parsed = {}
    for f in families:
        doc.claim(*f.sections)
        parsed[f.name] = f.parse_config(doc, core)
    return replace(core, families=parsed) if core is not None else None
