"""A damaged table stops the command that needs it, naming the table and ``surveil doctor``.

A table is damaged when its Delta log does not read (an entry cut short by a full disk, a
garbage file where the next version goes) or when a data file its snapshot lists is
gone. Every open of a table's log (``pipeline.warehouse.delta.open_delta``) and every
read of its files goes through here, so any command that needs such a table exits 2 with
one line (:class:`DamagedTableError`, a :class:`~pipeline.errors.UsageError`) instead of
a traceback from deltalake (``Json error: Truncated record...``, naming no table) or a
``FileNotFoundError`` from Arrow; a command that does not need the table is unaffected
(the views rebuild keeps a damaged table's previous view: ``pipeline.warehouse.views``).
``surveil doctor`` finds the damage and ``surveil doctor --repair`` repairs what it can
(``pipeline.warehouse.doctor``).
"""

from __future__ import annotations

import os
from collections.abc import Iterable

from pipeline.errors import UsageError

DOCTOR_HINT = "run `surveil doctor` (`surveil doctor --repair` repairs it)"


class DamagedTableError(UsageError):
    """Table ``table`` cannot be read: ``detail`` says why (exit code 2)."""

    def __init__(self, table: str, detail: str) -> None:
        self.table, self.detail = table, detail
        super().__init__(f"table {table} is damaged: {detail}; {DOCTOR_HINT}")


def log_error(table: str, exc: Exception) -> DamagedTableError:
    """The error of a Delta log that does not read (``exc``: deltalake's)."""
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return DamagedTableError(table, f"its Delta log does not read ({first[:200]})")


def missing_error(table: str, files: list[str]) -> DamagedTableError:
    """The error of a snapshot whose data files ``files`` are gone."""
    more = f" and {len(files) - 1} more" if len(files) > 1 else ""
    return DamagedTableError(table, f"data file {files[0]}{more} listed by its Delta log "
                                    "is missing")


def require_local_files(table: str, files: Iterable[str]) -> None:
    """:class:`DamagedTableError` when one of the local ``files`` (a snapshot's) is gone:
    a stat each (~2 us), before DuckDB or Arrow is handed the list."""
    missing = [f for f in files if not os.path.exists(f.removeprefix("file://"))]
    if missing:
        raise missing_error(table, missing)
