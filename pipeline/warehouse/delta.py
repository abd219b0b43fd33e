"""Delta Lake tables of the warehouse: snapshot reads and atomic predicate replaces.

Every table lives at ``<warehouse>/tables/<name>`` (delta-rs, no server; the warehouse a
local folder or an object-store prefix: :class:`~pipeline.warehouse.location.Location`,
whose storage options every open and write passes), partitioned by
``date`` when its canonical schema has one (``schemas/tables.toml``) and written sorted by
the table's sort key. A write is ONE Delta commit, ``write_deltalake(mode="overwrite",
predicate=...)``: readers see the old rows or the new rows, never a mix, and Delta itself
rejects a row that lies outside the predicate instead of writing it (measured in
``research/architecture.md`` §2.3). An empty table with a predicate deletes the matching
rows in one commit (checked on deltalake 1.6.6).

Readers go through the Delta log (the snapshot's file list, ``DeltaTable.file_uris()``,
read with Arrow's own filesystem: :func:`_snapshot_dataset` says why not
``to_pyarrow_dataset()``): a glob over a table folder also sees the files that earlier
commits replaced and double-counts.

Times are int64 ns since the Unix epoch, UTC; windows are half-open ``[start_ns, end_ns)``.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import math
import os
import threading
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import unquote

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.dataset as pds
from deltalake import DeltaTable, WriterProperties, write_deltalake
from deltalake.exceptions import DeltaError, TableNotFoundError

from pipeline.tables import conform, empty, spec
from pipeline.units import NS
from pipeline.warehouse.damage import log_error, missing_error, require_local_files
from pipeline.warehouse.integrity import check_file_sizes
from pipeline.warehouse.location import Location, as_location
from pipeline.warehouse.pending import pinned_versions

NS_PER_DAY = 86_400 * 10**9
_EPOCH = dt.date(1970, 1, 1)


def table_path(warehouse: Path | Location, name: str) -> Path | Location:
    """Folder of table ``name``: ``<warehouse>/tables/<name>`` (a ``Path`` for a local
    warehouse, as before; a :class:`Location` on object storage)."""
    loc = table_location(warehouse, name)
    return loc.path if loc.is_local else loc


def table_location(warehouse: Path | Location, name: str) -> Location:
    """:func:`table_path` as a :class:`Location` (the storage options with it)."""
    return as_location(warehouse) / "tables" / name


def open_delta(table: Location, version: int | None = None) -> DeltaTable:
    """The Delta table at ``table`` (its latest version, or ``version``), through the
    location's storage options. A log that does not read (an entry cut short, a garbage
    next version) is :class:`~pipeline.warehouse.damage.DamagedTableError` naming the
    table (exit 2); a missing table is deltalake's ``TableNotFoundError``. Inside
    :func:`shared_handles`, a local table's log already read at that version is not read
    again."""
    shared = _shared_handle(table, version)
    if shared is not None:
        return shared
    try:
        dt = DeltaTable(table.uri, version=version,
                        storage_options=table.storage_options or None)
    except TableNotFoundError:
        raise
    except DeltaError as exc:
        raise log_error(table.name, exc) from None
    _share(table, dt)
    return dt


_handles: dict[str, dict[int, tuple[int, DeltaTable]]] | None = None
"""Inside :func:`shared_handles`: table URI -> version -> (its log entry's mtime, the
table at that version), the latest two versions of each table (a job's pins read the one
before its commit)."""
_handles_lock = threading.Lock()


@contextlib.contextmanager
def shared_handles() -> Iterator[None]:
    """Within: each local table's log is read once per version (opening a table costs
    ~4.5 ms of CPU, and a batch opened ~50: its checks, inputs, seams, commits and views
    file). A shared table is handed out again only while it is what a fresh open would
    give: still at that version, the version's log entry the same file (its mtime), and,
    for the latest version, no next entry yet. So every commit, this job's or another's,
    is seen. A job scopes it (``run_batch``; ``surveil run``, over its batches): its first
    open of a table reads the whole log, so a table damaged before the job still stops
    it. Nested: the outer scope's."""
    global _handles
    with _handles_lock:
        outer = _handles is not None
        if not outer:
            _handles = {}
    try:
        yield
    finally:
        if not outer:
            with _handles_lock:
                _handles = None


