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
from pipeline.configspec import Document
from pipeline.convert.config import IMPORT_SECTION
from pipeline.family import Family
from pipeline.gaps.stage import FAMILY as GAPS
from pipeline.maritime.stage import FAMILY as MARITIME
from pipeline.nav.stage import FAMILY as NAV
from pipeline.reports import REPORTS_SECTION
from pipeline.requirements import REQUIREMENTS_SECTION, ConfigSection

FAMILIES: tuple[Family, ...] = (MARITIME, AIRFIELD, GAPS, NAV)

# Sections read at load like a family's that belong to no family: what reports are
# judged against ([requirements]), the user's report folders ([reports]), and what
# `surveil import` / ASTERIX decoding take from the file ([import.csv], [asterix]).
SECTIONS: tuple[ConfigSection, ...] = (REQUIREMENTS_SECTION, REPORTS_SECTION, IMPORT_SECTION)


def family(name: str) -> Family:
    """The registered family called ``name`` (KeyError when there is none)."""
    for f in FAMILIES:
        if f.name == name:
            return f
    raise KeyError(name)


def load_config(path: str | Path | None = None) -> Config:
    """Load a TOML config (``None``: the shipped default) with every family's sections
    parsed and validated; :class:`~pipeline.config.ConfigError` on any problem."""
    return _config.load_config(path, (*FAMILIES, *SECTIONS))


def config_from_mapping(raw: Mapping[str, Any], source: str = "(in memory)") -> Config:
    """The same as :func:`load_config` for an already parsed TOML document."""
    return _config.config_from_mapping(raw, source, (*FAMILIES, *SECTIONS))


def read_config(path: str | Path | None = None) -> tuple[Config | None, Document]:
    """The config and the document it was read from, problems not yet raised (for
    ``surveil config check``: ``Document.finish``, then ``Document.resolved``)."""
    return _config.read_config(path, (*FAMILIES, *SECTIONS))
