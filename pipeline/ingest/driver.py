"""The ingest driver: MCAP archive files -> raw Delta tables, rejects, mcap_index, ledger.

The driver: expand the paths into one :class:`~pipeline.ingest.IngestUnit` per file, run
:func:`~pipeline.ingest.ingest_file` over them through an executor (serial, process pool,
Ray), commit each finished file's manifest (:func:`~pipeline.ingest.commit_file`: its
tables, its ``mcap_index`` rows, its ledger row last), and rebuild
``<warehouse>/surveil.duckdb`` once at the end. All of it inside one
:class:`~pipeline.ingest.IngestContext` (buffers, helper threads, DuckDB, allocator),
released when the run ends; a pool's worker processes make their own. What a worker
does, the ledger skip, the windows and the statuses: :mod:`pipeline.ingest`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from pipeline.config import Config
from pipeline.convert.config import import_options
from pipeline.decode.registry import RAW_TABLES
from pipeline.executors import Executor, UnitResult, make_executor
from pipeline.ingest import FileManifest, IngestContext, IngestSummary, commit_file, ingest_file
from pipeline.ingest.plan import IngestUsageError, check_sites, expand_paths, plan_units
from pipeline.signals import deferred_interrupts
from pipeline.tables import default_site
from pipeline.units import iso
from pipeline.warehouse.damage import DamagedTableError
from pipeline.warehouse.delta import require_readable
from pipeline.warehouse.ledger import LEDGER, same_content
from pipeline.warehouse.location import Location, as_location
from pipeline.warehouse.overlaps import record_overlaps, synthetic_time_channels
from pipeline.warehouse.views import rebuild_views_after_commits

log = logging.getLogger(__name__)

__all__ = ["IngestSummary", "IngestUsageError", "expand_paths", "run_ingest"]


def run_ingest(
    paths: Sequence[Path | str],
    cfg: Config,
    warehouse: Path | Location,
    *,
    start_ns: int | None = None,
    end_ns: int | None = None,
    force: bool = False,
    executor: Executor | str | None = None,
    on_result: Callable[[UnitResult], None] | None = None,
    site: str | None = None,
) -> IngestSummary:
    """Ingest MCAP files (directories expand to ``*.mcap``) into ``warehouse``.

    ``[start_ns, end_ns)``: optional window, both bounds or neither (ns, UTC).
    ``executor``: an :class:`Executor`, or a kind (``serial``/``process``/``ray``) sized
    by ``cfg.execution``; ``None`` uses ``cfg.execution`` entirely. ``on_result`` is
    called per finished unit (progress display). ``site``: the site of files whose MCAP
    metadata names none (default: ``default``). Raises :class:`IngestUsageError` for
    bad paths, a bad window, or a ``site`` a file's metadata contradicts.
    """
    if as_location(warehouse).is_local:
        warehouse = Path(warehouse).resolve()
    staging = as_location(warehouse) / "_staging" / f"ingest-{os.getpid()}-{time.time_ns()}"
    not_files: list[tuple[str, str]] = []
    units = plan_units(
        paths, warehouse=warehouse, staging=staging, validation=cfg.validation,
        start_ns=start_ns, end_ns=end_ns, force=force,
        asterix_editions=tuple(sorted(import_options(cfg).asterix_editions.items())),
        site=site, skipped=not_files,
    )  # fmt: skip
    check_sites(units)
    if units:  # every file's commit replaces its rows in each: exit 2 when a log is broken
        # (a missing data file is not read: `ingest --force` of its source replaces it)
        require_readable(warehouse, [*RAW_TABLES, "mcap_index", LEDGER], files=False)
    ex = _executor(executor, cfg, len(units))
    summary = IngestSummary(files_total=len(units), not_files=not_files)
    if start_ns is not None:
        summary.window = (start_ns, end_ns)  # type: ignore[assignment]
    committed = False
    seen: dict[str, str] = {}
    with IngestContext() as ctx:
        ctx.views.warm_up()  # the views file's DuckDB instance, built while files decode
        try:
            results = ex.map_units(ingest_file, units, context=ctx.for_workers())
            with contextlib.closing(results):  # an interrupt stops the pool at once
                for res in results:
                    with deferred_interrupts():  # a file's commit is whole or not begun
                        committed |= _handle(warehouse, res, summary, start_ns, end_ns, seen)
                    if on_result is not None:
                        on_result(res)
        finally:
            staging.rmtree()
            staging.parent.rmdir_if_empty()
        if committed:
            if start_ns is None:  # whole files: their mcap_index rows are new
                _warn_overlaps(warehouse, summary)
                _warn_synthetic(warehouse, summary)
            _warn_place(warehouse, cfg, summary)
            with deferred_interrupts():
                summary.views_error = rebuild_views_after_commits(warehouse, ctx.views)
    return summary


def _warn_overlaps(warehouse: Path, summary: IngestSummary) -> None:
    """Record and warn about other files carrying the same topics over the same times."""
    found = record_overlaps(warehouse, summary.committed_files)
    for r in found.iter_rows(named=True):
        text = (f"{r['source_file']} and {r['other_file']} both carry {r['topic']} over "
                f"[{iso(r['overlap_start_ns'])}, {iso(r['overlap_end_ns'])}]")
        summary.overlaps.append(text)
        log.warning("two sources overlap: %s", text)


def _warn_synthetic(warehouse: Path, summary: IngestSummary) -> None:
    """Warn about files whose rows have no time of the world (and how to give them one)."""
    for f, topic, source in synthetic_time_channels(warehouse, summary.committed_files):
        text = (f"{f}: {topic} has no time of its own ({source}): its rows are kept with "
                "synthetic times (1970-01-01, or --base-time's day, plus 1 ms per line or "
                "times of day on an unknown date) and take no part in overlap checks or the "
                "batch; import the recording again with `surveil import --base-time <UTC "
                "start or date>` and ingest that file")
        summary.time_warnings.append(text)
        log.warning("synthetic times: %s", text)


def _warn_place(warehouse: Path, cfg: Config, summary: IngestSummary) -> None:
    """Warn when most positions this ingest brought to a site lie outside the config's
    region (the batch will refuse them, :mod:`pipeline.batch.place`); nothing is lost."""
    if not summary.rows.get("ais_reports"):
        return  # no position this check measures (pipeline.batch.place.POSITION_TABLES)
    from pipeline.batch.place import files_place  # (the batch engine: imported when used)

    by_site: dict[str, list[str]] = {}
    for path, site in summary.file_sites.items():
        by_site.setdefault(site, []).append(path)
    for site, files in sorted(by_site.items()):
        place = files_place(warehouse, cfg, site, files)
        if place.refused:
            text = (f"{place.describe()}: batch will refuse them; {place.advice()} "
                    "(the rows are kept)")
            summary.place_warnings.append(text)
            log.warning("place check: %s", text)


def _executor(executor: Executor | str | None, cfg: Config, n_units: int) -> Executor:
    if executor is not None and not isinstance(executor, str):
        return executor
    ex = cfg.execution
    kind = executor or ex.executor
    workers = max(1, min(ex.max_workers, n_units))
    # fewer files than workers: the idle workers' thread budget goes to the busy ones
    threads = max(ex.threads_per_worker, ex.max_workers * ex.threads_per_worker // workers)
    return make_executor(kind, workers, threads)


def _as_duplicate(m: FileManifest, twin: str) -> FileManifest:
    """``m`` as a ``duplicate`` of ``twin``: no rows (its old rows, if any, are removed
    by the commit), a ledger row that names the file holding the same content."""
    return dataclasses.replace(
        m, status="duplicate", error=f"same content (sha256) as {twin}", staged={},
        rows=dict.fromkeys(m.rows, 0), rejects_by_reason={}, not_stored={},
    )  # fmt: skip


def _handle(
    warehouse: Path,
    res: UnitResult,
    summary: IngestSummary,
    start_ns: int | None,
    end_ns: int | None,
    seen: dict[str, str],
) -> bool:
    """Commit one finished unit; returns True when something was committed. ``seen``:
    SHA-256 -> path of the files this run ingested (a second copy is a duplicate)."""
    if not res.ok:
        summary.failed.append((res.unit.path, res.error or "unknown error"))
        return False
    m: FileManifest = res.value
    if m.skipped:
        summary.add(m)
        return False
    if m.changed_while_read:  # still being written: nothing of it committed
        summary.changed.append(m.source_file)
        return False
    staged = m.staged
    if start_ns is None and m.sha256 and m.status in ("ok", "partial"):
        twin = seen.get(m.sha256) or same_content(warehouse, m.sha256, m.source_file)
        if twin is not None and twin != m.source_file:  # ingested already, under its name
            m = _as_duplicate(m, twin)
        else:
            seen[m.sha256] = m.source_file
    try:
        commit_file(warehouse, m, start_ns=start_ns, end_ns=end_ns)
    except DamagedTableError:  # every file needs the table: exit 2 naming it
        raise
    except Exception as exc:  # the file stays re-runnable: its ledger row was not written
        summary.failed.append((m.source_file, f"commit failed: {type(exc).__name__}: {exc}"))
        return True
    finally:
        where = as_location(warehouse)
        for sf in (sf for files in staged.values() for sf in files):
            where.at(sf.path).unlink()  # still there only when the commit did not take it
    summary.add(m)
    summary.committed_files.append(m.source_file)
    summary.file_sites[m.source_file] = m.site or default_site()
    return True
