"""Stage one source file's rows as Parquet data files, then commit them to Delta at once.

Writing through ``write_deltalake(mode="overwrite", predicate=...)`` re-encodes every row
in the driver (delta-rs: ~4 s per million radar rows here, against ~0.7 s for pyarrow's
Parquet writer). For ingest the rows are instead encoded ONCE, by the worker, streaming:

- :class:`TableStager` (worker) writes each table's rows, part by part as the decoder
  produces them, to one Parquet file per (table, ``date`` partition) under the staging
  directory, in row groups of ``ROW_GROUP_ROWS`` rows sorted by the table's sort key, in a
  background thread. The ``date`` column is not stored in the file (Delta keeps partition
  values in the log, as delta-rs does). It returns :class:`StagedFile` descriptions with
  the Delta statistics of each file (row count, per-column min/max/null count).
- :func:`commit_staged` (driver) moves the staged files into the table folder and makes
  ONE Delta commit that removes every data file holding rows of this source file and adds
  the new ones (``DeltaTable.create_write_transaction`` with Remove and Add actions). Ingest
  writes each source file's rows to files of their own, so "the rows of source file X" is
  a set of whole files, found from the ``source_file`` min/max statistics. A file whose
  statistics cannot prove it holds only X (older writers, missing stats) makes the table
  fall back to :func:`pipeline.warehouse.delta.replace_source_file`: same result, one
  ``write_deltalake`` commit, slower.

Readers see the old files or the new ones, never both (one commit); a crash before the
commit leaves the staged files unreferenced (``vacuum`` removes them).

The staging folder and the tables may be on object storage
(:class:`~pipeline.warehouse.location.Location`): files are then written through the
location's ``S3FileSystem`` and moved into the table by a server-side copy; the commit
is deltalake's, through the same storage options.
"""

from __future__ import annotations

import json
import math
import time
import uuid
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from deltalake import DeltaTable, Field
from deltalake import Schema as DeltaSchema
from deltalake.transaction import AddAction, RemoveAction, create_table_with_add_actions

from pipeline.tables import SITE, conform, constant_strings, spec
from pipeline.threads import WRITER_NICE, helper_pool
from pipeline.warehouse.delta import (
    checkpoint_if_due,
    committed,
    open_delta,
    replace_source_file,
    table_exists,
    table_location,
)
from pipeline.warehouse.location import Location, as_location

# 64 Ki rows: a file's last row group is encoded after its last chunk is decoded (~50 ms
# here, against ~100 ms for 128 Ki); same instructions and file size (47.95 MB per 1 M
# radar rows either way)
ROW_GROUP_ROWS = 64 * 1024
MAX_FILES_PER_SLOT = 2  # staged files (and writer threads) per (table, date) of a source
PARTITION = "date"


@dataclass(frozen=True)
class StagedFile:
    """A Parquet data file written by a worker, ready to be added to table ``table``.

    ``path``: absolute path (or object-store URI) in the staging folder; ``partition``:
    Delta partition values (``{"date": "YYYY-MM-DD"}``, or empty for unpartitioned
    tables); ``stats_json``: the Delta statistics of the file."""

    table: str
    path: str
    partition: dict[str, str]
    rows: int
    size_bytes: int
    stats_json: str


