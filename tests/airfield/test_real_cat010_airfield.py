"""The real CAT010 recordings of ../shared/data/real/asterix ingest into airfield_obs with
the shipped config (the decoder's own tests are tests/realdata/test_real_asterix.py) and
the airfield batch handles them: their SAC/SIC are not sensors of our [airfield] config,
so each sensor becomes ONE batch rejects row with its count, nothing is dropped silently."""

from __future__ import annotations

from datetime import date

import polars as pl
import pytest

from jobs.batch import run_batch
from pipeline.convert.asterix import wrap_asterix_file
from pipeline.ingest.driver import run_ingest
from pipeline.units import NS
from pipeline.warehouse.delta import read_table
from tests.real_data import real_data_dir

pytestmark = pytest.mark.realdata
DAY = date(2026, 1, 15)
DAY_NS = 1_768_435_200 * NS


def test_real_cat010_ingests_and_the_airfield_batch_runs(tmp_path, cfg):
    root = real_data_dir() / "asterix" / "jasterix_single_records"
    files = sorted(root.glob("cat010*.bin"))
    assert files, "no real CAT010 samples"
    wrapped = [wrap_asterix_file(p, tmp_path / "mcap", day=DAY) for p in files]
    wh = tmp_path / "wh"
    ingest = run_ingest(wrapped, cfg, wh, executor="serial")
    obs = pl.from_arrow(read_table(wh, "airfield_obs"))
    rejects = pl.from_arrow(read_table(wh, "rejects"))
    ed031 = obs.filter(pl.col("source_file").str.contains("cat010ed0.31"))
    assert ed031.height == 1 and ed031["asterix_category"].to_list() == [10]
    # the 0.24 Sensis edition (another UAP) is decoded with its declared edition too
    ed024 = obs.filter(pl.col("source_file").str.contains("cat010ed0.24"))
    assert ed024.height == 1 and rejects.height == 0
    assert ingest.files_total == len(files)
    t0 = int(obs["time_ns"].min()) // (3600 * NS) * 3600 * NS
    summary = run_batch(cfg, wh, start_ns=t0, end_ns=t0 + 3600 * NS, executor_kind="serial")
    assert summary.exit_code == 0, summary.render()
    batch_rej = pl.from_arrow(read_table(wh, "rejects")).filter(pl.col("stage") == "batch")
    unknown = batch_rej.filter(pl.col("reason_code") == "unknown_sensor")
    in_window = obs.filter((pl.col("time_ns") >= t0) & (pl.col("time_ns") < t0 + 3600 * NS))
    assert unknown.height == in_window["sensor_id"].n_unique() >= 1
    assert unknown["reason"].str.contains("not in the \\[airfield\\] config").all()
    assert pl.from_arrow(read_table(wh, "airfield_tracks")).height == 0
    assert t0 >= DAY_NS
