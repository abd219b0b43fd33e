"""Ingest job: MCAP archive files -> raw Delta tables, rejects, mcap_index and the ledger.

One work unit per source file (:class:`IngestUnit`, small and picklable). A worker streams
the file: the reader yields chunk by chunk (``pipeline.io.mcap_read``: chunk index walk,
decompression in a background thread, no Python object per message), the decoder turns
batches into Arrow rows (radar/truth JSON in bulk parses of ~50k messages), and
:class:`~pipeline.warehouse.staged.TableStager` appends those rows to staged Parquet files,
one per (table, date), as they come. Memory holds a few chunks and row groups, not the
file. Meanwhile a thread computes the file's SHA-256 (whole-file runs only). The worker
returns a small :class:`FileManifest`.

The DRIVER then commits, per file: every raw table (``RAW_TABLES``) with
:func:`~pipeline.warehouse.staged.commit_staged`, ONE Delta commit per table that removes
the file's old data files and adds the staged ones (also when the file has no rows for a
table, so a changed file leaves no stale rows; a table with nothing to add or remove is
not touched), then the file's ``mcap_index`` rows, and the ledger row LAST. A crash in
between leaves a ledger without the new hash, so the next run redoes the file.
``<warehouse>/surveil.duckdb`` is rebuilt once at the end.

Ledger: a file whose size and SHA-256 match its ledger row (status ok/partial) is skipped
without any commit, unless ``force``, or unless an optional decoder was missing when it was
read (error "decoder not installed": it may be installed now). Status: ``ok``;
``partial`` (chunks lost, file cut off, channels whose decoder is not installed);
``quarantined`` (not MCAP, or nothing readable: one rejects row says why).

Time window ``[start_ns, end_ns)``: rows are kept when the table's time column is inside
(``time_ns``; ``log_time_ns`` for rejects) and the replace predicate is source_file AND
window (``replace_source_file``), so the file's rows outside the window stay. Only the
chunks whose index overlaps the window (widened by ``WINDOW_READ_MARGIN_NS`` of log time
on each side, so that a report whose own time is in the window but was logged just outside
it is not lost) are read; a file whose summary lies wholly outside is read no further
than its footer and summary, and is not hashed. File-level rejects (not_mcap,
corrupt_chunk, truncated, unknown_schema) are clipped into the window. A windowed run
neither skips by the ledger nor writes it (nor ``mcap_index``): those describe whole-file
ingests.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from jobs.common import UsageError, keep_freed_memory
from pipeline.config import Config, ValidationConfig
from pipeline.convert.config import import_options
from pipeline.decode.registry import RAW_TABLES, FileDecoder, make_rejects
from pipeline.executors import Executor, UnitResult, make_executor
from pipeline.io.mcap_index import mcap_index_rows
from pipeline.io.mcap_read import ReadStatus, read_mcap_batches
from pipeline.tables import conform, empty, spec, table_specs
from pipeline.threads import HASHER_NICE, helper_pool
from pipeline.warehouse.delta import replace_source_file
from pipeline.warehouse.ledger import file_fingerprint, ledger_entry, lookup, write_entry
from pipeline.warehouse.staged import StagedFile, TableStager, commit_staged, read_staged
from pipeline.warehouse.views import rebuild_views_file, warm_up

# the table schemas (schemas/*.toml, ~16 ms of TOML) are parsed with the imports, once per
# process: otherwise the first file's run waits for them before it reads anything
table_specs()
# this process (a job's driver, or a worker that imports this module to ingest) keeps
# freed memory for reuse: see keep_freed_memory
keep_freed_memory()

WINDOW_READ_MARGIN_NS = 60 * 10**9
FILE_LEVEL_CODES = frozenset({"not_mcap", "corrupt_chunk", "truncated", "unknown_schema"})
_MAGIC_SAMPLE = 64  # bytes of a not-MCAP file kept in its rejects row
MISSING_DECODER = "decoder not installed"


class IngestUsageError(UsageError):
    """Bad input paths (missing path, directory without MCAP files) or window: exit 2."""


@dataclass(frozen=True)
class IngestUnit:
    """One source file to ingest (picklable; carries paths, not data)."""

    path: str
    warehouse: str
    staging_dir: str
    validation: ValidationConfig
    start_ns: int | None = None
    end_ns: int | None = None
    force: bool = False
    asterix_editions: tuple[tuple[int, str], ...] = ()  # config [asterix] editions

    @property
    def windowed(self) -> bool:
        return self.start_ns is not None


@dataclass(frozen=True)
class FileManifest:
    """What a worker made of one file: counts, status, the staged Parquet files per table,
    the file's ``mcap_index`` rows (whole-file runs), and what was read (``bytes_read``,
    ``chunks_decompressed``)."""

    source_file: str
    size_bytes: int
    sha256: str
    skipped: bool = False
    status: str = "ok"
    error: str | None = None
    message_count: int = 0
    rows: dict[str, int] = field(default_factory=dict)
    rejects_by_reason: dict[str, int] = field(default_factory=dict)
    not_stored: dict[str, int] = field(default_factory=dict)
    start_time_ns: int | None = None
    end_time_ns: int | None = None
    staged: dict[str, list[StagedFile]] = field(default_factory=dict)
    index_rows: pa.Table | None = None
    bytes_read: int = 0
    chunks_decompressed: int = 0


@dataclass
class IngestSummary:
    """Counts of one ingest run; ``exit_code`` 0 when every file is ok or skipped."""

    files_total: int = 0
    files_ok: int = 0
    files_partial: int = 0
    files_quarantined: int = 0
    files_skipped: int = 0
    messages_read: int = 0
    rows: dict[str, int] = field(default_factory=lambda: dict.fromkeys(RAW_TABLES, 0))
    rejects: dict[str, int] = field(default_factory=dict)
    not_stored: dict[str, int] = field(default_factory=dict)
    failed: list[tuple[str, str]] = field(default_factory=list)
    window: tuple[int, int] | None = None

    @property
    def exit_code(self) -> int:
        """0: all files ok or skipped; 1: some file partial/quarantined or a unit failed."""
        bad = self.files_partial or self.files_quarantined or self.failed
        return 1 if bad else 0

    def add(self, m: FileManifest) -> None:
        if m.skipped:
            self.files_skipped += 1
            return
        self.files_ok += m.status == "ok"
        self.files_partial += m.status == "partial"
        self.files_quarantined += m.status == "quarantined"
        self.messages_read += m.message_count
        for k, v in m.rows.items():
            self.rows[k] = self.rows.get(k, 0) + v
        _merge(self.rejects, m.rejects_by_reason)
        _merge(self.not_stored, m.not_stored)

    def render(self) -> str:
        """One screen of text for the CLI."""
        lines = [
            f"ingest: {self.files_total} files: {self.files_ok} ok, {self.files_partial} "
            f"partial, {self.files_quarantined} quarantined, {self.files_skipped} skipped "
            f"(unchanged), {len(self.failed)} failed; {self.messages_read} messages read"
        ]
        if self.window:
            lines.append(f"window: [{self.window[0]}, {self.window[1]}) ns")
        lines.append("rows:    " + _fmt(self.rows))
        lines.append("rejects: " + (_fmt(self.rejects) or "none"))
        if self.not_stored:
            lines.append("valid, not stored (by type): " + _fmt(self.not_stored))
        if self.rejects.get("decoder_missing"):
            lines.append("WARNING: ASTERIX channels not decoded: the ASTERIX decoder is not "
                         "installed; pip install 'surveil-pipeline[asterix]'")  # fmt: skip
        for path, err in self.failed[:10]:
            lines.append(f"FAILED {path}: {err}")
        if len(self.failed) > 10:
            lines.append(f"... and {len(self.failed) - 10} more failed units")
        lines.append(f"exit code {self.exit_code}")
        return "\n".join(lines)


def _merge(into: dict[str, int], counts: dict[str, int]) -> None:
    for k, v in counts.items():
        into[k] = into.get(k, 0) + v


def _fmt(counts: dict[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))


# -- inputs ------------------------------------------------------------------------------


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


# -- worker ------------------------------------------------------------------------------


def ingest_file(unit: IngestUnit) -> FileManifest:
    """Decode one file and stage its rows (runs in a worker; commits nothing)."""
    path = Path(unit.path)
    size = path.stat().st_size
    sha: str | Future[str] = ""
    hasher = None
    if not unit.windowed:  # a windowed run never uses the hash: do not read the whole file
        prior = None if unit.force else lookup(unit.warehouse, unit.path)
        if (
            prior is not None
            and prior["status"] in ("ok", "partial")
            and prior["size_bytes"] == size
            and MISSING_DECODER not in (prior["error"] or "")  # a decoder may be there now
        ):
            sha = file_fingerprint(path)[1]
            if sha == prior["sha256"]:
                return FileManifest(unit.path, size, sha, skipped=True)
        else:  # hash while decoding (hashlib releases the GIL)
            hasher = helper_pool(1, "sha256", HASHER_NICE)
            sha = hasher.submit(lambda: file_fingerprint(path)[1])
    try:
        return _decode_and_stage(unit, path, size, sha)
    finally:
        if hasher is not None:
            hasher.shutdown(wait=True)


def _decode_and_stage(
    unit: IngestUnit, path: Path, size: int, sha: str | Future[str]
) -> FileManifest:
    lo, hi = _read_window(unit)
    scan = read_mcap_batches(path, start_ns=lo, end_ns=hi)
    decoder = FileDecoder(source_file=unit.path, validation=unit.validation,
                          asterix_editions=dict(unit.asterix_editions))  # fmt: skip
    stager = TableStager(_stage_folder(unit))
    reasons: Counter = Counter()

    def stage(name: str, table: pa.Table) -> None:
        if unit.windowed:
            table = _in_window(name, table, unit.start_ns, unit.end_ns)  # type: ignore[arg-type]
        if name == "rejects" and table.num_rows:
            reasons.update(table["reason_code"].to_pylist())
        stager.add(name, table)

    try:
        for batch in scan:
            decoder.feed(batch, scan.chunks_left)
            for name, parts in decoder.drain().items():
                for part in parts:
                    stage(name, part)
        decoder.add_rejects(_status_rejects(unit, scan.status))
        for name, table in decoder.finish().items():
            stage(name, table)
    finally:
        staged = stager.close()
    by_table: dict[str, list[StagedFile]] = {}
    for sf in staged:
        by_table.setdefault(sf.table, []).append(sf)
    status = scan.status
    index = None
    if not unit.windowed:
        index = mcap_index_rows(unit.path, size, scan.summary, scan.channels, status,
                                decoder.not_stored_by_channel)  # fmt: skip
    file_status, error = status.status, status.error
    if decoder.missing_decoders:  # partly read: exit 1, and read again once installed
        missing = f"{MISSING_DECODER}: {', '.join(sorted(decoder.missing_decoders))}"
        file_status = "partial" if file_status == "ok" else file_status
        error = missing if error is None else f"{error}; {missing}"
    return FileManifest(
        source_file=unit.path,
        size_bytes=size,
        sha256=sha if isinstance(sha, str) else sha.result(),
        status=file_status,
        error=error,
        message_count=status.messages_read,
        rows={n: stager.rows.get(n, 0) for n in (*RAW_TABLES, *stager.rows)},
        rejects_by_reason=dict(reasons),
        not_stored=dict(sorted(decoder.not_stored.items())),
        start_time_ns=status.start_time_ns,
        end_time_ns=status.end_time_ns,
        staged=by_table,
        index_rows=index,
        bytes_read=status.bytes_read,
        chunks_decompressed=status.chunks_decompressed,
    )


def _stage_folder(unit: IngestUnit) -> Path:
    """``<staging>/<hash of path>``: deterministic per source file."""
    return Path(unit.staging_dir) / hashlib.sha256(unit.path.encode()).hexdigest()[:24]


def _read_window(unit: IngestUnit) -> tuple[int | None, int | None]:
    if not unit.windowed:
        return None, None
    return unit.start_ns - WINDOW_READ_MARGIN_NS, unit.end_ns + WINDOW_READ_MARGIN_NS


def _status_rejects(unit: IngestUnit, status: ReadStatus) -> pa.Table:
    """One rejects row per problem the reader reported (not MCAP, lost chunk, cut-off)."""
    if not status.problems:
        return empty("rejects")
    raw: list[bytes | None] = []
    for p in status.problems:
        if p.reason_code == "not_mcap":
            with open(unit.path, "rb") as f:
                raw.append(f.read(_MAGIC_SAMPLE))
        else:
            raw.append(None)
    reasons = []
    for p in status.problems:
        lost = "" if p.messages_lost is None else f" ({p.messages_lost} messages lost)"
        reasons.append(p.detail + lost)
    return make_rejects(
        [p.log_time_ns or 0 for p in status.problems],
        source_file=unit.path,
        topic=None,
        reason_code=[p.reason_code for p in status.problems],
        reason=reasons,
        raw=raw,
    )


def _in_window(name: str, table: pa.Table, start_ns: int, end_ns: int) -> pa.Table:
    """Rows of ``table`` whose time column is in ``[start_ns, end_ns)``; file-level
    rejects are first clipped into the window so that they are kept."""
    col = spec(name).time_column
    if name == "rejects" and table.num_rows:
        t = table[col].to_numpy(zero_copy_only=False)
        file_level = np.isin(
            table["reason_code"].to_numpy(zero_copy_only=False), list(FILE_LEVEL_CODES)
        )
        clipped = np.where(file_level, np.clip(t, start_ns, end_ns - 1), t)
        table = conform(
            name,
            table.set_column(table.column_names.index(col), col, pa.array(clipped, pa.int64())),
        )
    t = table[col]
    keep = pc.and_(pc.greater_equal(t, start_ns), pc.less(t, end_ns))
    return table.filter(keep)


# -- driver ------------------------------------------------------------------------------


def commit_file(
    warehouse: Path, m: FileManifest, *, start_ns: int | None = None, end_ns: int | None = None
) -> None:
    """Replace the file's rows in every raw table (one commit per table that changes),
    then (whole-file runs) its ``mcap_index`` rows and its ledger row."""
    for name in dict.fromkeys((*RAW_TABLES, *m.staged)):
        staged = m.staged.get(name, [])
        if start_ns is None:
            commit_staged(warehouse, name, staged, source_file=m.source_file)
        else:
            replace_source_file(
                warehouse,
                name,
                read_staged(name, staged),
                source_file=m.source_file,
                start_ns=start_ns,
                end_ns=end_ns,
            )
    if start_ns is None:
        index = m.index_rows if m.index_rows is not None else empty("mcap_index")
        replace_source_file(warehouse, "mcap_index", index, source_file=m.source_file)
        entry = ledger_entry(
            m.source_file,
            size_bytes=m.size_bytes,
            sha256=m.sha256,
            status=m.status,
            error=m.error,
            message_count=m.message_count,
            rows={n: m.rows.get(n, 0) for n in RAW_TABLES if n != "rejects"},
            rejects_count=m.rows.get("rejects", 0),
            start_time_ns=m.start_time_ns,
            end_time_ns=m.end_time_ns,
            not_stored=m.not_stored,
        )
        write_entry(warehouse, entry)


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
    editions = tuple(sorted(import_options(cfg).asterix_editions.items()))
    units = [
        IngestUnit(
            str(f), str(warehouse), str(staging), cfg.validation, start_ns, end_ns, force,
            editions,
        )
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