@dataclass
class _ColumnStats:
    """Min / max / null count of one column (``usable`` false: no min/max for Delta).

    Float columns are tracked while the rows are written (:meth:`update`: a NaN makes the
    min/max unusable, where Parquet's statistics would silently skip it); every other
    column's come from the Parquet footer (:func:`_footer_stats`), which the writer
    computes anyway."""

    lo: object = None
    hi: object = None
    nulls: int = 0
    usable: bool = True

    def update(self, col: pa.ChunkedArray) -> None:
        self.nulls += col.null_count
        for chunk in col.chunks:
            if not self.usable:
                return
            if chunk.null_count < len(chunk):
                self._update_chunk(chunk)

    def _update_chunk(self, chunk: pa.Array) -> None:
        """One chunk of a float column (the only columns tracked here)."""
        if chunk.null_count == 0:  # numpy, zero-copy: one pass each, NaN propagates
            v = chunk.to_numpy(zero_copy_only=False)
            lo, hi = v.min().item(), v.max().item()
            if lo != lo or hi != hi:
                self.usable = False  # NaN has no place in min/max statistics
                return
        else:
            if pc.any(pc.is_nan(chunk)).as_py():
                self.usable = False
                return
            mm = pc.min_max(chunk).as_py()
            lo, hi = mm["min"], mm["max"]
        self.lo = lo if self.lo is None else min(self.lo, lo)
        self.hi = hi if self.hi is None else max(self.hi, hi)


def _footer_stats(md: pq.FileMetaData, columns: list[str]) -> dict[str, _ColumnStats]:
    """Min / max / null count of ``columns`` over the row groups of a written Parquet file
    (its footer, ``md``); a row group with values but no min/max (a string over the
    writer's statistics size limit) makes the column's min/max unusable."""
    index = {md.schema.column(i).name: i for i in range(md.num_columns)}
    out = {}
    for name in columns:
        st = _ColumnStats()
        for rg in range(md.num_row_groups):
            s = md.row_group(rg).column(index[name]).statistics
            if s is None or not s.has_null_count:
                st.usable = False
                continue
            st.nulls += s.null_count
            if s.has_min_max:
                st.lo = s.min if st.lo is None else min(st.lo, s.min)
                st.hi = s.max if st.hi is None else max(st.hi, s.max)
            elif s.num_values > 0:
                st.usable = False
        out[name] = st
    return out


def _write_group(f: _OpenFile, group: pa.Table) -> None:
    """Statistics, then one row group (in the stage thread: Arrow releases the GIL; jobs
    of one stager run one at a time, in order)."""
    for col, st in f.stats.items():
        st.update(group[col])
    for name in f.dictionary_columns:
        i = group.schema.get_field_index(name)
        group = group.set_column(i, f.writer.schema.field(i), _as_dictionary(group[name]))
    f.writer.write_table(group, row_group_size=group.num_rows)


def _constant_string(col: pa.ChunkedArray) -> str | None:
    """The value of a string column whose rows all hold the same one (no null), else
    None. Read off the Arrow buffers: offsets in equal steps, and data equal to itself
    shifted by one value (8-byte words; ~0.5 ms per 128 Ki rows of 40-byte paths)."""
    if not pa.types.is_string(col.type) or col.null_count or len(col) == 0:
        return None
    value = None
    for chunk in col.chunks:
        n = len(chunk)
        if n == 0:
            continue
        _, offsets_buf, data = chunk.buffers()
        data = data if data is not None else pa.py_buffer(b"")
        off = np.frombuffer(offsets_buf, np.int32, n + 1, 4 * chunk.offset)
        step, start = int(off[1] - off[0]), int(off[0])
        if not np.array_equal(off, start + step * np.arange(n + 1, dtype=np.int64)):
            return None
        first = data[start : start + step].to_pybytes().decode()
        if (value is not None and first != value) or not _periodic(data, start, n, step):
            return None
        value = first
    return value


def _periodic(data: pa.Buffer, start: int, n: int, step: int) -> bool:
    """Bytes [start, start + n * step) of ``data`` are their first ``step`` bytes n times:
    every byte equals the one ``step`` before it."""
    total = (n - 1) * step
    if step == 0 or total == 0:
        return True
    words, tail = divmod(total, 8)
    later = np.frombuffer(data, np.uint64, words, start + step)
    earlier = np.frombuffer(data, np.uint64, words, start)
    end = start + 8 * words
    return np.array_equal(later, earlier) and np.array_equal(
        np.frombuffer(data, np.uint8, tail, end + step), np.frombuffer(data, np.uint8, tail, end)
    )


