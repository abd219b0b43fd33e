"""``surveil doctor``: what is damaged in a warehouse, and the repairs the warehouse can
make itself (``pipeline.batch.doctor`` composes them with the batch that re-computes lost rows).

:func:`examine` checks every table under ``<warehouse>/tables/`` (reads only; on
object storage too, through :class:`~pipeline.warehouse.location.Location`):

- **log**: the Delta log reads. When it does not (its newest entry cut short by a full
  disk, a garbage file where the next version goes), the newest version that still reads
  is the *last good* one, and the entries after it are the broken ones.
- **files**: every data file the snapshot lists is there with the size its add action
  records (one listing of the table's folder: no request per file on object storage).
- **schema**: the columns, types and ``date`` partitioning ``schemas/`` declares (a
  nullable column the canonical schema gained after the table was written may be absent:
  the next write adds it); a folder under ``tables/`` that ``schemas/`` does not declare.
- **views**: ``surveil.duckdb`` is not older than the tables (``views_stale``).
- **leftovers** of dead jobs, when no job holds the warehouse: ``_staging/`` entries
  (ingest and batch staging, rewrites), temporary views files, pending markers
  (``pipeline.warehouse.pending``: a crashed job's tables read as before it).

The repairs here (``pipeline.batch.doctor`` runs them under the writer lock): :func:`restore_log`
moves the broken log entries aside (backed up under ``<warehouse>/_doctor/<time>/``), so
the table reads as at its last good version; :func:`forget_files` moves data files of the
wrong size aside and removes the references to missing ones (deltalake's FSCK,
``DeltaTable.repair``: one commit). :func:`lost_rows` says whose rows went with them:
the ``batch_units`` that owned the lost derived rows (to batch again), the archive files
whose raw rows went (``ingest_ledger``: to ingest again with ``surveil ingest --force``).
Both work on object storage too (a move there is a copy then a delete).
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote

import polars as pl
import pyarrow as pa
from deltalake import DeltaTable

from pipeline.tables import SITE, spec, table_specs
from pipeline.units import iso
from pipeline.warehouse import pending
from pipeline.warehouse.damage import DamagedTableError
from pipeline.warehouse.delta import open_delta, read_table, table_location
from pipeline.warehouse.location import Location, as_location
from pipeline.warehouse.lock import STAGING_DIR, held_by
from pipeline.warehouse.views import VIEWS_FILE, views_stale

DOCTOR_DIR = "_doctor"  # backups of what a repair moved aside: _doctor/<UTC time>/tables/...
LOST_RAW = "lost_raw.json"  # _doctor/: archive files whose raw rows a repair took out
LOG_DIR = "_delta_log"


@dataclass(frozen=True)
class Finding:
    """One problem: the table (or ``views``, ``_staging``, ``_pending``), what is wrong
    (a short name), the detail, and what ``--repair`` does about it."""

    table: str
    problem: str
    detail: str
    repair: str


@dataclass
class TableDamage:
    """A table whose log or files are damaged, with what a repair needs."""

    name: str
    good_version: int | None = None  # log broken: the newest version that reads (None: none)
    good_at_ns: int | None = None  # when that version was committed
    broken_entries: list[str] = field(default_factory=list)  # log files after it
    log_error: str | None = None
    bad_files: list[dict] = field(default_factory=list)  # their add actions (stats too)

    @property
    def kind(self) -> str:
        return spec(self.name).kind if self.name in table_specs() else "unknown"


@dataclass
class Examination:
    """What :func:`examine` found: the findings in order, the damaged tables, the pending
    markers of dead jobs and, when a job holds the warehouse, its lock's holder."""

    findings: list[Finding] = field(default_factory=list)
    damaged: dict[str, TableDamage] = field(default_factory=dict)
    markers: list[tuple[Location, dict]] = field(default_factory=list)
    busy: dict | None = None

    @property
    def healthy(self) -> bool:
        return not self.findings


