"""DuckDB views over the current Delta snapshot of each warehouse table.

DuckDB's ``delta`` extension downloads itself at run time and fails offline, so each view
reads exactly the Parquet files listed by the table's current Delta snapshot:
``read_parquet([...], hive_partitioning=true, union_by_name=true)``. A glob over the table
folder would also read files that later commits replaced (double counting), so we never
glob. delta-rs keeps the ``date`` partition only in the path (``date=YYYY-MM-DD/``); the
view casts it (and every other column) explicitly to the canonical type.

``<warehouse>/surveil.duckdb`` holds these views for analysts. It is updated in a temporary
copy and swapped in with ``os.replace``; the pipeline never keeps it open. There, each
table is two views: ``snapshot.<table>`` over the snapshot's files (rewritten after every
commit that changed the table), and ``main.<table>`` (``SELECT * FROM snapshot.<table>``)
carrying the table's doc as its comment and every column's ``[unit] meaning`` from
``schemas/`` as a column comment (``duckdb_columns()``, ``FROM describe_table('x')``):
writing ~550 comments costs ~0.5 s, so they sit on views that change only when the
schemas' docs do. The copy is attached to an in-memory DuckDB instance
(:class:`ViewsEngine`: the ingest's context owns one; other callers share a module
default). :meth:`ViewsEngine.warm_up` creates it in the background: building DuckDB's
function catalog costs ~40 ms per instance, and a job would otherwise pay it at its very
end, after the last write. Each snapshot view carries the digest of its statement and
the snapshot it reads (Delta version, when its log entry was written, the schema's view
code) as its comment (``duckdb_views().comment``), so an update reads the Delta log of,
and rewrites, only the tables whose snapshot changed since the file was written (an
ingest changes three or four of ~35 tables; opening a table's log costs ~3 ms); a
missing or unreadable file is built from scratch.

**Portable.** The snapshot views name their files relative to the warehouse folder
(``tables/<name>/date=.../part-....parquet``), so a copied or moved warehouse reads its
own files. DuckDB resolves a relative path against the working directory, then against
the ``file_search_path`` setting (not stored in the file): open the file from inside the
warehouse (``cd warehouse && duckdb surveil.duckdb``), or set the setting
(``duckdb -cmd "SET file_search_path='warehouse'" warehouse/surveil.duckdb``), or use
:func:`connect_views_file`. **Readable by DuckDB 1.x.** The file is written in the
storage format of :data:`STORAGE_VERSION` (``ATTACH ... (STORAGE_VERSION ...)``), which
every DuckDB 1.x opens (the 2.x default, storage version 69, makes the 1.x command line
fail with "we can only read versions between 64 and 68"); a file in another format is
built anew.

**Object storage.** A warehouse on object storage (``s3://``) has no views file: DuckDB
cannot write a database file there, and an analyst reads it with ``surveil sql`` (the
views of :func:`register_tables`, over each snapshot's pyarrow dataset on the
warehouse's own filesystem). :func:`rebuild_views_file` returns None there.

**Read-only for analysts.** ``surveil sql``, the reports and the audit do not use this
file: their in-memory connection (:func:`pipeline.reports.open_warehouse`) gets the
views of :func:`register_tables` over pyarrow datasets and is then locked
(:func:`lock_down`): DuckDB reaches no file by a path, so no statement can rewrite the
warehouse or read outside it. The file itself is for DuckDB's own command line, which
has every right of the user running it.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import logging
import os
import re
import shutil
import threading
import uuid
from collections.abc import Collection, Iterable
from pathlib import Path
from typing import Any

import duckdb
import pyarrow as pa

from pipeline.tables import column_comment, spec, table_specs
from pipeline.warehouse.crashpoints import crash_point
from pipeline.warehouse.damage import DamagedTableError
from pipeline.warehouse.delta import sql_literal, table_path, table_snapshot
from pipeline.warehouse.location import Location, as_location
from pipeline.warehouse.pending import pinned_versions

log = logging.getLogger(__name__)

VIEWS_FILE = "surveil.duckdb"
STORAGE_VERSION = "v1.0.0"  # the oldest storage format of DuckDB 1.x: every 1.x reads it
SNAPSHOT_SCHEMA = "snapshot"  # views over each table's current files, in surveil.duckdb
DESCRIBE_MACRO = "describe_table"  # FROM describe_table('radar_tracks'): columns, types, comments
_ATTACHED = "views_file"  # the name the temporary copy is attached under

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


def _select_list(schema: pa.Schema, *, null: bool, present: Collection[str] | None = None
                 ) -> str:
    cols = []
    for f in schema:
        src = "NULL" if null or (present is not None and f.name not in present) else _ident(f.name)
        cols.append(f"CAST({src} AS {_duckdb_type(f.type)}) AS {_ident(f.name)}")
    return ", ".join(cols)


def view_sql(name: str, files: list[str], schema: str | None = None,
             present: Collection[str] | None = None, root: Path | None = None,
             damage: str | None = None) -> str:
    """``CREATE OR REPLACE VIEW`` statement of table ``name`` over ``files``.

    With no files the view is typed and empty (``... WHERE false``), and DuckDB (2.0 on)
    binds it when it is first queried instead of when it is created: such a view cannot
    fail to bind, and binding its casts costs ~1 ms per view, most of writing the views
    of a new warehouse (27 of 30 tables empty). A view over files is bound at creation,
    so that a file missing from the snapshot fails the job, not an analyst's query.
    File paths come from the Delta log and are quoted with ``sql_literal`` (DuckDB cannot
    bind parameters in a view definition); with ``root`` (the warehouse), they are written
    relative to it, as in the views file. ``present``: the columns the table has (None:
    all); one the canonical schema gained after the table was written reads as NULL.
    ``damage``: the view is typed and raises this message when a query reads it.
    """
    s = spec(name).schema
    qualified = f"{_ident(schema)}.{_ident(name)}" if schema else _ident(name)
    if damage is not None:
        body = f"SELECT {_select_list(s, null=True)} WHERE error({sql_literal(damage)})"
        return f"CREATE OR REPLACE VIEW {qualified}{_DEFER_BINDING} AS {body}"
    if not files:
        body = f"SELECT {_select_list(s, null=True)} WHERE false"
        return f"CREATE OR REPLACE VIEW {qualified}{_DEFER_BINDING} AS {body}"
    if root is not None:
        base = os.path.abspath(root)
        files = [os.path.relpath(f, base) for f in files]
    file_list = ", ".join(sql_literal(f) for f in files)
    body = (
        f"SELECT {_select_list(s, null=False, present=_missing_only(s, present))} "
        f"FROM read_parquet([{file_list}], "
        "hive_partitioning=true, union_by_name=true)"
    )
    return f"CREATE OR REPLACE VIEW {qualified} AS {body}"


def _damaged_view_sql(name: str, message: str) -> str:
    """A view of a damaged table that fails with ``message`` when a query names it: when
    the query is bound (DuckDB 2.0 on, a deferred view), else when it runs."""
    error = f"error({sql_literal(message)})"
    if _DEFER_BINDING:
        return (f"CREATE OR REPLACE VIEW {_ident(name)}{_DEFER_BINDING} AS "
                f"SELECT * FROM read_parquet({error})")
    return (f"CREATE OR REPLACE VIEW {_ident(name)} AS SELECT NULL AS damaged "
            f"FROM range(1) WHERE {error} IS NULL")


def _missing_only(s: pa.Schema, present: Collection[str] | None) -> Collection[str] | None:
    """``present`` when it lacks a column of ``s``, else None (the usual case: the view's
    text stays the same as without it)."""
    if present is None or all(n in present for n in s.names):
        return None
    return present


def _defer_binding_clause(version: str) -> str:
    """`` WITH (DEFER_BINDING)`` where the DuckDB release accepts it (2.0 and later)."""
    found = re.match(r"(\d+)\.(\d+)", version)
    major_minor = (int(found[1]), int(found[2])) if found else (0, 0)
    return " WITH (DEFER_BINDING)" if major_minor >= (2, 0) else ""


_DEFER_BINDING = _defer_binding_clause(duckdb.__version__)


def view_statements(warehouse: Path, names: Iterable[str] | None = None) -> dict[str, str]:
    """Table name -> its ``CREATE OR REPLACE VIEW`` over the current snapshot (all
    canonical tables when ``names`` is None: then a damaged table's view fails when it is
    queried, naming the table and ``surveil doctor``, and the other views work; a table
    named in ``names`` must read: :class:`DamagedTableError`)."""
    if names is not None:
        return {name: _current_view_sql(warehouse, name) for name in names}
    out = {}
    for name in table_specs():
        try:
            out[name] = _current_view_sql(warehouse, name)
        except DamagedTableError as exc:
            out[name] = _damaged_view_sql(name, str(exc))
    return out


def _current_view_sql(warehouse: Path, name: str, schema: str | None = None,
                      root: Path | None = None) -> str:
    """:func:`view_sql` of ``name`` over its current snapshot (paths relative to
    ``root`` when given)."""
    files, present = table_snapshot(warehouse, name)
    return view_sql(name, files, schema, present, root)


def doc_view_statements(name: str) -> list[str]:
    """``main.<name>`` over ``snapshot.<name>``, with the table's doc as the view comment
    and ``[unit] meaning`` as each column's comment."""
    t = spec(name)
    view = f"main.{_ident(name)}"
    out = [
        f"CREATE OR REPLACE VIEW {view}{_DEFER_BINDING} AS "
        f"SELECT * FROM {_ident(SNAPSHOT_SCHEMA)}.{_ident(name)}",
        f"COMMENT ON VIEW {view} IS {sql_literal(t.doc)}",
    ]
    out += [f"COMMENT ON COLUMN {view}.{_ident(f.name)} IS {sql_literal(column_comment(f))}"
            for f in t.schema]
    return out


