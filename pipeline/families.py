"""Every sensor family the batch runs, in the order their units are planned, and the
config loader that parses each family's sections when the file loads.

To add a family: a package under ``pipeline/`` exporting a :class:`~pipeline.family.Family`
(``stage.FAMILY``), and one line here.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pipeline import config as _config
from pipeline.airfield.stage import FAMILY as AIRFIELD
from pipeline.config import Config
from pipeline.family import Family
from pipeline.gaps.stage import FAMILY as GAPS
from pipeline.maritime.stage import FAMILY as MARITIME
from pipeline.nav.stage import FAMILY as NAV
from pipeline.reports import parse_reports_section
from pipeline.requirements import parse_requirements

FAMILIES: tuple[Family, ...] = (MARITIME, AIRFIELD, GAPS, NAV)

# Sections parsed at load like a family's, that belong to no family: what reports are
# judged against ([requirements]) and the user's report folders ([reports]).
SECTIONS: dict[str, Any] = {"requirements": parse_requirements, "reports": parse_reports_section}


def family(name: str) -> Family:
    """The registered family called ``name`` (KeyError when there is none)."""
    for f in FAMILIES:
        if f.name == name:
            return f
    raise KeyError(name)


def _parsers() -> dict[str, Any]:
    return {**{f.name: f.parse_config for f in FAMILIES}, **SECTIONS}


def load_config(path: str | Path | None = None) -> Config:
    """Load a TOML config (``None``: the shipped default) with every family's sections
    parsed and validated; :class:`~pipeline.config.ConfigError` on any problem."""
    return _config.load_config(path, _parsers())


def config_from_mapping(raw: Mapping[str, Any], source: str = "(in memory)") -> Config:
    """The same as :func:`load_config` for an already parsed TOML document."""
    return _config.config_from_mapping(raw, source, _parsers())
