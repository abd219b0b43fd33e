"""Results do not depend on where work units are cut (issue 17 item 2, issue 19 item 4).

The e2e window is batched once with its units at the UTC hour and once more with the
maritime units also cut at unaligned instants, as the volume cuts of a dense day would
cut them: the per-epoch tables are equal row for row (system track ids included:
identity votes, pairings and integrity state carried over the seams by the units'
lead-in and look-ahead, ids stitched) and the per-unit aggregates sum alike.
"""

from __future__ import annotations

import shutil

import polars as pl
import pytest
from polars.testing import assert_frame_equal

import pipeline.batch.plan
from jobs.batch import run_batch
from pipeline.families import family
from pipeline.units import NS
from pipeline.warehouse.delta import read_table, table_path

MIN = 60 * NS
PER_EPOCH = ("associations", "system_tracks", "identifications", "track_errors",
             "maritime_channel_health", "sensor_registration")


def _table(wh, name: str) -> pl.DataFrame:
    t = pl.from_arrow(read_table(wh, name))
    return t.sort(t.columns) if t.height else t


def _batch_cut_at(e2e, wh, cuts_ns: list[int], monkeypatch) -> None:
    """Batch the e2e window again with extra maritime unit cuts at ``cuts_ns``."""
    for name in (*family("maritime").outputs, "batch_units"):
        shutil.rmtree(table_path(wh, name), ignore_errors=True)
    volume_cuts = pipeline.batch.plan.volume_cuts
    monkeypatch.setattr(pipeline.batch.plan, "volume_cuts",
                        lambda *a, **k: sorted({*volume_cuts(*a, **k), *cuts_ns}))
    res = run_batch(e2e.cfg, wh, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                    executor_kind="serial")
    assert res.exit_code == 0, res.render()
    units = pl.from_arrow(read_table(wh, "batch_units")).filter(
        pl.col("family") == "maritime")
    assert set(cuts_ns) <= set(units["start_ns"].to_list())


@pytest.fixture(scope="module")
def single(e2e):
    return {name: _table(e2e.warehouse, name) for name in family("maritime").outputs}


@pytest.mark.parametrize("offsets_s", [(437,), (131, 437, 905)], ids=["one", "three"])
def test_cutting_units_elsewhere_changes_no_row(e2e, single, tmp_path, monkeypatch,
                                                offsets_s):
    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    _batch_cut_at(e2e, wh, [e2e.start_ns + s * NS for s in offsets_s], monkeypatch)
    for name in PER_EPOCH:
        assert single[name].height > 0, name
        try:
            assert_frame_equal(_table(wh, name), single[name])
        except AssertionError as exc:
            raise AssertionError(f"cut at {offsets_s} s: {name} differs: {exc}") from None
    # the aggregates are per unit: their additive counts sum alike over the window
    siap = _table(wh, "siap_by_sector")
    sums = [c for c in siap.columns if c.endswith(("_epochs", "_error_m", "_error_mps"))
            or c in ("track_number_changes", "track_swaps", "tracked_time_s")]
    assert len(sums) >= 12

    def by_sector(df: pl.DataFrame) -> pl.DataFrame:
        return df.group_by("sector").agg(pl.col(sums).sum()).sort("sector")

    assert_frame_equal(by_sector(siap), by_sector(single["siap_by_sector"]))