_DESCRIBE_SQL = (
    f"CREATE OR REPLACE MACRO main.{DESCRIBE_MACRO}(t) AS TABLE "
    "SELECT column_name, data_type, comment FROM duckdb_columns() "
    "WHERE database_name = current_database() AND schema_name = 'main' AND table_name = t "
    "ORDER BY column_index"
)


@functools.cache
def _docs_digest() -> str:
    """Digest of every ``main`` view statement and the describe macro: a change of the
    schemas' docs rewrites them all."""
    text = "\n".join([_DESCRIBE_SQL, *(s for n in table_specs() for s in doc_view_statements(n))])
    return _digest(text)


def register_tables(
    con: duckdb.DuckDBPyConnection, warehouse: Path | Location,
    names: Iterable[str] | None = None, *, refuse_damaged: bool = True
) -> list[str]:
    """Create one view per table (all canonical tables when ``names`` is None) in ``con``
    over the table's current snapshot; returns the view names.

    Each view reads the snapshot's pyarrow dataset (the Parquet files the Delta log
    lists, each checked against its recorded size:
    :func:`pipeline.warehouse.integrity.check_file_sizes`) on the warehouse's own
    filesystem, locally or on object storage: DuckDB itself opens no file of the
    warehouse, so a connection locked by :func:`lock_down` can neither read nor write
    one by a path (``surveil sql``, reports: issue 40). DuckDB pushes projections and
    filters into the dataset; each of its files carries the time range of its Delta
    statistics (:func:`~pipeline.warehouse.delta.reader_dataset`), so a filter on the
    time column opens only the files of its window. The tables' Delta logs are read in
    parallel: on object storage each costs round trips (~10-60 ms each on a store here),
    locally ~3 ms.

    A damaged table (its log unreadable, or its files not those its log records) raises
    its :class:`~pipeline.warehouse.damage.DamagedTableError`; with ``refuse_damaged``
    False (``surveil sql``: the other tables stay readable) its view raises that message
    instead when a query reads it."""
    from concurrent.futures import ThreadPoolExecutor

    from pipeline.warehouse.delta import reader_dataset

    loc = as_location(warehouse)
    selected = list(names) if names is not None else list(table_specs())
    pins = pinned_versions(loc)

    def dataset_of(name: str) -> Any:
        try:
            return reader_dataset(loc, name, pins)
        except DamagedTableError as exc:  # its log unreadable or its files changed
            if refuse_damaged:
                raise
            return exc

    with ThreadPoolExecutor(max(1, min(8, len(selected)))) as pool:
        found = list(pool.map(dataset_of, selected))
    for name, dataset in zip(selected, found, strict=True):
        s = spec(name).schema
        if dataset is None or isinstance(dataset, DamagedTableError):
            con.execute(view_sql(name, [], damage=None if dataset is None else str(dataset)))
            continue
        arrow = f"_surveil_arrow_{name}"
        con.register(arrow, dataset)
        present = _missing_only(s, set(dataset.schema.names))
        con.execute(f"CREATE OR REPLACE VIEW {_ident(name)} AS SELECT "
                    f"{_select_list(s, null=False, present=present)} FROM {_ident(arrow)}")
    return selected


