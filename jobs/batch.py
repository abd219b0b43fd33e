"""Batch job: every sensor family's derived tables for one time window.

A *batch family* (maritime radar + AIS here; own-ship navigation and airfield surface
surveillance plug in the same way) reads its inputs from the warehouse for a sub-window
and returns its derived tables. The window is cut into work units (family, sub-window:
one per UTC hour, or the whole window for families whose filters need continuity, when
their inputs hold rows in it); each
unit writes its outputs once, as the tables' final Parquet data files (sorted row groups,
Delta statistics) in a staging folder, and returns a small manifest (the files and the
family's unit seam). Only when every unit of the window has succeeded does the driver
join the units (a family's ``join_units`` over the seams; units whose ids must be
relabelled are rewritten by the workers) and commit: one Delta transaction per derived
table that removes the window's old files and adds the staged ones (a file that also
holds rows outside the window is rewritten without them), so no row passes through the
driver and its memory does not grow with the window. A failure or a crash before the
commit leaves the previous data of the window untouched.

**Units own rows.** Every committed unit is recorded in ``batch_units`` (family, start,
end). A batch whose window overlaps committed units is widened to cover them whole
(:func:`owned_window`, repeated until no unit straddles an edge), and each family's units
inside are cut as a single pass cuts them: at its unit grid and inside each grid cell
by that whole cell's volume (:func:`unit_cuts`), and, for a family without a grid (one
unit per window), at the edges of its committed units. So a reprocess of any
sub-window re-runs exactly the units that own it, with the same inputs, and replaces
their rows: an aggregate row keyed by its unit (``siap_by_sector``) is replaced, never
left beside a new one, and every table equals the single-pass result. A family with a
``join_units`` (system track ids stitched across seams) also joins the window's first
unit to the rows committed just before the window (``stitch_lookback_s``), so ids
continue across the window's leading edge as they do across unit seams. At the trailing
edge, the units committed after the window stitched their ids to the window's old last
rows: when the batch changed those rows (the family's ``unit_seam`` of the rows just
before the window's end differs), the next committed units are batched again, and so on
until a window ends as it ended before (:func:`run_batch`, ``BatchSummary.continued``).
That promise is written down before the window's commit (``_continue/``, with a digest
of the rows at its end as they were): a job killed between the commit and the end of
the chain leaves it there, and the next batch of the site runs the chain first.
One-unit-per-window families plan no unit where their inputs hold no row (the ``nav``
family in an archive without own-ship data), so they never own, nor widen a reprocess
to, a window they have nothing in; a unit recorded before this rule without input rows
is ignored (:func:`unit_is_live`).

**One commit for readers.** Families that read another family's output run in a later
wave (``family_waves``: gaps after maritime) and read this batch's staged rows of it
inside the window. The commits of a window sit between a pending marker and its removal
(``pipeline.warehouse.pending``): readers see every table of the window old or new.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import json
import logging
import os
import shutil
import time
from collections.abc import Callable, Iterator, Mapping, Sequence, Sized
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa

from pipeline import tables
from pipeline.config import Config
from pipeline.executors import UnitQueue, UnitResult, make_executor
from pipeline.families import FAMILIES, family
from pipeline.family import Family, Relabel, Window, relabel
from pipeline.signals import deferred_interrupts
from pipeline.units import NS
from pipeline.warehouse import pending
from pipeline.warehouse.crashpoints import crash_point
from pipeline.warehouse.delta import (
    read_table,
    replace_rows,
    replace_window,
    rows_per_second,
    sql_literal,
    volume_cuts,
)
from pipeline.warehouse.staged import StagedFile, TableStager, commit_window, read_staged
from pipeline.warehouse.views import rebuild_views_file, warm_up

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BatchUnit:
    """One picklable work unit: a family's sub-window, read and written by path."""

    warehouse: str
    staging_dir: str
    start_ns: int
    end_ns: int
    cfg: Config
    family: str = "maritime"
    # {table: staged Parquet files}: this batch's rows of another family's output for
    # the whole window, read instead of the warehouse's rows inside the window
    overrides: tuple[tuple[str, tuple[str, ...]], ...] = ()
    window: tuple[int, int] | None = None  # the batch window the overrides cover
    site: str | None = None  # the site whose rows the unit reads (and stamps on its outputs)


@dataclass
class BatchSummary:
    start_ns: int
    end_ns: int
    requested: tuple[int, int] | None = None  # the window asked for, when widened
    site: str | None = None
    units_total: int = 0
    failed_units: list[str] = field(default_factory=list)
    rows: dict[str, int] = field(default_factory=dict)
    rejects: int = 0
    committed: bool = False
    family_s: dict[str, float] = field(default_factory=dict)  # summed unit wall time
    commit_s: float = 0.0
    # the committed units after the window whose ids continued the window's old rows,
    # when the batch changed those rows: (start, end) to batch again
    next_window: tuple[int, int] | None = None
    # the batches of those units (ids continued across the trailing edge)
    continued: list[BatchSummary] = field(default_factory=list)
    continuation: Path | None = None  # its record (``_continue/``) until they are

    @property
    def exit_code(self) -> int:
        own = 0 if self.committed and not self.failed_units else 1
        return max([own, *(c.exit_code for c in self.continued)])

    def render(self) -> str:
        at = f"site {self.site}: " if self.site is not None else ""
        lines = [
            f"{at}batch window [{_iso(self.start_ns)}, {_iso(self.end_ns)}): "
            f"{self.units_total} unit(s), {len(self.failed_units)} failed, "
            f"{'committed' if self.committed else 'NOT committed (previous data kept)'}"
        ]
        if self.requested is not None:
            lines.append(f"  (asked for [{_iso(self.requested[0])}, {_iso(self.requested[1])}): "
                         "widened to the committed units it overlaps, re-run whole)")
        lines += [f"  {name:<16} {n:>9} rows" for name, n in self.rows.items()]
        if self.family_s:
            lines.append("  time: " + ", ".join(f"{fam} {s:.1f} s" for fam, s in
                                                 self.family_s.items())
                         + f" (summed over units); commit {self.commit_s:.1f} s")
        if self.rejects:
            lines.append(f"  rejects (batch)  {self.rejects:>9} rows")
        lines += [f"  failed: {u}" for u in self.failed_units]
        for c in self.continued:
            lines.append("  the rows at the window's end changed: the next committed units "
                         "batched again so their ids continue them")
            lines += ["  " + line for line in c.render().splitlines()]
        return "\n".join(lines)