def _as_dictionary(col: pa.ChunkedArray) -> pa.DictionaryArray:
    """A string column as one dictionary array (int32 indices): a constant column (the
    provenance columns) without hashing, any other by ``dictionary_encode``. Parquet then
    writes the dictionary and the indices as they are, and its statistics look at the
    dictionary's values, not at every row's string."""
    value = _constant_string(col)
    if value is not None:
        zeros = pa.array(np.zeros(len(col), np.int32))
        return pa.DictionaryArray.from_arrays(zeros, pa.array([value], pa.string()))
    return pc.dictionary_encode(col.combine_chunks())


def _sorted_by_first(table: pa.Table, key: str) -> bool:
    """True when ``key`` strictly increases (then the table is sorted by any key list
    starting with it); ties or disorder -> False (the caller sorts)."""
    col = table[key]
    if table.num_rows < 2 or not pa.types.is_integer(col.type):
        return table.num_rows < 2
    v = col.to_numpy()
    return bool(np.all(v[1:] > v[:-1]))


def _stat_value(v: object) -> object:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _file_stats(f: _OpenFile) -> dict[str, _ColumnStats]:
    """Every non-binary column's statistics of a closed staged file, in schema order."""
    names = [c.name for c in f.writer.schema if not pa.types.is_binary(c.type)]
    footer = _footer_stats(f.writer.writer.metadata, [n for n in names if n not in f.stats])
    return {n: f.stats[n] if n in f.stats else footer[n] for n in names}


def _stats_json(rows: int, stats: dict[str, _ColumnStats]) -> str:
    usable = {k: s for k, s in stats.items() if s.usable and s.lo is not None}
    return json.dumps(
        {
            "numRecords": rows,
            "minValues": {k: _stat_value(s.lo) for k, s in usable.items()},
            "maxValues": {k: _stat_value(s.hi) for k, s in usable.items()},
            "nullCount": {k: s.nulls for k, s in stats.items()},
        }
    )


@dataclass
class _OpenFile:
    """One staged Parquet file of a (table, partition) slot, and the thread writing it."""

    table: str
    partition: dict[str, str]
    path: Location
    writer: pq.ParquetWriter
    pool: ThreadPoolExecutor | None
    rows: int = 0
    stats: dict[str, _ColumnStats] = field(default_factory=dict)
    inflight: list[Future] = field(default_factory=list)
    dictionary_columns: list[str] = field(default_factory=list)  # see _as_dictionary

    def busy(self) -> bool:
        return any(not fut.done() for fut in self.inflight)

    def submit(self, group: pa.Table) -> None:
        """Write ``group`` as the file's next row group (in order), at most two behind."""
        self.rows += group.num_rows
        if self.pool is None:
            _write_group(self, group)
            return
        while self.inflight and (self.inflight[0].done() or len(self.inflight) >= 2):
            self.inflight.pop(0).result()  # re-raises a failed write here
        self.inflight.append(self.pool.submit(_write_group, self, group))


@dataclass
class _Slot:
    """The rows of one (table, partition) not yet written, and the files they go to."""

    table: str
    partition: dict[str, str]
    files: list[_OpenFile] = field(default_factory=list)
    pending: list[pa.Table] = field(default_factory=list)
    pending_rows: int = 0


