"""Ingest job: MCAP archive files -> raw Delta tables, rejects, mcap_index and the ledger.

The driver: expand the paths into one :class:`~pipeline.ingest.IngestUnit` per file, run
:func:`~pipeline.ingest.ingest_file` over them through an executor (serial, process pool,
Ray), commit each finished file's manifest (:func:`~pipeline.ingest.commit_file`: its
tables, its ``mcap_index`` rows, its ledger row last), and rebuild
``<warehouse>/surveil.duckdb`` once at the end. What a worker does, the ledger skip,
the windows and the statuses: :mod:`pipeline.ingest`.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

from jobs.common import UsageError, keep_freed_memory
from pipeline.config import Config
from pipeline.executors import Executor, UnitResult, make_executor
from pipeline.ingest import FileManifest, IngestSummary, IngestUnit, commit_file, ingest_file
from pipeline.tables import table_specs
from pipeline.warehouse.views import rebuild_views_file, warm_up

__all__ = ["IngestSummary", "IngestUsageError", "expand_paths", "run_ingest"]

# the table schemas (schemas/*.toml, ~16 ms of TOML) are parsed with the imports, once per
# process: otherwise the first file's run waits for them before it reads anything
table_specs()
# this process (a job's driver, or a worker that imports this module to ingest) keeps
# freed memory for reuse: see keep_freed_memory
keep_freed_memory()


class IngestUsageError(UsageError):
    """Bad input paths (missing path, directory without MCAP files) or window: exit 2."""


def expand_paths(paths: Iterable[Path | str]) -> list[Path]:
    """Absolute file paths: directories expand to their ``*.mcap`` files (recursive,
    sorted); an explicit file is taken as given. Raises :class:`IngestUsageError` for a
    missing path, a directory without MCAP files, or no paths at all."""
    out: list[Path] = []
    for raw in paths:
        p = Path(raw).expanduser()
        if not p.exists():
            raise IngestUsageError(f"input path does not exist: {p}")
        if p.is_dir():
            found = sorted(q for q in p.rglob("*.mcap") if q.is_file())
            if not found:
                raise IngestUsageError(f"no *.mcap files under directory: {p}")
            out.extend(found)
        else:
            out.append(p)
    if not out:
        raise IngestUsageError("no input paths given")
    return list(dict.fromkeys(q.resolve() for q in out))


def run_ingest(
    paths: Sequence[Path | str],
    cfg: Config,
    warehouse: Path,
    *,
    start_ns: int | None = None,
    end_ns: int | None = None,
    force: bool = False,
    executor: Executor | str | None = None,
    on_result: Callable[[UnitResult], None] | None = None,
) -> IngestSummary:
    """Ingest MCAP files (directories expand to ``*.mcap``) into ``warehouse``.

    ``[start_ns, end_ns)``: optional window, both bounds or neither (ns, UTC).
    ``executor``: an :class:`Executor`, or a kind (``serial``/``process``/``ray``) sized
    by ``cfg.execution``; ``None`` uses ``cfg.execution`` entirely. ``on_result`` is
    called per finished unit (progress display). Raises :class:`IngestUsageError` for
    bad paths or a bad window.
    """
    if (start_ns is None) != (end_ns is None):
        raise IngestUsageError("give both start and end of the window, or neither")
    if start_ns is not None and end_ns <= start_ns:  # type: ignore[operator]
        raise IngestUsageError(f"empty window [{start_ns}, {end_ns})")
    files = expand_paths(paths)
    warm_up()  # the views file's DuckDB instance, built while the files are decoded
    warehouse = Path(warehouse).resolve()
    staging = warehouse / "_staging" / f"ingest-{os.getpid()}-{time.time_ns()}"
    ex = _executor(executor, cfg, len(files))
    units = [
        IngestUnit(str(f), str(warehouse), str(staging), cfg.validation, start_ns, end_ns, force)
        for f in files
    ]
    summary = IngestSummary(files_total=len(units))
    if start_ns is not None:
        summary.window = (start_ns, end_ns)  # type: ignore[assignment]
    committed = False
    try:
        for res in ex.map_units(ingest_file, units):
            committed |= _handle(warehouse, res, summary, start_ns, end_ns)
            if on_result is not None:
                on_result(res)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        with contextlib.suppress(OSError):
            (warehouse / "_staging").rmdir()
    if committed:
        rebuild_views_file(warehouse)
    return summary


def _executor(executor: Executor | str | None, cfg: Config, n_units: int) -> Executor:
    if executor is not None and not isinstance(executor, str):
        return executor
    ex = cfg.execution
    kind = executor or ex.executor
    workers = max(1, min(ex.max_workers, n_units))
    # fewer files than workers: the idle workers' thread budget goes to the busy ones
    threads = max(ex.threads_per_worker, ex.max_workers * ex.threads_per_worker // workers)
    return make_executor(kind, workers, threads)


def _handle(
    warehouse: Path,
    res: UnitResult,
    summary: IngestSummary,
    start_ns: int | None,
    end_ns: int | None,
) -> bool:
    """Commit one finished unit; returns True when something was committed."""
    if not res.ok:
        summary.failed.append((res.unit.path, res.error or "unknown error"))
        return False
    m: FileManifest = res.value
    if m.skipped:
        summary.add(m)
        return False
    try:
        commit_file(warehouse, m, start_ns=start_ns, end_ns=end_ns)
    except Exception as exc:  # the file stays re-runnable: its ledger row was not written
        summary.failed.append((m.source_file, f"commit failed: {type(exc).__name__}: {exc}"))
        return True
    finally:
        for sf in (sf for files in m.staged.values() for sf in files):
            with contextlib.suppress(OSError):
                os.remove(sf.path)  # still there only when the commit did not take it
    summary.add(m)
    return True