def read_inputs(fam: Family, warehouse: Path, cfg: Config, window: Window,
                overrides: dict[str, tuple[str, ...]] | None = None,
                batch_window: tuple[int, int] | None = None,
                site: str | None = None) -> dict[str, pl.DataFrame]:
    """The tables ``fam``'s stage declares, each over its own span around ``window``. A
    table in ``overrides`` (another family's output of this same batch) is read from
    those files inside ``batch_window`` and from the warehouse outside it. ``site``: that
    site's rows only (the stage sees one site: its ids are unique)."""
    out = {}
    for spec in fam.inputs(cfg):
        columns = list(spec.columns) if spec.columns else None
        at = site if site is not None and tables.has_site(spec.table) else None
        if overrides and spec.table in overrides and batch_window is not None:
            lo, hi = (None, None) if spec.whole_table else spec.span_ns(window)
            out[spec.table] = _overridden(warehouse, spec.table, overrides[spec.table],
                                          batch_window, lo, hi, columns, at)
            continue
        if spec.whole_table:
            table = read_table(warehouse, spec.table, columns=columns, sort=spec.sorted,
                               site=at)
        else:
            lo, hi = spec.span_ns(window)
            table = read_table(warehouse, spec.table, start_ns=lo, end_ns=hi, columns=columns,
                               sort=spec.sorted, site=at)
        out[spec.table] = pl.from_arrow(table)
    return out


def _overridden(warehouse: Path, name: str, paths: tuple[str, ...], batch_window: tuple[int, int],
                lo: int | None, hi: int | None, columns: list[str] | None,
                site: str | None = None) -> pl.DataFrame:
    """Rows of ``name`` in [lo, hi): this batch's (``paths``: one site's) inside
    ``batch_window``, the warehouse's (of ``site``) outside it, sorted by the table's
    sort key."""
    w_lo, w_hi = batch_window
    time_col = tables.spec(name).time_column
    parts = []  # in time order: before the batch window, in it, after it
    if lo is None or lo < w_lo:  # the warehouse's rows before the batch window
        parts.append(pl.from_arrow(read_table(warehouse, name, start_ns=lo, end_ns=w_lo,
                                              columns=columns, site=site)))
    keep = pl.lit(True)
    if lo is not None:
        keep = keep & (pl.col(time_col) >= max(lo, w_lo))
    if hi is not None:
        keep = keep & (pl.col(time_col) < min(hi, w_hi))
    # the staged files of the whole batch, pruned by their row groups' time statistics:
    # an hourly unit of a day's batch reads its hour, not the day (was: read whole, 2+ GB)
    mine = (pl.scan_parquet(list(paths)).filter(keep).select(columns or pl.all()).collect()
            if paths else pl.from_arrow(tables.empty(name)).select(columns or pl.all()))
    parts.append(mine)
    if hi is None or hi > w_hi:  # and the warehouse's after it
        parts.append(pl.from_arrow(read_table(warehouse, name, start_ns=w_hi, end_ns=hi,
                                              columns=columns, site=site)))
    frame = pl.concat([p for p in parts if p.width], how="vertical_relaxed")
    keys = [k for k in tables.spec(name).sort_by if k in frame.columns]
    # the parts are in time order and each unit's files sorted by the key (a stage's
    # contract), so the rows usually are already: a sort would copy them all (a gaps
    # unit of a dense hour: ~0.85 GB more RSS for its 4 M system-track rows)
    return frame if not keys or is_sorted_by(frame, keys) else frame.sort(keys)


def is_sorted_by(frame: pl.DataFrame, keys: list[str]) -> bool:
    """Whether the rows are in ascending lexicographic order of ``keys`` (no nulls)."""
    if frame.height < 2:
        return True
    if frame.select(pl.any_horizontal(pl.col(keys).is_null().any())).item():
        return False
    later = pl.lit(False)  # the row is after the previous one on the keys seen so far
    tie = pl.lit(True)
    for k in keys:
        later = later | (tie & (pl.col(k) > pl.col(k).shift(1)))
        tie = tie & (pl.col(k) == pl.col(k).shift(1))
    return bool(frame.select((later | tie).slice(1).all()).item())


@dataclass(frozen=True)
class UnitManifest:
    """What a worker staged: {table: data files ready to commit} for one family's
    sub-window, and the family's ``unit_seam`` of it (a frame stays in the unit's
    folder: :class:`SeamFile`)."""

    family: str
    start_ns: int
    files: dict[str, list]  # IPC paths after the unit, StagedFile after finalize_unit
    seam: Any = None
    staging_dir: str = ""
    elapsed_s: float = 0.0  # the unit's wall time (read, compute, IPC)
    site: str | None = None  # stamped on the outputs when they are staged


