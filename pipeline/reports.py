"""Report queries: load ``<name>.sql`` from the shipped ``sql/`` folder or a user report
folder (``[reports] dirs``), and run it in DuckDB with bound parameters.

Every report takes the window and sector parameters, always bound, never pasted into SQL
text: ``$start_ns`` and ``$end_ns`` (int64 ns UTC, half-open window) and ``$sector`` (a
sector name, or ``None`` for every sector). Requirement figures come from the config's
``[requirements]`` (``$ed87_manoeuvring_p95_m``, ...: :mod:`pipeline.requirements`). A
report may declare more parameters in its header, each with a default and bounds
(``$step_s (DOUBLE, default 20, >= 0.001)``), that a caller may override; a number must
be finite and within the bounds.

Header (every file, shipped or user's)::

    -- name: <the file stem>
    -- description: what the report answers (continuation lines start with "--  ")
    -- grain: what one row is
    -- params: $start_ns (BIGINT, inclusive), $end_ns (BIGINT, exclusive), $sector (VARCHAR),
    --         $site (VARCHAR, NULL = every site)

``$site`` is bound too (None: every site); a report over per-site rows filters on it and
groups by ``site`` so that sites are reported apart, never summed.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import operator
import os
import re
import tempfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import duckdb
import pyarrow as pa
import pyarrow.csv as pacsv

from pipeline.config import Config
from pipeline.configspec import Document, setting
from pipeline.errors import UsageError
from pipeline.requirements import ConfigSection, RequirementsConfig, requirements_config
from pipeline.resources import resource_path
from pipeline.tables import table_specs
from pipeline.threads import machine_memory_bytes
from pipeline.warehouse.location import Location
from pipeline.warehouse.views import lock_down, register_tables

_HEADER = re.compile(r"^--\s*(\w[\w ]*?):\s*(.*)$")
_PARAM = re.compile(r"\$(\w+)\s*(?:\(([^)]*)\))?")
_COMMENT = re.compile(r"--[^\n]*")
_NAME = re.compile(r"[A-Za-z0-9_]+")
_BOUND = re.compile(r"(>=|<=|>|<)\s*([-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)")
_BOUND_OPS = {">": operator.gt, ">=": operator.ge, "<": operator.lt, "<=": operator.le}
WINDOW_PARAMS = ("start_ns", "end_ns", "sector", "site")
REQUIRED_HEADER = ("name", "description", "params")


class UnknownReportError(KeyError):
    """No ``<name>.sql`` in the shipped or the user report folders."""


class ReportError(ValueError):
    """A report file is malformed, or a parameter is missing or of the wrong type."""


@dataclass(frozen=True)
class ReportParam:
    """A ``$name`` of a report header: DuckDB type (when declared), default (text,
    when declared) and the rest of its parenthesis."""

    name: str
    sql_type: str | None = None
    default: str | None = None
    doc: str = ""
    bounds: tuple[tuple[str, float], ...] = ()  # ((">", 0.0), ...): what a value must be

    def convert(self, value: Any) -> Any:
        """A value given as text (command line) -> the declared type's Python value,
        checked: a DOUBLE is finite (no ``inf``, ``nan``) and every value within the
        header's bounds (``$step_s (DOUBLE, default 20, >= 0.001)``); ReportError
        otherwise."""
        got = self._parsed(value)
        if isinstance(got, float) and not math.isfinite(got):
            raise ReportError(f"parameter ${self.name} must be a finite number, not {value!r}")
        if isinstance(got, int | float) and not isinstance(got, bool):
            for op, limit in self.bounds:
                if not _BOUND_OPS[op](got, limit):
                    raise ReportError(f"parameter ${self.name} must be {op} {limit:g}, "
                                      f"not {value!r}")
        return got

    def _parsed(self, value: Any) -> Any:
        if not isinstance(value, str):
            return value
        t = (self.sql_type or "").upper()
        try:
            if t in ("BIGINT", "INTEGER", "INT", "SMALLINT", "HUGEINT"):
                return int(value)
            if t in ("DOUBLE", "FLOAT", "REAL", "DECIMAL"):
                return float(value)
            if t == "BOOLEAN":
                if value.lower() not in ("true", "false", "1", "0"):
                    raise ValueError(value)
                return value.lower() in ("true", "1")
        except ValueError:
            raise ReportError(f"parameter ${self.name} must be {t}, not {value!r}") from None
        if t in ("VARCHAR", "TEXT", "STRING"):
            return None if value.upper() == "NULL" else value
        for conv in (int, float):  # no declared type: the narrowest that reads it
            try:
                return conv(value)
            except ValueError:
                pass
        return value


@dataclass(frozen=True)
class ReportSql:
    name: str
    path: Path
    text: str
    header: dict[str, str]
    params: tuple[ReportParam, ...] = ()
    shipped: bool = True
    used: frozenset[str] = field(default_factory=frozenset)

    @property
    def description(self) -> str:
        return self.header.get("description", "")

    @property
    def origin(self) -> str:
        return "shipped" if self.shipped else str(self.path.parent)

    def param(self, name: str) -> ReportParam | None:
        return next((p for p in self.params if p.name == name), None)

    def tables_used(self) -> list[str]:
        """The warehouse tables the report's SQL names (outside comments): the views a
        connection for it needs (opening each costs a Delta log read: ~3 ms locally,
        more on object storage)."""
        body = _COMMENT.sub("", self.text)
        words = set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", body))
        return [name for name in table_specs() if name in words]

    def source_tables(self) -> list[str]:
        """Tables named by the header's ``source table(s):`` line."""
        text = self.header.get("source tables", self.header.get("source table", ""))
        # each name may carry a remark in parentheses ("channel_health (airfield), ..."):
        # the names are what remains once the remarks are removed (was: the text before
        # the first parenthesis, so only the first table of such a list)
        text = re.sub(r"\([^)]*(\)|$)", "", text)
        return [t.strip() for t in text.split(",") if _NAME.fullmatch(t.strip())]


