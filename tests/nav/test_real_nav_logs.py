"""The nav batch on every public NMEA log in ../shared/data/real/nav/ (issue 5 §1: "runs
without error on every nav log ... and writes outages found there"): `surveil import` ->
MCAP -> ingest -> batch (each log's own hours) -> nav_quality. Skipped without the
recordings; slow (~30 s on 2 cores)."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from jobs.batch import run_batch
from pipeline.convert.importer import run_import
from pipeline.ingest.driver import run_ingest
from pipeline.reports import run_named_report
from pipeline.warehouse.delta import read_table
from tests.real_data import real_data_dir

pytestmark = [pytest.mark.realdata, pytest.mark.slow]
HOUR_NS = 3600 * 10**9


def test_nav_batch_runs_on_every_real_log_and_writes_its_outages(tmp_path, cfg):
    logs = sorted((real_data_dir() / "nav").glob("*.log"))
    assert len(logs) >= 7
    imported = run_import(logs, tmp_path / "mcap")
    assert imported.exit_code == 0, imported.render()
    wh = tmp_path / "warehouse"
    ingest = run_ingest(sorted((tmp_path / "mcap").glob("*.mcap")), cfg, wh, executor="serial")
    assert ingest.exit_code == 0, ingest.render()
    gnss = pl.from_arrow(read_table(wh, "nav_gnss"))
    spans = gnss.group_by("platform_id").agg(pl.col("time_ns").min().alias("a"),
                                             pl.col("time_ns").max().alias("b"))
    assert spans.height == len(logs)
    for pid, a, b in spans.sort("a").iter_rows():  # one batch per log's own hours
        summary = run_batch(cfg, wh, start_ns=(a // HOUR_NS) * HOUR_NS,
                            end_ns=(b // HOUR_NS + 1) * HOUR_NS, executor_kind="serial")
        assert summary.exit_code == 0, f"{pid}: {summary.render()}"
    sol = pl.from_arrow(read_table(wh, "nav_solution"))
    per = sol.group_by("platform_id").agg(pl.len(), pl.col("lat_deg").is_not_null().mean())
    assert sorted(per["platform_id"].to_list()) == sorted(spans["platform_id"].to_list())
    assert (per["lat_deg"] > 0.8).all()  # a position on (nearly) every step
    # no gyro signals in plain NMEA: the heading is the gyro's own, not "corrected"
    head = sol.filter(pl.col("heading_rad").is_not_null())
    assert head.height > 0 and head["gyro_error_rad"].null_count() == head.height
    assert np.allclose(head["heading_rad"], head["gyro_heading_rad"] % (2 * np.pi))
    # the Trimble RTK log stops for 10.5 min between its 3D-fix and RTK parts
    outages = pl.from_arrow(read_table(wh, "nav_outages"))
    rtk = outages.filter(pl.col("platform_id") == "gpsd_nmea-rtk")
    assert rtk.height == 1 and rtk["kind"][0] == "silence"
    assert rtk["duration_s"][0] == pytest.approx(630.0, abs=1.0)
    report = pl.from_arrow(run_named_report(wh, "nav_quality"))
    assert report["outages"].sum() == outages.height
    assert report["steps"].sum() == sol.height
