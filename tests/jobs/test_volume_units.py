"""Work units sized by data volume: cuts from the Parquet footers, a batch over many
units commits the same association rows as over one."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import polars as pl
import pytest

from jobs import batch
from pipeline.families import FAMILIES
from pipeline.warehouse.delta import read_table, volume_cuts, volume_profile


def test_volume_cuts_balance_rows() -> None:
    first = np.array([0, 100, 200, 300])
    last = np.array([99, 199, 299, 399])
    rows = np.array([1000, 4000, 1000, 1000])
    cuts = volume_cuts(first, last, rows, 0, 400, 2000)
    edges = [0, *cuts, 400]
    per = []
    for a, b in itertools.pairwise(edges):
        per.append(sum(r * max(0, min(b, e + 1) - max(a, f)) / (e + 1 - f)
                       for f, e, r in zip(first, last, rows, strict=True)))
    assert len(cuts) == 3 and max(per) <= 2000 * 1.01 and sum(per) == pytest.approx(7000)
    assert volume_cuts(first, last, rows, 0, 400, 10_000) == []


def test_many_units_same_association_rows(e2e, monkeypatch) -> None:
    """The e2e window cut into ~6 units by volume: the same (epoch, site, track) rows as
    the hour-cut batch; system track ids stitched across the seams (a local track keeps
    its system track across a seam)."""
    _, _, rows = volume_profile(e2e.warehouse, "radar_tracks", e2e.start_ns, e2e.end_ns)
    assert rows.sum() > 0
    batch.run_batch(e2e.cfg, e2e.warehouse, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                    executor_kind="serial", families=("maritime",))
    hourly = read_table(e2e.warehouse, "associations", start_ns=e2e.start_ns, end_ns=e2e.end_ns)
    small = dataclasses.replace(FAMILIES[0], unit_rows=int(rows.sum() // 6))
    monkeypatch.setattr(batch, "family", lambda name: small)
    s = batch.run_batch(e2e.cfg, e2e.warehouse, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                        executor_kind="serial", families=("maritime",))
    assert s.committed and s.units_total >= 6
    cut = pl.from_arrow(read_table(e2e.warehouse, "associations", start_ns=e2e.start_ns,
                                   end_ns=e2e.end_ns))
    key = ["time_ns", "site_id", "local_track_id"]
    assert cut.select(key).sort(key).equals(pl.from_arrow(hourly).select(key).sort(key))
    ids = cut.group_by("site_id", "local_track_id").agg(pl.col("system_track_id").n_unique())
    assert (ids["system_track_id"] == 1).mean() > 0.9