def _folders(dirs: tuple[str, ...]) -> str | None:
    return None if all(d.strip() for d in dirs) else "folder paths must not be empty"


@dataclass(frozen=True)
class _ReportsSection:
    """``[reports]`` as written: ``dirs``, folder paths relative to the config file."""

    dirs: tuple[str, ...] = setting([], check=_folders)


@dataclass(frozen=True)
class ReportsConfig:
    """``[reports]``: user report folders (absolute), listed and run beside ``sql/``."""

    dirs: tuple[Path, ...] = ()


def parse_reports_section(doc: Document, core: Any = None) -> ReportsConfig | None:
    """``[reports]`` (no folders when absent); each folder must exist."""
    got = doc.read(_ReportsSection, "reports")
    if got is None:
        return None
    base = Path(doc.source).parent if doc.source and not doc.source.startswith("(") \
        else Path.cwd()
    out = []
    for i, d in enumerate(got.dirs):
        p = Path(d).expanduser()
        p = p if p.is_absolute() else base / p
        if not p.is_dir():
            doc.problem(("reports", "dirs", i), f"{p} is not a folder")
        out.append(p.resolve())
    return ReportsConfig(tuple(out))


REPORTS_SECTION = ConfigSection("reports", ("reports",), parse_reports_section)


def reports_config(cfg: Any) -> ReportsConfig:
    """The ``[reports]`` of a loaded config (no user folders when loaded without)."""
    got = (getattr(cfg, "families", {}) or {}).get("reports")
    return got if isinstance(got, ReportsConfig) else ReportsConfig()


def sql_dir() -> Path:
    return resource_path("sql")