def _entry_mtime_ns(table: Location, version: int) -> int | None:
    try:
        return os.stat(table.path / "_delta_log" / f"{version:020d}.json").st_mtime_ns
    except OSError:
        return None


def _shared_handle(table: Location, version: int | None) -> DeltaTable | None:
    """The shared table at ``version`` (None: the latest) when still valid, else None."""
    with _handles_lock:
        if _handles is None or not table.is_local:
            return None
        known = _handles.get(table.uri, {})
        v = version if version is not None else max(known, default=None)
        if v is None or v not in known:
            return None
        mtime_ns, dt = known[v]
    fresh = (dt.version() == v and _entry_mtime_ns(table, v) == mtime_ns
             and (version is not None or _is_latest(table, v)))
    if fresh:
        return dt
    with _handles_lock:
        if _handles is not None:
            _handles.get(table.uri, {}).pop(v, None)
    return None


def _share(table: Location, dt: DeltaTable) -> None:
    """Keep ``dt`` (just opened or brought up to date) for :func:`shared_handles`."""
    if _handles is None or not table.is_local:
        return
    v = dt.version()
    mtime_ns = _entry_mtime_ns(table, v)
    with _handles_lock:
        if _handles is not None and mtime_ns is not None:
            known = _handles.setdefault(table.uri, {})
            known[v] = (mtime_ns, dt)
            for older in sorted(known)[:-2]:  # the latest two (a job's pin: the one before)
                del known[older]


def committed(table: Location, dt: DeltaTable) -> None:
    """``dt`` just committed a new version of ``table``: inside :func:`shared_handles`,
    bring it up to the new version (~2.5 ms, against 3.5-8 ms for a fresh open) and share it,
    so that the job's next reader of the table (its views file) does not read the log
    anew. Outside, nothing."""
    if _handles is None or not table.is_local:
        return
    if not _is_latest(table, dt.version()):  # (a write through the table advances it)
        dt.update_incremental()
    _share(table, dt)


def _is_latest(table: Location, version: int) -> bool:
    return _entry_mtime_ns(table, version + 1) is None


def table_exists(warehouse: Path | Location, name: str) -> bool:
    """True when ``name`` has at least one Delta commit."""
    t = table_location(warehouse, name)
    if _shared_handle(t, None) is not None:
        return True
    return DeltaTable.is_deltatable(t.uri, storage_options=t.storage_options or None)


def table_version(warehouse: Path | Location, name: str) -> int | None:
    """Current Delta version of ``name``, ``None`` when the table does not exist."""
    if not table_exists(warehouse, name):
        return None
    return open_delta(table_location(warehouse, name)).version()


