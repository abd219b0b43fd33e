"""The ingest worker: one MCAP file -> staged Parquet per table and a :class:`FileManifest`.

:func:`ingest_file` runs in a worker (in the driver's process, a pool process or a Ray
task) and commits nothing: the driver commits the manifest (:mod:`pipeline.ingest.commit`).
It streams the file: the reader yields chunk by chunk (``pipeline.io.mcap_read``: chunk
index walk, decompression in a background thread, no Python object per message), the
decoder turns batches into Arrow rows (radar/truth JSON in bulk parses of up to 100k
messages), and :class:`~pipeline.warehouse.staged.TableStager` appends those rows to
staged Parquet files, one per (table, date), as they come. Memory holds a few chunks and
row groups, not the file. Meanwhile a thread computes the file's SHA-256 (whole-file runs
only).

Ledger: a file whose size and SHA-256 match its ledger row (status ok/duplicate) is skipped
(``FileManifest.skipped``), unless ``force``, or unless an optional decoder was missing
when it was read (error "decoder not installed": it may be installed now); it is hashed
first, before any decoding. Status: ``ok``; ``partial`` (chunks lost, file cut off,
channels whose decoder is not installed); ``quarantined`` (not MCAP, nothing
readable, or a ``site`` in its metadata that is not a site name: one rejects row says
why, ``invalid_site`` for the last; nothing of such a file is read, the other files of
the run are not affected).

Time window ``[start_ns, end_ns)``: rows are kept when the table's time column is inside
(``time_ns``; ``log_time_ns`` for rejects). Only the chunks whose index overlaps the
window (widened by ``WINDOW_READ_MARGIN_NS`` of log time on each side, so that a report
whose own time is in the window but was logged just outside it is not lost) are read; a
file whose summary lies wholly outside is read no further than its footer and summary,
and is not hashed. File-level rejects (not_mcap, corrupt_chunk, truncated,
unknown_schema) are clipped into the window.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import tempfile
from collections import Counter
from collections.abc import Iterator
from concurrent.futures import Future, wait
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pipeline.config import ValidationConfig
from pipeline.decode.registry import RAW_TABLES, FileDecoder, make_rejects
from pipeline.ingest.context import IngestContext
from pipeline.io.mcap_index import mcap_index_rows
from pipeline.io.mcap_read import ReadStatus, read_mcap_batches
from pipeline.io.mcap_site import declared_site
from pipeline.tables import SITE_NAME_RULE, conform, default_site, empty, is_site_name, spec
from pipeline.warehouse.ledger import SKIP_STATUSES, file_fingerprint, lookup
from pipeline.warehouse.location import Location, as_location
from pipeline.warehouse.staged import StagedFile, TableStager

WINDOW_READ_MARGIN_NS = 60 * 10**9
FILE_LEVEL_CODES = frozenset({"not_mcap", "corrupt_chunk", "truncated", "unknown_schema",
                              "invalid_site"})
_MAGIC_SAMPLE = 64  # bytes of a not-MCAP file kept in its rejects row
MISSING_DECODER = "decoder not installed"


@dataclass(frozen=True)
class IngestUnit:
    """One source file to ingest (picklable; carries paths and locations, not data)."""

    path: str
    warehouse: str | Location
    staging_dir: str | Location
    validation: ValidationConfig
    start_ns: int | None = None
    end_ns: int | None = None
    force: bool = False
    asterix_editions: tuple[tuple[int, str], ...] = ()  # config [asterix] editions
    site: str | None = None  # `surveil ingest --site`: for files whose metadata names none

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
    site: str = ""  # the site stamped on every row of the file
    # the file's size or mtime changed while it was read (still being written): nothing
    # of it is committed; a later run reads it again (issue 40)
    changed_while_read: bool = False


class InvalidSiteError(ValueError):
    """A file's metadata names a site that is not a site name (``[/]``, a path, 65
    characters...): the file is refused, as ``--site`` would refuse the name."""


def file_site(unit: IngestUnit, path: Path | None = None) -> str:
    """The file's site: its MCAP metadata's (:mod:`pipeline.io.mcap_site`), else the
    command's ``--site``, else the default (``schemas/tables.toml [site]``). The driver
    refuses an explicit ``--site`` that contradicts a file's metadata before any work.
    ``path``: where the file's bytes are read (its local copy). :class:`InvalidSiteError`
    when the metadata's site is not a site name (:data:`pipeline.tables.SITE_NAME`)."""
    named = declared_site(path or unit.path)
    if named is not None and not is_site_name(named):
        raise InvalidSiteError(f"its metadata names site {named!r}: {SITE_NAME_RULE}; "
                               "nothing of the file was read")
    return named or unit.site or default_site()


@contextlib.contextmanager
def local_copy(unit: IngestUnit) -> Iterator[Path]:
    """The unit's file as a local path: itself, or for an archive on object storage
    (``s3://``, reached with the warehouse's storage options) a copy in this worker's
    temporary folder, removed afterwards. The file is read whole (decoded, hashed), so
    one download costs what the reads would."""
    source = as_location(unit.warehouse).at(unit.path)
    if source.is_local:
        yield Path(unit.path)
        return
    fd, tmp = tempfile.mkstemp(prefix="surveil-", suffix=".mcap")
    try:
        with os.fdopen(fd, "wb") as out, source.fs.open_input_stream(source.fs_path) as src:
            shutil.copyfileobj(src, out, 8 << 20)
        yield Path(tmp)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