def _files(dirs: Iterable[Path]) -> dict[str, tuple[Path, bool]]:
    """Report name -> (file, shipped); a user report may not reuse a name."""
    found: dict[str, tuple[Path, bool]] = {p.stem: (p, True) for p in sql_dir().glob("*.sql")}
    for d in dirs:
        for p in sorted(Path(d).glob("*.sql")):
            if p.stem in found:
                raise ReportError(f"report {p.stem!r} is defined twice: {found[p.stem][0]} "
                                  f"and {p}; rename one")
            found[p.stem] = (p, False)
    return found


def list_reports(dirs: Sequence[Path] = ()) -> list[str]:
    """Every report name, shipped and in ``dirs``, sorted."""
    return sorted(_files(dirs))


def parse_header(text: str) -> dict[str, str]:
    """The ``-- key: value`` lines at the top of a report (continuations joined)."""
    header: dict[str, str] = {}
    last_key = None
    for line in text.splitlines():
        if not line.startswith("--"):
            break
        m = _HEADER.match(line)
        if m and not line.startswith("--  "):
            last_key = m.group(1).strip()
            header[last_key] = m.group(2).strip()
        elif last_key:  # continuation line of the previous key
            header[last_key] += " " + line.lstrip("- ").strip()
    return header


def parse_params(text: str) -> tuple[ReportParam, ...]:
    """``$name (TYPE, ..., default X)`` items of a ``params:`` header value. A type given
    once for a run of names (``$a, $b (DOUBLE)``) applies to the whole run."""
    out: list[ReportParam] = []
    pending: list[str] = []
    for m in _PARAM.finditer(text):
        name, paren = m.group(1), m.group(2)
        if paren is None:
            pending.append(name)
            continue
        parts = [p.strip() for p in paren.split(",")]
        sql_type = parts[0].upper() if parts and re.fullmatch(r"[A-Za-z]+", parts[0]) else None
        default = next((p.split(None, 1)[1] for p in parts
                        if p.lower().startswith("default ") and len(p.split(None, 1)) == 2),
                       None)
        bounds = tuple((m[1], float(m[2])) for m in map(_BOUND.fullmatch, parts) if m)
        for n in [*pending, name]:
            out.append(ReportParam(n, sql_type, default if n == name else None, paren.strip(),
                                   bounds))
        pending = []
    out += [ReportParam(n) for n in pending]
    return tuple(out)


def load_report(name: str, dirs: Sequence[Path] = ()) -> ReportSql:
    """Read report ``name`` (shipped ``sql/`` or a folder of ``dirs``) and its header."""
    if not _NAME.fullmatch(name or ""):
        raise UnknownReportError(name)
    found = _files(dirs).get(name)
    if found is None:
        raise UnknownReportError(name)
    path, shipped = found
    text = path.read_text()
    header = parse_header(text)
    missing = [k for k in REQUIRED_HEADER if k not in header]
    if missing:
        raise ReportError(f"{path}: header lacks {', '.join('-- ' + k + ':' for k in missing)} "
                          "(see sql/README.md)")
    if header["name"] != name:
        raise ReportError(f"{path}: header names {header['name']!r}, the file {name!r}")
    body = _COMMENT.sub("", text)
    return ReportSql(name=name, path=path, text=text, header=header,
                     params=parse_params(header["params"]), shipped=shipped,
                     used=frozenset(re.findall(r"\$(\w+)", body)))


