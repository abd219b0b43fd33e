"""Two sources in one warehouse (issue 17, item 4): an ingest whose topics overlap
another file of the SAME site over the same times warns and records it; two sites over
the same times are the normal case (their rows are batched and reported apart:
tests/jobs/test_sites.py). Before sites: the gaps scenario ingested into the channel
warehouse mixed silently (fused RMS 34.8 -> 389.7 m)."""

from __future__ import annotations

import shutil

import polars as pl

from jobs.simulate import run_simulate
from pipeline.ingest.driver import run_ingest
from pipeline.warehouse.delta import read_table


def test_a_second_source_of_one_site_over_the_same_times_is_warned_and_recorded(e2e, tmp_path):
    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    assert read_table(wh, "source_overlaps").num_rows == 0  # consecutive files: none
    first = run_simulate("gaps", 600.0, 3, tmp_path / "first", e2e.cfg, start_ns=e2e.start_ns)
    summary = run_ingest(first, e2e.cfg, wh, executor="serial")
    assert not summary.overlaps, summary.render()  # site 'gaps' beside 'channel-clean'
    other = run_simulate("gaps", 600.0, 4, tmp_path / "other", e2e.cfg,
                         start_ns=e2e.start_ns)
    summary = run_ingest(other, e2e.cfg, wh, executor="serial")
    assert summary.overlaps, summary.render()
    assert "WARNING: two sources overlap" in summary.render()
    rows = pl.from_arrow(read_table(wh, "source_overlaps"))
    assert set(rows["source_file"]) == {str(p.resolve()) for p in other}
    assert set(rows["other_file"]) == {str(p.resolve()) for p in first}
    assert set(rows["site"]) == {"gaps"}
    assert "/truth/vessels" in set(rows["topic"])
    assert (rows["overlap_start_ns"] >= e2e.start_ns).all()
    assert (rows["overlap_end_ns"] > rows["overlap_start_ns"]).all()
    # ingesting it again (unchanged: skipped) adds nothing; the rows stay
    again = run_ingest(other, e2e.cfg, wh, executor="serial")
    assert again.files_skipped == len(other) and not again.overlaps
    assert read_table(wh, "source_overlaps").num_rows == rows.height
