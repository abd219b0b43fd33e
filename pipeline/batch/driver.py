"""The batch driver: a window, site by site, planned, run, joined, committed, continued.

:func:`run_batch` batches ``[start_ns, end_ns)`` of every site with data in it (or one),
each site alone (its own units, ids and commit). For one site (:func:`run_site`): the
window widened to the committed units it overlaps (:mod:`~pipeline.batch.plan`), its
units run wave by wave through an executor (serial, process pool, Ray) and finalised as
they are joined (:mod:`~pipeline.batch.worker`, :mod:`~pipeline.batch.seams`), the
window committed once (:mod:`~pipeline.batch.commit`), then the units after it batched
again while the rows they continue changed (:mod:`~pipeline.batch.continuation`). A
failure or a crash before the commit leaves the previous data of the window untouched;
failed units are listed (exit code 1) so a re-run retries them.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from pipeline.batch.commit import commit_batch
from pipeline.batch.continuation import (
    drop_record,
    left_continuations,
    promise_continuation,
    units_after,
)
from pipeline.batch.place import check_places
from pipeline.batch.plan import (
    family_waves,
    granted,
    owned_window,
    plan_units,
    safe_name,
    unit_is_live,
)
from pipeline.batch.scope import batch_scope
from pipeline.batch.seams import Joiner, trailing_digests
from pipeline.batch.summary import BatchSummary, SitesSummary, iso_s
from pipeline.batch.worker import BatchUnit, FinalizeTask, UnitManifest, batch_task
from pipeline.config import Config
from pipeline.executors import UnitQueue, UnitResult, make_executor
from pipeline.families import FAMILIES, family
from pipeline.family import Family
from pipeline.signals import deferred_interrupts
from pipeline.warehouse.crashpoints import crash_point
from pipeline.warehouse.delta import require_readable, shared_handles
from pipeline.warehouse.location import as_location
from pipeline.warehouse.sites import sites_in
from pipeline.warehouse.views import rebuild_views_after_commits, rebuild_views_file, warm_up

log = logging.getLogger(__name__)


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
    ignore_place: bool = False,
) -> SitesSummary:
    """Run the batch for [start_ns, end_ns), site by site, and commit each site's window
    atomically per table.

    ``site``: that site only (its rows are read, replaced and recorded; other sites' rows
    are untouched); default: every site the ledger knows data of in the window, each
    batched alone (its own units, ids, commit). ``families``: names of the families to
    run (default: every registered family); ``progress``: the CLI's
    :class:`~jobs.progress.TerminalProgress` (or None). ``resume``: first run the chains
    killed jobs left (:func:`resume_continuations`); False for a caller that just did
    (``surveil run``: a chain that failed there is not tried again in the same job).
    Before any work, every site's positions are checked against the config's region
    (:func:`~pipeline.batch.place.check_places`: :class:`PlaceError`, exit 2, when most
    lie outside it), unless ``ignore_place``. A damaged table the batch reads or writes
    stops it before any work (:class:`~pipeline.warehouse.damage.DamagedTableError`,
    exit 2)."""
    if end_ns <= start_ns:
        raise ValueError("--to must be after --from")
    with shared_handles():  # each table's log read once per version
        return _run_batch(cfg, warehouse, start_ns, end_ns, executor_kind, families,
                          progress, site, resume, ignore_place)


def _run_batch(cfg: Config, warehouse: Path, start_ns: int, end_ns: int,
               executor_kind: str | None, families: tuple[str, ...] | None, progress: Any,
               site: str | None, resume: bool, ignore_place: bool) -> SitesSummary:
    fams = FAMILIES if families is None else tuple(family(name) for name in families)
    require_readable(warehouse, [*(i.table for f in fams for i in f.inputs(cfg)),
                                 *(n for f in fams for n in f.outputs),
                                 "rejects", "batch_units", "ingest_ledger"])
    sites = [site] if site is not None else sites_in(warehouse, start_ns, end_ns)
    if not ignore_place:
        check_places(warehouse, cfg, sites, start_ns, end_ns)
    out = SitesSummary({}, start_ns, end_ns)
    for name in sites:
        if resume:  # a killed job's chain first
            out.resumed += resume_continuations(cfg, warehouse, site=name,
                                                executor_kind=executor_kind, progress=progress)
        summary = run_site(cfg, warehouse, start_ns=start_ns, end_ns=end_ns,
                            executor_kind=executor_kind, families=families,
                            progress=progress, site=name)
        out.by_site[name] = summary
        _continue(cfg, warehouse, summary, executor_kind, progress)
    with deferred_interrupts():
        out.views_error = rebuild_views_after_commits(warehouse)
    return out


def resume_continuations(cfg: Config, warehouse: Path, *, site: str | None = None,
                         executor_kind: str | None = None, progress: Any = None
                         ) -> list[BatchSummary]:
    """Run the chains killed jobs left undone (``_continue/``: the rows at a window's
    end changed, the units after it not batched again yet), of ``site`` or of every
    site; one summary per record (its ``continued`` batches)."""
    out = []
    for left in left_continuations(warehouse, site):
        first = BatchSummary(left.end_ns, left.end_ns, site=left.site, committed=True,
                             next_window=units_after(warehouse, left.families,
                                                      left.end_ns, left.site))
        _continue(cfg, warehouse, first, executor_kind, progress)
        if first.exit_code == 0:
            drop_record(left.path)
        out.append(first)
    return out


def _continue(cfg: Config, warehouse: Path, summary: BatchSummary,
              executor_kind: str | None, progress: Any) -> None:
    """Batch again the units after ``summary``'s window while the rows they continue
    changed (a chain: each batch may change the rows the next units continue); each
    link's continuation record is removed once the link after it committed."""
    while summary.next_window is not None and summary.exit_code == 0:
        nxt = run_site(cfg, warehouse, start_ns=summary.next_window[0],
                        end_ns=summary.next_window[1], executor_kind=executor_kind,
                        families=None, progress=progress, site=summary.site)
        summary.continued.append(nxt)
        if nxt.committed and summary.continuation is not None:
            drop_record(summary.continuation)
        summary = nxt