@dataclass(frozen=True)
class SiteGeometry:
    """The config's polygons a report tests positions against, bound as
    ``$site_polygons``: a list of edges ``{kind, name, ord, lat1, lon1, lat2, lon2}``
    (deg), ``kind`` ``sector`` (``[[sectors]]``, ``ord`` their order: a point belongs to
    the first that holds it), ``land`` (``[[gaps.islands]]``) or ``water``
    (``[[gaps.admissible]]``). A report finds the polygons holding a point by counting
    the edges a ray from it crosses (even-odd rule, in lat/lon: exact for the polygons'
    straight edges in degrees, as the batch's sectors are drawn). Empty when the config
    declares none: the reports then say "no sectors" / "no coastline"."""

    polygons: tuple[tuple[str, str, tuple[tuple[float, float], ...]], ...] = ()

    def edges(self) -> list[dict[str, Any]]:
        out = []
        for order, (kind, name, ring) in enumerate(self.polygons):
            pts = list(ring)
            for (lat1, lon1), (lat2, lon2) in zip(pts, pts[1:] + pts[:1], strict=True):
                out.append({"kind": kind, "name": name, "ord": order, "lat1": float(lat1),
                            "lon1": float(lon1), "lat2": float(lat2), "lon2": float(lon2)})
        return out


def site_geometry(cfg: Any) -> SiteGeometry:
    """The sectors, land and water of a loaded config (:class:`SiteGeometry`); the one
    place that reads them for the reports. Land and water come from the ``[gaps]``
    section when the config has one (its islands and admissible areas), else none."""
    polys: list[tuple[str, str, tuple[tuple[float, float], ...]]] = []
    for sec in getattr(cfg, "sectors", ()) or ():
        polys.append(("sector", sec.name, tuple(sec.polygon_lat_lon_deg)))
    gaps = (getattr(cfg, "families", {}) or {}).get("gaps")
    for kind, attr in (("land", "islands"), ("water", "admissible")):
        for p in getattr(gaps, attr, ()) or ():
            polys.append((kind, p.name, tuple(p.polygon_lat_lon_deg)))
    return SiteGeometry(tuple(polys))


def bind_params(
    report: ReportSql,
    *,
    start_ns: int,
    end_ns: int,
    sector: str | None,
    requirements: RequirementsConfig | None = None,
    params: Mapping[str, Any] | None = None,
    site: str | None = None,
    geometry: SiteGeometry | None = None,
) -> dict[str, Any]:
    """The values of every ``$name`` the report's SQL uses: the window and sector, the
    requirement figures, the site's polygons (``$site_polygons``, :class:`SiteGeometry`;
    none when ``geometry`` is None), the caller's ``params`` (text is converted to the
    declared type), then the header's defaults. ReportError names any parameter left
    unbound."""
    given = dict(params or {})
    unknown = set(given) - {p.name for p in report.params} - set(WINDOW_PARAMS)
    if unknown:
        raise ReportError(f"report {report.name} has no parameter(s) "
                          f"{', '.join('$' + u for u in sorted(unknown))}; it takes "
                          + ", ".join("$" + p.name for p in report.params))
    if site is not None and "site" not in report.used:
        raise ReportError(f"report {report.name} does not take $site (its rows are not per "
                          "site); run it without --site")
    values: dict[str, Any] = {"start_ns": int(start_ns), "end_ns": int(end_ns), "sector": sector,
                              "site": site}
    values.update((requirements or RequirementsConfig()).sql_params())
    if "site_polygons" in report.used:
        values["site_polygons"] = (geometry or SiteGeometry()).edges()
    for p in report.params:
        if p.name in given:
            values[p.name] = p.convert(given[p.name])
        elif p.default is not None and p.name not in values:
            values[p.name] = p.convert(p.default)
    missing = sorted(report.used - set(values))
    if missing:
        raise ReportError(f"report {report.name} needs {', '.join('$' + m for m in missing)} "
                          "(declare a default in its header or pass --param NAME=VALUE)")
    return {k: v for k, v in values.items() if k in report.used}