def examine(warehouse: Path | Location, *, holding_lock: bool = False) -> Examination:
    """Check every table, the views file and the dead jobs' leftovers (module
    docstring). ``holding_lock``: the caller holds the writer lock (staging and markers
    are then a dead job's); otherwise a job holding it owns them and they are not
    checked (``busy`` says who)."""
    loc = as_location(warehouse)
    out = Examination()
    for name in _table_folders(loc):
        _examine_table(loc, name, out)
    if loc.is_local and views_stale(loc.path):
        out.findings.append(Finding(
            "views", "views_stale", f"{VIEWS_FILE} is older than the newest table commit "
            "(a job stopped between its commits and its views rebuild, or a full disk)",
            "rebuilt"))
    _examine_lost_raw(loc, out)
    out.busy = None if holding_lock else held_by(loc)
    if out.busy is None:
        _examine_leftovers(loc, out)
    return out


def _table_folders(loc: Location) -> list[str]:
    try:
        return sorted(n for n in (loc / "tables").listdir() if not n.startswith("."))
    except FileNotFoundError:
        return []


def _examine_table(loc: Location, name: str, out: Examination) -> None:
    table = loc / "tables" / name
    if name not in table_specs():
        out.findings.append(Finding(name, "unknown_table", f"tables/{name} is not a table "
                                    "schemas/ declares (another release's?)", "none: left alone"))
        return
    if not (table / LOG_DIR).is_dir() or not (table / LOG_DIR).listdir(missing_ok=True):
        return  # (a folder without a log: never committed, or its log set aside)
    try:
        dt = open_delta(table)
    except DamagedTableError as exc:
        damage = _log_damage(table, name, exc.detail)
        out.damaged[name] = damage
        out.findings.append(Finding(name, "log_unreadable", _log_detail(damage),
                                    _log_repair(damage)))
        return
    bad = _bad_files(table, pa.table(dt.get_add_actions(flatten=True)))
    if bad:
        out.damaged[name] = TableDamage(name, bad_files=bad)
        for f in bad:
            out.findings.append(Finding(name, f["problem"], f["detail"], _file_repair(name)))
    out.findings += [Finding(name, "schema", text, "none: rebuild the table from the archive "
                             "(docs/operations.md, 'A damaged warehouse')")
                     for text in schema_problems(name, dt)]


def _versions(table: Location) -> list[int]:
    names = (table / LOG_DIR).listdir(missing_ok=True)
    return sorted(int(n[:-5]) for n in names if n.endswith(".json") and n[:-5].isdigit())


def _log_damage(table: Location, name: str, detail: str) -> TableDamage:
    """The newest version of ``table`` that reads, and the log entries after it."""
    versions = _versions(table)
    damage = TableDamage(name, log_error=detail)
    for v in reversed(versions):
        try:
            open_delta(table, version=v)
        except (DamagedTableError, OSError):
            continue
        damage.good_version, damage.good_at_ns = v, _committed_at_ns(table, v)
        break
    after = -1 if damage.good_version is None else damage.good_version
    damage.broken_entries = [f"{v:020d}.json" for v in versions if v > after]
    return damage


def _committed_at_ns(table: Location, version: int) -> int:
    """The commitInfo timestamp of ``version`` (its log entry's mtime without one)."""
    entry = table / LOG_DIR / f"{version:020d}.json"
    for line in entry.read_text().splitlines():
        try:
            info = json.loads(line).get("commitInfo")
        except ValueError:
            continue
        if info and isinstance(info.get("timestamp"), int):
            return info["timestamp"] * 1_000_000
    return entry.stat()[1]


def _log_detail(d: TableDamage) -> str:
    entries = ", ".join(f"{LOG_DIR}/{e}" for e in d.broken_entries) or "(none found)"
    good = ("no version reads" if d.good_version is None
            else f"version {d.good_version} ({iso(d.good_at_ns or 0)}) is the last that reads")
    return f"{d.log_error}; broken: {entries}; {good}"


def _log_repair(d: TableDamage) -> str:
    if d.good_version is None:
        return ("moves its log aside and batches every unit again (a table the batch "
                "writes; any other: none, rebuild it from the archive)"
                if d.kind == "derived" else
                "none: no version reads; rebuild the table from the archive")
    then = ("re-batches the units committed since" if d.kind == "derived"
            else "names the archive files ingested since, to ingest again"
            if d.kind == "raw" else "`surveil run` redoes what it recorded since")
    return (f"moves the broken entries aside (backed up under {DOCTOR_DIR}/): the table "
            f"reads as at version {d.good_version}; {then}")


