"""Config provenance: which config computed the rows of each committed batch unit.

Issue 35, item 5. Every unit committed to ``batch_units`` records ``config_digest``: a
digest of the config its family reads (:func:`family_digest`: the core sections it
declares, ``Family.config_fields``, and its own typed sections as they were parsed, so
comments, key order and a default written out change nothing). With it:

- ``surveil run`` batches again every window whose units were computed with another
  config than the current one (:func:`stale_units`; ``pipeline.batch.pending``): after a
  config change it no longer says "nothing to do" over rows of the old config;
- reports and the audit name the digests behind their window's rows and warn when one
  window of a family mixes configs (:func:`window_digests`, :func:`provenance_lines`).

The simulator's settings a site config still carries (fault schedules, injected biases,
the own-ship scenario: :data:`SCENARIO_FIELDS`) are not part of the digest: no batch
reads them. Units committed before digests were recorded have none (null): they are
named as of unknown config, not batched again by themselves.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from pipeline.config import Config
from pipeline.families import FAMILY_DECLARATIONS
from pipeline.family import Family, FamilyDeclaration
from pipeline.units import iso
from pipeline.warehouse.delta import read_table

DIGEST_CHARS = 16
SCENARIO_FIELDS = frozenset({"faults", "simulate", "scenario"})
"""Fields of a family's config that only the simulator reads (until they move to the
scenario files, issue 35 item 1): left out of the digest."""


def _canonical(value: Any) -> Any:
    """``value`` as plain JSON types (dataclasses by field, mappings with str keys, arrays
    as lists), the simulator's fields dropped."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _canonical(getattr(value, f.name)) for f in dataclasses.fields(value)
                if f.name not in SCENARIO_FIELDS}
    if isinstance(value, Mapping):
        return {str(k): _canonical(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_canonical(v) for v in value]
    if isinstance(value, np.ndarray):
        return _canonical(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value


def family_digest(cfg: Config, fam: Family | FamilyDeclaration) -> str:
    """Digest (16 hex characters of SHA-256) of what ``fam`` reads of ``cfg``: the core
    fields it declares (``fam.config_fields``) and its own parsed sections."""
    doc = {"family": fam.name,
           "core": {name: _canonical(getattr(cfg, name)) for name in fam.config_fields},
           "own": _canonical((cfg.families or {}).get(fam.name))}
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()[:DIGEST_CHARS]


def current_digests(cfg: Config, families: Iterable[Family | FamilyDeclaration] = ()
                    ) -> dict[str, str]:
    """{family: digest} of ``cfg`` for ``families`` (default: every registered one, by
    its declaration: no stage imported)."""
    return {f.name: family_digest(cfg, f) for f in (tuple(families) or FAMILY_DECLARATIONS)}


def _units(warehouse: Path, site: str | None = None) -> pl.DataFrame:
    return pl.from_arrow(read_table(warehouse, "batch_units", site=site, columns=[
        "site", "family", "start_ns", "end_ns", "config_digest"]))


def stale_units(warehouse: Path, cfg: Config) -> pl.DataFrame:
    """Committed units whose recorded digest differs from ``cfg``'s for their family
    (site, family, start_ns, end_ns, config_digest, current); units without a digest
    (committed before digests were recorded) and of families no longer registered are
    not stale."""
    now = current_digests(cfg)
    units = _units(warehouse)
    return (units.filter(pl.col("config_digest").is_not_null()
                         & pl.col("family").is_in(list(now)))
            .with_columns(pl.col("family").replace_strict(now, return_dtype=pl.String)
                          .alias("current"))
            .filter(pl.col("config_digest") != pl.col("current"))
            .sort("site", "start_ns", "family"))


def window_digests(warehouse: Path, start_ns: int, end_ns: int, site: str | None = None,
                   families: Iterable[str] | None = None) -> pl.DataFrame:
    """Per (site, family, config_digest) the committed units overlapping the window:
    units, first start, last end. ``families``: those only (default: all)."""
    units = _units(warehouse, site).filter((pl.col("start_ns") < end_ns)
                                           & (pl.col("end_ns") > start_ns))
    if families is not None:
        units = units.filter(pl.col("family").is_in(list(families)))
    return (units.group_by("site", "family", "config_digest")
            .agg(pl.len().alias("units"), pl.col("start_ns").min(), pl.col("end_ns").max())
            .sort("site", "family", "start_ns", "config_digest", nulls_last=True))


def families_of(tables: Iterable[str]) -> list[str]:
    """The families owning any of ``tables`` (derived tables; raw ones own none)."""
    names = set(tables)
    return [f.name for f in FAMILY_DECLARATIONS if names & set(f.outputs)]


def provenance_lines(digests: pl.DataFrame, cfg: Config) -> tuple[list[str], list[str]]:
    """(what computed the rows, warnings): one line per site and family naming each
    digest (``current config`` or not), and a warning where a window of one family
    mixes configs, or holds rows of another config than the current one."""
    now = current_digests(cfg)
    lines: list[str] = []
    warnings: list[str] = []
    for (site, fam), rows in digests.group_by("site", "family", maintain_order=True):
        parts = []
        for r in rows.iter_rows(named=True):
            d = r["config_digest"]
            tag = ("current config" if d is not None and d == now.get(fam)
                   else "unknown config: batched before digests were recorded" if d is None
                   else "another config than the current one")
            parts.append(f"{d or '(none)'} ({r['units']} unit{'s' * (r['units'] != 1)}, "
                         f"[{iso(r['start_ns'])}, {iso(r['end_ns'])}), {tag})")
        lines.append(f"site {site}, {fam}: config digest {'; '.join(parts)}")
        digests_here = rows["config_digest"].to_list()
        if len(digests_here) > 1:
            warnings.append(
                f"site {site}, {fam}: the window's rows come from {len(digests_here)} "
                f"configs ({', '.join(d or '(none)' for d in digests_here)}): figures mix "
                "them; `surveil run` (or `surveil reprocess --from T --to T`) batches them "
                "again with the current config")
        elif digests_here[0] is not None and digests_here[0] != now.get(fam):
            warnings.append(
                f"site {site}, {fam}: the window's rows were computed with another config "
                f"({digests_here[0]}) than the current one ({now.get(fam)}); `surveil run` "
                "batches them again")
    return lines, warnings


def rows_provenance(warehouse: Path, cfg: Config, tables: Iterable[str], start_ns: int,
                    end_ns: int, site: str | None = None) -> tuple[list[str], list[str]]:
    """:func:`provenance_lines` of the units behind ``tables``' rows in the window (the
    families owning them; none for raw tables)."""
    fams = families_of(tables)
    if not fams:
        return [], []
    return provenance_lines(window_digests(warehouse, start_ns, end_ns, site, fams), cfg)


def report_provenance(warehouse: Path, cfg: Config, tables: Iterable[str],
                     start_ns: int | None, end_ns: int | None, site: str | None) -> list[str]:
    """What ``surveil report`` prints on stderr after a report: the config digests behind
    the rows of ``tables`` in the window (None: all time), then a ``WARNING:`` line when
    a family's rows there come from several configs or another than the current one
    (:func:`rows_provenance`)."""
    lines, warnings = rows_provenance(warehouse, cfg, tables,
                                      0 if start_ns is None else start_ns,
                                      2**63 - 1 if end_ns is None else end_ns, site)
    return [*lines, *(f"WARNING: {w}" for w in warnings)]
