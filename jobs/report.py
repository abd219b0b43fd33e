"""Report job: open the warehouse's current snapshot in DuckDB and run ``sql/<name>.sql``."""

from __future__ import annotations

import io
import json
from pathlib import Path

import duckdb
import pyarrow as pa
import pyarrow.csv as pacsv

from pipeline.reports import run_report
from pipeline.warehouse.views import register_tables

ALL_TIME = (0, 2**63 - 1)


def open_warehouse(warehouse: Path, threads: int = 2) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB whose views are the warehouse tables' current snapshots."""
    con = duckdb.connect(config={"threads": threads})
    register_tables(con, warehouse)
    return con


def run_named_report(
    warehouse: Path,
    name: str,
    *,
    start_ns: int | None = None,
    end_ns: int | None = None,
    sector: str | None = None,
) -> pa.Table:
    con = open_warehouse(warehouse)
    try:
        return run_report(
            con,
            name,
            start_ns=ALL_TIME[0] if start_ns is None else start_ns,
            end_ns=ALL_TIME[1] if end_ns is None else end_ns,
            sector=sector,
        )
    finally:
        con.close()


def format_report(table: pa.Table, fmt: str, title: str = "") -> str:
    """Render a report as a terminal table, CSV or JSON (a list of row objects)."""
    if fmt == "csv":
        buf = io.BytesIO()
        pacsv.write_csv(table, buf)
        return buf.getvalue().decode()
    if fmt == "json":
        return json.dumps(table.to_pylist(), indent=2, default=str)
    from rich.console import Console
    from rich.table import Table

    t = Table(title=title or None, show_lines=False)
    for name in table.column_names:
        t.add_column(name, justify="right" if _numeric(table.schema.field(name).type) else "left")
    for row in table.to_pylist():
        t.add_row(*("" if v is None else str(v) for v in row.values()))
    console = Console(width=160, record=True, file=io.StringIO())
    console.print(t)
    return console.export_text()


def _numeric(t: pa.DataType) -> bool:
    return pa.types.is_integer(t) or pa.types.is_floating(t)
