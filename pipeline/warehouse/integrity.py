"""A table's Parquet files as its Delta log records them (issue 40 item 2).

Every read of a table (:func:`pipeline.warehouse.delta.read_table`, the views of
``surveil sql`` and the reports) first checks that each file of the snapshot it reads is
there with the size the log's add action records (``size_bytes``). A file rewritten,
truncated or removed outside the pipeline (a ``COPY ... TO`` over a table's file, a
disk tool, a half-finished copy) is refused with :class:`TableFileError`, naming the
table and the file, instead of being read as if it were the table.

Cheap: a ``stat`` per file locally (no file is opened or read: ~2 us each), one listing
of the table's prefix on object storage (one request per 1,000 objects). It checks
sizes, not contents: a rewrite of a file to exactly its old size passes (the stats of
the log are not compared: that would mean reading every file's footer).
"""

from __future__ import annotations

import contextlib
import os
from urllib.parse import unquote

import pyarrow as pa
from deltalake import DeltaTable

from pipeline.warehouse.damage import DamagedTableError
from pipeline.warehouse.location import Location


class TableFileError(DamagedTableError):
    """A file of a table's snapshot is missing or not the size its Delta log records
    (exit code 2: the table must be repaired before it is read, ``surveil doctor``)."""

    def __init__(self, table: str, path: str, recorded_bytes: int, found_bytes: int | None):
        self.path = path
        self.recorded_bytes, self.found_bytes = recorded_bytes, found_bytes
        found = "is missing" if found_bytes is None else f"is {found_bytes} bytes"
        super().__init__(table, f"file {path} {found}, its Delta log records "
                         f"{recorded_bytes} bytes (changed outside surveil; nothing of the "
                         "table was read)")


def recorded_files(snapshot: DeltaTable) -> list[tuple[str, int]]:
    """``(path relative to the table folder, size_bytes)`` of every file of the
    snapshot, from its add actions (paths unquoted: ``%20`` -> space)."""
    adds = pa.table(snapshot.get_add_actions(flatten=True))
    if adds.num_rows == 0:
        return []
    return list(zip(map(unquote, adds["path"].to_pylist()), adds["size_bytes"].to_pylist(),
                    strict=True))


def check_file_sizes(table: str, snapshot: DeltaTable, root: Location) -> None:
    """:class:`TableFileError` for the first file of ``snapshot`` (table ``table`` at
    ``root``, its folder or prefix) that is missing or not of its recorded size."""
    files = recorded_files(snapshot)
    if not files:
        return
    found = _local_sizes(root, files) if root.is_local else _listed_sizes(root)
    for rel, size in files:
        if found.get(rel) != size:
            raise TableFileError(table, f"{root.uri.rstrip('/')}/{rel}", size, found.get(rel))


def _local_sizes(root: Location, files: list[tuple[str, int]]) -> dict[str, int]:
    out = {}
    base = str(root.path)
    for rel, _ in files:
        with contextlib.suppress(FileNotFoundError, NotADirectoryError):
            out[rel] = os.stat(os.path.join(base, rel)).st_size
    return out


def _listed_sizes(root: Location) -> dict[str, int]:
    import pyarrow.fs as pafs

    prefix = root.fs_path.rstrip("/")
    infos = root.fs.get_file_info(pafs.FileSelector(prefix, recursive=True,
                                                    allow_not_found=True))
    return {i.path[len(prefix) + 1:]: i.size for i in infos if i.type == pafs.FileType.File}
