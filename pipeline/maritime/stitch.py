"""Keep system track ids across the seams between batch work units.

A window is cut into work units that are associated independently (in parallel). Each
unit also tracks a lead-in before its window (``pipeline.maritime.stage``): by the end
of the lead-in its association has settled on the pairings of the unit before, only
under its own ids. On the last ``SEAM_S`` before the seam both units hold the same
epochs: a system track of unit k+1 whose (epoch, site, local track) rows there are the
rows of system track P of unit k *is* P, and this pass relabels it so. Ids born after
the seam need nothing: an id says when its track was born
(:func:`pipeline.maritime.associate.birth_ids`), the same in any cut.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import polars as pl

from pipeline.maritime.associate import BIRTH_RANK_LIMIT
from pipeline.units import NS

SEAM_S = 60.0
"""The overlap the stitch compares, s: two association track timeouts (a track seen in
it is alive at the seam, even if it coasts through the seam's epoch)."""

LEAD_ASSOCIATIONS = "_lead_associations"
"""The stage's output key for the lead-in's association rows in the ``SEAM_S`` before its
window (time_ns, site_id, local_track_id, system_track_id): read by :func:`unit_seam`,
never committed."""

_KEY = ["time_ns", "site_id", "local_track_id"]
SEAM_COLUMNS = (*_KEY, "system_track_id")
"""The associations' columns :func:`unit_seam` reads."""


def stitch_track_ids(seams: Sequence[pl.DataFrame]) -> list[dict[int, int]]:
    """Per unit (in time order) the relabelling {unit's system_track_id: id it
    continues}, from the units' seams (:func:`unit_seam`: ``part`` "head" for the
    lead-in's rows, "tail" for the unit's last ``SEAM_S``, "born" for the ids born in
    the lead-in). One-to-one per seam: the pairing sharing most rows first. An id born
    in the lead-in that continues nothing gets one of its own (:func:`_own_ids`); other
    ids that continue nothing are absent.

    One loop over seams (a handful per window); the work per seam is polars joins.
    """
    maps: list[dict[int, int]] = [{} for _ in range(len(seams))]  # (seams may be read lazily)
    for k, (prev, nxt) in enumerate(itertools.pairwise(seams)):
        tail = prev.filter(pl.col("part") == "tail")
        head = nxt.filter(pl.col("part") == "head")
        if tail.height == 0 or head.height == 0:
            continue
        tail = tail.select(*_KEY, pl.col("system_track_id").replace(maps[k])
                           .alias("continues"))
        votes = (
            head.join(tail, on=_KEY, how="inner")
            .group_by("system_track_id", "continues")
            .agg(pl.len().alias("shared"))
            .sort(["shared", "system_track_id", "continues"], descending=[True, False, False])
        )
        # one-to-one: the pairing with most shared rows first
        taken_new: set[int] = set()
        taken_old: set[int] = set()
        for new_id, old_id, _ in votes.iter_rows():
            if new_id in taken_new or old_id in taken_old:
                continue
            taken_new.add(new_id)
            taken_old.add(old_id)
            if new_id != old_id:
                maps[k + 1][new_id] = old_id
        maps[k + 1].update(_own_ids(nxt.filter(pl.col("part") == "born"), taken_new))
    return maps


def _own_ids(born: pl.DataFrame, continuing: set[int]) -> dict[int, int]:
    """{id: its own id} for the ids born in a unit's lead-in (``born``: system_track_id
    and the time_ns of its first row in the unit's window) that continue no id of the
    unit before: ``first_ms * BIRTH_RANK_LIMIT + rank`` with ranks from the top down
    (``BIRTH_RANK_LIMIT - 1`` first, in id order), where the ids born in the window
    take theirs from 0 up. No other unit has rows at that ms: the id is the unit's
    alone, the same in every batch that cuts the unit there."""
    own = (born.filter(~pl.col("system_track_id").is_in(list(continuing)))
           .sort("system_track_id")
           .with_columns(first_ms=pl.col("time_ns") // 1_000_000))
    if own.height == 0:
        return {}
    rank = pl.int_range(pl.len()).over("first_ms")
    ids = own.select("system_track_id", new=pl.col("first_ms") * BIRTH_RANK_LIMIT
                     + (BIRTH_RANK_LIMIT - 1) - rank)
    return dict(ids.iter_rows())


def unit_seam(outputs: dict[str, pl.DataFrame]) -> pl.DataFrame:
    """``Family.unit_seam`` of the maritime family: all :func:`stitch_track_ids` reads of
    a unit, the lead-in's association rows (``part`` "head"), those of the unit's last
    ``SEAM_S`` (``part`` "tail") and the ids born in the lead-in with the time of their
    first row in the window (``part`` "born", no site or local track): time_ns, site_id,
    local_track_id, system_track_id. ``outputs`` may be a unit's (with
    :data:`LEAD_ASSOCIATIONS`) or the rows committed before a window (tail only)."""
    cols = list(SEAM_COLUMNS)
    a = outputs["associations"].select(cols)
    parts = []
    if a.height:
        last = a["time_ns"].max() - round(SEAM_S * NS)
        parts.append(a.filter(pl.col("time_ns") > last).with_columns(part=pl.lit("tail")))
    lead = outputs.get(LEAD_ASSOCIATIONS)
    if lead is not None and lead.height:
        parts.append(lead.select(cols).with_columns(part=pl.lit("head")))
        lead_end_ms = lead["time_ns"].max() // 1_000_000
        born = (a.filter(pl.col("system_track_id") // BIRTH_RANK_LIMIT <= lead_end_ms)
                .group_by("system_track_id").agg(pl.col("time_ns").min()))
        parts.append(born.select(
            "time_ns", pl.lit(None, a.schema["site_id"]).alias("site_id"),
            pl.lit(None, a.schema["local_track_id"]).alias("local_track_id"),
            "system_track_id", part=pl.lit("born")))
    return pl.concat(parts) if parts else a.with_columns(part=pl.lit("tail"))


def join_units(seams: Sequence[pl.DataFrame]) -> list[dict[str, dict[int, int]] | None]:
    """``Family.join_units`` of the maritime family: per unit (in time order) the
    relabelling of ``system_track_id`` that continues the ids of the units before it."""
    return [{"system_track_id": m} if m else None for m in stitch_track_ids(seams)]
