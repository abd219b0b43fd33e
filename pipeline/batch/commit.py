"""The window's commit: one Delta transaction per derived table, by the driver alone.

Guarantee kept here: **one window, one commit.** Only when every unit of the window has
succeeded does the driver commit: one Delta transaction per derived table that removes
the window's old files and adds the units' staged ones (``commit_window``: a file that
also holds rows outside the window is rewritten without them; no row passes through the
driver), then the batch rejects and the window's units (``batch_units``). The commits sit
between a pending marker and its removal (``pipeline.warehouse.pending``): readers see
every table of the window old or new, and a crash in between leaves readers the previous
rows until a batch covering the window finishes.
"""

from __future__ import annotations

import time
from pathlib import Path

import polars as pl
import pyarrow as pa

from pipeline import tables
from pipeline.batch.provenance import family_digest
from pipeline.batch.summary import BatchSummary
from pipeline.batch.worker import BatchUnit, UnitManifest
from pipeline.families import FAMILIES, family
from pipeline.family import Family
from pipeline.warehouse import pending
from pipeline.warehouse.crashpoints import crash_point
from pipeline.warehouse.delta import (
    may_hold_rows,
    replace_rows,
    replace_window,
    sql_literal,
    table_exists,
)
from pipeline.warehouse.staged import commit_window, read_staged


def commit_batch(warehouse: Path, manifests: list[UnitManifest], summary: BatchSummary,
            families: tuple[Family, ...] = FAMILIES, units: list[BatchUnit] | None = None
            ) -> None:
    """One Delta commit per derived table replacing the window's rows by the units'
    staged files (``commit_window``: no row passes through the driver), then the batch
    rejects and the window's units (``batch_units``). Readers see none of them until all
    are made (a pending marker pins the tables: ``pipeline.warehouse.pending``); a crash
    in between leaves the marker, and readers the previous rows of every table, until a
    batch covering this window finishes. Only the driver commits."""
    derived = [name for fam in families for name in fam.outputs]
    site = summary.site
    marker = pending.begin(warehouse, [*derived, "rejects", "batch_units"], job="batch",
                           window=[summary.start_ns, summary.end_ns], site=site)
    for fam in families:
        ours = [m for m in manifests if m.family == fam.name]
        for name in fam.outputs:
            staged = [f for m in ours for f in m.files.get(name, [])]
            commit_window(warehouse, name, staged, start_ns=summary.start_ns,
                          end_ns=summary.end_ns, site=site)
            summary.rows[name] = sum(f.rows for f in staged)
            crash_point(f"batch.{name}")
    staged = [f for m in manifests for f in m.files.get("rejects", [])]
    rejects = read_staged("rejects", staged, warehouse) if staged else tables.empty("rejects")
    of_site = f"site = {sql_literal(site)} AND " if site is not None else ""
    ours = {"stage": "batch", **({"site": site} if site is not None else {})}
    # nothing to write and none to remove (by the files' statistics): no commit (~12 ms)
    if (rejects.num_rows or not table_exists(warehouse, "rejects")
            or may_hold_rows(warehouse, "rejects", summary.start_ns, summary.end_ns, ours)):
        replace_rows(
            warehouse,
            "rejects",
            rejects,
            predicate_sql=(
                f"{of_site}stage = 'batch' AND log_time_ns >= {int(summary.start_ns)} "
                f"AND log_time_ns < {int(summary.end_ns)}"
            ),
        )
    summary.rejects = rejects.num_rows
    summary.reject_reasons = reject_reasons(rejects)
    crash_point("batch.rejects")
    if units is not None:
        _record_units(warehouse, units, summary)
        crash_point("batch.batch_units")
    lo, hi = summary.start_ns, summary.end_ns
    pending.finish(warehouse, marker, supersedes=lambda doc: doc.get("job") == "batch"
                   and doc.get("site") in (None, site)
                   and lo <= doc["window"][0] and doc["window"][1] <= hi)
    summary.committed = True


def reject_reasons(rejects: pa.Table, limit: int = 8) -> list[str]:
    """The batch rejects by cause, most rows first: ``unknown_sensor: 6666 airfield_obs
    reports from sensor 0/7 (smr, CAT010) not in the [airfield] config: ...`` (a cause
    whose rows all say the same is given once with its count)."""
    if rejects.num_rows == 0:
        return []
    by = (pl.from_arrow(rejects.select(["reason_code", "reason"]))
          .group_by("reason_code", "reason").len()
          .sort(["len", "reason_code", "reason"], descending=[True, False, False]))
    out = [f"{code}: {reason}" + (f" ({n:,} rows)" if n > 1 else "")
           for code, reason, n in by.head(limit).iter_rows()]
    if by.height > limit:
        out.append(f"... and {by.height - limit} more causes (SELECT reason_code, reason FROM "
                   "rejects WHERE stage = 'batch')")
    return out


def _record_units(warehouse: Path, units: list[BatchUnit], summary: BatchSummary) -> None:
    """The window's units replace those of ``batch_units`` inside it (one commit), each
    with the digest of the config its family ran with (``config_digest``)."""
    now = time.time_ns()
    # each unit's config digest (pipeline.batch.provenance): the config it ran with
    digests = {(u.family, id(u.cfg)): family_digest(u.cfg, family(u.family)) for u in units}
    rows = pl.DataFrame(
        {"start_ns": [u.start_ns for u in units], "end_ns": [u.end_ns for u in units],
         "family": [u.family for u in units],
         "config_digest": [digests[(u.family, id(u.cfg))] for u in units]},
        schema={"start_ns": pl.Int64, "end_ns": pl.Int64, "family": pl.String,
                "config_digest": pl.String},
    ).with_columns(window_start_ns=pl.lit(summary.start_ns, pl.Int64),
                   window_end_ns=pl.lit(summary.end_ns, pl.Int64),
                   committed_at_ns=pl.lit(now, pl.Int64))
    site = summary.site if summary.site is not None else tables.default_site()
    replace_window(warehouse, "batch_units", tables.conform("batch_units", rows, site=site),
                   start_ns=summary.start_ns, end_ns=summary.end_ns, site=site)