def run_site(
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
    staging = as_location(warehouse) / "_staging" / f"batch-{safe_name(site)}-{start_ns}-{end_ns}"
    staging.rmtree()
    scope = batch_scope(warehouse, cfg, fams, start_ns, end_ns, site)
    # a skipped family plans no unit; its tables are still committed (empty) for the window
    units = plan_units(warehouse, cfg, start_ns, end_ns, staging,
                       tuple(f for f in fams if f.name in scope.run), committed_cuts, site)
    # no committed unit starts at the window's end (the batch in time order): nothing
    # continues its last rows, so neither their digests nor a promise are needed
    continued = units_after(warehouse, [f.name for f in fams], end_ns, site) is not None
    edge_before = trailing_digests(warehouse, fams, end_ns, site) if continued else {}
    summary = BatchSummary(start_ns=start_ns, end_ns=end_ns, units_total=len(units),
                           requested=None if requested == (start_ns, end_ns) else requested,
                           site=site, notes=list(scope.notes))
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
        staging.rmtree()
        raise
    if summary.failed_units:
        staging.rmtree()
        return summary
    t0 = time.perf_counter()
    record = promise_continuation(warehouse, site, end_ns, edge_before) if continued else None
    with deferred_interrupts():  # the window's commit is whole or not begun
        commit_batch(warehouse, manifests, summary, fams, units)
    summary.commit_s = time.perf_counter() - t0
    crash_point("batch.continuation")
    if record is not None:
        edge_after = trailing_digests(warehouse, fams, end_ns, site)
        changed = [name for name, digest in edge_after.items()
                   if digest != edge_before.get(name)]
        summary.next_window = units_after(warehouse, changed, end_ns, site)
        if summary.next_window is None:
            drop_record(record)
        else:
            summary.continuation = record
    staging.rmtree()
    staging.parent.rmdir_if_empty()  # only when empty: another job may be staging
    return summary


def retire_window(cfg: Config, warehouse: Path, *, site: str, start_ns: int, end_ns: int
                  ) -> BatchSummary:
    """Remove ``site``'s rows of every derived table, its batch rejects and its units
    (``batch_units``) in ``[start_ns, end_ns)`` widened to the committed units it
    overlaps: a site left without data there (its files now name another site: a
    half-written file read before its site metadata was) owns no rows there. One commit
    per table, as a batch's (:func:`~pipeline.batch.commit.commit_batch` of no unit)."""
    with shared_handles():
        start_ns, end_ns, _ = owned_window(warehouse, start_ns, end_ns, site,
                                           unit_is_live(warehouse, cfg, site))
        summary = BatchSummary(start_ns=start_ns, end_ns=end_ns, site=site)
        with deferred_interrupts():
            commit_batch(warehouse, [], summary, FAMILIES, [])
        with deferred_interrupts():
            rebuild_views_file(warehouse)
    return summary


def _run_units(executor, units: list[BatchUnit], fams: tuple[Family, ...],
               summary: BatchSummary, progress: Any = None,
               warehouse: Path | None = None) -> list[UnitManifest]:
    """Run a wave's units, and write each unit's outputs as Parquet data files in the same
    pool as soon as it and its family's units before it are done (:class:`Joiner`: its
    relabelling is known then). The workers so write the early units' files while the
    last units still compute, instead of after them all. Returns the finalised
    manifests (none of a failed wave)."""
    starts = {f.name: [u.start_ns for u in units if u.family == f.name] for f in fams}
    joiners = {f.name: Joiner(f, starts[f.name], summary, warehouse) for f in fams}
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
            label = f"{u.family} [{iso_s(u.start_ns)}, {iso_s(u.end_ns)}): {result.error}"
            summary.failed_units.append(label)
            log.error("batch unit failed %s", label)
    return [] if summary.failed_units else out


def _finalized(result: UnitResult, out: list[UnitManifest], summary: BatchSummary) -> None:
    if result.ok:
        out.append(result.value)
    else:
        m = result.unit.manifest
        summary.failed_units.append(f"{m.family} {iso_s(m.start_ns)} write: {result.error}")