class TableStager:
    """Stream a source file's rows into staged Parquet files (see module docstring).

    ``add(name, table)`` takes rows of raw table ``name`` (any column order: they are
    conformed); ``close()`` flushes and returns the :class:`StagedFile` list. Parquet
    encoding runs in a background thread per file (niced: ``WRITER_NICE``), at most two
    row groups behind. A row group that finds its slot's file still busy goes to a second
    file of the slot, with its own thread (``MAX_FILES_PER_SLOT``): a big table is then
    written on two cores, which shortens the tail of a file's ingest when decoding has
    kept both cores busy.
    """

    def __init__(
        self,
        folder: Path | Location,
        *,
        row_group_rows: int = ROW_GROUP_ROWS,
        threaded: bool = True,
        presorted: bool = False,
        site: str | None = None,
    ):
        """``presorted``: the caller adds each table's rows in the order of its sort key
        (e.g. a batch stage's outputs), so row groups are not checked nor sorted.
        ``site``: stamped on every row of a table carrying ``site`` (the ingested file's,
        the batch's); without it, rows keep theirs (a null site raises ``ValueError``)."""
        self.folder = as_location(folder)
        self.site = site
        self.row_group_rows = row_group_rows
        self.threaded = threaded
        self.presorted = presorted
        self.rows: dict[str, int] = {}
        self._slots: dict[tuple[str, str], _Slot] = {}

    def add(self, name: str, table: pa.Table) -> None:
        if table.num_rows == 0:
            return
        s = spec(name)
        data = table if table.schema.equals(s.schema) else conform(name, table)
        if SITE in s.schema.names:
            i = s.schema.get_field_index(SITE)
            if self.site is not None:
                data = data.set_column(i, s.schema.field(i),
                                       constant_strings(self.site, data.num_rows))
            elif data.column(i).null_count:
                raise ValueError(f"rows of {name} without a site: stage them with "
                                 "TableStager(site=...)")
        self.rows[name] = self.rows.get(name, 0) + data.num_rows
        if PARTITION not in s.partition_by:
            self._append(name, "", {}, data)
            return
        dates = data[PARTITION]
        span = pc.min_max(dates).as_py()
        days = [span["min"]] if span["min"] == span["max"] else pc.unique(dates).to_pylist()
        for day in days:
            part = data if len(days) == 1 else data.filter(pc.equal(dates, pa.scalar(day)))
            self._append(name, day.isoformat(), {PARTITION: day.isoformat()}, part)

    def _append(self, name: str, key: str, partition: dict[str, str], data: pa.Table) -> None:
        slot = self._slots.get((name, key))
        if slot is None:
            slot = self._slots[(name, key)] = _Slot(name, partition)
        slot.pending.append(data.drop_columns([PARTITION]) if partition else data)
        slot.pending_rows += data.num_rows
        if slot.pending_rows >= self.row_group_rows:
            self._flush(slot)

    def _open(self, slot: _Slot, first: pa.Table) -> _OpenFile:
        """A staged file for ``slot``; its first row group ``first`` decides which string
        columns go to Parquet as Arrow dictionaries (those constant in it)."""
        sub = self.folder / slot.table / "/".join(f"{k}={v}" for k, v in slot.partition.items())
        sub.mkdir()
        path = sub / f"part-{uuid.uuid4().hex}.parquet"
        schema = first.schema
        strings = [f.name for f in schema if pa.types.is_string(f.type)]
        constant = [c for c in strings if _constant_string(first[c]) is not None]
        for c in constant:
            i = schema.get_field_index(c)
            schema = schema.set(
                i, schema.field(i).with_type(pa.dictionary(pa.int32(), pa.string()))
            )
        encoding = {f.name: "BYTE_STREAM_SPLIT" for f in schema if pa.types.is_floating(f.type)}
        encoding |= {f.name: "DELTA_BINARY_PACKED" for f in schema if pa.types.is_integer(f.type)}
        with_stats = [f.name for f in schema if not pa.types.is_binary(f.type)]
        writer = pq.ParquetWriter(
            path.uri if path.is_local else path.fs_path,
            schema,
            filesystem=None if path.is_local else path.fs,
            compression="zstd",
            # zstd's first fast (negative) level: -14% of the encoder's instructions per row group
            # against level 1, files +1.3% (1 M radar rows: 47.95 -> 48.59 MB)
            compression_level=-1,
            use_dictionary=strings,
            column_encoding=encoding or None,
            write_statistics=with_stats,  # not of raw bytes (rejects.raw)
            store_schema=False,  # readers see strings, not the dictionaries
        )
        stats = {f.name: _ColumnStats() for f in schema if pa.types.is_floating(f.type)}
        pool = helper_pool(1, "stage", WRITER_NICE) if self.threaded else None
        return _OpenFile(
            slot.table, slot.partition, path, writer, pool, stats=stats, dictionary_columns=constant
        )

    def _flush(self, slot: _Slot) -> None:
        if not slot.pending:
            return
        parts, slot.pending, slot.pending_rows = slot.pending, [], 0
        group = pa.concat_tables(parts)
        keys = [k for k in spec(slot.table).sort_by if k in group.column_names]
        if keys and not self.presorted and not _sorted_by_first(group, keys[0]):
            group = group.sort_by([(k, "ascending") for k in keys])
        idle = [f for f in slot.files if not f.busy()]
        if idle:
            target = idle[0]
        elif not slot.files or (self.threaded and len(slot.files) < MAX_FILES_PER_SLOT):
            target = self._open(slot, group)
            slot.files.append(target)
        else:
            target = min(slot.files, key=lambda f: len(f.inflight))
        target.submit(group)

    def close(self) -> list[StagedFile]:
        """Write what is pending, close every file, return their descriptions."""
        files = []
        try:
            for slot in self._slots.values():
                self._flush(slot)
            files = [f for slot in self._slots.values() for f in slot.files]
            for f in files:
                for fut in f.inflight:
                    fut.result()
        finally:
            for f in (f for slot in self._slots.values() for f in slot.files):
                if f.pool is not None:
                    f.pool.shutdown(wait=True)
                f.writer.close()
        return [
            StagedFile(
                f.table,
                str(f.path),
                dict(f.partition),
                f.rows,
                f.path.stat()[0],
                _stats_json(f.rows, _file_stats(f)),
            )
            for f in files
        ]


