"""Reprocessing a window replaces exactly that window; twice gives identical tables."""

from __future__ import annotations

import shutil

import polars as pl
import pytest
from polars.testing import assert_frame_equal

from jobs.reprocess import run_reprocess
from pipeline.tables import table_specs
from pipeline.units import NS
from pipeline.warehouse.delta import read_table


def snapshot(warehouse) -> dict[str, pl.DataFrame]:
    out = {}
    for name in table_specs():
        t = pl.from_arrow(read_table(warehouse, name))
        if name == "ingest_ledger":
            t = t.drop("ingested_at_ns")
        if name == "batch_units":
            t = t.drop("committed_at_ns")
        cols = [c for c in t.columns if t.schema[c] != pl.Binary]
        out[name] = t.sort(cols) if t.height else t
    return out


@pytest.fixture()
def warehouse(e2e, tmp_path):
    dst = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, dst)
    return dst


def test_reprocess_twice_identical_and_window_only(e2e, warehouse):
    before = snapshot(warehouse)
    start = e2e.start_ns + 300 * NS  # a window inside the data, not aligned to the hour
    end = start + 900 * NS
    first = run_reprocess(e2e.cfg, warehouse, start_ns=start, end_ns=end, executor_kind="serial")
    assert first.exit_code == 0, first.render()
    after_one = snapshot(warehouse)
    second = run_reprocess(e2e.cfg, warehouse, start_ns=start, end_ns=end, executor_kind="serial")
    assert second.exit_code == 0, second.render()
    after_two = snapshot(warehouse)
    for name in before:
        assert_frame_equal(after_one[name], after_two[name], check_row_order=True)
    # raw tables: re-ingesting unchanged files inside the window changes nothing at all
    for name in ("radar_tracks", "ais_reports", "ais_static", "truth"):
        assert_frame_equal(before[name], after_two[name])
    # derived rows outside the window are untouched
    for name in ("system_tracks", "associations", "track_errors"):
        outside = (pl.col("time_ns") < start) | (pl.col("time_ns") >= end)
        assert_frame_equal(before[name].filter(outside), after_two[name].filter(outside))
        assert after_two[name].filter(~outside).height > 0
