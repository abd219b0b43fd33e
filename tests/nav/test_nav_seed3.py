"""Issue 21 item 5: the run that missed the heading goal, through the real chain.

``surveil simulate --scenario ownship --seed 3`` (default duration, one hour) -> zstd
MCAP -> ingest -> Delta warehouse -> batch (family nav) -> ``nav_quality``. Before the
heading Jacobian and the cloned turn rate of ``pipeline.filters.gyro_gnss_log`` this
gave 0.118 deg RMS (max 0.210) in the sector holding the turn; now ~0.055 (max ~0.105).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest

from jobs.batch import run_batch
from jobs.simulate import run_simulate
from pipeline.ingest.driver import run_ingest
from pipeline.reports import run_named_report
from pipeline.units import NS
from pipeline.warehouse.delta import read_table

START_NS = 1_768_435_200 * NS  # 2026-01-15T00:00:00Z, the CLI's default start
DURATION_S = 3600.0  # `surveil simulate`'s default --duration 1h
SEED = 3


@pytest.fixture(scope="module")
def seed3(tmp_path_factory, cfg) -> tuple[Path, pl.DataFrame]:
    root = tmp_path_factory.mktemp("ownship_seed3")
    files = run_simulate("ownship", DURATION_S, SEED, root / "archive", cfg, start_ns=START_NS)
    assert len(files) == 2  # hourly files: the last sample falls on 01:00:00
    wh = root / "warehouse"
    ingest = run_ingest(files, cfg, wh, executor="serial")
    assert ingest.exit_code == 0, ingest.render()
    end = START_NS + int(DURATION_S * NS)
    batch = run_batch(cfg, wh, start_ns=START_NS, end_ns=end, executor_kind="serial")
    assert batch.exit_code == 0, batch.render()
    report = pl.from_arrow(run_named_report(wh, "nav_quality", start_ns=START_NS, end_ns=end))
    return wh, report


def test_nav_quality_heading_within_goal_in_every_sector(seed3):
    _, report = seed3
    assert report.height == 2  # the approach sector (speed-up, turn, outages) and outside
    assert (report["converged_steps"] > 900).all()
    assert (report["heading_rms_deg"] <= 0.1).all(), report
    assert (report["heading_max_deg"] <= 0.3).all(), report
    assert report["gyro_max_deg"].max() > 10.0  # the gyro alone: > 14 deg in the paper


def test_solution_heading_rms_and_sigma_after_convergence(seed3):
    wh, report = seed3
    s = pl.from_arrow(read_table(wh, "nav_solution")).filter(pl.col("converged"))
    err = s["heading_error_rad"].to_numpy()
    assert np.degrees(np.sqrt(np.mean(err**2))) <= 0.1
    # the reported sigma is honest (not overconfident) after convergence: inside the 5-95 %
    # range of one-hour runs over seeds 1-50 (0.24-1.67; this seed 1.33, the in-memory
    # filter's figure to 1e-4; the discriminating test is the mean over seeds,
    # tests/nav/test_nav_acceptance.py and tests/filters/test_gyro_gnss_log_montecarlo.py)
    nees = float(np.mean((err / s["sigma_heading_rad"].to_numpy()) ** 2))
    assert 0.24 < nees < 1.67
    # the report's figures are those of the table
    assert report["steps"].sum() == pl.from_arrow(read_table(wh, "nav_solution")).height
