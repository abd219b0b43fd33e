"""Report queries: load ``sql/<name>.sql`` and run it in DuckDB with bound parameters.

Every report takes the same three parameters, always bound, never pasted into SQL
text: ``$start_ns`` and ``$end_ns`` (int64 ns UTC, half-open window) and ``$sector``
(a sector name, or ``None`` for every sector).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import duckdb
import pyarrow as pa

from pipeline.resources import resource_path

_HEADER = re.compile(r"^--\s*(\w+):\s*(.*)$")


class UnknownReportError(KeyError):
    """No ``sql/<name>.sql`` exists."""


@dataclass(frozen=True)
class ReportSql:
    name: str
    path: Path
    text: str
    header: dict[str, str]

    @property
    def description(self) -> str:
        return self.header.get("description", "")


def sql_dir() -> Path:
    return resource_path("sql")


def list_reports() -> list[str]:
    return sorted(p.stem for p in sql_dir().glob("*.sql"))


def load_report(name: str) -> ReportSql:
    """Read ``sql/<name>.sql`` and its ``-- key: value`` header lines."""
    if not re.fullmatch(r"[A-Za-z0-9_]+", name or ""):
        raise UnknownReportError(name)
    path = sql_dir() / f"{name}.sql"
    if not path.is_file():
        raise UnknownReportError(name)
    text = path.read_text()
    header: dict[str, str] = {}
    last_key = None
    for line in text.splitlines():
        if not line.startswith("--"):
            break
        m = _HEADER.match(line)
        if m:
            last_key = m.group(1)
            header[last_key] = m.group(2).strip()
        elif last_key:  # continuation line of the previous key
            header[last_key] += " " + line.lstrip("- ").strip()
    return ReportSql(name=name, path=path, text=text, header=header)


def run_report(
    con: duckdb.DuckDBPyConnection,
    name: str,
    *,
    start_ns: int,
    end_ns: int,
    sector: str | None = None,
) -> pa.Table:
    """Run report ``name`` on a connection whose views expose the warehouse tables."""
    report = load_report(name)
    params = {"start_ns": int(start_ns), "end_ns": int(end_ns), "sector": sector}
    used = {p for p in params if f"${p}" in report.text}
    bound = {k: v for k, v in params.items() if k in used}
    return con.sql(report.text, params=bound).to_arrow_table()
