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
    lead-in's rows, "tail" for the unit's last ``SEAM_S``). One-to-one per seam: the
    pairing sharing most rows first. Ids that continue nothing are absent.

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
    return maps


def unit_seam(outputs: dict[str, pl.DataFrame]) -> pl.DataFrame:
    """``Family.unit_seam`` of the maritime family: all :func:`stitch_track_ids` reads of
    a unit, the lead-in's association rows (``part`` "head") and those of the unit's
    last ``SEAM_S`` (``part`` "tail"): time_ns, site_id, local_track_id, system_track_id.
    ``outputs`` may be a unit's (with :data:`LEAD_ASSOCIATIONS`) or the rows committed
    before a window (tail only)."""
    cols = list(SEAM_COLUMNS)
    a = outputs["associations"].select(cols)
    parts = []
    if a.height:
        last = a["time_ns"].max() - round(SEAM_S * NS)
        parts.append(a.filter(pl.col("time_ns") > last).with_columns(part=pl.lit("tail")))
    lead = outputs.get(LEAD_ASSOCIATIONS)
    if lead is not None and lead.height:
        parts.append(lead.select(cols).with_columns(part=pl.lit("head")))
    return pl.concat(parts) if parts else a.with_columns(part=pl.lit("tail"))


def join_units(seams: Sequence[pl.DataFrame]) -> list[dict[str, dict[int, int]] | None]:
    """``Family.join_units`` of the maritime family: per unit (in time order) the
    relabelling of ``system_track_id`` that continues the ids of the units before it."""
    return [{"system_track_id": m} if m else None for m in stitch_track_ids(seams)]
