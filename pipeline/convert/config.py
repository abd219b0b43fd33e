"""The ``[import.csv]`` and ``[asterix]`` sections of the config, typed and validated.

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
(:data:`pipeline.decode.asterix_editions.EDITIONS`). A bad value is a
:class:`~pipeline.config.ConfigError` (exit 2) naming the key.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pipeline.config import Config, ConfigError
from pipeline.convert.ais_csv import COLUMN_NAMES, CsvOptions, canonical_field


@dataclass(frozen=True)
class ImportOptions:
    """What ``surveil import`` and ASTERIX decoding take from the config."""

    csv: CsvOptions = field(default_factory=CsvOptions)
    asterix_editions: Mapping[int, str] = field(default_factory=dict)


def parse_import_options(raw: Mapping[str, Any]) -> ImportOptions:
    """``ImportOptions`` from a whole parsed TOML mapping (module docstring)."""
    csv_raw = dict(raw.get("import", {}).get("csv", {}) or {})
    unknown = set(csv_raw) - {"columns", "time_format"}
    if unknown:
        raise ConfigError(f"[import.csv]: unknown keys {sorted(unknown)} (columns, time_format)")
    columns = csv_raw.get("columns", {}) or {}
    if not isinstance(columns, Mapping):
        raise ConfigError("[import.csv] columns must be a table: header cell = field")
    for cell, target in columns.items():
        if not isinstance(target, str) or canonical_field(target) is None:
            names = ", ".join(sorted(set(COLUMN_NAMES) - {"sog_mps"}))
            raise ConfigError(
                f"[import.csv] columns: {cell!r} = {target!r} is not a field (one of: {names})"
            )
    fmt = csv_raw.get("time_format")
    if fmt is not None and not isinstance(fmt, str):
        raise ConfigError("[import.csv] time_format must be a strftime format string")
    return ImportOptions(
        csv=CsvOptions(columns=dict(columns), time_format=fmt),
        asterix_editions=parse_editions(raw.get("asterix", {}) or {}),
    )


def parse_editions(section: Mapping[str, Any]) -> dict[int, str]:
    """``[asterix] editions`` -> {category: edition}; validated against the editions the
    decoder knows."""
    from pipeline.decode.asterix_editions import known_editions

    unknown = set(section) - {"editions"}
    if unknown:
        raise ConfigError(f"[asterix]: unknown keys {sorted(unknown)} (editions)")
    out: dict[int, str] = {}
    for cat, ed in (section.get("editions", {}) or {}).items():
        try:
            c = int(str(cat))
        except ValueError:
            raise ConfigError(f"[asterix] editions: {cat!r} is not a category number") from None
        known = known_editions(c)
        if str(ed) not in known:
            raise ConfigError(
                f"[asterix] editions: CAT{c:03d} edition {ed!r} is not one we decode "
                f"(known: {', '.join(known) or 'none'})"
            )
        out[c] = str(ed)
    return out


def import_options(cfg: Config | None) -> ImportOptions:
    """The options of a loaded config (defaults without one)."""
    if cfg is None:
        return ImportOptions()
    return parse_import_options(cfg.sections)