def ns_to_date(t_ns: int) -> dt.date:
    """UTC calendar day of an int64-ns time (same rule as ``pipeline.tables.with_date``)."""
    return _EPOCH + dt.timedelta(days=t_ns // NS_PER_DAY)


def sql_literal(value: object) -> str:
    """Render ``value`` as a SQL literal for a Delta (DataFusion) predicate.

    Strings are single-quoted with embedded quotes doubled (``it's`` -> ``'it''s'``);
    dates become ``DATE 'YYYY-MM-DD'``; ints and finite floats are written in full;
    ``None`` is ``NULL``. Anything else (NaN, bytes, objects) raises ``TypeError``, so no
    value reaches a predicate unquoted.
    """
    if value is None:
        return "NULL"
    if isinstance(value, bool):
        return "TRUE" if value else "FALSE"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise TypeError(f"non-finite float has no SQL literal: {value!r}")
        return repr(value)
    if isinstance(value, dt.datetime):
        raise TypeError("datetime literals are not used: compare int64 ns columns instead")
    if isinstance(value, dt.date):
        return f"DATE '{value.isoformat()}'"
    if isinstance(value, str):
        if "\x00" in value:
            raise TypeError("NUL byte in SQL string literal")
        return "'" + value.replace("'", "''") + "'"
    raise TypeError(f"no SQL literal for {type(value).__name__}")


def _check_window(start_ns: int, end_ns: int) -> None:
    if end_ns <= start_ns:
        raise ValueError(f"empty time window [{start_ns}, {end_ns})")


def window_predicate(name: str, start_ns: int, end_ns: int, site: str | None = None) -> str:
    """SQL predicate of ``[start_ns, end_ns)`` on ``name``'s time column, plus the ``date``
    range (when partitioned) so that Delta leaves files of other days untouched; and
    ``site = <site>`` when a site is given."""
    if site is not None:
        return f"site = {sql_literal(site)} AND {window_predicate(name, start_ns, end_ns)}"
    s = spec(name)
    if not s.time_column:
        raise ValueError(f"table {name} has no time column; it cannot be windowed")
    _check_window(start_ns, end_ns)
    col = s.time_column
    parts = [f"{col} >= {sql_literal(int(start_ns))}", f"{col} < {sql_literal(int(end_ns))}"]
    if "date" in s.partition_by:
        parts.append(f"date >= {sql_literal(ns_to_date(int(start_ns)))}")
        parts.append(f"date <= {sql_literal(ns_to_date(int(end_ns) - 1))}")
    return " AND ".join(parts)


def window_filter(name: str, start_ns: int | None, end_ns: int | None) -> pc.Expression | None:
    """Arrow filter of a (possibly open) window on ``name``'s time column and ``date``."""
    s = spec(name)
    if start_ns is None and end_ns is None:
        return None
    if not s.time_column:
        raise ValueError(f"table {name} has no time column; it cannot be windowed")
    time_col, parts = pds.field(s.time_column), []
    has_date = "date" in s.partition_by
    if start_ns is not None:
        parts.append(time_col >= int(start_ns))
        if has_date:
            parts.append(pds.field("date") >= pa.scalar(ns_to_date(int(start_ns)), pa.date32()))
    if end_ns is not None:
        parts.append(time_col < int(end_ns))
        if has_date:
            last_day = ns_to_date(int(end_ns) - 1)
            parts.append(pds.field("date") <= pa.scalar(last_day, pa.date32()))
    expr = parts[0]
    for p in parts[1:]:
        expr = expr & p
    return expr


def _reader_table(warehouse: Path | Location, name: str,
                  pins: dict[str, int] | None = None) -> DeltaTable | None:
    """The table as readers see it: at its pinned version while a job is committing it
    (``pipeline.warehouse.pending``; ``pins``: the pins already read), else its latest;
    None when readers see no table. On object storage the table is opened without a
    first existence check (one round trip less)."""
    where = table_location(warehouse, name)
    if where.is_local and not table_exists(warehouse, name):
        return None
    pinned = (pinned_versions(warehouse) if pins is None else pins).get(name)
    if pinned is not None and pinned < 0:
        return None
    try:
        return open_delta(where, version=pinned)
    except TableNotFoundError:
        return None


def reader_dataset(warehouse: Path | Location, name: str,
                   pins: dict[str, int] | None = None) -> pds.Dataset | None:
    """The Parquet files of the snapshot readers see of ``name`` as a pyarrow dataset on
    the warehouse's filesystem, in the canonical types but for string columns, read as
    dictionaries (as the files store them; for DuckDB, which scans such a column ~2x
    cheaper than plain strings), each file with the time range of its Delta statistics
    (:func:`_time_ranges`: a scan of a window opens only the files it overlaps);
    ``None``: no table yet."""
    delta_table = _reader_table(warehouse, name, pins)
    if delta_table is None:
        return None
    return _snapshot_dataset(delta_table, table_location(warehouse, name), name,
                             dictionaries=True, time_ranges=True)


def read_table(
    warehouse: Path,
    name: str,
    *,
    start_ns: int | None = None,
    end_ns: int | None = None,
    columns: list[str] | None = None,
    predicate: pc.Expression | None = None,
    sort: bool = True,
    site: str | None = None,
) -> pa.Table:
    """Rows of the current snapshot of ``name`` with the time column in ``[start_ns, end_ns)``,
    sorted by the table's sort key (when the selected columns include it and ``sort``).

    The window also filters the ``date`` partition, so files of other days are pruned.
    ``predicate`` is an extra Arrow filter; ``site``: that site's rows only. Returns an
    empty table with the canonical
    schema (or the selected ``columns``) when the table does not exist yet.
    """
    target = spec(name).schema
    if columns is not None:
        target = pa.schema([target.field(c) for c in columns])
    delta_table = _reader_table(warehouse, name)
    if delta_table is None:
        return target.empty_table()
    expr = window_filter(name, start_ns, end_ns)
    if site is not None:
        predicate = (pds.field("site") == site if predicate is None
                     else predicate & (pds.field("site") == site))
    if predicate is not None:
        expr = predicate if expr is None else expr & predicate
    dataset = _snapshot_dataset(delta_table, table_location(warehouse, name), name)
    have = set(dataset.schema.names)
    try:
        table = dataset.to_table(columns=[c for c in target.names if c in have], filter=expr)
    except FileNotFoundError as exc:  # (object storage: a file gone since the log listed it)
        raise missing_error(name, [str(exc)]) from None
    for i, f in enumerate(target):  # a nullable column added to the schema after the table
        if f.name not in have:
            table = table.add_column(i, f, pa.nulls(table.num_rows, f.type))
    table = table.cast(target)
    keys = spec(name).sort_by
    if sort and table.num_rows and keys and all(k in target.names for k in keys):
        table = table.sort_by([(k, "ascending") for k in keys])  # files come in any order
    return table


def has_rows(warehouse: Path, name: str, start_ns: int, end_ns: int,
             site: str | None = None) -> bool:
    """Whether ``name`` holds a row (of ``site``) with its time in ``[start_ns, end_ns)``:
    the scan stops at the first such row (partitions and row groups pruned first)."""
    delta_table = _reader_table(warehouse, name)
    if delta_table is None:
        return False
    expr = window_filter(name, start_ns, end_ns)
    if site is not None:
        expr = pds.field("site") == site if expr is None else expr & (pds.field("site") == site)
    dataset = _snapshot_dataset(delta_table, table_location(warehouse, name), name)
    return dataset.head(1, columns=[spec(name).time_column], filter=expr).num_rows > 0


def _snapshot_dataset(snapshot: DeltaTable, path: Location, name: str,
                      dictionaries: bool = False, time_ranges: bool = False) -> pds.Dataset:
    """``snapshot``'s (the version readers see) Parquet files as a plain pyarrow dataset
    on the table's filesystem (hive ``date=`` partitions): the local one, or the
    location's ``S3FileSystem``.

    Not ``DeltaTable.to_pyarrow_dataset()``: that dataset reads through delta-rs's
    Python filesystem handler (a ``PyFileSystem``), which Arrow's I/O threads call back
    into; when such a thread outlives a short script, the interpreter aborts at exit
    ("terminate called without an active exception", exit 134: about 1 run in 2 of a
    script that reads the ledger and exits; apache/arrow#34314, delta-io/delta-rs#2184).
    The file list comes from the Delta log (so replaced files are never read); the
    reading is Arrow's own. Each file is first checked against the size the log records
    (:func:`pipeline.warehouse.integrity.check_file_sizes`: a ``stat`` each): a file
    changed outside the pipeline is refused, never read as the table.

    ``time_ranges``: each file also carries the range of the table's time column its
    Delta statistics record (:func:`_time_ranges`), so that a scan filtered on that
    column opens only the files that overlap its window."""
    check_file_sizes(name, snapshot, path)
    # local paths, percent-encoded as URIs (a space is %20, '#' is %23, '%' is %25)
    schema = spec(name).schema
    parts = snapshot.metadata().partition_columns
    fmt = pds.ParquetFileFormat()
    # the columns the table has (one written before the canonical schema gained a column
    # lacks it) from its Delta schema: no file is opened to learn them
    have = {f.name for f in snapshot.schema().fields} | set(parts)
    keep = pa.schema([f for f in schema if f.name in have])  # canonical types
    if dictionaries:
        strings = [f.name for f in keep if pa.types.is_string(f.type) and f.name not in parts]
        fmt = pds.ParquetFileFormat(read_options=pds.ParquetReadOptions(
            dictionary_columns=strings))
        keep = pa.schema([f.with_type(pa.dictionary(pa.int32(), pa.string()))
                          if f.name in strings else f for f in keep])
    ranges = _time_ranges(snapshot, spec(name).time_column) if time_ranges else {}
    if not path.is_local:
        return _object_store_dataset(snapshot, path, keep, parts, fmt, ranges)
    files = [unquote(u) for u in snapshot.file_uris()]
    if not files:
        return pds.dataset([], schema=schema, format=fmt)
    partitioning = (
        pds.partitioning(pa.schema([schema.field(p) for p in parts]), flavor="hive")
        if parts else None
    )  # fmt: skip
    try:  # (Arrow stats every file here: a missing one is named, not a traceback)
        dataset = pds.dataset(files, schema=keep, format=fmt, partitioning=partitioning,
                              partition_base_dir=str(path))  # fmt: skip
    except FileNotFoundError:
        require_local_files(path.name, files)
        raise
    if not ranges:
        return dataset
    root = path.fs_path
    fragments = [f if (r := ranges.get(os.path.relpath(f.path, root))) is None
                 else fmt.make_fragment(f.path, f.filesystem, f.partition_expression & r)
                 for f in dataset.get_fragments()]
    return pds.FileSystemDataset(fragments, keep, fmt, dataset.filesystem)


def _time_ranges(snapshot: DeltaTable, time_column: str | None) -> dict[str, pc.Expression]:
    """Data file (its path in the table, decoded) -> ``min <= time <= max`` of the time
    column, from the snapshot's Delta statistics, for every file that has them and no
    null time: a guarantee about every row of the file, which Arrow's scanner holds
    against a scan's filter before opening the file. A report over one hour of a
    week-long table then opens that hour's few files, not the footer of every file
    (one hour of track_errors, 200 ships: 0.19 -> 0.017 CPU-s in a 7-day table of 413
    files, 0.033 -> 0.010 in a 1-day one of 59)."""
    if not time_column:
        return {}
    adds = pa.table(snapshot.get_add_actions(flatten=True))
    cols = [f"min.{time_column}", f"max.{time_column}", f"null_count.{time_column}"]
    if adds.num_rows == 0 or not all(c in adds.column_names for c in cols):
        return {}
    t = pds.field(time_column)
    lo, hi, nulls = (adds[c].to_pylist() for c in cols)
    return {unquote(rel): (t >= a) & (t <= b)
            for rel, a, b, n in zip(adds["path"].to_pylist(), lo, hi, nulls, strict=True)
            if a is not None and b is not None and n == 0}


def _object_store_dataset(snapshot: DeltaTable, path: Location, keep: pa.Schema,
                          parts: list[str], fmt: pds.ParquetFileFormat,
                          ranges: dict[str, pc.Expression]) -> pds.Dataset:
    """The snapshot's files on object storage, each with its size and partition values
    from the Delta log (and its time range from ``ranges``, by decoded path): reading a
    file then needs no request to learn its size."""
    adds = pa.table(snapshot.get_add_actions(flatten=True))
    if adds.num_rows == 0:
        return pds.dataset([], schema=keep, format=fmt)
    fragments = []
    for i, rel in enumerate(adds["path"].to_pylist()):
        expr = None
        for p in parts:
            value = adds[f"partition.{p}"][i]
            term = pds.field(p) == value.cast(keep.field(p).type) if value.is_valid \
                else pds.field(p).is_null()
            expr = term if expr is None else expr & term
        if (r := ranges.get(unquote(rel))) is not None:
            expr = r if expr is None else expr & r
        fragments.append(fmt.make_fragment(f"{path.fs_path}/{unquote(rel)}", path.fs, expr,
                                           file_size=adds["size_bytes"][i].as_py()))
    return pds.FileSystemDataset(fragments, keep, fmt, path.fs)


CHECKPOINT_EVERY = 10
"""A Delta checkpoint every this many versions of a table (delta-rs writes none itself
here): opening a table replays the JSON entries since its last checkpoint, ~0.5 ms each,
so without checkpoints every open (a read, a commit, each table of the views rebuild)
grew with the table's history: hourly batches add ~9,000 versions a year."""


CHECKPOINT_EVERY_OBJECT_STORE = 4
"""The same on object storage, where each JSON entry since the last checkpoint costs every
open of the table one GET (a round trip: ~10-50 ms) and a checkpoint one PUT."""


def checkpoint_if_due(dt: DeltaTable, version: int) -> None:
    """Write the checkpoint of ``version`` (just committed on ``dt``'s table) when it is a
    multiple of :data:`CHECKPOINT_EVERY` (:data:`CHECKPOINT_EVERY_OBJECT_STORE` on object
    storage; ~20 ms; readers are unaffected: a checkpoint holds the same snapshot as the
    entries it sums up, which stay)."""
    local = not dt.table_uri.lower().startswith(("s3://", "s3a://"))
    if version <= 0 or version % (CHECKPOINT_EVERY if local else CHECKPOINT_EVERY_OBJECT_STORE):
        return
    dt.update_incremental()
    if dt.version() == version:  # (another writer went on: its own commit decides)
        dt.create_checkpoint()


def _writer_properties() -> WriterProperties:
    return WriterProperties(compression="ZSTD", max_row_group_size=256 * 1024)


def replace_rows(warehouse: Path, name: str, table: pa.Table, *, predicate_sql: str) -> None:
    """Replace exactly the rows of ``name`` matching ``predicate_sql`` by ``table``, in ONE
    atomic Delta commit (creates the table on the first write).

    ``table`` is conformed to the canonical schema and sorted by the sort key first. A row
    of ``table`` outside the predicate makes Delta reject the whole write (``DeltaError``);
    nothing is committed then. An empty ``table`` deletes the matching rows. A nullable
    column added to the canonical schema after the table was created is added to the
    table by this write (``schema_mode="merge"``; older rows read as null). Column docs
    edited in ``schemas/`` since the table was created keep the table's (delta-rs refuses
    a write whose column metadata differs from the table's, merge or not).
    """
    where = table_location(warehouse, name)
    dt = open_delta(where) if table_exists(warehouse, name) else None
    version = dt.version() + 1 if dt is not None else 0  # the one this write makes
    data = _with_table_metadata(dt, conform(name, table))
    s = spec(name)
    write_deltalake(
        where.uri if dt is None else dt,  # (the table given: delta-rs reads no log again)
        data,
        storage_options=where.storage_options or None,
        mode="overwrite",
        predicate=predicate_sql,
        partition_by=list(s.partition_by) or None,
        writer_properties=_writer_properties(),
        schema_mode="merge",
    )
    if dt is not None:
        committed(where, dt)
        checkpoint_if_due(dt, version)


def _with_table_metadata(dt: DeltaTable | None, data: pa.Table) -> pa.Table:
    """``data`` with the column metadata the existing table ``dt`` stores (zero-copy)."""
    if dt is None:
        return data
    have = pa.schema(dt.schema().to_arrow())
    fields = [f.with_metadata(have.field(f.name).metadata) if f.name in have.names else f
              for f in data.schema]
    if all(f.equals(g, check_metadata=True) for f, g in zip(fields, data.schema, strict=True)):
        return data
    return pa.Table.from_arrays(data.columns, schema=pa.schema(fields, data.schema.metadata))


def replace_window(
    warehouse: Path, name: str, table: pa.Table, *, start_ns: int, end_ns: int,
    site: str | None = None,
) -> None:
    """Replace the rows of ``name`` whose time column is in ``[start_ns, end_ns)`` (of
    ``site`` only, when given: other sites' rows are untouched)."""
    replace_rows(warehouse, name, table,
                 predicate_sql=window_predicate(name, start_ns, end_ns, site))


def may_hold_rows(warehouse: Path, name: str, start_ns: int, end_ns: int,
                  equal: dict[str, str]) -> bool:
    """Whether the current snapshot of ``name`` may hold a row whose time lies in
    ``[start_ns, end_ns)`` and whose every column of ``equal`` has its value, by the
    files' statistics in the log (a file without them may); no file is read. False
    without a table."""
    if not table_exists(warehouse, name):
        return False
    adds = pa.table(open_delta(table_location(warehouse, name)).get_add_actions(flatten=True))
    if adds.num_rows == 0:
        return False
    bounds = {spec(name).time_column: (start_ns, end_ns - 1),
              **{c: (v, v) for c, v in equal.items()}}
    may = np.ones(adds.num_rows, dtype=bool)
    for col, (lo, hi) in bounds.items():
        if f"min.{col}" not in adds.column_names or f"max.{col}" not in adds.column_names:
            continue  # no statistics: every file may
        pairs = zip(adds[f"min.{col}"].to_pylist(), adds[f"max.{col}"].to_pylist(), strict=True)
        may &= np.array([_overlaps(_stat(a), _stat(b), lo, hi) for a, b in pairs], dtype=bool)
    return bool(may.any())


def _stat(value: object) -> object:
    return value.value if hasattr(value, "value") else value  # timestamps come as objects


def _overlaps(lo_stat: object, hi_stat: object, lo: object, hi: object) -> bool:
    """Whether a file with these min/max statistics may hold a value in ``[lo, hi]`` (a
    missing statistic: it may; a string's max may be a truncated prefix of the largest
    value)."""
    if lo_stat is None or hi_stat is None:
        return True
    above = hi_stat >= lo or (isinstance(hi_stat, str) and str(lo).startswith(hi_stat))
    return bool(lo_stat <= hi and above)


def source_file_predicate(
    name: str, source_file: str, start_ns: int | None = None, end_ns: int | None = None
) -> str:
    """``source_file = '<path>'``, AND the time window when both bounds are given."""
    pred = f"source_file = {sql_literal(source_file)}"
    if start_ns is None and end_ns is None:
        return pred
    if start_ns is None or end_ns is None:
        raise ValueError("give both start_ns and end_ns, or neither")
    return f"{pred} AND {window_predicate(name, start_ns, end_ns)}"


def replace_source_file(
    warehouse: Path,
    name: str,
    table: pa.Table,
    *,
    source_file: str,
    start_ns: int | None = None,
    end_ns: int | None = None,
) -> None:
    """Replace every row of ``name`` that came from ``source_file`` (only those in
    ``[start_ns, end_ns)`` when a window is given) by ``table``: one commit."""
    pred = source_file_predicate(name, source_file, start_ns, end_ns)
    replace_rows(warehouse, name, table, predicate_sql=pred)


def table_files(warehouse: Path | Location, name: str) -> list[str]:
    """Absolute paths (on object storage: ``s3://`` URIs) of the Parquet files of the
    snapshot readers see (the current one, or the pinned one while a job commits the
    table); empty if no table."""
    return table_snapshot(warehouse, name)[0]


def table_snapshot(warehouse: Path, name: str) -> tuple[list[str], frozenset[str]]:
    """``(files, column names)`` of the snapshot readers see (``([], {})`` if no table):
    a table written before its canonical schema gained a column lacks it."""
    t = _reader_table(warehouse, name)
    if t is None:
        return [], frozenset()
    files = [unquote(u.removeprefix("file://")) for u in t.file_uris()]  # %23 -> '#'...
    # (an object store's: s3://bucket/key, unquoted alike)
    if table_location(warehouse, name).is_local:  # DuckDB would fail on a missing one
        require_local_files(name, files)
    return files, frozenset(f.name for f in t.schema().fields)


def require_readable(warehouse: Path | Location, names: list[str], *, files: bool = True
                     ) -> None:
    """:class:`~pipeline.warehouse.damage.DamagedTableError` for the first of ``names``
    (existing tables) whose log does not read or (locally, with ``files``) whose
    snapshot lists a missing file: a job checks the tables it reads and writes before
    any work, so a damaged table stops it before its first commit (~3 ms a table)."""
    for name in dict.fromkeys(names):
        if files:
            table_snapshot(warehouse, name)
        else:
            _reader_table(warehouse, name)


def empty_table(name: str) -> pa.Table:
    """Empty table with ``name``'s canonical schema."""
    return empty(name)


def rows_per_second(warehouse: Path, name: str, start_ns: int, end_ns: int,
                    site: str | None = None) -> np.ndarray:
    """How many of ``name``'s rows (of ``site``, when given) fall in each second of
    ``[start_ns, end_ns)`` (counted from ``start_ns``), from its time column alone. A
    function of the rows, not of how the files hold them: a window re-ingested into
    other files has the same profile."""
    time_col = spec(name).time_column
    n_s = -(-(end_ns - start_ns) // NS)
    t = read_table(warehouse, name, start_ns=start_ns, end_ns=end_ns, columns=[time_col],
                   sort=False, site=site)
    seconds = (t[time_col].to_numpy() - start_ns) // NS
    return np.bincount(seconds, minlength=n_s)


def volume_cuts(rows_per_s: np.ndarray, start_ns: int, max_rows: int) -> list[int]:
    """Cut times (whole seconds after ``start_ns``) that split the rows counted by
    ``rows_per_s`` (:func:`rows_per_second`) into the fewest pieces of at most about
    ``max_rows`` rows each (one second's rows over), as even as whole seconds allow.
    Returns the interior cuts, ascending."""
    total = int(rows_per_s.sum())
    if total <= max_rows:
        return []
    k = -(-total // max_rows)
    targets = total * np.arange(1, k) / k
    after = np.searchsorted(np.cumsum(rows_per_s), targets) + 1  # seconds before the cut
    end_s = rows_per_s.size
    return sorted({start_ns + int(s) * NS for s in after if 0 < s < end_s})
