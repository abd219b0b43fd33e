"""The trailing edge of a window: the units after it batched again when its end changed.

Guarantee kept here: **ids continue across the trailing edge, even when the job is
killed.** The units committed after a window stitched their ids to the window's old last
rows. When a batch changes those rows (the family's seam digest of the rows just before
the window's end differs), the next committed units are batched again, and so on until a
window ends as it ended before (``pipeline.batch.driver``; a window no committed unit
starts at the end of, the usual batch in time order, has nothing to compare or promise).
That promise is written down before the window's commit (``_continue/``, with the
digests of the rows at its end as they were: :func:`promise_continuation`); a job killed
between the commit and the end of the chain leaves the record, and the next batch of the
site runs the chain first
(:func:`left_continuations`).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from pipeline.batch.plan import safe_name
from pipeline.batch.seams import trailing_digests
from pipeline.families import family
from pipeline.warehouse.delta import read_table
from pipeline.warehouse.location import Location, as_location

CONTINUE_DIR = "_continue"


@dataclass(frozen=True)
class Continuation:
    """A continuation record left by a killed job (``_continue/``)."""

    path: Location
    site: str
    end_ns: int
    families: list[str]


def promise_continuation(warehouse: Path | Location, site: str | None, end_ns: int,
                          digests: dict[str, str]) -> Location:
    """Record, before a window's commit, the digests of the rows at its end (atomic
    write): if the job dies before the units after it are batched again, the next batch
    finds the rows changed and does it (:func:`left_continuations`)."""
    folder = as_location(warehouse) / CONTINUE_DIR
    folder.mkdir()
    doc = {"site": site, "end_ns": end_ns, "digests": digests}
    path = folder / f"{safe_name(site or '')}-{end_ns}-{time.time_ns()}.json"
    path.write_atomic(json.dumps(doc).encode())
    return path


def left_continuations(warehouse: Path | Location, site: str | None) -> list[Continuation]:
    """The continuation records (of ``site``, or all) left by killed jobs whose window's
    end changed (those whose rows did not change, a job killed before its commit, are
    removed)."""
    out = []
    folder = as_location(warehouse) / CONTINUE_DIR
    for name in sorted(n for n in folder.listdir(missing_ok=True) if n.endswith(".json")):
        path = folder / name
        try:
            doc = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if site is not None and doc.get("site") != site:
            continue
        fams = tuple(family(n) for n in doc["digests"])
        now = trailing_digests(warehouse, fams, doc["end_ns"], doc["site"])
        changed = [n for n, d in doc["digests"].items() if now.get(n) != d]
        if changed:
            out.append(Continuation(path, doc["site"], doc["end_ns"], changed))
        else:
            drop_record(path)
    return out


def drop_record(record: Path | Location) -> None:
    """Remove a continuation record (and its folder once empty)."""
    loc = as_location(record)
    loc.unlink()
    loc.parent.rmdir_if_empty()


def units_after(warehouse: Path, families: list[str], end_ns: int, site: str | None
                 ) -> tuple[int, int] | None:
    """[end_ns, end) of ``families``' committed units that start at ``end_ns`` (None:
    none)."""
    if not families:
        return None
    units = pl.from_arrow(read_table(warehouse, "batch_units",
                                     columns=["family", "start_ns", "end_ns"], site=site))
    after = units.filter(pl.col("family").is_in(families) & (pl.col("start_ns") == end_ns))
    return (end_ns, int(after["end_ns"].max())) if after.height else None