def run_unit(unit: BatchUnit) -> UnitManifest:
    """Worker: read, compute, keep the outputs as Arrow IPC files (lz4: cheap to write and
    to read back) until the window's units are joined; return the manifest. The stage
    returns its frames sorted by the tables' sort keys (its contract)."""
    t0 = time.perf_counter()
    fam = family(unit.family)
    window = Window(unit.start_ns, unit.end_ns)
    inputs = read_inputs(fam, Path(unit.warehouse), unit.cfg, window, dict(unit.overrides),
                         unit.window, unit.site)
    out = fam.stage(inputs, window, unit.cfg)
    seam = fam.unit_seam(out) if fam.unit_seam is not None else None
    out = {name: frame for name, frame in out.items() if not name.startswith("_")}
    unknown = set(out) - set(fam.outputs) - {"rejects"}
    if unknown:
        raise ValueError(f"family {fam.name} returned tables it does not own: {unknown}")
    folder = Path(unit.staging_dir) / f"{unit.family}-{unit.start_ns}"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    if isinstance(seam, pl.DataFrame):
        seam = SeamFile.write(seam, folder / "_seam.arrow")
    files: dict[str, list[str]] = {}
    for name, frame in out.items():
        if frame.height:
            ordered = fam.sorted_outputs and name != "rejects"
            table = tables.shape(name, frame) if ordered else tables.conform(name, frame)
            path = folder / f"{name}.arrow"
            options = pa.ipc.IpcWriteOptions(compression="lz4")
            with pa.OSFile(str(path), "wb") as sink, pa.ipc.new_file(
                sink, table.schema, options=options
            ) as w:
                w.write_table(table)
            files[name] = [str(path)]
    return UnitManifest(unit.family, unit.start_ns, files, seam, str(folder),
                        time.perf_counter() - t0, unit.site)


@dataclass(frozen=True)
class SeamFile:
    """A unit's seam frame, kept in its staging folder until the window's units are
    joined. The driver holds a window's seams one pair at a time (:class:`_Seams`), not
    all of them: a region day has 260 maritime units of ~8 MB of seam rows each (was
    2 GB of the driver's memory)."""

    path: str

    @classmethod
    def write(cls, seam: pl.DataFrame, path: Path) -> SeamFile:
        seam.write_ipc(path, compression="lz4")
        return cls(str(path))

    def read(self) -> pl.DataFrame:
        return pl.read_ipc(self.path)


class _Seams(Sequence):
    """The seams given to a family's ``join_units``: a :class:`SeamFile` is read when
    its item is looked up (``join_units`` walks them in order)."""

    def __init__(self, items: list[Any]) -> None:
        self.items = items

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int) -> Any:  # type: ignore[override]
        item = self.items[i]
        return item.read() if isinstance(item, SeamFile) else item


@dataclass(frozen=True)
class FinalizeTask:
    """Write a unit's outputs as the tables' Parquet data files, a
    :data:`~pipeline.family.Relabel` applied first (``None``: as they are)."""

    manifest: UnitManifest
    mapping: Relabel | None


def finalize_unit(task: FinalizeTask) -> UnitManifest:
    """Worker: a unit's outputs (Arrow IPC) relabelled if its family's join asks for it
    and written once as final Parquet data files (``TableStager``: sorted row groups,
    Delta statistics); the manifest then lists those files."""
    m = task.manifest
    folder = Path(m.staging_dir + "-parquet")
    shutil.rmtree(folder, ignore_errors=True)
    stager = TableStager(folder, threaded=False, presorted=True,
                         site=m.site if m.site is not None else tables.default_site())
    for name, paths in m.files.items():
        for path in paths:
            with pa.memory_map(path) as source:
                table = pa.ipc.open_file(source).read_all()
            if task.mapping:
                table = tables.shape(name, relabel(pl.from_arrow(table), task.mapping))
            stager.add(name, table)
            del table
    files: dict[str, list[StagedFile]] = {}
    for f in stager.close():
        files.setdefault(f.table, []).append(f)
    shutil.rmtree(m.staging_dir, ignore_errors=True)
    return UnitManifest(m.family, m.start_ns, files, m.seam, str(folder), m.elapsed_s,
                        m.site)


def owned_window(warehouse: Path, start_ns: int, end_ns: int, site: str | None = None,
                 live: Callable[[str, int, int], bool] | None = None
                 ) -> tuple[int, int, dict[str, list[int]]]:
    """``[start_ns, end_ns)`` widened until no committed unit (``batch_units``, of
    ``site`` when given) of any family straddles its edges, and per family the edges of
    its committed units inside the widened window: (start, end, {family: cuts}).

    ``live(family, start, end)``: False for a committed unit that owns no rows now (a
    one-unit-per-window family's unit without input rows, as batches recorded before
    such units were skipped): it neither widens the window nor cuts it."""
    units = pl.from_arrow(read_table(warehouse, "batch_units",
                                     columns=["family", "start_ns", "end_ns"], site=site))
    dead: set[tuple[str, int, int]] = set()
    lo, hi = start_ns, end_ns
    while True:
        touched = units.filter((pl.col("start_ns") < hi) & (pl.col("end_ns") > lo))
        if live is not None:
            dead |= {u for u in touched.iter_rows() if u not in dead and not live(*u)}
            touched = touched.filter(~_keyed(touched, dead))
        if touched.height == 0:
            break
        new_lo = min(lo, int(touched["start_ns"].min()))
        new_hi = max(hi, int(touched["end_ns"].max()))
        if (new_lo, new_hi) == (lo, hi):
            break
        lo, hi = new_lo, new_hi
    inside = units.filter((pl.col("start_ns") >= lo) & (pl.col("end_ns") <= hi))
    inside = inside.filter(~_keyed(inside, dead))
    cuts: dict[str, list[int]] = {}
    for (name,), rows in inside.group_by(["family"]):
        edges = set(rows["start_ns"].to_list()) | set(rows["end_ns"].to_list())
        cuts[str(name)] = sorted(t for t in edges if lo < t < hi)
    return lo, hi, cuts


