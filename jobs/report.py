"""Report job: open the warehouse's current snapshot in DuckDB and run ``sql/<name>.sql``."""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, BinaryIO

import duckdb
import pyarrow as pa
import pyarrow.csv as pacsv

from pipeline.catalog import explain_empty_report
from pipeline.config import Config
from pipeline.reports import ReportSql, reports_config, run_report, site_geometry
from pipeline.requirements import requirements_config
from pipeline.tables import column_doc, column_unit, table_specs
from pipeline.warehouse.views import register_tables

ALL_TIME = (0, 2**63 - 1)
ROWS_PER_BATCH = 65_536  # rows a streamed report holds at a time
REPORT_MEMORY = os.environ.get("SURVEIL_REPORT_MEMORY", "2GB")
"""DuckDB's memory limit for a report: a larger aggregate (``map_tracks`` over a regional
day: tens of millions of groups) spills to the system's temporary folder."""
_SPILLS = itertools.count()  # one spill folder per connection (DuckDB names its files alike)


def open_warehouse(warehouse: Path, threads: int = 2) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB whose views are the warehouse tables' current snapshots."""
    spill = Path(tempfile.gettempdir()) / f"surveil-duckdb-{os.getpid()}-{next(_SPILLS)}"
    con = duckdb.connect(config={"threads": threads, "memory_limit": REPORT_MEMORY,
                                 "temp_directory": str(spill)})  # made and removed by DuckDB
    register_tables(con, warehouse)
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
    con = open_warehouse(warehouse)
    try:
        yield run_report(
            con,
            name,
            start_ns=ALL_TIME[0] if start_ns is None else start_ns,
            end_ns=ALL_TIME[1] if end_ns is None else end_ns,
            sector=sector,
            requirements=requirements_config(cfg) if cfg is not None else None,
            params=params,
            dirs=reports_config(cfg).dirs if cfg is not None else (),
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


def explain_empty(warehouse: Path, report: ReportSql, *, start_ns: int | None,
                  end_ns: int | None, sector: str | None, cfg: Config | None = None) -> str:
    """Why ``report`` has no rows in the window: what its source tables hold and which
    command writes them."""
    con = open_warehouse(warehouse)
    try:
        return explain_empty_report(
            con, report, start_ns=ALL_TIME[0] if start_ns is None else start_ns,
            end_ns=ALL_TIME[1] if end_ns is None else end_ns, sector=sector, cfg=cfg)
    finally:
        con.close()


def schema_table(name: str | None) -> pa.Table:
    """``surveil schema``: every table (name, kind, rows' meaning), or one table's
    columns (name, type, nullable, unit, meaning), from schemas/."""
    if name is None:
        specs = table_specs().values()
        return pa.table({"table": [s.name for s in specs], "kind": [s.kind for s in specs],
                         "one row is": [s.doc for s in specs]})
    fields = list(table_specs()[name].schema)
    return pa.table({
        "column": [f.name for f in fields],
        "type": [str(f.type).replace("date32[day]", "date32") for f in fields],
        "null": ["yes" if f.nullable else "no" for f in fields],
        "unit": [column_unit(f.name) for f in fields],
        "meaning": [column_doc(f) for f in fields],
    })


def terminal_width() -> int:
    """Columns of the terminal on stdout (``$COLUMNS`` first); not a terminal and no
    ``$COLUMNS``: no limit (a file or a pipe gets the table at its natural width)."""
    if not sys.stdout.isatty() and "COLUMNS" not in os.environ:
        return 100_000
    return shutil.get_terminal_size((100, 24)).columns


def format_report(table: pa.Table, fmt: str, title: str = "", width: int | None = None) -> str:
    """Render a report as a terminal table, CSV or JSON (a list of row objects).

    The table never cuts a value: text columns wrap at word boundaries to fit ``width``
    (the terminal's); when even then it does not fit (numbers are never wrapped), each
    row is printed as a block of ``column: value`` lines instead."""
    if fmt == "csv":
        buf = io.BytesIO()
        pacsv.write_csv(table, buf)
        return buf.getvalue().decode()
    if fmt == "json":
        return json.dumps(table.to_pylist(), indent=2, default=str)
    from rich.console import Console
    from rich.table import Table

    if table.num_rows == 0:
        return f"{title + ': ' if title else ''}(no rows)\n"
    width = width or terminal_width()
    cells = [[("" if v is None else str(v)) for v in row.values()] for row in table.to_pylist()]
    names = table.column_names
    numeric = [_numeric(table.schema.field(n).type) for n in names]
    # the narrowest each column can be: numbers and headers whole, text at its longest word
    least = []
    for j, n in enumerate(names):
        values = [r[j] for r in cells]
        if numeric[j]:
            least.append(max([len(n), *map(len, values)]))
        else:
            words = [len(w) for v in values for w in v.split()] or [0]
            least.append(max(len(n), min(max(words), 40)))
    if sum(least) + 3 * len(names) + 1 > width and names:
        return _vertical(names, cells, title)
    t = Table(title=title or None, show_lines=False)
    for j, name in enumerate(names):
        t.add_column(name, justify="right" if numeric[j] else "left", no_wrap=numeric[j],
                     overflow="fold", min_width=least[j])
    for row in cells:
        t.add_row(*row)
    natural = sum(max([len(n), *(len(r[j]) for r in cells)]) for j, n in enumerate(names))
    console = Console(width=min(width, natural + 3 * len(names) + 1) if names else width,
                      record=True, file=io.StringIO())
    console.print(t)
    return console.export_text()


def _vertical(names: list[str], cells: list[list[str]], title: str) -> str:
    """One block per row, ``column  value`` per line: for tables wider than the terminal."""
    pad = max(len(n) for n in names)
    out = [title] if title else []
    for i, row in enumerate(cells, start=1):
        out.append(f"-- row {i} " + "-" * max(0, pad - 4))
        out += [f"{n:<{pad}}  {v}" for n, v in zip(names, row, strict=True)]
    if not cells:
        out.append("(no rows)")
    return "\n".join(out) + "\n"


def _numeric(t: pa.DataType) -> bool:
    return pa.types.is_integer(t) or pa.types.is_floating(t)
