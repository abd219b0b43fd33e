"""Fusion + integrity on one seeded scenario (fast variants of the Monte Carlo in
test_airfield_acceptance.py): association, fault flags within 5 s, exclusion and
readmission, fused accuracy with exclusion on and off, false-alarm share."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from airfield_helpers import START_NS, acfg, seconds

from pipeline.airfield.associate import associate
from pipeline.airfield.frames import sensor_rows, to_common_frame
from pipeline.airfield.fusion import (
    Grids,
    birth_outliers,
    config_models,
    fuse_airfield,
)
from pipeline.experiments.airfield_montecarlo import (
    false_alarm_share,
    fault_metrics,
    mc_faults,
    run_scenario,
)
from pipeline.filters import airfield_kf as kf
from pipeline.simulate.airfield import simulate_airfield

SEED = 4


@pytest.fixture(scope="module")
def af(cfg):
    a = acfg(cfg)
    return a.with_faults(mc_faults(a))


@pytest.fixture(scope="module")
def run_on(af):
    return run_scenario(af, SEED)


@pytest.fixture(scope="module")
def run_off(af):
    return run_scenario(af.with_integrity(exclusion=False), SEED)


@pytest.fixture(scope="module")
def run_clean(af):
    return run_scenario(af.with_faults(()), SEED + 100)


def test_every_cooperative_target_is_one_track_with_its_identity(run_clean):
    tr = run_clean.tracks
    per_target = tr.group_by("truth_target_id").agg(pl.col("track_id").n_unique())
    assert per_target["track_id"].max() == 1
    coop = tr.filter(pl.col("cooperative"))
    assert coop["identity_correct"].mean() > 0.999


def test_association_votes_pair_the_sensor_tracks(af):
    sc = simulate_airfield(af.with_faults(()), start_ns=START_NS, duration_s=300.0, seed=SEED)
    obs = to_common_frame(sensor_rows(sc.reports, af), af).with_columns(
        (pl.col("time_ns") // 1_000_000_000).alias("epoch"))
    labelled, targets = associate(obs, gate_m=60.0, min_votes=5, timeout_epochs=10)
    purity = labelled.join(sc.reports.select("time_ns", "sensor_id", "track_number", "target_id"),
                           on=["time_ns", "sensor_id", "track_number"]).group_by("track_id").agg(
        pl.col("target_id").n_unique())
    assert purity["target_id"].max() == 1  # no track mixes two targets
    assert targets.height == sc.targets.height


def test_each_injected_fault_is_flagged_within_5_s(run_on):
    m = fault_metrics(run_on)
    assert m["detected"].all(), m
    assert (m["flagged_share"] >= 0.8).all(), m
    assert (m["median_delay_s"] <= 1.0).all(), m


def test_a_faulty_channel_is_excluded_and_readmitted(run_on, af):
    h = seconds(run_on.health)
    smr = h.filter(pl.col("channel") == af.sensor_of_kind("smr").sensor_id)
    during = smr.filter((pl.col("t_s") >= 125) & (pl.col("t_s") < 180))
    assert during["excluded"].mean() > 0.97 and not during["used"].any()
    after = smr.filter((pl.col("t_s") >= 200) & (pl.col("t_s") < 230))
    assert after["excluded"].mean() < 0.1  # readmitted after the run of passes


def test_vasn_dropout_is_an_outage(run_on, af):
    h = seconds(run_on.health)
    v = h.filter((pl.col("channel") == af.sensor_of_kind("vasn").sensor_id)
                 & (pl.col("t_s") >= 360) & (pl.col("t_s") < 420))
    assert v.height and (v["check"] == "outage").all() and (v["eta"] == 1).all()
    modes = seconds(run_on.tracks).filter((pl.col("t_s") > 362) & (pl.col("t_s") < 420))
    assert "vasn" not in set(modes["motion_mode"])  # no VASN input during the dropout


def test_exclusion_keeps_the_manoeuvring_area_within_7_5_m(run_on, run_off):
    on = fault_metrics(run_on)
    off = fault_metrics(run_off)
    single = on.filter(pl.col("start_s") < 480)
    assert (single["fused_p95_manoeuvring_m"] <= 7.5).all(), single
    # jamming and bias corrupt the fusion when the faulty channel stays in
    worse = off.filter(pl.col("kind").is_in(["jam", "bias"]) & (pl.col("start_s") < 480))
    assert (worse["fused_p95_manoeuvring_m"] > 7.5).all(), worse


def test_fault_free_false_alarms_are_near_q(run_clean, af):
    flagged, decisions = false_alarm_share(run_clean)
    q = af.integrity.q
    assert decisions > 10_000
    assert 0.5 * q <= flagged / decisions <= 2.0 * q


def test_birth_outlier_drops_the_one_channel_the_others_contradict(af):
    model = kf.build_model(("S", "M", "V"), {s: af.sensors[i].position_model
                                            for i, s in enumerate("SMV")},
                           af.sensor_of_kind("vasn").velocity_model, dt_s=1.0, sigma_input_m=0.2,
                           sigma_stationary_m=0.05, sigma_accel_mps2=1.5)
    z = np.zeros((3, 1, 2, 2))
    z[1, 0, 0] = [30.0, 20.0]  # target 0: M is 36 m off, S and V agree
    z[1, 0, 1] = [4.0, -3.0]   # target 1: everyone within their errors
    R = np.repeat(np.repeat((np.eye(2) / 12)[None, None, None], 3, 0), 2, 2)
    g = Grids(0, np.array(["a", "b"]), np.ones((3, 1, 2), bool), z, R,
              np.full((1, 2, 2), np.nan), np.zeros(2, int), np.zeros(2, int))
    out = birth_outliers(g, 0, np.array([True, True]), model, 10.6)
    np.testing.assert_array_equal(out, [[False, False], [True, False], [False, False]])


def test_fusion_without_reports_is_empty(af):
    empty = to_common_frame(sensor_rows(pl.DataFrame(schema={
        "time_ns": pl.Int64, "sensor_id": pl.String, "sac": pl.Int16, "sic": pl.Int16,
        "track_number": pl.Int64, "x_m": pl.Float64, "y_m": pl.Float64}), af), af)
    tracks, health = fuse_airfield(empty, af, config_models(af), start_ns=0, end_ns=10)
    assert tracks.height == 0 and health.height == 0
