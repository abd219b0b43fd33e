"""Every sensor family the batch runs, in the order their units are planned, and the
config loader that parses each family's sections when the file loads.

To add a family: a package under ``pipeline/`` exporting a :class:`~pipeline.family.Family`
(``stage.FAMILY``), one line in ``_STAGES`` and one in ``FAMILY_SECTIONS``.

Loading a config needs only each family's config module (``FAMILY_SECTIONS``); the stage
modules (scipy, shapely, the filters: ~0.5 s of imports on this machine) are imported when
``FAMILIES`` is first used, so commands that never run a stage (ingest, report, sql,
config check) do not pay for them.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline import config as _config
from pipeline.airfield.config import DECLARATION as AIRFIELD_DECLARATION
from pipeline.airfield.config import parse_airfield
from pipeline.config import Config
from pipeline.configspec import Document
from pipeline.convert.config import IMPORT_SECTION
from pipeline.family import FamilyDeclaration
from pipeline.gaps.config import DECLARATION as GAPS_DECLARATION
from pipeline.gaps.config import parse_gaps
from pipeline.maritime.config import DECLARATION as MARITIME_DECLARATION
from pipeline.maritime.config import SECTIONS as MARITIME_SECTIONS
from pipeline.maritime.config import parse_maritime
from pipeline.nav.config import DECLARATION as NAV_DECLARATION
from pipeline.nav.config import parse_ownship
from pipeline.reports import REPORTS_SECTION
from pipeline.requirements import REQUIREMENTS_SECTION, ConfigSection

if TYPE_CHECKING:
    from pipeline.family import Family

    FAMILIES: tuple[Family, ...]

_STAGES = ("pipeline.maritime.stage", "pipeline.airfield.stage", "pipeline.gaps.stage",
           "pipeline.nav.stage")  # fmt: skip
"""The modules whose ``FAMILY`` the batch runs, in this order (``FAMILIES``)."""

FAMILY_SECTIONS: tuple[ConfigSection, ...] = (
    ConfigSection("maritime", MARITIME_SECTIONS, parse_maritime),
    ConfigSection("airfield", ("airfield",), parse_airfield),
    ConfigSection("gaps", ("gaps",), parse_gaps),
    ConfigSection("nav", ("ownship",), parse_ownship),
)
"""What loading a config needs of each family: its sections and their parser (the same
as its ``Family``'s; a test checks)."""


FAMILY_DECLARATIONS: tuple[FamilyDeclaration, ...] = (
    MARITIME_DECLARATION, AIRFIELD_DECLARATION, GAPS_DECLARATION, NAV_DECLARATION)
"""Each family's declaration (its config module's ``DECLARATION``), in ``FAMILIES``'
order: what provenance reads without importing a stage."""


def _families() -> tuple[Family, ...]:
    if "FAMILIES" not in globals():
        globals()["FAMILIES"] = tuple(importlib.import_module(m).FAMILY for m in _STAGES)
    return globals()["FAMILIES"]


def __getattr__(name: str) -> Any:
    """``FAMILIES``, imported on first use (PEP 562; see the module docstring)."""
    if name == "FAMILIES":
        return _families()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# Sections read at load like a family's that belong to no family: what reports are
# judged against ([requirements]), the user's report folders ([reports]), and what
# `surveil import` / ASTERIX decoding take from the file ([import.csv], [asterix]).
SECTIONS: tuple[ConfigSection, ...] = (REQUIREMENTS_SECTION, REPORTS_SECTION, IMPORT_SECTION)


def family(name: str) -> Family:
    """The registered family called ``name`` (KeyError when there is none)."""
    for f in _families():
        if f.name == name:
            return f
    raise KeyError(name)


def load_config(path: str | Path | None = None,
                scenario_files: Sequence[str | Path] = ()) -> Config:
    """Load a TOML config (``None``: the shipped default) with every family's sections
    parsed and validated; :class:`~pipeline.config.ConfigError` on any problem.
    ``scenario_files``: the simulator's world merged on top (``surveil simulate``,
    ``demo``; :func:`pipeline.config.read_config`)."""
    return _config.load_config(path, (*FAMILY_SECTIONS, *SECTIONS), scenario_files)


def with_scenario_files(cfg: Config, scenario_files: Sequence[str | Path]) -> Config:
    """``cfg`` with the simulator's world of ``scenario_files`` on top
    (:func:`pipeline.config.with_scenario_files`)."""
    return _config.with_scenario_files(cfg, scenario_files, (*FAMILY_SECTIONS, *SECTIONS))


def config_from_mapping(raw: Mapping[str, Any], source: str = "(in memory)", *,
                        scenario: bool = False) -> Config:
    """The same as :func:`load_config` for an already parsed TOML document (``scenario``:
    a site with the simulator's world in it, :func:`pipeline.config.config_from_mapping`)."""
    return _config.config_from_mapping(raw, source, (*FAMILY_SECTIONS, *SECTIONS),
                                       scenario=scenario)


def read_config(path: str | Path | None = None, scenario_files: Sequence[str | Path] = ()
                ) -> tuple[Config | None, Document]:
    """The config and the document it was read from, problems not yet raised (for
    ``surveil config check``: ``Document.finish``, then ``Document.resolved``)."""
    return _config.read_config(path, (*FAMILY_SECTIONS, *SECTIONS), scenario_files)


# --- what a site declares ---------------------------------------------------------------


@dataclass(frozen=True)
class DeclaredSensor:
    """One declared sensor: its family, id, kind, the SAC/SIC it is matched by (ASTERIX
    sources; None otherwise) and where its error model comes from (``config``: the
    file gives it; ``default``: the documented default of its kind)."""

    family: str
    sensor_id: str
    kind: str
    sac_sic: str | None = None
    error_model: str = "config"


@dataclass(frozen=True)
class Declared:
    """What a config declares, family by family: the one answer to "which families and
    sensors does this site have" (the batch's skipped families, empty reports, verdicts
    "not applicable", ``surveil config init``). Every family and sensor is optional."""

    sensors: tuple[DeclaredSensor, ...]
    airfield: bool  # an [airfield] section (the airfield family runs)
    sectors: tuple[str, ...]  # maritime sectors
    legs: tuple[str, ...]  # fairway legs
    airfield_sectors: tuple[str, ...]
    water: bool  # [[gaps.admissible]] polygons (gap forecasts are constrained)

    def of(self, kind: str) -> tuple[DeclaredSensor, ...]:
        """The declared sensors of a kind (``radar``, ``smr``, ``mlat``, ``vasn``)."""
        return tuple(s for s in self.sensors if s.kind == kind)

    @property
    def radars(self) -> tuple[str, ...]:
        return tuple(s.sensor_id for s in self.of("radar"))

    def unconfigured(self, family_name: str) -> str | None:
        """Why ``family_name`` cannot run on this config, or None when it can (only the
        airfield family needs a section of its own; the others run on defaults)."""
        if family_name == "airfield" and not self.airfield:
            return "no [airfield] section in the config"
        return None


def declared(cfg: Config) -> Declared:
    """What ``cfg`` declares (see :class:`Declared`)."""
    fams = cfg.families or {}
    sensors = [DeclaredSensor("maritime", s.site_id, "radar",
                              error_model="default" if s.sigmas_default else "config")
               for s in cfg.radar_sites]
    a = fams.get("airfield")
    for s in getattr(a, "sensors", ()) or ():
        sensors.append(DeclaredSensor("airfield", s.sensor_id, s.kind,
                                      None if s.kind == "vasn" else s.sac_sic,
                                      getattr(s, "error_model", "config")))
    g = fams.get("gaps")
    return Declared(
        sensors=tuple(sensors), airfield=a is not None,
        sectors=tuple(s.name for s in cfg.sectors),
        legs=tuple(leg.leg_id for leg in cfg.fairway_legs),
        airfield_sectors=tuple(s.name for s in getattr(a, "sectors", ()) or ()),
        water=bool(getattr(g, "admissible", ())),
    )