def _file_repair(name: str) -> str:
    kind = spec(name).kind
    if kind == "derived":
        return "removes its reference (FSCK) and re-batches the units that owned its rows"
    if kind == "raw":
        return ("removes its reference (FSCK) and names the archive files that fed it, to "
                "ingest again (`surveil ingest --force FILE`)")
    return "removes its reference (FSCK); `surveil run` redoes what its rows recorded"


def _bad_files(table: Location, adds: pa.Table) -> list[dict]:
    """The add actions (as dicts, stats included) whose file is missing or of another
    size than recorded, each with ``problem`` and ``detail``."""
    if adds.num_rows == 0:
        return []
    import pyarrow.fs as pafs

    base = table.fs_path
    infos = table.fs.get_file_info(pafs.FileSelector(base, recursive=True,
                                                     allow_not_found=True))
    sizes = {i.path[len(base) + 1:]: i.size for i in infos if i.type == pafs.FileType.File}
    out = []
    for row in adds.to_pylist():
        rel = unquote(row["path"])
        have = sizes.get(rel)
        if have is None:
            row.update(problem="file_missing", detail=f"{rel} ({row['size_bytes']:,} bytes, "
                       f"{row.get('num_records') or 0:,} rows) is listed but missing")
        elif have != row["size_bytes"]:
            row.update(problem="file_size", detail=f"{rel} is {have:,} bytes, the log "
                       f"records {row['size_bytes']:,} (rewritten or cut short)")
        else:
            continue
        row["rel"] = rel
        out.append(row)
    return out


_SAME_TYPE = {pa.large_string(): pa.string(), pa.string_view(): pa.string(),
              pa.large_binary(): pa.binary()}


def schema_problems(name: str, dt: DeltaTable) -> list[str]:
    """How the Delta table ``dt``'s schema and partitioning differ from what
    ``schemas/`` declares for ``name`` (empty: as declared)."""
    want = spec(name).schema
    have = pa.schema(dt.schema().to_arrow())
    out = []
    for f in have:
        if f.name not in want.names:
            out.append(f"column {f.name} is not in schemas/")
            continue
        t, w = _SAME_TYPE.get(f.type, f.type), want.field(f.name).type
        if t != w:
            out.append(f"column {f.name} is {f.type}, schemas/ declares {w}")
    out += [f"column {f.name} ({f.type}, not null) is missing" for f in want
            if f.name not in have.names and not f.nullable]
    parts = list(dt.metadata().partition_columns)
    if parts != list(spec(name).partition_by):
        out.append(f"partitioned by {parts or 'nothing'}, schemas/ declares "
                   f"{list(spec(name).partition_by) or 'none'}")
    return out


def _lost_raw(loc: Location) -> dict[str, dict]:
    """``_doctor/lost_raw.json``: archive file -> {tables, at_ns} whose raw rows an
    earlier repair took out and that have not been ingested again since."""
    note = loc / DOCTOR_DIR / LOST_RAW
    try:
        found = json.loads(note.read_text())
    except (OSError, ValueError):
        return {}
    if not found:
        return {}
    try:
        ledger = pl.from_arrow(read_table(loc, "ingest_ledger",
                                          columns=["source_file", "ingested_at_ns"]))
    except DamagedTableError:
        return found
    since = dict(ledger.group_by("source_file").agg(pl.col("ingested_at_ns").max()).iter_rows())
    return {f: e for f, e in found.items() if (since.get(f) or 0) <= e["at_ns"]}


def record_lost_raw(warehouse: Path | Location, files: dict[str, list[str]]) -> None:
    """Remember the archive files (-> the raw tables) whose rows a repair just took
    out, so that every later ``surveil doctor`` names them until they are ingested
    again."""
    loc = as_location(warehouse)
    kept = _lost_raw(loc)
    now = time.time_ns()
    for f, names in files.items():
        kept[f] = {"tables": sorted(set(names) | set(kept.get(f, {}).get("tables", []))),
                   "at_ns": now}
    note = loc / DOCTOR_DIR / LOST_RAW
    note.parent.mkdir()
    note.write_atomic(json.dumps(kept, indent=1, sort_keys=True).encode())


def _examine_lost_raw(loc: Location, out: Examination) -> None:
    for f, e in sorted(_lost_raw(loc).items()):
        out.findings.append(Finding(
            ", ".join(e["tables"]), "raw_rows_lost", f"rows of {f} were taken out by a repair "
            f"at {iso(e['at_ns'])} (their data file was lost) and not ingested since",
            f"none: `surveil ingest --force {f}`, then `surveil run`"))


