"""Keep system track ids across the seams between batch work units.

A window is cut into work units that are associated independently (in parallel), so a
ship followed across a seam gets one system track id per unit. A radar's local track
continues across the seam, though: a system track of unit k+1 whose radar members at
the unit's first epoch include a (site, local track) that belonged to system track P at
unit k's last epoch *is* P. This pass relabels it so.
"""

from __future__ import annotations

import itertools

import polars as pl


def stitch_track_ids(associations_by_unit: list[pl.DataFrame]) -> dict[int, int]:
    """Relabelling {unit-local system_track_id: id it continues}, from the units'
    ``associations`` frames in time order (columns time_ns, system_track_id, site_id,
    local_track_id). Ids that continue nothing are absent from the map.

    One loop over seams (a handful per window); the work per seam is polars joins.
    """
    mapping: dict[int, int] = {}
    for prev, nxt in itertools.pairwise(associations_by_unit):
        if prev.height == 0 or nxt.height == 0:
            continue
        tail = prev.filter(pl.col("time_ns") == pl.col("time_ns").max()).select(
            "site_id",
            "local_track_id",
            pl.col("system_track_id").replace(mapping).alias("continues"),
        )
        head = nxt.filter(pl.col("time_ns") == pl.col("time_ns").min()).select(
            "site_id", "local_track_id", "system_track_id"
        )
        votes = (
            head.join(tail, on=["site_id", "local_track_id"], how="inner")
            .group_by("system_track_id", "continues")
            .agg(pl.len().alias("shared"))
            .sort(["shared", "system_track_id", "continues"], descending=[True, False, False])
        )
        # one-to-one: the pairing with most shared members first
        taken_new: set[int] = set()
        taken_old: set[int] = set()
        for new_id, old_id, _ in votes.iter_rows():
            if new_id in taken_new or old_id in taken_old:
                continue
            taken_new.add(new_id)
            taken_old.add(old_id)
            mapping[new_id] = old_id
    return mapping


def unit_seam(outputs: dict[str, pl.DataFrame]) -> pl.DataFrame:
    """``Family.unit_seam`` of the maritime family: the association rows of the unit's
    first and last epochs (site_id, local_track_id, system_track_id, time_ns): all that
    :func:`stitch_track_ids` reads of a unit."""
    a = outputs["associations"].select("time_ns", "site_id", "local_track_id",
                                       "system_track_id")
    if a.height == 0:
        return a
    t = a["time_ns"]
    return a.filter((pl.col("time_ns") == t.min()) | (pl.col("time_ns") == t.max()))


def join_units(seams: list[pl.DataFrame]) -> list[dict[str, dict[int, int]] | None]:
    """``Family.join_units`` of the maritime family: per unit (in time order) the
    relabelling of ``system_track_id`` that continues the ids of the units before it."""
    mapping = stitch_track_ids(seams)
    out: list[dict[str, dict[int, int]] | None] = []
    for seam in seams:
        ids = set(seam["system_track_id"].to_list()) if seam.height else set()
        own = {k: v for k, v in mapping.items() if k in ids}
        out.append({"system_track_id": own} if own else None)
    return out
