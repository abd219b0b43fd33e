"""``surveil config check [FILE]``: validate a config file exactly as every command
does when it loads one, and print it resolved."""

from __future__ import annotations

from pathlib import Path

from pipeline.families import read_config


def resolved_config(path: str | Path | None) -> str:
    """The config at ``path`` (None: the shipped default) as TOML: every section and
    every value the pipeline reads, in file units, ``# default`` where the file does not
    set it (loading the output gives the same config). Raises
    :class:`~pipeline.config.ConfigError` listing every problem (the CLI exits 2)."""
    _, doc = read_config(path)
    doc.finish()
    return (f"# {doc.source}: ok. Resolved: every value read, in file units; "
            "'# default': not set in the file.\n\n" + doc.resolved())