def lock_down(con: duckdb.DuckDBPyConnection, write_dir: Path | None = None) -> None:
    """Make ``con`` reach no file and no network: external access off (no
    ``read_csv('/etc/passwd')``, ``COPY ... TO``, ``ATTACH``, ``INSTALL``/``LOAD``), no
    extension auto-installed or auto-loaded, and the configuration locked (no ``SET``
    undoes it). ``write_dir``: the one folder its statements may read and write
    (``surveil sql --allow-write-files``: exports). Call it after
    :func:`register_tables`; DuckDB's spill files (``temp_directory``) still work."""
    con.execute("SET autoinstall_known_extensions = false")
    con.execute("SET autoload_known_extensions = false")
    if write_dir is not None:
        folder = os.path.join(os.path.abspath(write_dir), "")  # a prefix: the trailing '/'
        con.execute(f"SET allowed_directories = [{sql_literal(folder)}]")
    con.execute("SET enable_external_access = false")
    con.execute("SET lock_configuration = true")


_TEMPLATE = "views_template"  # in-memory database: the documented views of a new file


class ViewsEngine:
    """The in-memory DuckDB connection that writes views files (one thread: it only
    writes views) and the template of a new file it holds, created on first use or by
    :meth:`warm_up`; :meth:`close` closes them. Thread-safe: a lock guards the
    connection's creation and every use."""

    def __init__(self) -> None:
        self._con: duckdb.DuckDBPyConnection | None = None
        self._template_digest: str | None = None
        self._lock = threading.Lock()
        self._warming: threading.Thread | None = None

    def warm_up(self, warehouse: Path | None = None) -> None:
        """Create the connection in a thread (DuckDB does it without the GIL), so that a
        job's decoding hides its cost. Given a ``warehouse`` without a views file yet,
        also the documented views a new file copies (~1 s of CPU: only then is it worth
        spending while the job works)."""
        new_file = (warehouse is not None and as_location(warehouse).is_local
                    and not (Path(warehouse) / VIEWS_FILE).exists())
        # not a daemon: the interpreter waits for it at exit. A job that stops early (a
        # damaged table: exit 2) would otherwise exit with a daemon thread still inside
        # DuckDB, which aborts the process (SIGABRT, "terminate called after throwing an
        # instance of ''", exit 134)
        self._warming = threading.Thread(
            target=self._warm, args=(new_file,), name="duckdb-warm-up", daemon=False
        )
        self._warming.start()

    def _warm(self, with_template: bool = False) -> None:
        with self._lock:
            con = self._connection()
            if with_template:
                self._docs_template(con)

    def _connection(self) -> duckdb.DuckDBPyConnection:
        """The connection (created now if need be); the caller holds ``_lock``."""
        if self._con is None:
            self._con = duckdb.connect(config={"threads": 1})
        return self._con

    def _docs_template(self, con: duckdb.DuckDBPyConnection) -> str:
        """Build (once per engine) the in-memory database holding what every views file
        shares: the ``snapshot`` schema with typed empty views, the ``main`` views with
        their ~550 comments and the describe macro. Writing those comments one by one
        costs ~1 s here; a new file copies them in ~25 ms (``COPY FROM DATABASE``), and
        :meth:`warm_up` builds this while the job decodes. Returns the docs digest; the
        caller holds ``_lock``."""
        if self._template_digest is None:
            digest = _docs_digest()
            con.execute(f"ATTACH ':memory:' AS {_TEMPLATE}")
            try:
                con.execute(f"USE {_TEMPLATE}")
                script = [f"CREATE SCHEMA {_ident(SNAPSHOT_SCHEMA)}"]
                for name in table_specs():
                    empty = view_sql(name, [], SNAPSHOT_SCHEMA)
                    script.append(empty)  # digest as in a file: a table without files stays
                    script.append(f"COMMENT ON VIEW {_ident(SNAPSHOT_SCHEMA)}.{_ident(name)} "
                                  f"IS {sql_literal(_digest(empty))}")
                    script += doc_view_statements(name)
                script.append(_DESCRIBE_SQL)
                script.append(
                    f"COMMENT ON MACRO TABLE main.{DESCRIBE_MACRO} IS {sql_literal(digest)}"
                )
                con.execute(";\n".join(["BEGIN", *script, "COMMIT"]))
            except BaseException:
                con.execute("USE memory")
                con.execute(f"DETACH DATABASE IF EXISTS {_TEMPLATE}")
                raise
            con.execute("USE memory")
            self._template_digest = digest
        return self._template_digest

    def close(self) -> None:
        """Wait for a warm-up still running, then close the connection."""
        if self._warming is not None:
            self._warming.join()
            self._warming = None
        with self._lock:
            if self._con is not None:
                self._con.close()
                self._con, self._template_digest = None, None

    def rebuild(self, warehouse: Path | Location) -> Path | None:
        """:func:`rebuild_views_file` through this engine."""
        return _rebuild(self, warehouse)