def _examine_leftovers(loc: Location, out: Examination) -> None:
    staging = loc / STAGING_DIR
    for entry in sorted(staging.listdir(missing_ok=True)):
        out.findings.append(Finding(STAGING_DIR, "orphan_staging", f"{STAGING_DIR}/{entry} "
                                    "left by a job that stopped", "removed"))
    if loc.is_local:
        for tmp in sorted(loc.path.glob(f".{VIEWS_FILE}.tmp-*")):
            out.findings.append(Finding("views", "orphan_staging", f"{tmp.name} left by a "
                                        "killed views rebuild", "removed"))
    out.markers = pending.markers(loc)
    for path, doc in out.markers:
        out.findings.append(Finding(pending.PENDING_DIR, "pending_marker",
                                    _marker_detail(path, doc), _marker_repair(doc)))


def _marker_detail(path: Location, doc: dict) -> str:
    pins = ", ".join(sorted(doc.get("pins", {})))
    what = (f"window [{iso(doc['window'][0])}, {iso(doc['window'][1])})"
            f"{' of site ' + doc['site'] if doc.get('site') else ''}"
            if doc.get("job") == "batch" and doc.get("window") else doc.get("source_file", "?"))
    return (f"{path.name}: a {doc.get('job', '?')} job ({what}) stopped between its commits; "
            f"readers see these tables as before it: {pins}")


def _marker_repair(doc: dict) -> str:
    if doc.get("job") == "batch" and doc.get("window"):
        return "re-batches the window (which removes the marker)"
    return (f"none: ingest the file again (`surveil ingest --force "
            f"{doc.get('source_file', 'FILE')}`), which removes the marker")


# --- repairs (under the writer lock) ---------------------------------------------------


def backup_folder(warehouse: Path | Location) -> Location:
    """``<warehouse>/_doctor/<UTC time>``: where one repair backs up what it moves."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    return as_location(warehouse) / DOCTOR_DIR / stamp


def _move_aside(src: Location, backup: Location, rel: str) -> None:
    target = backup / rel
    target.parent.mkdir()
    src.move_to(target)


def restore_log(warehouse: Path | Location, damage: TableDamage, backup: Location) -> None:
    """Move the broken log entries of ``damage`` (and checkpoints after the last good
    version) aside into ``backup``: the table then reads as at its last good version,
    and its next commit writes the version after it."""
    if damage.good_version is None:
        raise ValueError(f"table {damage.name}: no version reads; nothing to restore")
    log = table_location(warehouse, damage.name) / LOG_DIR
    rel = f"tables/{damage.name}/{LOG_DIR}"
    for entry in damage.broken_entries:
        _move_aside(log / entry, backup, f"{rel}/{entry}")
    for n in log.listdir(missing_ok=True):  # a checkpoint of a version moved aside
        head = n.split(".", 1)[0]
        if ".checkpoint" in n and head.isdigit() and int(head) > damage.good_version:
            _move_aside(log / n, backup, f"{rel}/{n}")
    last = log / "_last_checkpoint"
    if last.exists():
        try:
            newer = json.loads(last.read_text()).get("version", -1) > damage.good_version
        except ValueError:
            newer = True
        if newer:
            _move_aside(last, backup, f"{rel}/_last_checkpoint")


def set_aside_log(warehouse: Path | Location, damage: TableDamage, backup: Location) -> None:
    """Move every entry of ``damage``'s log aside into ``backup`` (no version of it
    reads): the table then reads as absent (empty), its data files unreferenced, and its
    next commit is its version 0. For a table the batch re-computes whole."""
    log = table_location(warehouse, damage.name) / LOG_DIR
    rel = f"tables/{damage.name}/{LOG_DIR}"
    for n in log.listdir(missing_ok=True):
        _move_aside(log / n, backup, f"{rel}/{n}")


def forget_files(warehouse: Path | Location, damage: TableDamage, backup: Location
                 ) -> list[str]:
    """Move ``damage``'s files of the wrong size aside into ``backup``, then remove the
    references to every missing file in one commit (``DeltaTable.repair``, FSCK).
    Returns the files whose references were removed."""
    table = table_location(warehouse, damage.name)
    for f in damage.bad_files:
        if f["problem"] == "file_size":
            _move_aside(table / f["rel"], backup, f"tables/{damage.name}/{f['rel']}")
    removed = open_delta(table).repair(dry_run=False).get("files_removed", [])
    return [unquote(r) for r in removed]


@dataclass
class LostRows:
    """Whose rows a repair took out: ``spans`` (site, start_ns, end_ns) of the committed
    ``batch_units`` to batch again; ``archive_files`` to ingest again; ``tables`` not
    re-computed by the batch nor the ingest (derived tables of other jobs: calibrations)."""

    spans: list[tuple[str, int, int]] = field(default_factory=list)
    archive_files: dict[str, list[str]] = field(default_factory=dict)  # -> raw tables
    raw_spans: list[tuple[str, int, int]] = field(default_factory=list)  # (site, lo, hi)
    ledgers: list[str] = field(default_factory=list)  # ledger tables that lost entries


def lost_rows(warehouse: Path | Location, damaged: Iterable[TableDamage]) -> LostRows:
    """What the repairs of ``damaged`` took out (read after them: the tables read
    again). A derived table's rows go back to the units that owned them: those whose
    site and span meet a lost file's statistics, or, for a log restored to an earlier
    version, every unit committed since that version; a raw table's to the ledger's
    archive files within a lost file's ``source_file`` statistics, or ingested since."""
    out = LostRows()
    units = ledger = None
    for d in damaged:
        kind = d.kind
        if kind == "derived":
            if units is None:
                units = pl.from_arrow(read_table(warehouse, "batch_units"))
            out.spans += _owning_units(units, d, spec(d.name).time_column)
        elif kind == "raw":
            if ledger is None:
                ledger = pl.from_arrow(read_table(warehouse, "ingest_ledger"))
            fed = _feeding_files(ledger, d)
            for f in fed["source_file"]:
                out.archive_files.setdefault(f, []).append(d.name)
            out.raw_spans += [(r[0], int(r[1]), int(r[2]) + 1) for r in fed.select(
                SITE, "start_time_ns", "end_time_ns").drop_nulls().iter_rows()]
        else:
            out.ledgers.append(d.name)
    out.spans = sorted(set(out.spans))
    return out


