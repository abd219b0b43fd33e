"""Scoring against truth (else AIS): references, errors, NEES calibration, schemas."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from batch_builders import NS, T0_NS, lane_ships, run_chain, vessel_of

from pipeline import frames, tables
from pipeline.config import Config
from pipeline.families import load_config
from pipeline.maritime.score import ERROR_COLUMNS, score_tracks, truth_at_epochs


@pytest.fixture(scope="module")
def cfg() -> Config:
    return load_config()


@pytest.fixture(scope="module")
def chain(cfg):
    return run_chain(lane_ships(8, np.random.default_rng(91)), cfg, seed=92, duration_s=600.0)


def test_nees_of_calibrated_synthetic_data_averages_about_two(chain):
    nees = chain.errors.group_by("source").agg(pl.col("nees").mean(), pl.len())
    assert set(nees["source"]) == {"fused", "R1", "R2"}
    assert nees["len"].min() > 500
    for row in nees.iter_rows(named=True):
        assert 1.6 <= row["nees"] <= 2.4, row


def test_fused_beats_each_radar_rms(chain):
    rms = dict(chain.errors.group_by("source").agg(
        (pl.col("error_m") ** 2).mean().sqrt()).iter_rows())
    assert rms["fused"] < rms["R1"] and rms["fused"] < rms["R2"]


def test_reference_is_the_right_vessel_and_shared_by_radar_points(chain):
    e = chain.errors
    assert e.columns == list(ERROR_COLUMNS)
    assert set(e["reference"]) == {"truth"}
    refs = e.group_by("time_ns", "system_track_id").agg(pl.col("reference_id").n_unique())
    assert refs["reference_id"].max() == 1
    vessel = chain.associated.select("time_ns", "system_track_id",
                                     vessel_of(pl.col("local_track_id")).alias("v")).unique()
    j = e.filter(pl.col("source") == "fused").join(vessel, on=["time_ns", "system_track_id"])
    assert (j["reference_id"] == j["v"]).mean() > 0.99
    mmsi = {s.vessel_id: s.mmsi for s in chain.ships}
    assert all(m == mmsi[v] for v, m in zip(j["reference_id"], j["reference_mmsi"], strict=True))


def test_error_is_estimate_minus_interpolated_truth_and_nees_inline(chain, cfg):
    row = chain.errors.filter(pl.col("source") == "R2").row(7, named=True)
    pt = chain.associated.filter(
        (pl.col("time_ns") == row["time_ns"]) & (pl.col("system_track_id") ==
                                                 row["system_track_id"])
        & (pl.col("site_id") == "R2")).row(0, named=True)
    ship = next(s for s in chain.ships if s.vessel_id == row["reference_id"])
    tx, ty = ship.position(np.array([row["time_ns"]]))
    assert row["error_east_m"] == pytest.approx(pt["x_enu_m"] - tx[0], abs=0.01)
    assert row["error_north_m"] == pytest.approx(pt["y_enu_m"] - ty[0], abs=0.01)
    e = np.array([row["error_east_m"], row["error_north_m"]])
    P = np.array([[pt["P_xx"], pt["P_xy"]], [pt["P_xy"], pt["P_yy"]]])
    assert row["nees"] == pytest.approx(e @ np.linalg.solve(P, e))
    assert row["sector"] == pt["sector"]


def test_truth_interpolation_inline(cfg):
    o = (cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
    lat, lon = frames.enu_to_geodetic(np.array([0.0, 100.0]), np.array([0.0, -50.0]), *o)
    truth = pl.DataFrame({"time_ns": [T0_NS, T0_NS + 10 * NS], "vessel_id": [3, 3],
                          "mmsi": [None, None], "lat_deg": lat, "lon_deg": lon},
                         schema_overrides={"mmsi": pl.Int64})
    epochs = T0_NS + np.array([-1, 0, 4, 10, 11, 13, 15]) * NS
    at = truth_at_epochs(truth, epochs, cfg.region)
    assert ((at["time_ns"] - T0_NS) // NS).to_list() == [0, 4, 10]
    np.testing.assert_allclose(at["ref_x_m"], [0.0, 40.0, 100.0], atol=0.01)
    np.testing.assert_allclose(at["ref_y_m"], [0.0, -20.0, -50.0], atol=0.01)
    # prolonged past the last sample with the last segment's velocity
    at = truth_at_epochs(truth, epochs, cfg.region, extrapolate_s=3.0)
    assert ((at["time_ns"] - T0_NS) // NS).to_list() == [0, 4, 10, 11, 13]
    np.testing.assert_allclose(at["ref_x_m"][3:], [110.0, 130.0], atol=0.01)
    np.testing.assert_allclose(at["ref_y_m"][3:], [-55.0, -65.0], atol=0.01)
    one = truth_at_epochs(truth.head(1), epochs, cfg.region, extrapolate_s=3.0)
    assert one["time_ns"].to_list() == [T0_NS]


def test_ais_reference_when_no_truth(chain, cfg):
    e = score_tracks(chain.fused, chain.associated, truth=None, ais_reports=chain.ais,
                     region=cfg.region, sectors=cfg.sectors)
    assert set(e["reference"]) == {"ais"}
    assert (e["reference_id"] == e["reference_mmsi"]).all()
    fused = e.filter(pl.col("source") == "fused").join(
        chain.fused.select("time_ns", "system_track_id", "mmsi"), on=["time_ns",
                                                                      "system_track_id"])
    assert (fused["reference_id"] == fused["mmsi"]).all()
    n_ident = chain.fused["mmsi"].is_not_null().sum()
    assert 0.95 * n_ident <= fused.height <= n_ident  # points without identity skipped
    assert (e["error_m"] ** 2).mean() ** 0.5 < 150.0


def test_false_track_far_from_any_vessel_is_not_scored(chain, cfg):
    far = chain.fused.head(1).with_columns(pl.lit(99_999, pl.Int64).alias("system_track_id"),
                                           pl.col("x_enu_m") + 20_000.0)
    e = score_tracks(pl.concat([chain.fused, far]), chain.associated, truth=chain.truth,
                     ais_reports=chain.ais, region=cfg.region, sectors=cfg.sectors)
    assert 99_999 not in e["system_track_id"].to_list()
    assert e.height == chain.errors.height


def test_chain_outputs_conform_to_the_canonical_schemas(chain):
    associations = chain.associated.with_columns(
        pl.col("P_xx").sqrt().alias("sigma_x_m"), pl.col("P_yy").sqrt().alias("sigma_y_m"),
        pl.col("P_xy").alias("cov_xy_m2"))
    for name, frame in (("associations", associations), ("system_tracks", chain.fused),
                        ("identifications", chain.identifications),
                        ("track_errors", chain.errors)):
        # associations.used comes from the integrity step
        # (tests/maritime/test_channel_integrity.py); the batch stamps the site on a stage's
        # outputs (stages are site-agnostic)
        expected = set(tables.schema(name).names) - {"date", "used", "site"}
        assert expected <= set(frame.columns), (name, expected - set(frame.columns))
        assert tables.conform(name, frame).num_rows == frame.height
    assert set(chain.fused.columns) == set(tables.schema("system_tracks").names) - {"date", "site"}
    assert set(chain.errors.columns) == set(tables.schema("track_errors").names) - {"date", "site"}


def test_empty_inputs_give_empty_conforming_outputs(chain, cfg):
    fused, assoc = chain.fused.clear(), chain.associated.clear()
    for truth, ais in ((None, chain.ais.clear()), (chain.truth, chain.ais), (None, chain.ais)):
        e = score_tracks(fused, assoc, truth=truth, ais_reports=ais, region=cfg.region,
                         sectors=cfg.sectors)
        assert e.height == 0 and tables.conform("track_errors", e).num_rows == 0


def test_radar_rows_of_an_unfused_track_get_no_truth_reference(chain, cfg):
    """A (time, track) with radar rows but no fused row (every radar of the track excluded
    at that epoch, issue 22; the last epoch too) scores the other rows as before and those
    not at all, as the AIS path's join does (it once took the next key's reference, or
    indexed past the end)."""
    fused = chain.fused.sort("time_ns", "system_track_id")
    last = fused["time_ns"].max()
    drop = (fused.filter(pl.col("time_ns") == last).head(2)
            .vstack(fused.filter(pl.col("time_ns") < last).gather_every(37)))
    keep = fused.join(drop.select("time_ns", "system_track_id"),
                      on=["time_ns", "system_track_id"], how="anti")
    e = score_tracks(keep, chain.associated, truth=chain.truth, ais_reports=chain.ais,
                     region=cfg.region, sectors=cfg.sectors)
    gone = drop.select("time_ns", "system_track_id")
    want = chain.errors.join(gone, on=["time_ns", "system_track_id"], how="anti")
    from polars.testing import assert_frame_equal

    assert e.join(gone, on=["time_ns", "system_track_id"]).height == 0
    assert_frame_equal(e, want, check_exact=True)