def run_report(
    con: duckdb.DuckDBPyConnection,
    name: str | ReportSql,
    *,
    start_ns: int,
    end_ns: int,
    sector: str | None = None,
    requirements: RequirementsConfig | None = None,
    params: Mapping[str, Any] | None = None,
    dirs: Sequence[Path] = (),
    site: str | None = None,
    rows_per_batch: int | None = None,
    geometry: SiteGeometry | None = None,
) -> pa.Table | pa.RecordBatchReader:
    """Run a report on a connection whose views expose the warehouse tables.
    ``requirements``: the config's ``[requirements]`` (None: the shipped figures);
    ``site``: that site's rows (None: every site, each its own rows: reports group by
    ``site``). ``rows_per_batch``: the rows as a stream of record batches of that size,
    read while ``con`` is open (a report of tens of millions of rows is then written
    without being held); None: one table."""
    report = name if isinstance(name, ReportSql) else load_report(name, dirs)
    bound = bind_params(report, start_ns=start_ns, end_ns=end_ns, sector=sector,
                        requirements=requirements, params=params, site=site,
                        geometry=geometry)
    rel = con.sql(report.text, params=bound)
    return rel.to_arrow_table() if rows_per_batch is None else rel.to_arrow_reader(rows_per_batch)


# --- running a report over the warehouse ----------------------------------------------

ALL_TIME = (0, 2**63 - 1)
ROWS_PER_BATCH = 65_536  # rows a streamed report holds at a time


def half_the_memory(total_bytes: int) -> str:
    """DuckDB's memory limit for reports: half of ``total_bytes``, at least 2 GiB. Exact
    percentiles hold each group's values in memory, which DuckDB cannot spill: over a
    day of a 1,000-ship region (77 M ``track_errors`` rows) ``error_decomposition``'s
    two need more than 2 GB, over a week ~7-10 GiB (docs/scale.md)."""
    return f"{max(2 * 1024**3, total_bytes // 2) // 1024**2}MiB"


REPORT_MEMORY = (os.environ.get("SURVEIL_REPORT_MEMORY")
                 or half_the_memory(machine_memory_bytes()))
"""DuckDB's memory limit for a report (``SURVEIL_REPORT_MEMORY``, else half the
machine's memory): a larger aggregate (``map_tracks`` over a regional day: tens of
millions of groups) spills to the system's temporary folder beyond it."""
_SPILLS = itertools.count()  # one spill folder per connection (DuckDB names its files alike)


def open_warehouse(warehouse: Path | Location, threads: int = 2,
                   tables: Sequence[str] | None = None, write_dir: Path | None = None,
                   refuse_damaged: bool = True) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB whose views are the warehouse tables' current snapshots (of
    ``tables`` only, when given), read-only: the views scan each snapshot's pyarrow
    dataset (no DuckDB extension is downloaded, locally or on object storage), then the
    connection is locked (:func:`pipeline.warehouse.views.lock_down`): its SQL reaches
    no file and no network, only ``write_dir`` when given (``surveil sql
    --allow-write-files``). A table whose files differ from its Delta log is refused
    (:class:`pipeline.warehouse.integrity.TableFileError`; ``refuse_damaged`` False:
    its view raises that message when read, the other tables stay readable)."""
    spill = Path(tempfile.gettempdir()) / f"surveil-duckdb-{os.getpid()}-{next(_SPILLS)}"
    con = duckdb.connect(config={"threads": threads, "memory_limit": REPORT_MEMORY,
                                 "temp_directory": str(spill),  # made and removed by DuckDB
                                 "autoinstall_known_extensions": False,
                                 "autoload_known_extensions": False})
    try:
        con.execute("SET enable_progress_bar = false")  # never into a CSV on stdout
        register_tables(con, warehouse, tables, refuse_damaged=refuse_damaged)
        lock_down(con, write_dir)
    except BaseException:
        con.close()
        raise
    return con


def run_named_report(warehouse: Path, name: str, **options: Any) -> pa.Table:
    """Report ``name`` over the warehouse as one table; ``options``: those of
    :func:`named_report_batches` (window, sector, config, parameters, site)."""
    with named_report_batches(warehouse, name, **options) as reader:
        return reader.read_all()


@contextlib.contextmanager
def named_report_batches(
    warehouse: Path,
    name: str,
    *,
    start_ns: int | None = None,
    end_ns: int | None = None,
    sector: str | None = None,
    cfg: Config | None = None,
    params: Mapping[str, Any] | None = None,
    site: str | None = None,
) -> Iterator[pa.RecordBatchReader]:
    """Report ``name``'s rows as a stream of record batches, read while the ``with``
    block holds the warehouse open: ``surveil report --format csv`` writes a report of
    tens of millions of rows (``map_tracks`` over a regional day) without holding it.
    All time when no window; ``cfg``: its ``[requirements]`` are bound and its
    ``[reports] dirs`` searched (None: the shipped figures, shipped reports only);
    ``site``: that site's rows (None: every site, apart)."""
    dirs = reports_config(cfg).dirs if cfg is not None else ()
    report = load_report(name, dirs)
    con = open_warehouse(warehouse, tables=report.tables_used())
    try:
        yield run_report(
            con,
            report,
            start_ns=ALL_TIME[0] if start_ns is None else start_ns,
            end_ns=ALL_TIME[1] if end_ns is None else end_ns,
            sector=sector,
            requirements=requirements_config(cfg) if cfg is not None else None,
            params=params,
            dirs=dirs,
            site=site,
            rows_per_batch=ROWS_PER_BATCH,
            geometry=site_geometry(cfg) if cfg is not None else None,
        )
    finally:
        con.close()


