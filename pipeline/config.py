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
    gate,
    height,
    latitude,
    longitude,
    polygon,
    positive,
    probability,
    sector_list,
    setting,
    text,
)
from pipeline.resources import resource_path

__all__ = ["Config", "ConfigError", "load_config"]


SCAN_PERIOD_WHY = ("a rotating antenna turns once per 0.5 s (120 rpm, surface movement "
                   "radars) to 30 s (2 rpm, long-range surveillance); VTS radars 2-4 s")
SIGMA_SPEED_WHY = ("a speed sigma is millimetres to metres per second; 20 m/s is no "
                   "measurement of a ship or a taxiing aircraft")
AIS_AGE_WHY = ("AIS reports every 2 s to 6 min (ITU-R M.1371): older than an hour is no "
               "position")
GNSS_POSITION_WHY = ("a GNSS position sigma is decimetres (RTK) to tens of metres; "
                     "1 km is no fix")


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
    radius_m: float = setting(100_000.0, gt=0.0, le=1_000_000.0, why=(
        "the regional frame is a tangent plane: 1000 km from its origin its north is "
        "off by ~9 deg"))
    max_outside_share: float = setting(0.5, ge=0.0, le=1.0)


@dataclass(frozen=True)
class RadarSite:
    """A coastal radar site (``[[radar_sites]]``, optional: a site may have none).

    The sigmas are the expected accuracy of the site's track reports. The batch uses
    each report's own sigmas (``radar_tracks.sigma_*``, from the tracker); these are what
    the simulator draws from and the experiments assume. When the file does not give
    them they are the documented defaults of the ``vts`` class (a coastal X-band VTS
    radar with a plot-extractor tracker: 15 m in range, 0.45 deg in azimuth, 0.25 m/s,
    2 deg; :data:`RADAR_CLASS_DEFAULTS`), and ``sigmas_default`` says so."""

    site_id: str = text(unique=True)
    lat_deg: float = latitude()
    lon_deg: float = longitude()
    height_m: float = height(0.0, file_only=True)
    north_alignment_rad: float = setting(0.0, unit="deg", ge=-180.0, le=180.0, file_only=True)
    scan_period_s: float = setting(ge=0.5, le=30.0, why=SCAN_PERIOD_WHY)
    max_range_m: float = setting(ge=100.0, le=250_000.0, why=(
        "from a surface movement radar's few hundred metres to a long-range coastal "
        "radar's 250 km (beyond it a ship is below the radar horizon of any mast)"))
    sigma_range_m: float = setting(15.0, ge=0.1, le=1000.0, why=(
        "a tracker's range sigma is a few metres to tens of metres; 1 km is no track"))
    sigma_azimuth_rad: float = setting(0.45, unit="deg", ge=0.001, le=10.0, why=(
        "an antenna's beam is 0.3-3 deg wide: its tracks' azimuth sigma is hundredths "
        "to a few degrees"))
    sigma_speed_mps: float = setting(0.25, ge=0.001, le=20.0, why=SIGMA_SPEED_WHY)
    sigma_course_rad: float = setting(2.0, unit="deg", ge=0.01, le=90.0, why=(
        "a track's course sigma is under a degree to tens of degrees (slow targets)"))
    # none of the four sigmas was in the file: the class defaults (set when it loads)
    sigmas_default: bool = field(default=False, repr=False)


RADAR_CLASS_DEFAULTS = {"vts": {"sigma_range_m": 15.0, "sigma_azimuth_deg": 0.45,
                                "sigma_speed_mps": 0.25, "sigma_course_deg": 2.0}}
"""The documented sigmas of a radar site that declares none, per class (file units)."""