_SHARED = ViewsEngine()  # for callers without an engine of their own (batch, calibrate)


def warm_up(warehouse: Path | None = None) -> None:
    """:meth:`ViewsEngine.warm_up` of the engine shared by callers without their own."""
    _SHARED.warm_up(warehouse)


def rebuild_views_file(warehouse: Path | Location, engine: ViewsEngine | None = None
                       ) -> Path | None:
    """Bring ``<warehouse>/surveil.duckdb`` up to date with the views of every table.

    The views whose statement changed (their table got new files, or the code a new
    schema) are rewritten in a temporary copy of the file, which then replaces it with
    ``os.replace``: an analyst opening the file sees the old or the new views. An
    unchanged file is left alone. The result equals a build from scratch
    (tests/warehouse/test_views.py checks it). ``engine``: the DuckDB instance to work
    through (``None``: the shared one). None (nothing written) on object storage.
    """
    return _rebuild(engine if engine is not None else _SHARED, warehouse)


def rebuild_views_after_commits(warehouse: Path | Location,
                                engine: ViewsEngine | None = None) -> str | None:
    """:func:`rebuild_views_file` after a job's commits: a rebuild that fails on the disk
    (a full disk: ``OSError``, DuckDB's ``IOException``) leaves the commits standing and
    the file stale (the next writer or ``surveil doctor --repair`` rebuilds it); returns
    why it failed, logged, or None when it is up to date."""
    try:
        rebuild_views_file(warehouse, engine)
    except (OSError, duckdb.IOException) as exc:
        log.error("views file not rebuilt after the commits: %s", exc)
        return f"{type(exc).__name__}: {exc}"
    return None


