"""Work units sized by data volume: cuts from the Parquet footers, a batch over many
units commits the same association rows as over one."""

from __future__ import annotations

import dataclasses
import itertools
import shutil

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


def test_many_units_same_association_rows(e2e, tmp_path, monkeypatch) -> None:
    """The e2e window cut two ways, by the hour and into ~6 units by volume: the same
    association rows, system track ids included (was: the same (epoch, site, track) rows
    but >= 85 % of local tracks keeping one id, each unit starting its association
    afresh), and the same fused errors against truth. On a copy of the warehouse (the
    e2e one stays hour-cut for the other tests)."""
    wh = tmp_path / "warehouse"
    shutil.copytree(e2e.warehouse, wh)
    _, _, rows = volume_profile(wh, "radar_tracks", e2e.start_ns, e2e.end_ns)
    assert rows.sum() > 0
    hourly = _run(e2e, wh)
    small = dataclasses.replace(FAMILIES[0], unit_rows=int(rows.sum() // 6))
    monkeypatch.setattr(batch, "family", lambda name: small)
    cut = _run(e2e, wh, min_units=6)
    a, b = cut["a"], hourly["a"]
    assert a.sort(a.columns).equals(b.sort(b.columns))
    assert _kept_one_id(a) == _kept_one_id(b) > 0.85
    assert cut["rms"] == hourly["rms"]


def _run(e2e, wh, min_units: int = 1) -> dict:
    s = batch.run_batch(e2e.cfg, wh, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                        executor_kind="serial", families=("maritime",))
    assert s.committed and s.units_total >= min_units
    a = pl.from_arrow(read_table(wh, "associations", start_ns=e2e.start_ns, end_ns=e2e.end_ns))
    err = pl.from_arrow(read_table(wh, "track_errors", start_ns=e2e.start_ns,
                                   end_ns=e2e.end_ns)).filter(pl.col("source") == "fused")
    return {"a": a, "rms": float(np.sqrt((err["error_m"] ** 2).mean()))}


def _kept_one_id(a: pl.DataFrame) -> float:
    """Share of (site, local track) pairs that kept a single system track id."""
    ids = a.group_by("site_id", "local_track_id").agg(pl.col("system_track_id").n_unique())
    return float((ids["system_track_id"] == 1).mean())