# -- driver side -----------------------------------------------------------------------


def _add_actions(table: Location, staged: list[StagedFile]) -> list[AddAction]:
    """Move staged files into ``table`` (same file system: a rename; object storage: a
    server-side copy) -> Add actions."""
    out = []
    now_ms = int(time.time() * 1000)
    for sf in staged:
        staged_file = table.at(sf.path)
        rel = "/".join([*(f"{k}={v}" for k, v in sf.partition.items()), staged_file.name])
        target = table / rel
        target.parent.mkdir()
        staged_file.move_to(target)
        out.append(AddAction(rel, sf.size_bytes, dict(sf.partition), now_ms, True, sf.stats_json))
    return out


def files_of_source(dt: DeltaTable, source_file: str) -> tuple[list[RemoveAction], bool]:
    """Remove actions for the data files of ``dt`` that hold rows of ``source_file`` only,
    and whether that set is exact (``False``: some file may mix it with other sources)."""
    adds = pa.table(dt.get_add_actions(flatten=True))
    if adds.num_rows == 0:
        return [], True
    names = adds.column_names
    if "min.source_file" not in names or "max.source_file" not in names:
        return [], False
    lo = adds["min.source_file"].to_pylist()
    hi = adds["max.source_file"].to_pylist()
    lo_arr = np.array([x if x is not None else "" for x in lo], dtype=object)
    hi_arr = np.array([x if x is not None else "" for x in hi], dtype=object)
    missing = np.array([a is None or b is None for a, b in zip(lo, hi, strict=True)])
    only = (lo_arr == source_file) & (hi_arr == source_file)
    maybe = missing | ((lo_arr <= source_file) & (hi_arr >= source_file))
    if np.any(maybe & ~only):
        return [], False
    part_cols = [c for c in names if c.startswith("partition.")]
    now_ms = int(time.time() * 1000)
    removes = []
    for i in np.flatnonzero(only).tolist():
        pv = {c.removeprefix("partition."): _part_str(adds[c][i].as_py()) for c in part_cols}
        removes.append(
            RemoveAction(adds["path"][i].as_py(), True, now_ms, adds["size_bytes"][i].as_py(), pv)
        )
    return removes, True


def _part_str(v: object) -> str | None:
    return None if v is None else v.isoformat() if hasattr(v, "isoformat") else str(v)