def _rebuild(engine: ViewsEngine, warehouse: Path | Location) -> Path | None:
    if not as_location(warehouse).is_local:
        return None
    warehouse = Path(warehouse)
    warehouse.mkdir(parents=True, exist_ok=True)
    target = warehouse / VIEWS_FILE
    names = list(table_specs())
    pins = pinned_versions(warehouse)
    keys = {name: _snapshot_key(warehouse, name, pins) for name in names}
    tmp = warehouse / f".{VIEWS_FILE}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    try:
        with engine._lock:
            con = engine._connection()
            # the snapshot views' relative paths bind against the warehouse
            con.execute(f"SET file_search_path = {sql_literal(str(warehouse.resolve()))}")
            copied = _attach_copy_or_new(con, target, tmp)
            try:
                docs_digest = _docs_digest()
                if not copied:  # a new file: the documented views from the template
                    engine._docs_template(con)  # (building it leaves `USE memory`)
                    con.execute(f"USE {_ATTACHED}")
                    con.execute(f"COPY FROM DATABASE {_TEMPLATE} TO {_ATTACHED} (SCHEMA)")
                written = _view_digests(con)  # (the query costs ~10 ms)
                main = _main_comments(con)
                docs_changed = _macro_comment(con) != docs_digest
                # a view whose comment names the snapshot readers see now is up to date:
                # only the others' statements are made (~3 ms each: the Delta log read)
                statements = _changed_statements(
                    warehouse, [n for n in names if keys[n] is None
                                or written.get(n, "").partition(" ")[2] != keys[n]])
                digests = {n: _digest(sql) + (f" {keys[n]}" if keys[n] else "")
                           for n, sql in statements.items()}
                changed = [n for n in statements if written.get(n) != digests[n]]
                # a table no longer defined: its views (and those of older releases, which
                # kept the digest as the comment of the view in main)
                stale = [n for n in written if n not in keys]
                stale += [n for n, c in main.items()
                          if c is not None and n not in keys and n not in stale]
                main_changed = [n for n in names
                                if docs_changed or main.get(n) != spec(n).doc]
                if copied and not changed and not stale and not main_changed:
                    os.utime(target)  # up to date with the tables (views_stale)
                    return target
                script = [f"CREATE SCHEMA IF NOT EXISTS {_ident(SNAPSHOT_SCHEMA)}"]
                for name in stale:
                    script.append(f"DROP VIEW IF EXISTS main.{_ident(name)}")
                    script.append(
                        f"DROP VIEW IF EXISTS {_ident(SNAPSHOT_SCHEMA)}.{_ident(name)}")
                for name in changed:
                    script.append(statements[name])
                    script.append(
                        f"COMMENT ON VIEW {_ident(SNAPSHOT_SCHEMA)}.{_ident(name)} "
                        f"IS {sql_literal(digests[name])}"
                    )
                for name in main_changed:
                    script += doc_view_statements(name)
                if docs_changed:
                    script.append(_DESCRIBE_SQL)
                    script.append(f"COMMENT ON MACRO TABLE main.{DESCRIBE_MACRO} "
                                  f"IS {sql_literal(docs_digest)}")
                # one call, one transaction: ~20% less than a commit per statement (30 views)
                con.execute(";\n".join(["BEGIN", *script, "COMMIT"]))
                con.execute(f"CHECKPOINT {_ATTACHED}")
            finally:
                _detach(con)
                con.execute("RESET file_search_path")
        crash_point("views.written")
        os.replace(tmp, target)
        crash_point("views.replaced")
    finally:
        _remove_db_files(tmp)
    return target