def _keyed(units: pl.DataFrame, keys: set[tuple[str, int, int]]) -> pl.Series:
    """Which rows of ``units`` (family, start_ns, end_ns) are in ``keys``."""
    return pl.Series([u in keys for u in units.iter_rows()], dtype=pl.Boolean)


def has_input_rows(warehouse: Path, fam: Family, cfg: Config, start_ns: int, end_ns: int,
                   site: str | None = None, derived: frozenset[str] = frozenset()) -> bool:
    """True when one of ``fam``'s input tables (``whole_table`` ones aside) holds a row
    of ``site`` in ``[start_ns, end_ns)``, or when it reads one of ``derived`` (another
    family's output, maybe written by this same batch: not known before it runs). Reads
    the time column of the window only (partitions and row groups pruned)."""
    for spec in fam.inputs(cfg):
        if spec.whole_table:
            continue
        if spec.table in derived:
            return True
        at = site if site is not None and tables.has_site(spec.table) else None
        time_col = tables.spec(spec.table).time_column
        if read_table(warehouse, spec.table, start_ns=start_ns, end_ns=end_ns,
                      columns=[time_col], sort=False, site=at).num_rows:
            return True
    return False


def unit_is_live(warehouse: Path, cfg: Config, site: str | None = None
                 ) -> Callable[[str, int, int], bool]:
    """``owned_window``'s ``live``: a committed unit of a one-unit-per-window family owns
    rows only while its inputs hold rows in its span (:func:`plan_units` plans no such
    unit otherwise); every other unit (and one of a family no longer registered) does."""
    owners = {f.name: f for f in FAMILIES}
    derived = frozenset(n for f in FAMILIES for n in f.outputs)

    def live(name: str, start_ns: int, end_ns: int) -> bool:
        fam = owners.get(name)
        return (fam is None or fam.unit_s is not None
                or has_input_rows(warehouse, fam, cfg, start_ns, end_ns, site, derived))

    return live


def plan_units(
    warehouse: Path, cfg: Config, start_ns: int, end_ns: int, staging_dir: Path,
    families: tuple[Family, ...] = FAMILIES,
    committed_cuts: dict[str, list[int]] | None = None,
    site: str | None = None,
) -> list[BatchUnit]:
    """Cut [start_ns, end_ns) into each family's work units (:func:`unit_cuts`). A
    family with one unit per window plans none where its inputs hold no row
    (:func:`has_input_rows`): a unit it does not need would own, and a reprocess of any
    part of it would re-run, the whole window."""
    derived = frozenset(n for f in FAMILIES for n in f.outputs)
    units = []
    for fam in families:
        kept = (committed_cuts or {}).get(fam.name, [])
        cuts = unit_cuts(warehouse, fam, start_ns, end_ns, kept, site)
        pieces = [(a, b) for a, b in itertools.pairwise(cuts) if b > a]
        if fam.unit_s is None:
            pieces = [(a, b) for a, b in pieces
                      if has_input_rows(warehouse, fam, cfg, a, b, site, derived)]
        units += [BatchUnit(str(warehouse), str(staging_dir), a, b, cfg, fam.name, site=site)
                  for a, b in pieces]
    return units