def _between(col: str, lo: object, hi: object) -> pl.Expr:
    if lo is None or hi is None:
        return pl.lit(True)
    return (pl.col(col) >= lo) & (pl.col(col) <= hi)


def _owning_units(units: pl.DataFrame, d: TableDamage, time_col: str
                  ) -> list[tuple[str, int, int]]:
    if units.height == 0:
        return []
    picked = []
    if d.good_at_ns is not None:
        picked.append(units.filter(pl.col("committed_at_ns") > d.good_at_ns))
    for f in d.bad_files:
        lo, hi = f.get(f"min.{time_col}"), f.get(f"max.{time_col}")
        near = _between(SITE, f.get(f"min.{SITE}"), f.get(f"max.{SITE}"))
        if lo is not None and hi is not None:
            near = near & (pl.col("start_ns") <= hi) & (pl.col("end_ns") > lo)
        picked.append(units.filter(near))
    if not picked:
        return []
    rows = pl.concat(picked).select(SITE, "start_ns", "end_ns").unique()
    return [(r[0], int(r[1]), int(r[2])) for r in rows.iter_rows()]


def _feeding_files(ledger: pl.DataFrame, d: TableDamage) -> pl.DataFrame:
    """The ledger rows of the archive files whose raw rows ``d``'s repair took out."""
    if ledger.height == 0:
        return ledger
    picked = []
    if d.good_at_ns is not None:
        picked.append(ledger.filter(pl.col("ingested_at_ns") > d.good_at_ns))
    for f in d.bad_files:
        near = (_between("source_file", f.get("min.source_file"), f.get("max.source_file"))
                & _between(SITE, f.get(f"min.{SITE}"), f.get(f"max.{SITE}")))
        picked.append(ledger.filter(near))
    if not picked:
        return ledger.clear()
    return pl.concat(picked).unique("source_file").sort("source_file")


def findings_table(findings: list[Finding]) -> pa.Table:
    """The findings as a table (table, problem, detail, repair) for ``format_report``."""
    return pa.table({
        "table": [f.table for f in findings], "problem": [f.problem for f in findings],
        "detail": [f.detail for f in findings], "repair": [f.repair for f in findings],
    })
