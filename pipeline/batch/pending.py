"""The windows a nightly run must batch: what the ledger holds that ``batch_units`` does
not, and what ``batch_units`` holds of another config than the current one.

Read from the warehouse, not remembered by a job: a file ingested by a run that crashed
or whose batch failed is found again by the next run, and nothing else is redone. A
unit whose recorded config digest differs from the current config's for its family
(``pipeline.batch.provenance``: the config changed since it was batched) is pending too.
"""

from __future__ import annotations

from pathlib import Path

import polars as pl

from pipeline.batch.plan import unit_is_live
from pipeline.batch.provenance import stale_units
from pipeline.config import Config
from pipeline.families import FAMILIES
from pipeline.units import NS
from pipeline.warehouse.delta import read_table

HOUR_NS = 3600 * NS


def pending_windows(warehouse: Path, site: str | None = None) -> list[tuple[int, int]]:
    """Windows to batch (of ``site``, default any): :func:`pending_by_site`'s, merged
    over the sites; ascending."""
    by_site = pending_by_site(warehouse)
    return _merged([w for name, windows in by_site.items() if site in (None, name)
                    for w in windows])


def pending_by_site(warehouse: Path) -> dict[str, list[tuple[int, int]]]:
    """Per site, the windows to batch: the spans of its ledger files (ok or partial) not
    covered by its ``batch_units`` committed after the file was ingested, cut out to
    whole UTC hours and merged; ascending. Only that site is batched over them. (The
    units of another config: :func:`stale_spans`, :func:`with_spans`.)"""
    ledger = pl.from_arrow(read_table(warehouse, "ingest_ledger")).filter(
        pl.col("status").is_in(["ok", "partial"]) & pl.col("start_time_ns").is_not_null()
        & pl.col("end_time_ns").is_not_null())
    units = pl.from_arrow(read_table(warehouse, "batch_units"))
    spans: dict[str, list[tuple[int, int]]] = {}
    for f in ledger.iter_rows(named=True):
        lo, hi = f["start_time_ns"], f["end_time_ns"] + 1
        fresh = units.filter((pl.col("site") == f["site"])
                             & (pl.col("committed_at_ns") >= f["ingested_at_ns"])
                             & (pl.col("start_ns") < hi) & (pl.col("end_ns") > lo))
        if not _covers(fresh, lo, hi):
            spans.setdefault(f["site"], []).append(
                (lo // HOUR_NS * HOUR_NS, -(-hi // HOUR_NS) * HOUR_NS))
    return {name: _merged(windows) for name, windows in sorted(spans.items())}


def with_spans(by_site: dict[str, list[tuple[int, int]]],
               spans: list[tuple[str, int, int]]) -> dict[str, list[tuple[int, int]]]:
    """``by_site`` with the (site, start, end) ``spans`` added, cut out to whole UTC hours
    and merged per site; ascending."""
    out = {name: list(windows) for name, windows in by_site.items()}
    for name, lo, hi in spans:
        out.setdefault(name, []).append((lo // HOUR_NS * HOUR_NS, -(-hi // HOUR_NS) * HOUR_NS))
    return {name: _merged(windows) for name, windows in sorted(out.items())}


def stale_spans(warehouse: Path, cfg: Config) -> list[tuple[str, int, int]]:
    """(site, start, end) of the committed units batched with another config than
    ``cfg`` (:func:`pipeline.batch.provenance.stale_units`) that still own rows: a unit
    of a one-unit-per-window family without input rows in its span (planned no more,
    :func:`pipeline.batch.plan.unit_is_live`) is left out, as the batch ignores it."""
    stale = stale_units(warehouse, cfg)
    out = []
    live: dict[str, object] = {}
    for r in stale.iter_rows(named=True):
        fam = next((f for f in FAMILIES if f.name == r["family"]), None)
        if fam is not None and fam.unit_s is None:
            check = live.setdefault(r["site"], unit_is_live(warehouse, cfg, r["site"]))
            if not check(r["family"], r["start_ns"], r["end_ns"]):  # type: ignore[operator]
                continue
        out.append((r["site"], r["start_ns"], r["end_ns"]))
    return out


def _merged(spans: list[tuple[int, int]]) -> list[tuple[int, int]]:
    merged: list[tuple[int, int]] = []
    for a, b in sorted(spans):
        if merged and a <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], b))
        else:
            merged.append((a, b))
    return merged


def _covers(units: pl.DataFrame, lo: int, hi: int) -> bool:
    """True when the units' intervals cover [lo, hi)."""
    t = lo
    for a, b in sorted(zip(units["start_ns"].to_list(), units["end_ns"].to_list(),
                           strict=True)):
        if a > t:
            return False
        t = max(t, b)
        if t >= hi:
            return True
    return t >= hi
