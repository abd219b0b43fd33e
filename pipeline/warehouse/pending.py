"""One job, one commit for readers: tables a job is still committing read as before it.

Delta commits one table at a time. A job that writes several tables (a batch window: every
derived table and ``batch_units``; an ingested file: its raw tables, ``mcap_index``, the
ledger) first writes a *pending marker*, ``<warehouse>/_pending/<job>.json``, holding
each table's version before the job (its *pin*; -1: the table did not exist), then
commits table by table, then removes the marker. Readers (:func:`pinned_versions`, used
by ``delta.read_table`` and ``delta.table_files``, hence every report, the views file and
every stage input) read a pinned table at its pinned version. So while a job commits,
and after it crashed half way, readers see every table of the job as it was before the
job: old or new as a whole, never ``associations`` new beside ``system_tracks`` old.

A crashed job's marker stays until a later job that re-does its work finishes (a batch
whose window covers the crashed window, a re-ingest of the same file): that job removes
it with its own (``supersedes``). Until then the pinned tables read as before the crash,
later commits to them included; ``surveil run`` re-does a crashed batch window by itself
(its files are not covered by committed units).

The marker is written with ``os.replace`` (atomic; on object storage one PUT, which is
atomic too); readers list ``_pending/`` (nothing to list in normal operation). Versions
come from the ``_delta_log`` listing (no table load).
"""

from __future__ import annotations

import contextlib
import json
import os
import time
import uuid
from collections.abc import Callable, Iterable
from pathlib import Path

from pipeline.warehouse.location import Location, as_location

PENDING_DIR = "_pending"


def latest_version(warehouse: Path | Location, name: str) -> int:
    """Latest Delta version of table ``name`` from its log listing; -1 without a table."""
    log = as_location(warehouse) / "tables" / name / "_delta_log"
    try:
        names = log.listdir()
    except FileNotFoundError:
        return -1
    versions = [int(n[:-5]) for n in names if n.endswith(".json") and n[:-5].isdigit()]
    return max(versions, default=-1)


def begin(warehouse: Path | Location, names: Iterable[str], *, job: str,
          **about: object) -> Location:
    """Write the marker of a job about to commit ``names``; returns its location.
    ``about`` (JSON values: the window, the source file) lets a later job tell it
    supersedes it."""
    folder = as_location(warehouse) / PENDING_DIR
    folder.mkdir()
    doc = {"job": job, "started_at_ns": time.time_ns(), "pid": os.getpid(), **about,
           "pins": {n: latest_version(warehouse, n) for n in dict.fromkeys(names)}}
    path = folder / f"{job}-{time.time_ns()}-{uuid.uuid4().hex[:8]}.json"
    path.write_atomic(json.dumps(doc).encode())
    return path


def markers(warehouse: Path | Location) -> list[tuple[Location, dict]]:
    """Every pending marker (location, content), oldest first."""
    folder = as_location(warehouse) / PENDING_DIR
    try:
        names = sorted(n for n in folder.listdir() if n.endswith(".json"))
    except FileNotFoundError:
        return []
    out = []
    for n in names:
        with contextlib.suppress(OSError, ValueError):
            out.append((folder / n, json.loads((folder / n).read_text())))
    return out


def finish(warehouse: Path | Location, marker: Path | Location,
           supersedes: Callable[[dict], bool] = lambda _doc: False) -> None:
    """The job's commits are all made: remove its marker, and every other marker whose
    work this job re-did (``supersedes(doc)``), then the folder when empty."""
    for path, doc in markers(warehouse):
        if path.uri == str(marker) or supersedes(doc):
            path.unlink()
    (as_location(warehouse) / PENDING_DIR).rmdir_if_empty()


def pinned_versions(warehouse: Path | Location) -> dict[str, int]:
    """Table -> the version readers read (the earliest pin over the markers); tables not
    pinned are absent (readers read their latest version)."""
    pins: dict[str, int] = {}
    for _, doc in markers(warehouse):
        for name, v in doc.get("pins", {}).items():
            pins[name] = min(v, pins.get(name, v))
    return pins
