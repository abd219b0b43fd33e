"""The ``[import.csv]`` and ``[asterix]`` sections of the config, declared with
:mod:`pipeline.configspec` and read when the file loads (``IMPORT_SECTION``, registered
in :mod:`pipeline.families`).

```toml
[import.csv]
columns = { "Zeit" = "time", "Kennung" = "mmsi", "Breite" = "lat", "Laenge" = "lon" }
time_format = "%d.%m.%Y %H:%M:%S"   # optional: else detected per file

[asterix]
editions = { "010" = "0.24", "021" = "0.26" }   # optional: else detected per data block
```

``columns``: header cell as written (case and blanks ignored) -> canonical field
(:func:`pipeline.convert.ais_csv.canonical_field`: ``time``, ``mmsi``, ``lat``, ``lon``,
``sog``, ``cog``, ``heading``, ... or the schema's own names, or ``ignore``).
``editions``: ASTERIX category (``"10"`` or ``"010"``) -> edition
(:func:`pipeline.decode.asterix_editions.known_editions`). A bad value is a
:class:`~pipeline.config.ConfigError` (exit 2) naming the key.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pipeline.config import Config
from pipeline.configspec import Document, setting
from pipeline.convert.ais_csv import COLUMN_NAMES, CsvOptions, canonical_field
from pipeline.decode.asterix_editions import known_editions

SECTION = "import"


def _check_columns(columns: Mapping[str, str]) -> str | None:
    for cell, target in columns.items():
        if canonical_field(target) is None:
            names = ", ".join(sorted(set(COLUMN_NAMES) - {"sog_mps"}))
            return f"{cell!r} = {target!r} is not a field (one of: {names})"
    return None


def _editions(raw: Mapping[str, str]) -> dict[int, str]:
    out = {}
    for cat, ed in raw.items():
        out[int(str(cat))] = str(ed)
    return out


def _check_editions(editions: Mapping[str, str]) -> str | None:
    for cat, ed in editions.items():
        try:
            c = int(str(cat))
        except ValueError:
            return f"{cat!r} is not a category number"
        known = known_editions(c)
        if str(ed) not in known:
            return (f"CAT{c:03d} edition {ed!r} is not one we decode "
                    f"(known: {', '.join(known) or 'none'})")  # fmt: skip
    return None


@dataclass(frozen=True)
class CsvImportConfig:
    """``[import.csv]``."""

    columns: Mapping[str, str] = setting({}, factory=dict, check=_check_columns)
    time_format: str = setting("")  # "": detected per file


@dataclass(frozen=True)
class ImportConfig:
    """``[import]``."""

    csv: CsvImportConfig = setting({}, factory=CsvImportConfig)


@dataclass(frozen=True)
class AsterixConfig:
    """``[asterix]``."""

    editions: Mapping[str, str] = setting({}, factory=dict, check=_check_editions)


@dataclass(frozen=True)
class ImportOptions:
    """What ``surveil import`` and ASTERIX decoding take from the config."""

    csv: CsvOptions = field(default_factory=CsvOptions)
    asterix_editions: Mapping[int, str] = field(default_factory=dict)


def parse_import_section(doc: Document, core: Any = None) -> ImportOptions | None:
    """``[import]`` and ``[asterix]`` (defaults when absent); problems go to ``doc``."""
    imp = doc.read(ImportConfig, SECTION)
    ast = doc.read(AsterixConfig, "asterix")
    if imp is None or ast is None:
        return None
    return ImportOptions(
        csv=CsvOptions(columns=dict(imp.csv.columns), time_format=imp.csv.time_format or None),
        asterix_editions=_editions(ast.editions),
    )


@dataclass(frozen=True)
class _Section:
    name: str
    sections: tuple[str, ...]
    parse_config: Any


IMPORT_SECTION = _Section(SECTION, (SECTION, "asterix"), parse_import_section)
"""Read at load like a family's sections (:data:`pipeline.families.SECTIONS`)."""


def parse_import_options(raw: Mapping[str, Any]) -> ImportOptions:
    """``ImportOptions`` from a parsed TOML mapping holding only these sections (tests,
    tools); :class:`~pipeline.config.ConfigError` listing every problem."""
    doc = Document(raw, "(in memory)")
    out = parse_import_section(doc)
    doc.finish()
    assert out is not None
    return out


def parse_editions(section: Mapping[str, Any]) -> dict[int, str]:
    """``[asterix]`` alone -> {category: edition} (validated)."""
    return dict(parse_import_options({"asterix": dict(section)}).asterix_editions)


def import_options(cfg: Config | None) -> ImportOptions:
    """The options of a loaded config (defaults without one, or when it was loaded
    without the import section)."""
    families = getattr(cfg, "families", {}) or {}
    opts = families.get(SECTION)
    return opts if isinstance(opts, ImportOptions) else ImportOptions()
