"""Is the reconstructed reference honest? (issue 37, slow): 10 seeds x 1 h of the channel
scenario with the config's fault schedule and of the airfield scenario without faults,
through the batch stages with the truth and with it withheld; the shipped reports on
both (pipeline/experiments/reference_montecarlo.py, `surveil experiment reference`).

Every accuracy figure (RMS and 95th percentile per sector / ED-87 area and per radar /
channel / fused) must be within 10 % of the truth-based one and PD per radar and channel
within 0.01, except, on the airfield, the cells whose p95 rests on a few hundred points
(the apron taxiways: ~1,400 updates an hour); there the worst seed must stay within
15 %. The airfield with its fault schedule is measured, not judged: a reference made
of the same reports cannot see an error every channel shares (docs/evaluation.md)."""

from __future__ import annotations

import polars as pl
import pytest

from pipeline.experiments.reference_montecarlo import run_montecarlo, summarise
from pipeline.families import load_config

pytestmark = pytest.mark.slow

SEEDS = range(1, 11)


def _show(figures: pl.DataFrame) -> None:
    with pl.Config(tbl_rows=200, tbl_cols=20, tbl_width_chars=220):
        print(summarise(figures))


def test_maritime_with_faults_truth_withheld():
    figures = run_montecarlo(load_config(None), seeds=SEEDS, duration_s=3600.0,
                             scenes=("maritime",))
    _show(figures)
    judged = figures.filter(pl.col("within_tolerance").is_not_null())
    assert judged.height >= 10 * (9 * 2 + 2)
    bad = judged.filter(~pl.col("within_tolerance"))
    assert bad.height == 0, bad


def test_airfield_truth_withheld():
    figures = run_montecarlo(load_config(None), seeds=SEEDS, duration_s=3600.0, clean=True,
                             scenes=("airfield",))
    _show(figures)
    judged = figures.filter(pl.col("within_tolerance").is_not_null())
    assert judged.height >= 10 * (12 * 2 + 4)
    pd = judged.filter(pl.col("metric") == "pd")
    assert pd["within_tolerance"].all()
    dense = judged.filter((pl.col("metric") != "pd") & (pl.col("scope") != "apron_taxiway"))
    assert dense["within_tolerance"].all(), dense.filter(~pl.col("within_tolerance"))
    apron = judged.filter((pl.col("metric") != "pd") & (pl.col("scope") == "apron_taxiway"))
    assert apron["difference"].abs().max() < 0.15, apron.sort("difference")
