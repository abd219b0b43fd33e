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


def relabel(frame: pl.DataFrame, mapping: dict[int, int]) -> pl.DataFrame:
    """Apply a stitch map to a frame's ``system_track_id``."""
    if not mapping or "system_track_id" not in frame.columns or frame.height == 0:
        return frame
    return frame.with_columns(pl.col("system_track_id").replace(mapping))


def join_units(parts: dict[str, list[pl.DataFrame]]) -> dict[str, list[pl.DataFrame]]:
    """``Family.join_units`` of the maritime family: every table's unit parts (in time
    order) with the system track ids stitched across the seams."""
    mapping = stitch_track_ids(parts.get("associations", []))
    return {name: [relabel(p, mapping) for p in frames] for name, frames in parts.items()}