def read_parquet(file: Location) -> pa.Table:
    """One Parquet file, local or on object storage."""
    if file.is_local:
        return pq.read_table(file.uri)
    return pq.read_table(file.fs_path, filesystem=file.fs)


def read_staged(name: str, staged: list[StagedFile],
                warehouse: Path | Location | None = None) -> pa.Table:
    """The rows of staged files of table ``name``, conformed (partition column restored);
    ``warehouse``: the storage they are on (None: local paths, or the environment's
    object store)."""
    where = as_location(warehouse) if warehouse is not None else Location(".")
    parts = []
    for sf in staged:
        t = read_parquet(where.at(sf.path))
        for k, v in sf.partition.items():
            t = t.append_column(k, pa.array([v] * t.num_rows, pa.string()).cast(pa.date32()))
        parts.append(t)
    if not parts:
        return spec(name).schema.empty_table()
    return conform(name, pa.concat_tables(parts))


def commit_staged(warehouse: Path, name: str, staged: list[StagedFile], *, source_file: str) -> str:
    """Replace every row of ``name`` from ``source_file`` by the staged files: one commit.

    Returns how: ``noop`` (nothing staged, nothing to remove), ``create`` (new table),
    ``swap`` (remove + add actions) or ``rewrite`` (fallback through ``write_deltalake``).
    """
    uri = table_location(warehouse, name)
    if not table_exists(warehouse, name):
        if not staged:
            return "noop"
        adds = _add_actions(uri, staged)
        schema = DeltaSchema.from_arrow(spec(name).schema)
        try:
            create_table_with_add_actions(
                uri.uri, schema, adds, mode="error", partition_by=list(spec(name).partition_by),
                storage_options=uri.storage_options or None,
            )
        except Exception:
            _drop_added(uri, adds)
            raise
        return "create"
    dt = open_delta(uri)
    removes, exact = files_of_source(dt, source_file)
    if not exact:
        replace_source_file(warehouse, name, read_staged(name, staged, warehouse),
                            source_file=source_file)
        for sf in staged:
            uri.at(sf.path).unlink()
        return "rewrite"
    if not staged and not removes:
        return "noop"
    if staged:
        add_new_columns(dt, name)
    adds = _add_actions(uri, staged)
    version = dt.version() + 1
    try:
        dt.create_write_transaction(
            [*removes, *adds],
            mode="append",
            schema=dt.schema(),
            partition_by=list(spec(name).partition_by),
        )
    except Exception:
        _drop_added(uri, adds)
        raise
    checkpoint_if_due(dt, version)
    return "swap"


def add_new_columns(dt: DeltaTable, name: str) -> list[str]:
    """Add to ``dt`` the nullable columns the canonical schema of ``name`` gained since the
    table was created (one metadata commit, before the data commit that brings them: the
    table's older rows read them as null). The staged files hold every canonical column,
    but a commit of add actions keeps the table's schema, so without this the new column
    stayed unread forever (the views read it as null). A new non-nullable column is not
    added (``surveil doctor`` reports the schema). Returns the names added."""
    have = set(pa.schema(dt.schema().to_arrow()).names)
    new = [f for f in spec(name).schema if f.name not in have and f.nullable]
    if new:
        dt.alter.add_columns([Field.from_arrow(f) for f in new])
    return [f.name for f in new]


def _drop_added(table: Location, adds: list[AddAction]) -> None:
    for a in adds:
        (table / a.path).unlink()


# -- derived tables: replace a time window -----------------------------------------------