def ingest_file(unit: IngestUnit, ctx: IngestContext) -> FileManifest:
    """Decode one file and stage its rows (runs in a worker; commits nothing). ``ctx``:
    the worker process's context (entered), whose buffers and threads it uses."""
    with local_copy(unit) as path:
        return _ingest(unit, ctx, path)


def _ingest(unit: IngestUnit, ctx: IngestContext, path: Path) -> FileManifest:
    before = path.stat()
    size = before.st_size
    sha: str | Future[str] = ""
    if not unit.windowed:  # a windowed run never uses the hash: do not read the whole file
        prior = None if unit.force else lookup(unit.warehouse, unit.path)
        if (
            prior is not None
            and prior["status"] in SKIP_STATUSES  # partial: read again, it may be whole now
            and prior["size_bytes"] == size
            and MISSING_DECODER not in (prior["error"] or "")  # a decoder may be there now
        ):
            sha = file_fingerprint(path)[1]
            if sha == prior["sha256"]:
                return FileManifest(unit.path, size, sha, skipped=True)
        else:  # hash while decoding (hashlib releases the GIL)
            sha = ctx.hasher.submit(lambda: file_fingerprint(path)[1])  # type: ignore[union-attr]
    try:
        m = _decode_and_stage(unit, ctx, path, size, sha)
    finally:
        if isinstance(sha, Future) and not sha.cancel():
            wait([sha])  # the file is not read any more once the unit returns
    after = path.stat()
    if (after.st_size, after.st_mtime_ns) != (before.st_size, before.st_mtime_ns):
        # still being written: what was read is a moment of it (its site may be unread,
        # its end cut off); the driver commits none of it
        for sf in (sf for files in m.staged.values() for sf in files):
            Path(sf.path).unlink(missing_ok=True)
        return FileManifest(unit.path, after.st_size, "", status=m.status,
                            error="changed while being read (still being written?)",
                            changed_while_read=True, site=m.site)
    return m


def _decode_and_stage(
    unit: IngestUnit, ctx: IngestContext, path: Path, size: int, sha: str | Future[str]
) -> FileManifest:
    try:
        site = file_site(unit, path)
    except InvalidSiteError as exc:
        return _refused(unit, size, sha, "invalid_site", str(exc))
    lo, hi = _read_window(unit)
    scan = read_mcap_batches(path, start_ns=lo, end_ns=hi, buffers=ctx.chunk_buffers)
    decoder = FileDecoder(
        source_file=unit.path,
        validation=unit.validation,
        asterix_editions=dict(unit.asterix_editions),
        parse_pool=ctx.parse_pool,
        strings=ctx.strings,
    )
    stager = TableStager(_stage_folder(unit), site=site)
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
        decoder.add_rejects(_status_rejects(unit, scan.status, path))
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
        index = conform("mcap_index", mcap_index_rows(
            unit.path, size, scan.summary, scan.channels, status,
            decoder.not_stored_by_channel), site=site)  # fmt: skip
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
        site=site,
    )


def _refused(unit: IngestUnit, size: int, sha: str | Future[str], reason_code: str,
             reason: str) -> FileManifest:
    """A file refused whole before it is read: ``quarantined``, one rejects row (under
    the default site: the file names none that may be stored) saying why."""
    stager = TableStager(_stage_folder(unit), site=default_site())
    try:
        rejects = make_rejects([unit.start_ns or 0], source_file=unit.path, topic=None,
                               reason_code=[reason_code], reason=[reason], raw=[None])
        stager.add("rejects", rejects)
    finally:
        staged = stager.close()
    return FileManifest(
        source_file=unit.path, size_bytes=size,
        sha256=sha if isinstance(sha, str) else sha.result(), status="quarantined",
        error=reason, rows={"rejects": 1}, rejects_by_reason={reason_code: 1},
        staged={"rejects": list(staged)}, site=default_site(),
    )  # fmt: skip


def _stage_folder(unit: IngestUnit) -> Location:
    """``<staging>/<hash of path>``: deterministic per source file."""
    folder = as_location(unit.warehouse).at(unit.staging_dir)
    return folder / hashlib.sha256(unit.path.encode()).hexdigest()[:24]


def _read_window(unit: IngestUnit) -> tuple[int | None, int | None]:
    if not unit.windowed:
        return None, None
    return unit.start_ns - WINDOW_READ_MARGIN_NS, unit.end_ns + WINDOW_READ_MARGIN_NS


def _status_rejects(unit: IngestUnit, status: ReadStatus, path: Path) -> pa.Table:
    """One rejects row per problem the reader reported (not MCAP, lost chunk, cut-off)."""
    if not status.problems:
        return empty("rejects")
    raw: list[bytes | None] = []
    for p in status.problems:
        if p.reason_code == "not_mcap":
            with open(path, "rb") as f:
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