def unit_cuts(warehouse: Path, fam: Family, start_ns: int, end_ns: int,
              kept: list[int], site: str | None = None) -> list[int]:
    """``fam``'s unit edges in [start_ns, end_ns), both ends included.

    A family with a ``unit_s`` grid is cut at its UTC multiples, and, with ``unit_rows``,
    inside each grid cell wherever the rows of its ``unit_table`` in the *whole cell*
    call for it (:func:`volume_cuts`, on whole seconds). So the cuts are a function of
    the cell's rows and the config, not of the window asked for nor of the files that
    hold the rows: a day batched at once, hour by hour or reprocessed over any
    sub-window (widened to the committed units it touches) is cut at the same times and
    its units see the same inputs. A family without a grid (one unit per window) is
    cut at ``kept``, the edges of its committed units (:func:`owned_window`), and by
    volume over the window."""
    if fam.unit_s is None:
        cuts = {start_ns, end_ns, *kept}
        cells = [(start_ns, end_ns)]
    else:
        step = fam.unit_s * NS
        cells = [(t, t + step) for t in range(start_ns // step * step, end_ns, step)]
        cuts = {start_ns, end_ns, *(a for a, _ in cells if a > start_ns)}
    if fam.unit_rows is not None and fam.unit_table:
        for a, b in cells:  # one cell's time column at a time
            per_s = rows_per_second(warehouse, fam.unit_table, a, b, site)
            cuts |= {c for c in volume_cuts(per_s, a, fam.unit_rows) if start_ns < c < end_ns}
    return sorted(cuts)


@dataclass
class SitesSummary:
    """A batch over several sites: one :class:`BatchSummary` per site, each reported
    apart (a site's rows, units and failures are its own)."""

    by_site: dict[str, BatchSummary]
    asked_start_ns: int
    asked_end_ns: int
    # chains a killed job left undone (``_continue/``), run before the window
    resumed: list[BatchSummary] = field(default_factory=list)

    @property
    def start_ns(self) -> int:
        """Start of the window batched (widened to committed units), earliest site's."""
        return min((b.start_ns for b in self.by_site.values()), default=self.asked_start_ns)

    @property
    def end_ns(self) -> int:
        return max((b.end_ns for b in self.by_site.values()), default=self.asked_end_ns)

    @property
    def requested(self) -> tuple[int, int] | None:
        """The window asked for, when some site's was widened."""
        widened = any(b.requested is not None for b in self.by_site.values())
        return (self.asked_start_ns, self.asked_end_ns) if widened else None

    @property
    def rejects(self) -> int:
        return sum(b.rejects for b in self.by_site.values())

    @property
    def committed(self) -> bool:
        return all(b.committed for b in self.by_site.values())

    @property
    def failed_units(self) -> list[str]:
        return [f"site {s}: {u}" for s, b in self.by_site.items() for u in b.failed_units]

    @property
    def units_total(self) -> int:
        return sum(b.units_total for b in self.by_site.values())

    @property
    def rows(self) -> dict[str, int]:
        """Rows written per table, all sites (for run records; reports stay per site),
        continued and resumed batches included."""
        out: dict[str, int] = {}
        todo = [*self.by_site.values(), *self.resumed]
        while todo:
            b = todo.pop()
            todo += b.continued
            for name, n in b.rows.items():
                out[name] = out.get(name, 0) + n
        return out

    @property
    def exit_code(self) -> int:
        return max((b.exit_code for b in [*self.by_site.values(), *self.resumed]),
                   default=0)

    def render(self) -> str:
        lines = []
        for r in self.resumed:
            lines.append(f"site {r.site}: a killed job left the units after "
                         f"{_iso(r.end_ns)} to batch again (the rows they continue changed)")
            lines += ["  " + line for c in r.continued for line in c.render().splitlines()]
        if not self.by_site and not self.resumed:
            lines.append(f"batch window [{_iso(self.asked_start_ns)}, "
                         f"{_iso(self.asked_end_ns)}): no site has data in it; nothing written")
        return "\n".join([*lines, *(b.render() for b in self.by_site.values())])


def sites_in(warehouse: Path, start_ns: int, end_ns: int) -> list[str]:
    """The sites the ingest ledger knows files of (ok or partial) overlapping
    ``[start_ns, end_ns)``, sorted."""
    ledger = pl.from_arrow(read_table(warehouse, "ingest_ledger", columns=[
        "site", "status", "start_time_ns", "end_time_ns"]))
    hit = ledger.filter(pl.col("status").is_in(["ok", "partial"])
                        & (pl.col("start_time_ns") < end_ns)
                        & (pl.col("end_time_ns") >= start_ns))
    return sorted(hit["site"].unique().to_list())


def run_batch(
    cfg: Config,
    warehouse: Path,
    *,
    start_ns: int,
    end_ns: int,
    executor_kind: str | None = None,
    families: tuple[str, ...] | None = None,
    progress: Any = None,
    site: str | None = None,
    resume: bool = True,
) -> SitesSummary:
    """Run the batch for [start_ns, end_ns), site by site, and commit each site's window
    atomically per table.

    ``site``: that site only (its rows are read, replaced and recorded; other sites' rows
    are untouched); default: every site the ledger knows data of in the window, each
    batched alone (its own units, ids, commit). ``families``: names of the families to
    run (default: every registered family); ``progress``: the CLI's
    :class:`~jobs.progress.TerminalProgress` (or None). ``resume``: first run the chains
    killed jobs left (:func:`resume_continuations`); False for a caller that just did
    (``surveil run``: a chain that failed there is not tried again in the same job)."""
    if end_ns <= start_ns:
        raise ValueError("--to must be after --from")
    sites = [site] if site is not None else sites_in(warehouse, start_ns, end_ns)
    out = SitesSummary({}, start_ns, end_ns)
    for name in sites:
        if resume:  # a killed job's chain first
            out.resumed += resume_continuations(cfg, warehouse, site=name,
                                                executor_kind=executor_kind, progress=progress)
        summary = _run_site(cfg, warehouse, start_ns=start_ns, end_ns=end_ns,
                            executor_kind=executor_kind, families=families,
                            progress=progress, site=name)
        out.by_site[name] = summary
        _continue(cfg, warehouse, summary, executor_kind, progress)
    with deferred_interrupts():
        rebuild_views_file(warehouse)
    return out


def resume_continuations(cfg: Config, warehouse: Path, *, site: str | None = None,
                         executor_kind: str | None = None, progress: Any = None
                         ) -> list[BatchSummary]:
    """Run the chains killed jobs left undone (``_continue/``: the rows at a window's
    end changed, the units after it not batched again yet), of ``site`` or of every
    site; one summary per record (its ``continued`` batches)."""
    out = []
    for left in _left_continuations(warehouse, site):
        first = BatchSummary(left.end_ns, left.end_ns, site=left.site, committed=True,
                             next_window=_units_after(warehouse, left.families,
                                                      left.end_ns, left.site))
        _continue(cfg, warehouse, first, executor_kind, progress)
        if first.exit_code == 0:
            _drop(left.path)
        out.append(first)
    return out


def _continue(cfg: Config, warehouse: Path, summary: BatchSummary,
              executor_kind: str | None, progress: Any) -> None:
    """Batch again the units after ``summary``'s window while the rows they continue
    changed (a chain: each batch may change the rows the next units continue); each
    link's continuation record is removed once the link after it committed."""
    while summary.next_window is not None and summary.exit_code == 0:
        nxt = _run_site(cfg, warehouse, start_ns=summary.next_window[0],
                        end_ns=summary.next_window[1], executor_kind=executor_kind,
                        families=None, progress=progress, site=summary.site)
        summary.continued.append(nxt)
        if nxt.committed and summary.continuation is not None:
            _drop(summary.continuation)
        summary = nxt


def _run_site(
    cfg: Config,
    warehouse: Path,
    *,
    start_ns: int,
    end_ns: int,
    executor_kind: str | None,
    families: tuple[str, ...] | None,
    progress: Any,
    site: str,
) -> BatchSummary:
    """One site's batch of [start_ns, end_ns) (widened to its committed units)."""
    fams = FAMILIES if families is None else tuple(family(name) for name in families)
    warm_up(warehouse)  # the views file's DuckDB instance, built while the batch runs
    requested = (start_ns, end_ns)
    start_ns, end_ns, committed_cuts = owned_window(
        warehouse, start_ns, end_ns, site, unit_is_live(warehouse, cfg, site))
    staging = warehouse / "_staging" / f"batch-{_safe(site)}-{start_ns}-{end_ns}"
    shutil.rmtree(staging, ignore_errors=True)
    units = plan_units(warehouse, cfg, start_ns, end_ns, staging, fams, committed_cuts, site)
    edge_before = _trailing_digests(warehouse, fams, end_ns, site)
    summary = BatchSummary(start_ns=start_ns, end_ns=end_ns, units_total=len(units),
                           requested=None if requested == (start_ns, end_ns) else requested,
                           site=site)
    ex = cfg.execution
    kind, workers = executor_kind or ex.executor, min(ex.max_workers, len(units))
    executor = make_executor(kind, workers, ex.threads_per_worker)
    manifests: list[UnitManifest] = []
    if progress is not None:
        progress.batch_units(len(units))
    try:
        with executor:  # one pool for the units and their finalisation
            for wave in family_waves(fams, cfg):
                # a family reading another family's output reads this batch's rows of it
                # (its units' files in time order: the rows then need no sort)
                in_time = sorted(manifests, key=lambda m: m.start_ns)
                overrides = tuple(
                    (name, tuple(f.path for m in in_time for f in m.files.get(name, [])))
                    for fam in fams if fam.name in {m.family for m in manifests}
                    for name in fam.outputs)
                names = {f.name for f in wave}
                ours = granted([replace(u, overrides=overrides, window=(start_ns, end_ns))
                                for u in units if u.family in names], kind, workers)
                manifests += _run_units(executor, ours, tuple(wave), summary, progress,
                                        warehouse)
                if summary.failed_units:
                    break
    except BaseException:  # interrupted: the pool is stopped, nothing was committed
        shutil.rmtree(staging, ignore_errors=True)
        raise
    if summary.failed_units:
        shutil.rmtree(staging, ignore_errors=True)
        return summary
    t0 = time.perf_counter()
    record = _promise_continuation(warehouse, site, end_ns, edge_before)
    with deferred_interrupts():  # the window's commit is whole or not begun
        _commit(warehouse, manifests, summary, fams, units)
    summary.commit_s = time.perf_counter() - t0
    crash_point("batch.continuation")
    edge_after = _trailing_digests(warehouse, fams, end_ns, site)
    changed = [name for name, digest in edge_after.items() if digest != edge_before.get(name)]
    summary.next_window = _units_after(warehouse, changed, end_ns, site)
    if summary.next_window is None:
        _drop(record)
    else:
        summary.continuation = record
    shutil.rmtree(staging, ignore_errors=True)
    with contextlib.suppress(OSError):  # only when empty: another job may be staging
        (warehouse / "_staging").rmdir()
    return summary


def granted(units: list[BatchUnit], kind: str, workers: int) -> list[BatchUnit]:
    """The units of a wave with the cores it leaves idle: a wave of fewer units than the
    process pool's workers (a reprocessed hour's one gaps unit after its maritime wave)
    gives each unit ``workers // len(units)`` times its ``threads_per_worker``, for a
    stage that runs its own threads (gaps). Not for Ray, whose tasks ask for one CPU."""
    if kind != "process" or not units or len(units) >= workers:
        return units
    share = workers // len(units)
    return [replace(u, cfg=replace(u.cfg, execution=replace(
        u.cfg.execution, threads_per_worker=u.cfg.execution.threads_per_worker * share)))
        for u in units]


def _safe(site: str) -> str:
    """A site as a folder name part (any site name is a valid string, not a path)."""
    return hashlib.sha256(site.encode()).hexdigest()[:12]


def _run_units(executor, units: list[BatchUnit], fams: tuple[Family, ...],
               summary: BatchSummary, progress: Any = None,
               warehouse: Path | None = None) -> list[UnitManifest]:
    """Run a wave's units, and write each unit's outputs as Parquet data files in the same
    pool as soon as it and its family's units before it are done (:class:`_Joiner`: its
    relabelling is known then). The workers so write the early units' files while the
    last units still compute, instead of after them all. Returns the finalised
    manifests (none of a failed wave)."""
    starts = {f.name: [u.start_ns for u in units if u.family == f.name] for f in fams}
    joiners = {f.name: _Joiner(f, starts[f.name], summary, warehouse) for f in fams}
    queue = UnitQueue(units)
    out: list[UnitManifest] = []
    for result in executor.map_units(batch_task, queue):
        if isinstance(result.unit, FinalizeTask):
            _finalized(result, out, summary)
            continue
        if progress is not None:
            progress.batch_result(result)
        if result.ok:
            m = result.value
            summary.family_s[m.family] = summary.family_s.get(m.family, 0.0) + m.elapsed_s
            if not summary.failed_units:  # a failed wave commits nothing: write nothing
                queue.add(joiners[m.family].ready(m))
        else:
            u = result.unit
            label = f"{u.family} [{_iso(u.start_ns)}, {_iso(u.end_ns)}): {result.error}"
            summary.failed_units.append(label)
            log.error("batch unit failed %s", label)
    return [] if summary.failed_units else out


def batch_task(task: BatchUnit | FinalizeTask) -> UnitManifest:
    """Worker: a batch unit (:func:`run_unit`) or a unit's finalisation
    (:func:`finalize_unit`), the two kinds of task of a wave's one map."""
    return finalize_unit(task) if isinstance(task, FinalizeTask) else run_unit(task)


def _finalized(result: UnitResult, out: list[UnitManifest], summary: BatchSummary) -> None:
    if result.ok:
        out.append(result.value)
    else:
        m = result.unit.manifest
        summary.failed_units.append(f"{m.family} {_iso(m.start_ns)} write: {result.error}")


def family_waves(families: tuple[Family, ...], cfg: Config) -> list[list[Family]]:
    """The families in waves: a family that reads another family's output (gaps reads
    maritime's system_tracks) runs in a wave after it, on this batch's rows of it."""
    owner = {name: f.name for f in families for name in f.outputs}
    needs = {f.name: {owner[i.table] for i in f.inputs(cfg) if i.table in owner} - {f.name}
             for f in families}
    waves: list[list[Family]] = []
    done: set[str] = set()
    while len(done) < len(families):
        wave = [f for f in families if f.name not in done and needs[f.name] <= done]
        if not wave:
            raise ValueError(f"families read each other's outputs in a cycle: {needs}")
        waves.append(wave)
        done |= {f.name for f in wave}
    return waves


class _StoredOutputs(Mapping[str, pl.DataFrame]):
    """A family's committed outputs in ``[start_ns, end_ns)``, each table read from the
    warehouse when first looked up (the maritime seam reads one of eight tables)."""

    def __init__(self, warehouse: Path, names: tuple[str, ...], start_ns: int,
                 end_ns: int, site: str | None = None,
                 columns: Mapping[str, tuple[str, ...]] | None = None) -> None:
        self._warehouse, self._names, self._site = warehouse, names, site
        self._window = (start_ns, end_ns)
        self._columns = dict(columns or {})
        self._read: dict[str, pl.DataFrame] = {}

    def __getitem__(self, name: str) -> pl.DataFrame:
        if name not in self._names:
            raise KeyError(name)
        if name not in self._read:
            lo, hi = self._window
            cols = self._columns.get(name)
            self._read[name] = pl.from_arrow(read_table(
                self._warehouse, name, start_ns=lo, end_ns=hi, site=self._site,
                columns=list(cols) if cols else None))
        return self._read[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)


def _stored_before(warehouse: Path, fam: Family, start_ns: int, site: str | None = None
                   ) -> Mapping[str, pl.DataFrame]:
    """``fam``'s committed outputs (of ``site``) in the ``stitch_lookback_s`` before
    ``start_ns``: the unit before the window as its ``join_units`` sees a unit (a
    pseudo-unit); tables are read when the family's ``unit_seam`` looks them up."""
    lo = start_ns - round(fam.stitch_lookback_s * NS)
    return _StoredOutputs(warehouse, tuple(fam.outputs), lo, start_ns, site, fam.seam_columns)


def _trailing_seams(warehouse: Path, fams: tuple[Family, ...], end_ns: int,
                    site: str | None) -> dict[str, Any]:
    """Per family with a ``join_units``, the ``unit_seam`` of its committed rows just
    before ``end_ns``: what the units after ``end_ns`` continued."""
    return {fam.name: fam.unit_seam(_stored_before(warehouse, fam, end_ns, site))
            for fam in fams
            if fam.join_units is not None and fam.unit_seam is not None
            and fam.stitch_lookback_s}


def _trailing_digests(warehouse: Path, fams: tuple[Family, ...], end_ns: int,
                      site: str | None) -> dict[str, str]:
    """:func:`_seam_digest` of each :func:`_trailing_seams`."""
    return {name: _seam_digest(seam)
            for name, seam in _trailing_seams(warehouse, fams, end_ns, site).items()}


def _seam_digest(seam: Any) -> str:
    """sha256 of a seam's rows (a frame in any row order, or any value's repr)."""
    if isinstance(seam, pl.DataFrame):
        text = seam.sort(seam.columns).write_csv() if seam.height else ",".join(seam.columns)
    else:
        text = repr(seam)
    return hashlib.sha256(text.encode()).hexdigest()


CONTINUE_DIR = "_continue"


@dataclass(frozen=True)
class _Continuation:
    """A continuation record left by a killed job (``_continue/``)."""

    path: Path
    site: str
    end_ns: int
    families: list[str]


def _promise_continuation(warehouse: Path, site: str | None, end_ns: int,
                          digests: dict[str, str]) -> Path:
    """Record, before a window's commit, the digests of the rows at its end (atomic
    write): if the job dies before the units after it are batched again, the next batch
    finds the rows changed and does it (:func:`_left_continuations`)."""
    folder = warehouse / CONTINUE_DIR
    folder.mkdir(exist_ok=True)
    doc = {"site": site, "end_ns": end_ns, "digests": digests}
    path = folder / f"{_safe(site or '')}-{end_ns}-{time.time_ns()}.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(doc))
    os.replace(tmp, path)
    return path


def _left_continuations(warehouse: Path, site: str | None) -> list[_Continuation]:
    """The continuation records (of ``site``, or all) left by killed jobs whose window's
    end changed (those whose rows did not change, a job killed before its commit, are
    removed)."""
    out = []
    for path in sorted((warehouse / CONTINUE_DIR).glob("*.json")):
        try:
            doc = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if site is not None and doc.get("site") != site:
            continue
        fams = tuple(family(n) for n in doc["digests"])
        now = _trailing_digests(warehouse, fams, doc["end_ns"], doc["site"])
        changed = [n for n, d in doc["digests"].items() if now.get(n) != d]
        if changed:
            out.append(_Continuation(path, doc["site"], doc["end_ns"], changed))
        else:
            _drop(path)
    return out


def _drop(record: Path) -> None:
    """Remove a continuation record (and its folder once empty)."""
    record.unlink(missing_ok=True)
    with contextlib.suppress(OSError):
        record.parent.rmdir()


def _units_after(warehouse: Path, families: list[str], end_ns: int, site: str | None
                 ) -> tuple[int, int] | None:
    """[end_ns, end) of ``families``' committed units that start at ``end_ns`` (None:
    none)."""
    if not families:
        return None
    units = pl.from_arrow(read_table(warehouse, "batch_units",
                                     columns=["family", "start_ns", "end_ns"], site=site))
    after = units.filter(pl.col("family").is_in(families) & (pl.col("start_ns") == end_ns))
    return (end_ns, int(after["end_ns"].max())) if after.height else None


def _has_rows(seam: Any) -> bool:
    """A seam with rows (a frame or any sized value; anything else counts as rows)."""
    return len(seam) > 0 if isinstance(seam, Sized) else seam is not None


class _Joiner:
    """A family's units of a wave joined in time order as they finish (``join_units``):
    :meth:`ready` takes a finished unit and gives the :class:`FinalizeTask` of every unit
    that is now joined (it and the units after it that waited on it).

    The join is a chain: a unit's relabelling depends on the units before it only through
    the seam of the unit just before, relabelled. So the join of ``[seam of the last
    joined unit, relabelled; seams of the units now done]`` gives the units now done the
    relabelling the join of every seam at once gives them. The chain is led by the seam
    of the rows committed just before the window (``stitch_lookback_s``)."""

    def __init__(self, fam: Family, starts: list[int], summary: BatchSummary,
                 warehouse: Path | None) -> None:
        self.fam, self.summary, self.warehouse = fam, summary, warehouse
        self.order = sorted(starts)
        self.joined = 0
        self.waiting: dict[int, UnitManifest] = {}
        self.last_seam: Any = None  # the seam the next unit continues (None: none)

    def ready(self, m: UnitManifest) -> list[FinalizeTask]:
        self.waiting[m.start_ns] = m
        now: list[UnitManifest] = []
        while self.joined < len(self.order) and self.order[self.joined] in self.waiting:
            now.append(self.waiting.pop(self.order[self.joined]))
            self.joined += 1
        if not now or self.fam.join_units is None:
            return [FinalizeTask(u, None) for u in now]
        if self.joined == len(now):  # the first units of the window
            self.last_seam = self._lead()
        seams = [s for s in (self.last_seam,) if s is not None] + [u.seam for u in now]
        lead = len(seams) - len(now)
        maps = (self.fam.join_units(_Seams(seams))[lead:] if len(seams) > 1
                else [None] * len(now))
        self.last_seam = _relabelled_seam(now[-1].seam, maps[-1])
        return [FinalizeTask(u, mapping) for u, mapping in zip(now, maps, strict=True)]

    def _lead(self) -> Any:
        """The seam of the rows committed before the window, None when there are none."""
        fam = self.fam
        if fam.unit_seam is None or not fam.stitch_lookback_s or self.warehouse is None:
            return None
        seam = fam.unit_seam(_stored_before(self.warehouse, fam, self.summary.start_ns,
                                            self.summary.site))
        return seam if _has_rows(seam) else None


def _relabelled_seam(seam: Any, mapping: Relabel | None) -> Any:
    """A unit's seam with its relabelling applied. A :class:`SeamFile` is read now: the
    unit's finalisation, sent next, removes its staging folder."""
    frame = seam.read() if isinstance(seam, SeamFile) else seam
    if not mapping:
        return frame
    if not isinstance(frame, pl.DataFrame):
        raise TypeError(f"a seam to relabel must be a frame, not {type(frame).__name__}")
    return relabel(frame, mapping)


def _commit(warehouse: Path, manifests: list[UnitManifest], summary: BatchSummary,
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
    rejects = read_staged("rejects", staged) if staged else tables.empty("rejects")
    of_site = f"site = {sql_literal(site)} AND " if site is not None else ""
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
    crash_point("batch.rejects")
    if units is not None:
        _record_units(warehouse, units, summary)
        crash_point("batch.batch_units")
    lo, hi = summary.start_ns, summary.end_ns
    pending.finish(warehouse, marker, supersedes=lambda doc: doc.get("job") == "batch"
                   and doc.get("site") in (None, site)
                   and lo <= doc["window"][0] and doc["window"][1] <= hi)
    summary.committed = True


def _record_units(warehouse: Path, units: list[BatchUnit], summary: BatchSummary) -> None:
    """The window's units replace those of ``batch_units`` inside it (one commit)."""
    now = time.time_ns()
    rows = pl.DataFrame(
        {"start_ns": [u.start_ns for u in units], "end_ns": [u.end_ns for u in units],
         "family": [u.family for u in units]},
        schema={"start_ns": pl.Int64, "end_ns": pl.Int64, "family": pl.String},
    ).with_columns(window_start_ns=pl.lit(summary.start_ns, pl.Int64),
                   window_end_ns=pl.lit(summary.end_ns, pl.Int64),
                   committed_at_ns=pl.lit(now, pl.Int64))
    site = summary.site if summary.site is not None else tables.default_site()
    replace_window(warehouse, "batch_units", tables.conform("batch_units", rows, site=site),
                   start_ns=summary.start_ns, end_ns=summary.end_ns, site=site)


def _iso(t_ns: int) -> str:
    return str(np.datetime64(int(t_ns), "ns").astype("datetime64[s]")) + "Z"
