"""Where a warehouse is: a path Delta can use, a folder that is a warehouse, one whose rows
carry their site."""

from __future__ import annotations

from pathlib import Path

from pipeline.errors import UsageError

# deltalake (1.6) panics on a table path with these ("Invalid object store url") or fails
# on a control character: refused up front, exit 2, instead of a Rust panic mid-commit
_DELTA_UNSAFE = frozenset("^[]|\\")


def checked_warehouse(path: Path) -> Path:
    """The warehouse path, absolute; :class:`UsageError` when Delta cannot use it."""
    path = path.expanduser().resolve()
    bad = sorted({c for c in str(path) if c in _DELTA_UNSAFE or ord(c) < 32})
    if bad:
        raise UsageError(
            f"warehouse path {str(path)!r} holds {', '.join(repr(c) for c in bad)}, which the "
            "Delta Lake library cannot use in a table path: choose another directory"
        )
    return path


def require_warehouse(warehouse: Path) -> Path:
    """``warehouse`` when it is one (a folder holding ``tables/``, what ``ingest``, ``run``
    and ``demo`` create), else :class:`UsageError` naming it: a command that reads a
    warehouse must not read a mistyped path as an empty one, nor create it."""
    path = Path(warehouse)
    if not (path / "tables").is_dir():
        why = "does not exist" if not path.exists() else "is not a warehouse (no tables/ in it)"
        raise UsageError(
            f"warehouse {path} {why}; `surveil ingest ARCHIVE --warehouse {path}` (or "
            "`surveil run`, `surveil demo`) creates one")
    return path


def refuse_pre_sites(warehouse: Path) -> None:
    """:class:`UsageError` when ``warehouse`` was written before rows carried their site
    (its ``ingest_ledger`` has no ``site`` column): ids of two sites could not be told
    apart in it, so it is not migrated in place; rebuild it from the archive."""
    log_dir = Path(warehouse) / "tables" / "ingest_ledger" / "_delta_log"
    if not log_dir.is_dir():
        return
    from deltalake import DeltaTable

    names = {f.name for f in DeltaTable(str(log_dir.parent)).schema().fields}
    if "site" not in names:
        raise UsageError(
            f"warehouse {warehouse} was written before rows carried their site (no `site` "
            "column); rebuild it: `surveil ingest ARCHIVE --warehouse NEW [--site NAME]` "
            "then `surveil batch` (docs/operations.md, 'Many sites, one warehouse')")
