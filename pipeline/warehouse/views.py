"""DuckDB views over the current Delta snapshot of each warehouse table.

DuckDB's ``delta`` extension downloads itself at run time and fails offline, so each view
reads exactly the Parquet files listed by the table's current Delta snapshot:
``read_parquet([...], hive_partitioning=true, union_by_name=true)``. A glob over the table
folder would also read files that later commits replaced (double counting), so we never
glob. delta-rs keeps the ``date`` partition only in the path (``date=YYYY-MM-DD/``); the
view casts it (and every other column) explicitly to the canonical type.

``<warehouse>/surveil.duckdb`` holds these views for analysts. It is updated in a temporary
copy and swapped in with ``os.replace``; the pipeline never keeps it open. Each view carries
the digest of its statement as its comment (``duckdb_views().comment``), so an update
rewrites only the views whose table changed since the file was written (an ingest changes
three or four of ~30 tables); a missing or unreadable file is built from scratch. Ingest
prepares the update in a thread while it decodes (:class:`ViewsUpdate`).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import uuid
from collections.abc import Iterable
from pathlib import Path

import duckdb
import pyarrow as pa

from pipeline.tables import spec, table_specs
from pipeline.warehouse.delta import sql_literal, table_files

VIEWS_FILE = "surveil.duckdb"

_DUCKDB_TYPES: dict[pa.DataType, str] = {
    pa.int16(): "SMALLINT",
    pa.int32(): "INTEGER",
    pa.int64(): "BIGINT",
    pa.float64(): "DOUBLE",
    pa.string(): "VARCHAR",
    pa.bool_(): "BOOLEAN",
    pa.binary(): "BLOB",
    pa.date32(): "DATE",
}


def _ident(name: str) -> str:
    """Double-quoted SQL identifier."""
    return '"' + name.replace('"', '""') + '"'


def _duckdb_type(t: pa.DataType) -> str:
    try:
        return _DUCKDB_TYPES[t]
    except KeyError:
        raise TypeError(f"no DuckDB type mapped for Arrow {t}") from None


def _select_list(schema: pa.Schema, *, null: bool) -> str:
    cols = []
    for f in schema:
        src = "NULL" if null else _ident(f.name)
        cols.append(f"CAST({src} AS {_duckdb_type(f.type)}) AS {_ident(f.name)}")
    return ", ".join(cols)


def view_sql(name: str, files: list[str]) -> str:
    """``CREATE OR REPLACE VIEW`` statement of table ``name`` over ``files``.

    With no files the view is typed and empty (``... WHERE false``). File paths come from
    the Delta log and are quoted with ``sql_literal`` (DuckDB cannot bind parameters in a
    view definition).
    """
    s = spec(name).schema
    if not files:
        body = f"SELECT {_select_list(s, null=True)} WHERE false"
    else:
        file_list = ", ".join(sql_literal(f) for f in files)
        body = (
            f"SELECT {_select_list(s, null=False)} FROM read_parquet([{file_list}], "
            "hive_partitioning=true, union_by_name=true)"
        )
    return f"CREATE OR REPLACE VIEW {_ident(name)} AS {body}"


def register_tables(
    con: duckdb.DuckDBPyConnection, warehouse: Path, names: Iterable[str] | None = None
) -> list[str]:
    """Create one view per table (all canonical tables when ``names`` is None) in ``con``
    over the table's current snapshot; returns the view names."""
    selected = list(names) if names is not None else list(table_specs())
    for name in selected:
        con.execute(view_sql(name, table_files(warehouse, name)))
    return selected


def rebuild_views_file(warehouse: Path) -> Path:
    """Bring ``<warehouse>/surveil.duckdb`` up to date with the views of every table
    (:class:`ViewsUpdate` prepared and finished at once)."""
    update = ViewsUpdate(warehouse)
    update.prepare()
    return update.finish()


class ViewsUpdate:
    """An update of ``<warehouse>/surveil.duckdb`` in two steps.

    :meth:`prepare` opens a temporary copy of the file (a new database when there is none
    or it does not open) and brings every view to the tables' current snapshots;
    :meth:`finish` rewrites the views whose statement changed since (the tables a job
    committed to meanwhile, or a new schema), then swaps the copy in with ``os.replace``:
    an analyst opening the file sees the old or the new views. A job can run ``prepare``
    in a thread while it works, so that its end only pays for the tables it changed. The
    result equals a build from scratch (tests/warehouse/test_views.py checks it).
    """

    def __init__(self, warehouse: Path) -> None:
        self.warehouse = Path(warehouse)
        self.target = self.warehouse / VIEWS_FILE
        self._tmp = self.warehouse / f".{VIEWS_FILE}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self._con: duckdb.DuckDBPyConnection | None = None
        self._written: dict[str, str] = {}
        self._changed = False

    def prepare(self) -> None:
        """Open the temporary copy and write the views of the current snapshots."""
        self.warehouse.mkdir(parents=True, exist_ok=True)
        self._con = _copy_or_new(self.target, self._tmp)
        self._written = _view_digests(self._con)
        self._sync()

    def finish(self) -> Path:
        """Write the views changed since :meth:`prepare`; swap the file in if any view
        differs from the old file's (an unchanged file is left alone)."""
        if self._con is None:
            raise RuntimeError("ViewsUpdate.finish() before prepare()")
        try:
            self._sync()
            self._con.execute("CHECKPOINT")
            self._con.close()
            self._con = None
            if self._changed or not self.target.exists():
                os.replace(self._tmp, self.target)
        finally:
            self.discard()
        return self.target

    def discard(self) -> None:
        """Close and delete the temporary copy (the file stays as it was)."""
        if self._con is not None:
            self._con.close()
            self._con = None
        _remove_db_files(self._tmp)

    def _sync(self) -> None:
        assert self._con is not None
        for name in table_specs():
            sql = view_sql(name, table_files(self.warehouse, name))
            digest = _digest(sql)
            if self._written.get(name) != digest:
                self._con.execute(sql)
                self._con.execute(f"COMMENT ON VIEW {_ident(name)} IS {sql_literal(digest)}")
                self._written[name] = digest
                self._changed = True


def _digest(sql: str) -> str:
    return hashlib.sha256(sql.encode()).hexdigest()[:32]


def _copy_or_new(target: Path, tmp: Path) -> duckdb.DuckDBPyConnection:
    """A connection to ``tmp``: a copy of ``target`` when that opens, else a new database."""
    if target.exists():
        try:
            shutil.copyfile(target, tmp)
            return duckdb.connect(str(tmp))
        except (OSError, duckdb.Error):  # unreadable or not a database: build from scratch
            _remove_db_files(tmp)
    return duckdb.connect(str(tmp))


def _view_digests(con: duckdb.DuckDBPyConnection) -> dict[str, str]:
    """View name -> the digest its comment holds (views written by this module)."""
    rows = con.execute(
        "SELECT view_name, comment FROM duckdb_views() WHERE NOT internal AND comment IS NOT NULL"
    ).fetchall()
    return {name: comment for name, comment in rows}


def _remove_db_files(db: Path) -> None:
    for p in (db, db.with_name(db.name + ".wal")):
        with contextlib.suppress(FileNotFoundError):
            p.unlink()