@dataclass(frozen=True)
class AisConfig:
    gate_probability: float = gate(0.999)
    max_report_age_s: float = setting(30.0, gt=0.0, le=3600.0, why=AIS_AGE_WHY)
    sigma_position_m: float = setting(10.0, ge=0.1, le=1000.0, why=GNSS_POSITION_WHY)
    sigma_sog_mps: float = setting(0.3, ge=0.001, le=20.0, why=SIGMA_SPEED_WHY)
    # the history the identity test carries over a unit cut (the units' lead-in; also
    # their look-ahead, for the smoothed reference: pipeline.maritime.stage)
    identity_window_s: float = setting(300.0, ge=1.0, le=86_400.0, why=(
        "the identity test's history spans seconds to at most a day"))
    # the false-identification budget alpha: the chance a pair that is not one ship is
    # confirmed; beta: the chance a ship's own AIS pair is rejected (Wald's boundaries)
    false_identification_probability: float = setting(0.001, gt=0.0, le=0.1, why=(
        "a false-identification budget above 10 % names ships by chance"))
    missed_identification_probability: float = probability(0.01)
    # offline: a point takes the identity decision reached at most this much later
    # (pipeline.maritime.identity, "Fixed lag"); 0: the causal test, as a live picture
    identity_lag_s: float = setting(60.0, ge=0.0, le=86_400.0, why=(
        "the identity test's lag spans seconds to at most a day"))
    # per epoch: the chance a ship's own AIS is assigned to its track (P_M), and that
    # another ship's AIS is (P_S < P_M)
    match_probability: float = probability(0.95)
    stray_match_probability: float = probability(0.05)


@dataclass(frozen=True)
class ValidationConfig:
    max_speed_mps: float = setting(40.0, ge=1.0, le=350.0, why=(
        "the fastest plausible target, from a harbour's 1 m/s to a landing aircraft "
        "(350 m/s is the speed of sound)"))
    max_range_m: float = setting(60000.0, ge=100.0, le=250_000.0, why=(
        "a report farther than 250 km from its radar is below any mast's radar horizon"))


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
    # optional: an AIS-only, airfield-only or own-ship-only site declares no radar
    radar_sites: tuple[RadarSite, ...] = setting([], file_only=True)
    ais: AisConfig = setting({})
    validation: ValidationConfig = setting({})
    fairway_legs: tuple[FairwayLeg, ...] = setting([], file_only=True)
    sectors: tuple[Sector, ...] = sector_list()
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
    # the scenario files merged on top of the site (the simulator's world: fault
    # schedules, injected biases; read_config); () for a site config
    scenario_files: tuple[str, ...] = field(default=(), compare=False, repr=False)
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


def load_config(path: str | Path | None, families: Sequence[FamilySections],
                scenario_files: Sequence[str | Path] = ()) -> Config:
    """Load and validate a TOML config; ``None`` loads the shipped default.

    Every family's sections are parsed here, so a bad value fails the load (one
    :class:`ConfigError` listing every problem), not a later work unit; a section no
    family claims is an unknown section. ``pipeline.families.load_config`` passes every
    registered family. ``scenario_files``: see :func:`read_config`."""
    cfg, doc = read_config(path, families, scenario_files)
    doc.finish()
    assert cfg is not None  # finish raised otherwise
    return cfg


def read_config(path: str | Path | None, families: Sequence[FamilySections],
                scenario_files: Sequence[str | Path] = ()
                ) -> tuple[Config | None, Document]:
    """The config and its :class:`Document` (``Document.finish`` not yet called: the
    caller raises the problems, or renders ``Document.resolved``). ConfigError when the
    file cannot be read as TOML at all.

    ``scenario_files``: the simulator's world on top of the site (``surveil simulate``,
    ``demo``, the experiments): each may hold only simulator settings
    (:data:`SCENARIO_KEYS`), merged into the site's tables; the document then reads
    them (a site config alone never does: ``setting(scenario=...)``)."""
    raw, text, p = _toml(Path(path) if path is not None else DEFAULT_CONFIG_PATH)
    if not scenario_files:
        doc = Document(raw, str(p), text)
        return _read(doc, families), doc
    return _world(raw, str(p), scenario_files, families)


def with_scenario_files(cfg: Config, scenario_files: Sequence[str | Path],
                        families: Sequence[FamilySections]) -> Config:
    """``cfg`` (a site config) with ``scenario_files`` merged on top and every section
    parsed again (:func:`read_config`); ConfigError listing every problem."""
    out, doc = _world(cfg.sections, cfg.source, scenario_files, families)
    doc.finish()
    assert out is not None
    return out


def _world(raw: Mapping[str, Any], source: str, scenario_files: Sequence[str | Path],
           families: Sequence[FamilySections]) -> tuple[Config | None, Document]:
    merged: dict[str, Any] = dict(raw)
    names = []
    for f in scenario_files:
        extra, _, fp = _toml(Path(f))
        _check_scenario_keys(extra, fp)
        merged = _merged(merged, extra)
        names.append(str(fp))
    doc = Document(merged, " + ".join([source, *names]), None, scenario=True)
    cfg = _read(doc, families)
    if cfg is not None:
        cfg = replace(cfg, source=source, scenario_files=tuple(names))
    return cfg, doc