def _changed_statements(warehouse: Path, names: list[str]) -> dict[str, str]:
    """The snapshot views of ``names`` (relative paths); a damaged table is left out, so
    its view stays as the file had it (its last good snapshot, or typed and empty in a
    new file) and the other tables' views are brought up to date."""
    out = {}
    for n in names:
        try:
            out[n] = _current_view_sql(warehouse, n, SNAPSHOT_SCHEMA, root=warehouse)
        except DamagedTableError as exc:
            log.warning("views file: %s (its view is left as it was)", exc)
    return out


def views_stale(warehouse: Path) -> bool:
    """Whether ``surveil.duckdb`` may be older than the tables: some table's newest Delta
    commit (``_delta_log/<version>.json``) is newer than the file (or the file is missing
    while tables exist). A job killed between its commits and its views rebuild leaves
    such a file. Costs a listing of each table's log; a rebuild that finds nothing to
    change touches the file, so a table pinned by a crashed job's marker does not make
    every later check rebuild. False on object storage (no views file there)."""
    if not as_location(warehouse).is_local:
        return False
    warehouse = Path(warehouse)
    try:
        built = (warehouse / VIEWS_FILE).stat().st_mtime_ns
    except FileNotFoundError:
        built = None
    tables_dir = warehouse / "tables"
    try:
        names = os.listdir(tables_dir)
    except FileNotFoundError:
        return False
    for name in names:
        log = tables_dir / name / "_delta_log"
        try:
            versions = [n for n in os.listdir(log) if n.endswith(".json") and n[:-5].isdigit()]
        except (FileNotFoundError, NotADirectoryError):
            continue
        if not versions:
            continue
        if built is None:
            return True
        newest = max(versions, key=lambda n: int(n[:-5]))
        with contextlib.suppress(FileNotFoundError):
            if (log / newest).stat().st_mtime_ns >= built:
                return True
    return False


def refresh_views_file(warehouse: Path) -> bool:
    """Rebuild ``surveil.duckdb`` when :func:`views_stale`; returns whether it did. Every
    writer job calls it when it takes the warehouse lock (``pipeline.warehouse.lock``)."""
    if not views_stale(warehouse):
        return False
    rebuild_views_file(warehouse)
    return True


def _snapshot_key(warehouse: Path, name: str, pins: dict[str, int]) -> str | None:
    """What a snapshot view's statement depends on besides the files: the schema's view
    code (the digest of its empty view), the Delta version readers see (pinned or the
    latest) and when that version's log entry was written (a table removed and made
    anew reuses version numbers). None when the log entry is gone: always rebuilt."""
    log = table_path(warehouse, name) / "_delta_log"
    version = pins.get(name)
    if version is None:
        try:
            found = [int(f[:-5]) for f in os.listdir(log)
                     if f.endswith(".json") and f[:-5].isdigit()]
        except (FileNotFoundError, NotADirectoryError):
            found = []
        version = max(found, default=-1)
    if version < 0:
        return f"{_empty_view_digest(name)}:none"
    try:
        written_ns = os.stat(log / f"{version:020d}.json").st_mtime_ns
    except FileNotFoundError:
        return None
    return f"{_empty_view_digest(name)}:{version}@{written_ns}"


