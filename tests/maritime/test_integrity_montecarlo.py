"""Channel integrity measured like the airfield's (issue 22; slow, seeded Monte Carlo):
every radar and AIS fault kind in a compressed channel scene, a GNSS outage and jump on
the own ship, and the fault-free false alarms.

Run: .venv/bin/pytest -m slow tests/maritime/test_integrity_montecarlo.py -s (10 seeds;
the docs' table is `surveil experiment channel-faults --runs 100`)."""

from __future__ import annotations

import polars as pl
import pytest

from pipeline.experiments.channel_montecarlo import REGISTRATION_OF, run_montecarlo, summarise

SEEDS = range(1000, 1010)


@pytest.fixture(scope="module")
def result(cfg):
    return run_montecarlo(cfg, seeds=SEEDS, executor="serial")


@pytest.mark.slow
def test_every_fault_flagged_within_3_scans_reports_or_fixes(result):
    table = summarise(result)
    with pl.Config(tbl_rows=40, tbl_cols=20, tbl_width_chars=250):
        print("\n", table)
    f = result["faults"]
    assert f["detected"].all()
    by_kind = f.group_by("kind").agg(pl.col("detected_within_3").mean())
    # 10 runs: at most one late per kind (the docs' 100-run table has the shares)
    assert by_kind["detected_within_3"].min() >= 0.9, by_kind


@pytest.mark.slow
def test_false_alarm_share_near_q(result):
    fa = result["false_alarms"].group_by("sensor_kind").agg(
        pl.col("decisions").sum(), pl.col("flagged").sum(), pl.col("q").mean())
    for row in fa.iter_rows(named=True):
        share = row["flagged"] / row["decisions"]
        if row["sensor_kind"] in ("radar", "ais"):
            # the goal (10 seeds: ~24 radar and ~380 AIS false alarms expected)
            assert 0.5 * row["q"] <= share <= 2 * row["q"], row
        elif row["sensor_kind"] == "gnss_position":
            # ~6 expected over 10 seeds: only the upper bound is a meaningful test here
            assert share <= 2 * row["q"], row
        # gnss_gate: the nav filter's eq. 3 gate, not this test (docs/integrity.md §8)


@pytest.mark.slow
def test_exclusion_keeps_the_fused_sigma_honest_during_radar_faults(result):
    f = result["faults"].filter(pl.col("kind").is_in(
        ["radar_range_bias", "radar_azimuth_bias", "radar_time_offset", "radar_noise"]))
    nees = f.group_by("kind").agg(pl.col("fused_nees_on").median(),
                                  pl.col("fused_nees_off").median())
    assert (nees["fused_nees_on"] < 3.0).all(), nees
    assert (nees["fused_nees_off"] > nees["fused_nees_on"]).all(), nees


@pytest.mark.slow
def test_fused_never_materially_worse_than_the_best_radar_left(result):
    # issue 38: the fused p95 against the best radar the fault did not touch (fault-free
    # run, same points); 60 seeds: worst 1.07 (noise), docs/integrity.md §9
    f = result["faults"].filter(pl.col("sensor_kind") == "radar")
    ratio = f["fused_p95_on_m"] / f["healthy_best_radar_p95_m"]
    assert ratio.max() <= 1.10, f.select("kind", "seed", "fused_p95_on_m",
                                         "healthy_best_radar_p95_m")
    # where a registration fault is corrected, fused beats the radar left by far
    corrected = f.filter(pl.col("kind").is_in(list(REGISTRATION_OF)))
    assert (corrected["fused_p95_on_m"] < 0.8 * corrected["healthy_best_radar_p95_m"]).all()