def commit_window(
    warehouse: Path, name: str, staged: list[StagedFile], *, start_ns: int, end_ns: int,
    site: str | None = None,
) -> str:
    """Replace the rows of ``name`` whose time is in ``[start_ns, end_ns)`` by the staged
    files: ONE Delta commit (the batch's window replace, without re-encoding the rows).

    The data files of the current snapshot whose time statistics lie wholly inside the
    window are removed; a file that also holds rows outside it (an earlier batch over a
    wider window) is rewritten without the window's rows (read, filtered, staged again)
    and swapped in the same commit; a file without usable time statistics is treated
    like one that overlaps. Returns ``noop``, ``create`` or ``swap``.

    ``site``: only that site's rows of the window are replaced; a file of another site
    (by its ``site`` statistics) is untouched, a file holding several sites is rewritten
    without this site's rows of the window.
    """
    if not table_exists(warehouse, name):
        return _create(warehouse, name, staged)
    time_column = spec(name).time_column

    def keep(t: pa.Table) -> pa.Array:  # rows outside the window (or of another site)
        col = t[time_column]
        outside = pc.or_(pc.less(col, start_ns), pc.greater_equal(col, end_ns))
        if site is not None and SITE in t.column_names:
            outside = pc.or_(outside, pc.not_equal(t[SITE], site))
        return outside

    dt = open_delta(table_location(warehouse, name))
    removes, partial = files_in_window(dt, time_column, start_ns, end_ns, site)
    return _swap(warehouse, name, dt, staged, removes, partial, keep)

def commit_source_window(
    warehouse: Path, name: str, staged: list[StagedFile], *, source_file: str, start_ns: int,
    end_ns: int,
) -> str:
    """Replace the rows of ``name`` from ``source_file`` whose time is in
    ``[start_ns, end_ns)`` by the staged files: ONE Delta commit, the rows of
    ``replace_source_file(..., start_ns, end_ns)`` (a windowed re-ingest) without reading
    the staged rows into memory (that path held the hour's rows, ~2 GB for an hour of a
    1,000-ship region, in the committing process).

    Data files whose statistics say they hold only ``source_file`` rows inside the window
    are removed; a file that may also hold other rows (another source, times outside the
    window, no usable statistics) is read alone, filtered, staged again and swapped in the
    same commit. Returns ``noop``, ``create`` or ``swap``."""
    if not table_exists(warehouse, name):
        return _create(warehouse, name, staged)
    time_column = spec(name).time_column

    def keep(t: pa.Table) -> pa.Array:  # every row but this source's inside the window
        col = t[time_column]
        inside = pc.and_(pc.greater_equal(col, start_ns), pc.less(col, end_ns))
        ours = pc.and_(pc.equal(t["source_file"], source_file), inside)
        return pc.invert(pc.fill_null(ours, False))

    dt = open_delta(table_location(warehouse, name))
    removes, partial = files_in_window(dt, time_column, start_ns, end_ns,
                                       source_file=source_file)
    return _swap(warehouse, name, dt, staged, removes, partial, keep)


def _create(warehouse: Path, name: str, staged: list[StagedFile]) -> str:
    """A new table of the staged files (``noop`` when there are none)."""
    if not staged:
        return "noop"
    uri, s = table_location(warehouse, name), spec(name)
    adds = _add_actions(uri, staged)
    try:
        create_table_with_add_actions(
            uri.uri, DeltaSchema.from_arrow(s.schema), adds, mode="error",
            partition_by=list(s.partition_by), storage_options=uri.storage_options or None,
        )
    except Exception:
        _drop_added(uri, adds)
        raise
    return "create"


