"""AIS identification: AIS picture at epochs, gated one-to-one matches, the MMSI vote."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from batch_builders import NS, T0_NS, Ship, ais_reports, lane_ships, run_chain, vessel_of

from pipeline import frames
from pipeline.config import AisConfig, Config
from pipeline.families import load_config
from pipeline.maritime.associate import gate_threshold
from pipeline.maritime.identity import (
    IDENTIFICATION_COLUMNS,
    ais_at_epochs,
    identify,
    vote_identity,
)


@pytest.fixture(scope="module")
def cfg() -> Config:
    return load_config()


@pytest.fixture(scope="module")
def chain(cfg):
    ships = lane_ships(10, np.random.default_rng(71))
    return run_chain(ships, cfg, seed=72, duration_s=600.0)


def _ais(cfg: Config, rows: list[tuple[float, float, float, float | None, float | None]]):
    """(t_s, x_m, y_m, sog, cog) rows of MMSI 1 as ais_reports."""
    t, x, y, sog, cog = zip(*rows, strict=True)
    lat, lon = frames.enu_to_geodetic(np.array(x), np.array(y), cfg.region.origin_lat_deg,
                                      cfg.region.origin_lon_deg)
    return pl.DataFrame({
        "time_ns": [T0_NS + int(v * NS) for v in t], "mmsi": 1, "lat_deg": lat,
        "lon_deg": lon, "sog_mps": list(sog), "cog_rad": list(cog),
    }, schema_overrides={"mmsi": pl.Int64, "sog_mps": pl.Float64, "cog_rad": pl.Float64})


def test_ais_picture_latest_report_extrapolated_with_simple_covariance(cfg):
    ais = _ais(cfg, [(0.0, 100.0, 200.0, 5.0, np.pi / 2), (10.0, 150.0, 200.0, 5.0, np.pi / 2),
                     (60.0, 0.0, 0.0, None, None)])
    epochs = T0_NS + np.array([-4, 0, 4, 10, 12, 45, 64]) * NS
    a = ais_at_epochs(ais, epochs, cfg=AisConfig(), region=cfg.region)
    got = {(t - T0_NS) // NS: r for t, r in zip(a["time_ns"], a.iter_rows(named=True),
                                                 strict=True)}
    assert sorted(got) == [0, 4, 10, 12, 64]  # none before the first, none 35 s old
    assert got[4]["ais_time_ns"] == T0_NS and got[12]["ais_time_ns"] == T0_NS + 10 * NS
    assert got[4]["x_enu_m"] == pytest.approx(120.0, abs=0.01)
    assert got[12]["x_enu_m"] == pytest.approx(160.0, abs=0.01)
    assert got[4]["y_enu_m"] == pytest.approx(200.0, abs=0.01)
    sp, ss = AisConfig().sigma_position_m, AisConfig().sigma_sog_mps
    assert got[4]["P_xx"] == pytest.approx(sp**2 + (ss * 4) ** 2)
    assert got[4]["P_yy"] == pytest.approx(sp**2)
    assert got[4]["P_xy"] == pytest.approx(0.0, abs=1e-12)
    assert got[64]["x_enu_m"] == pytest.approx(0.0, abs=0.01)  # no SOG/COG: not moved
    assert got[64]["P_xx"] == pytest.approx(sp**2)


def test_vote_most_matches_in_window_ties_to_smaller_d2():
    t = [T0_NS + k * 4 * NS for k in range(6)]
    matches = pl.DataFrame({
        "time_ns": [t[0], t[1], t[2], t[3], t[4], t[4]],
        "system_track_id": [1, 1, 1, 1, 1, 2],
        "mmsi": [10, 10, 20, 20, 30, 30],
        "mahalanobis_d2": [1.0, 1.0, 0.5, 0.5, 9.0, 1.0],
    })
    points = pl.DataFrame({"time_ns": [*t, t[5] + 100 * NS], "system_track_id": [1] * 7})
    got = vote_identity(points, matches, window_s=4.0, min_matches=1)
    ident = dict(zip(got["time_ns"], got["mmsi"], strict=True))
    assert ident[t[0]] == 10  # window [t0-4, t0+4]: 10 x2
    assert ident[t[1]] == 10  # 10 x2, 20 x1
    assert ident[t[2]] == 20  # 10 x1 (t1), 20 x2 (t2, t3)
    assert ident[t[3]] == 20  # 20 x2, 30 x1
    assert ident[t[4]] == 20  # 20 x1 (d2 0.5) vs 30 x1 (d2 9): tie -> smaller d2
    assert t[5] + 100 * NS not in ident  # no match in the window: no identity
    wide = vote_identity(points, matches, window_s=100.0, min_matches=1)
    assert set(wide["mmsi"]) == {20}  # 10 x2 (d2 2) vs 20 x2 (d2 1)


def test_identity_right_for_95_percent_of_points(chain):
    truth_mmsi = pl.DataFrame({
        "v": [s.vessel_id for s in chain.ships], "true_mmsi": [s.mmsi for s in chain.ships],
    }, schema_overrides={"v": pl.Int64, "true_mmsi": pl.Int64})
    vessel = chain.associated.select(
        "time_ns", "system_track_id", vessel_of(pl.col("local_track_id")).alias("v")
    ).unique(["time_ns", "system_track_id"])
    f = chain.fused.join(vessel, on=["time_ns", "system_track_id"]).join(truth_mmsi, on="v")
    right = (f["mmsi"] == f["true_mmsi"]).fill_null(False) | (
        f["mmsi"].is_null() & f["true_mmsi"].is_null())
    assert f.height == chain.fused.height
    assert right.mean() >= 0.95
    assert f["true_mmsi"].null_count() > 0  # the case includes ships without AIS


def test_matches_are_one_to_one_per_epoch_and_gated(chain, cfg):
    ids = chain.identifications
    assert ids.columns == list(IDENTIFICATION_COLUMNS)
    assert not ids.select("time_ns", "system_track_id").is_duplicated().any()
    assert not ids.select("time_ns", "mmsi").is_duplicated().any()
    assert (ids["mahalanobis_d2"] < gate_threshold(cfg.ais.gate_probability)).all()
    assert (ids["ais_time_ns"] <= ids["time_ns"]).all()
    age = (ids["time_ns"] - ids["ais_time_ns"]) / NS
    assert age.max() <= cfg.ais.max_report_age_s


def test_ais_only_ship_far_away_is_never_matched(cfg):
    ships = lane_ships(3, np.random.default_rng(81))
    ghost = Ship(99, 15_000.0, 15_000.0, 0.0, 5.0, 299_000_099)
    c = run_chain(ships, cfg, seed=82, duration_s=120.0)
    ais = pl.concat([c.ais, ais_reports([ghost], cfg, np.random.default_rng(83),
                                        duration_s=120.0)]).sort("time_ns", "mmsi")
    ids, fused = identify(c.fused, ais, cfg=cfg.ais, region=cfg.region)
    assert 299_000_099 not in ids["mmsi"].to_list()
    assert fused.height == c.fused.height and "mmsi" in fused.columns


def test_vote_needs_mutual_support():
    """A track that caught one stray match of an MMSI whose main track is another one
    gets no identity from it (a ship without AIS in the lane of an AIS ship)."""
    t = [T0_NS + k * 4 * NS for k in range(10)]
    matches = pl.DataFrame({
        "time_ns": [*t, t[5]],
        "system_track_id": [1] * 10 + [2],
        "mmsi": [10] * 11,
        "mahalanobis_d2": [1.0] * 11,
    })
    points = pl.DataFrame({"time_ns": t + t, "system_track_id": [1] * 10 + [2] * 10})
    got = vote_identity(points, matches, window_s=300.0, min_matches=1)
    assert set(got.filter(pl.col("system_track_id") == 1)["mmsi"]) == {10}
    assert got.filter(pl.col("system_track_id") == 2).height == 0
    few = vote_identity(points, matches.head(2), window_s=300.0, min_matches=3)
    assert few.height == 0


def test_in_epochs_without_any_epoch():
    """Radar tracks and no AIS in the window: no epoch to match (an IndexError failed
    the whole maritime unit before; found by bench/hostile.py)."""
    import numpy as np

    from pipeline.maritime.identity import _in_epochs

    assert _in_epochs(np.array([5, 6], dtype=np.int64), np.empty(0, dtype=np.int64)).size == 0
