"""Errors the command line maps to exit code 2 (usage or configuration), and exit code 3
(the commits are made, the views file could not be rebuilt after them)."""

from __future__ import annotations


class UsageError(ValueError):
    """Bad arguments or inputs the user must fix (exit code 2)."""


EXIT_VIEWS_STALE = 3
"""Exit code of a job whose commits are all made but whose views file (``surveil.duckdb``)
could not be rebuilt after them (a full disk)."""


def views_stale_note(job: str, error: str) -> str:
    """What a ``job`` ("batch", "ingest", ...) whose commits are made says when its views
    rebuild failed (``error``)."""
    return (f"the {job} is committed, but the views file surveil.duckdb could not be rebuilt "
            f"({error}): its views are stale (the tables, `surveil report` and `surveil sql` "
            "are up to date); `surveil doctor --repair` or the next writing command rebuilds "
            f"it (exit code {EXIT_VIEWS_STALE})")