def _swap(warehouse: Path, name: str, dt: DeltaTable, staged: list[StagedFile],
          removes: list[RemoveAction], partial: list[tuple[str, dict[str, str]]],
          keep: Callable[[pa.Table], pa.Array]) -> str:
    """ONE commit: ``removes`` out, the staged files in, and each ``partial`` data file
    rewritten with the rows ``keep`` selects (read one at a time, staged again)."""
    uri, s = table_location(warehouse, name), spec(name)
    scratch = as_location(warehouse) / "_staging" / f"rewrite-{uuid.uuid4().hex}"
    try:
        kept: list[StagedFile] = []
        if partial:
            stager = TableStager(scratch, threaded=False)
            for path, partition in partial:  # one data file in memory at a time
                t = read_parquet(uri / path)
                for k, v in partition.items():
                    t = t.append_column(k, pa.array([v] * t.num_rows, pa.string())
                                        .cast(pa.date32()))
                stager.add(name, conform(name, t.filter(keep(t))))
            kept = stager.close()
        if not staged and not removes and not kept:
            return "noop"
        if staged:
            add_new_columns(dt, name)
        adds = _add_actions(uri, [*staged, *kept])
        version = dt.version() + 1
        try:
            dt.create_write_transaction([*removes, *adds], mode="append", schema=dt.schema(),
                                        partition_by=list(s.partition_by))
        except Exception:
            _drop_added(uri, adds)
            raise
    finally:
        scratch.rmtree()
    committed(uri, dt)
    checkpoint_if_due(dt, version)
    return "swap"

def files_in_window(
    dt: DeltaTable, time_column: str, start_ns: int, end_ns: int, site: str | None = None,
    *, source_file: str | None = None,
) -> tuple[list[RemoveAction], list[tuple[str, dict[str, str]]]]:
    """Remove actions for every data file holding rows of ``[start_ns, end_ns)``, and the
    (path, partition values) of those that also hold rows outside it (to rewrite).
    ``site``: only that site's rows count as the window's (by the files' ``site``
    statistics: a file of other sites is untouched, a file holding several is to
    rewrite). ``source_file``: only rows of that source count as the window's (by the
    files' ``source_file`` statistics; a file that may mix sources is to rewrite)."""
    adds = pa.table(dt.get_add_actions(flatten=True))
    if adds.num_rows == 0:
        return [], []
    names = adds.column_names
    lo_col, hi_col = f"min.{time_column}", f"max.{time_column}"
    n = adds.num_rows
    lo = adds[lo_col].to_pylist() if lo_col in names else [None] * n
    hi = adds[hi_col].to_pylist() if hi_col in names else [None] * n
    rows = adds["num_records"].to_pylist() if "num_records" in names else [None] * n
    s_lo = adds[f"min.{SITE}"].to_pylist() if f"min.{SITE}" in names else [None] * n
    s_hi = adds[f"max.{SITE}"].to_pylist() if f"max.{SITE}" in names else [None] * n
    src_lo = (adds["min.source_file"].to_pylist() if "min.source_file" in names
              else [None] * n)
    src_hi = (adds["max.source_file"].to_pylist() if "max.source_file" in names
              else [None] * n)
    part_cols = [c for c in names if c.startswith("partition.")]
    now_ms = int(time.time() * 1000)
    removes, partial = [], []
    for i in range(n):
        a, b = lo[i], hi[i]
        a = a.value if hasattr(a, "value") else a  # timestamps come back as objects
        b = b.value if hasattr(b, "value") else b
        if rows[i] == 0:
            continue
        known = a is not None and b is not None
        if known and (b < start_ns or a >= end_ns):
            continue  # wholly outside: untouched
        whole = known and a >= start_ns and b < end_ns
        if site is not None:
            sa, sb = s_lo[i], s_hi[i]
            if sa is not None and sb is not None and (sb < site or sa > site):
                continue  # other sites only: untouched
            whole = whole and sa == site and sb == site
        if source_file is not None:
            sa, sb = src_lo[i], src_hi[i]
            # (a max statistic may be a truncated prefix of the largest value: below the
            # source and not a prefix of it, the largest value is below it too)
            below = sb is not None and sb < source_file and not source_file.startswith(sb)
            if below or (sa is not None and sa > source_file):
                continue  # no row of the source: untouched
            whole = whole and sa == source_file and sb == source_file
        pv = {c.removeprefix("partition."): _part_str(adds[c][i].as_py()) for c in part_cols}
        path = adds["path"][i].as_py()
        removes.append(RemoveAction(path, True, now_ms, adds["size_bytes"][i].as_py(), pv))
        if not whole:
            partial.append((path, {k: v for k, v in pv.items() if v is not None}))
    return removes, partial