def write_csv(reader: pa.RecordBatchReader, sink: BinaryIO) -> int:
    """Write ``reader``'s rows to ``sink`` as CSV (one header), batch by batch, as
    :func:`format_report` formats them; returns the rows written."""
    rows = 0
    with pacsv.CSVWriter(sink, reader.schema) as writer:
        for batch in reader:
            writer.write_batch(batch)
            rows += batch.num_rows
    return rows


def report_listing(dirs: tuple[Path, ...]) -> list[str]:
    """``surveil report --list``: one line per report, its name and description (and
    where it comes from when it is not shipped); an unusable one says why."""
    names = list_reports(dirs)
    width = max((len(n) for n in names), default=20) + 2
    lines = []
    for n in names:
        try:
            r = load_report(n, dirs)
            text, origin = r.description, "" if r.shipped else f"  [{r.origin}]"
        except ReportError as exc:
            text, origin = f"(unusable: {exc})", ""
        lines.append(f"{n:<{width}}{text[:110]}{'...' if len(text) > 110 else ''}{origin}")
    return lines


def sql_write_dir(warehouse: Path | Location, given: str | None) -> Path | None:
    """``surveil sql --allow-write-files``: an existing folder outside the warehouse
    (:class:`UsageError`, exit 2, otherwise); None without one."""
    if given is None:
        return None
    folder = Path(given).expanduser().resolve()
    if not folder.is_dir():
        raise UsageError(f"--allow-write-files {given}: no such folder")
    if isinstance(warehouse, Path):
        wh = warehouse.resolve()
        if folder == wh or folder.is_relative_to(wh) or wh.is_relative_to(folder):
            raise UsageError(f"--allow-write-files {given}: the folder holds or is inside the "
                             f"warehouse {wh}; the SQL may not write there")
    return folder


def run_sql(con: duckdb.DuckDBPyConnection, text: str) -> pa.Table | None:
    """The rows of ``con.sql(text)`` (every statement run, the last one's rows) as an
    Arrow table (None: a statement without rows); a DuckDB error as a
    :class:`UsageError` (a refused file access says why)."""
    try:
        rel = con.sql(text)
        return None if rel is None else rel.to_arrow_table()
    except duckdb.PermissionException as exc:
        raise UsageError(f"{str(exc).strip()}: surveil sql reads the warehouse through its "
                         "views only (no file, ATTACH or extension); to export results, "
                         "give --allow-write-files DIR and COPY ... TO a file under DIR"
                         ) from None
    except duckdb.Error as exc:
        raise UsageError(str(exc).strip()) from None