@functools.cache
def _empty_view_digest(name: str) -> str:
    return _digest(view_sql(name, [], SNAPSHOT_SCHEMA))[:12]


def _digest(sql: str) -> str:
    return hashlib.sha256(sql.encode()).hexdigest()[:32]


def _attach_copy_or_new(con: duckdb.DuckDBPyConnection, target: Path, tmp: Path) -> bool:
    """Attach ``tmp`` to ``con`` as the default database: a copy of ``target`` when that
    opens (True), else a new database (False)."""
    if target.exists():
        try:
            shutil.copyfile(target, tmp)
            _attach(con, tmp)
            if _storage_version(con) == STORAGE_VERSION:
                return True
        except (OSError, duckdb.Error):  # unreadable or not a database: build from scratch
            pass
        # (or written in another storage format, e.g. by an older release)
        _detach(con)
        _remove_db_files(tmp)
    _attach(con, tmp)
    return False


def _attach(con: duckdb.DuckDBPyConnection, db: Path) -> None:
    con.execute(f"ATTACH {sql_literal(str(db))} AS {_ATTACHED} "
                f"(STORAGE_VERSION {sql_literal(STORAGE_VERSION)})")
    con.execute(f"USE {_ATTACHED}")


def _storage_version(con: duckdb.DuckDBPyConnection) -> str | None:
    """The storage format of the attached file (``v1.0.0``; DuckDB reports ``v1.0.0+``)."""
    rows = con.execute("SELECT tags['storage_version'] FROM duckdb_databases() "
                       "WHERE database_name = ?", [_ATTACHED]).fetchall()
    return rows[0][0].rstrip("+") if rows and rows[0][0] else None


def connect_views_file(warehouse: Path, *, read_only: bool = True
                       ) -> duckdb.DuckDBPyConnection:
    """A connection to ``<warehouse>/surveil.duckdb`` whose relative file paths resolve
    in the warehouse (``file_search_path``), wherever the process runs."""
    warehouse = Path(warehouse).resolve()
    con = duckdb.connect(str(warehouse / VIEWS_FILE), read_only=read_only)
    con.execute(f"SET file_search_path = {sql_literal(str(warehouse))}")
    return con


def _detach(con: duckdb.DuckDBPyConnection) -> None:
    """Back to the in-memory database; ``tmp`` detached (closed) if it was attached."""
    con.execute("USE memory")
    con.execute(f"DETACH DATABASE IF EXISTS {_ATTACHED}")


def _view_digests(con: duckdb.DuckDBPyConnection) -> dict[str, str]:
    """Snapshot view name -> the digest its comment holds (views written by this module)."""
    rows = con.execute(
        "SELECT view_name, comment FROM duckdb_views() WHERE NOT internal "
        "AND comment IS NOT NULL AND database_name = ? AND schema_name = ?",
        [_ATTACHED, SNAPSHOT_SCHEMA],
    ).fetchall()
    return {name: comment for name, comment in rows}


def _main_comments(con: duckdb.DuckDBPyConnection) -> dict[str, str | None]:
    """View name in ``main`` -> its comment (a table's doc; None: an analyst's view)."""
    rows = con.execute(
        "SELECT view_name, comment FROM duckdb_views() WHERE NOT internal "
        "AND database_name = ? AND schema_name = 'main'",
        [_ATTACHED],
    ).fetchall()
    return dict(rows)


def _macro_comment(con: duckdb.DuckDBPyConnection) -> str | None:
    """The docs digest the describe macro's comment holds (None: no macro yet)."""
    rows = con.execute(
        "SELECT comment FROM duckdb_functions() WHERE function_name = ? "
        "AND database_name = ? AND schema_name = 'main'",
        [DESCRIBE_MACRO, _ATTACHED],
    ).fetchall()
    return rows[0][0] if rows else None


def _remove_db_files(db: Path) -> None:
    for p in (db, db.with_name(db.name + ".wal")):
        with contextlib.suppress(FileNotFoundError):
            p.unlink()