SCENARIO_KEYS: tuple[tuple[str, ...], ...] = (
    ("channel_faults",), ("radar_bias", "simulate"), ("airfield", "faults"),
    ("ownship", "scenario"),
)
"""The simulator settings a scenario file may hold (each declared beside its field with
``setting(scenario=...)``; the own ship's scenario in ``pipeline.nav.config``)."""


def _check_scenario_keys(raw: Mapping[str, Any], path: Path) -> None:
    """A scenario file holds simulator settings only (a site setting there would
    silently override the site's)."""
    bad = []
    for k, v in raw.items():
        if (k,) in SCENARIO_KEYS:
            continue
        subs = [key[1] for key in SCENARIO_KEYS if key[0] == k and len(key) == 2]
        if subs and isinstance(v, Mapping):
            bad += [f"[{k}.{sub}]" for sub in v if sub not in subs]
        else:
            bad.append(f"[{k}]")
    if bad:
        allowed = ", ".join("[" + ".".join(key) + "]" for key in SCENARIO_KEYS)
        raise ConfigError(f"scenario file {path}: {', '.join(bad)} is a site setting, not the "
                          f"simulator's: put it in the site config (a scenario file holds "
                          f"only {allowed})")


def _merged(base: Mapping[str, Any], extra: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``extra``'s tables merged in (arrays and values replaced)."""
    out = dict(base)
    for k, v in extra.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = _merged(out[k], v)
        else:
            out[k] = v
    return out


def _toml(p: Path) -> tuple[dict[str, Any], str, Path]:
    """A TOML file parsed: (document, text, path); ConfigError naming the problem."""
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
    return raw, text, p


def config_from_mapping(raw: Mapping[str, Any], source: str,
                        families: Sequence[FamilySections], *, scenario: bool = False
                        ) -> Config:
    """Validate an already parsed TOML document (see :func:`load_config`); ``scenario``:
    it is a site merged with the simulator's world, which it may then hold (the config is
    marked as one: ``scenario_files``)."""
    doc = Document(raw, source, scenario=scenario)
    cfg = _read(doc, families)
    doc.finish()
    assert cfg is not None
    return replace(cfg, scenario_files=("(in memory)",)) if scenario else cfg


def _check_identity_test(doc: Document, ais: AisConfig) -> None:
    """``[ais]``: Wald's boundaries need alpha + beta < 1; a stray match must be less
    likely than a ship's own (else a match would be evidence against the identity)."""
    if ais.false_identification_probability + ais.missed_identification_probability >= 1.0:
        doc.problem(("ais", "missed_identification_probability"),
                    "false_identification_probability + missed_identification_probability "
                    "must be below 1")
    if ais.identity_lag_s > ais.identity_window_s:
        doc.problem(("ais", "identity_lag_s"),
                    f"must be at most identity_window_s ({ais.identity_window_s:g} s, the "
                    "units' look-ahead: a longer lag would make results depend on the cuts)")
    if ais.stray_match_probability >= ais.match_probability:
        doc.problem(("ais", "stray_match_probability"),
                    f"must be below match_probability ({ais.match_probability})")


def _read(doc: Document, families: Sequence[FamilySections]) -> Config | None:
    """The core sections, then every family's (each reports its problems to ``doc``);
    then the keys nobody read (``doc.finish``, by the caller)."""
    core = doc.read(Config)
    if core is not None:
        sigmas = RADAR_CLASS_DEFAULTS["vts"]
        given = [r if isinstance(r, Mapping) else {} for r in doc.raw.get("radar_sites", [])]
        core = replace(core, radar_sites=tuple(
            replace(s, sigmas_default=not any(k in g for k in sigmas))
            for s, g in zip(core.radar_sites, given, strict=True)))
        _check_identity_test(doc, core.ais)
        for i, leg in enumerate(core.fairway_legs):
            if (leg.start_lat_deg, leg.start_lon_deg) == (leg.end_lat_deg, leg.end_lon_deg):
                doc.problem(("fairway_legs", i, "end"), "equals start (a leg needs two points)")
        core = replace(core, source=doc.source, sections=doc.raw)
    parsed = {}
    for f in families:
        doc.claim(*f.sections)
        parsed[f.name] = f.parse_config(doc, core)
    return replace(core, families=parsed) if core is not None else None
