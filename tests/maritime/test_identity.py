"""AIS identification: AIS picture at epochs, gated one-to-one matches, the confirmed
identity (Wald's sequential test per track and MMSI)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import polars as pl
import pytest
from batch_builders import NS, T0_NS, Ship, ais_reports, lane_ships, run_chain, vessel_of

from pipeline import frames
from pipeline.config import AisConfig, Config, ConfigError
from pipeline.families import load_config
from pipeline.filters.sequential import held_cumsum_reference, wald_boundaries
from pipeline.maritime.associate import gate_threshold
from pipeline.maritime.identity import IDENTIFICATION_COLUMNS, ais_at_epochs, identify


@pytest.fixture(scope="module")
def cfg() -> Config:
    return load_config()


@pytest.fixture(scope="module")
def chain(cfg):
    ships = lane_ships(10, np.random.default_rng(71))
    return run_chain(ships, cfg, seed=72, duration_s=600.0)


def _ais(cfg: Config, rows: list[tuple[float, float, float, float | None, float | None]],
         mmsi: int = 1):
    """(t_s, x_m, y_m, sog, cog) rows of ``mmsi`` as ais_reports."""
    t, x, y, sog, cog = zip(*rows, strict=True)
    lat, lon = frames.enu_to_geodetic(np.array(x), np.array(y), cfg.region.origin_lat_deg,
                                      cfg.region.origin_lon_deg)
    return pl.DataFrame({
        "time_ns": [T0_NS + int(v * NS) for v in t], "mmsi": mmsi, "lat_deg": lat,
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


def test_in_epochs_without_any_epoch():
    """Radar tracks and no AIS in the window: no epoch to match (an IndexError failed
    the whole maritime unit before; found by bench/hostile.py)."""
    import numpy as np

    from pipeline.maritime.identity import _in_epochs

    assert _in_epochs(np.array([5, 6], dtype=np.int64), np.empty(0, dtype=np.int64)).size == 0


EPOCH_S = 4.0
SIGMA_TRACK_M = 20.0


def _tracks(positions: dict[int, list[tuple[float, float]]]) -> pl.DataFrame:
    """Fused points of stationary tracks: {system_track_id: [(x_m, y_m) per epoch]}."""
    rows = [(T0_NS + round(k * EPOCH_S * NS), sid, x, y)
            for sid, xy in positions.items() for k, (x, y) in enumerate(xy)]
    t, sid, x, y = zip(*rows, strict=True)
    return pl.DataFrame({"time_ns": t, "system_track_id": sid, "x_enu_m": x, "y_enu_m": y,
                         "sigma_x_m": SIGMA_TRACK_M, "sigma_y_m": SIGMA_TRACK_M,
                         "cov_xy_m2": 0.0}).sort("time_ns", "system_track_id")


def _identity(cfg: Config, tracks: pl.DataFrame, ais: pl.DataFrame, sid: int) -> list:
    _, fused = identify(tracks, ais, cfg=cfg.ais, region=cfg.region)
    return fused.filter(pl.col("system_track_id") == sid).sort("time_ns")["mmsi"].to_list()


@pytest.mark.parametrize("lag_s", [0.0, 60.0])
def test_identity_confirmed_by_the_test_and_dropped_the_same_way(cfg, lag_s):
    """AIS next to the track for 20 epochs, then reported 3 km away: with the causal
    test (lag 0) the MMSI is taken at the first epoch the held sum of log-likelihood
    ratios reaches Wald's A (not before) and dropped when it falls to B (the old +-300 s
    vote named all 60 epochs); with a 60 s lag both decisions reach back to the start
    of their evidence: named exactly while the AIS was beside the track."""
    cfg = replace(cfg, ais=replace(cfg.ais, identity_lag_s=lag_s))
    n, near = 60, 20
    tracks = _tracks({7: [(0.0, 0.0)] * n})
    ais = _ais(cfg, [(k * EPOCH_S, 10.0 if k < near else 3000.0, 0.0, None, None)
                     for k in range(n)], mmsi=555)
    a = cfg.ais
    lo, hi = wald_boundaries(a.false_identification_probability,
                             a.missed_identification_probability)
    d2 = 10.0**2 / (SIGMA_TRACK_M**2 + a.sigma_position_m**2)
    hit = (np.log(a.match_probability / a.stray_match_probability)
           + np.log(gate_threshold(a.gate_probability) / 2) - d2 / 2)
    miss = np.log((1 - a.match_probability) / (1 - a.stray_match_probability))
    s = held_cumsum_reference([hit] * near + [miss] * (n - near), [True] + [False] * (n - 1),
                              lo, hi)
    first, last = int(np.argmax(s >= hi)), int(np.argmax(s <= lo)) - 1
    assert 0 < first < near < last < n - 1
    got = _identity(cfg, tracks, ais, 7)
    if lag_s == 0:
        assert got == [None] * first + [555] * (last + 1 - first) + [None] * (n - 1 - last)
    else:
        assert first * EPOCH_S <= lag_s and (last + 1 - near) * EPOCH_S <= lag_s
        assert got == [555] * near + [None] * (n - near)


def test_stray_matches_never_name_a_ship_without_ais(cfg):
    """A ship without AIS whose neighbour's AIS (no radar track of its own) falls in
    its gate one epoch in three: the old vote named it (it held every match of that
    MMSI); the test sees two misses per match and never confirms."""
    n = 90
    tracks = _tracks({3: [(0.0, 0.0)] * n})
    ais = _ais(cfg, [(k * EPOCH_S, 10.0 if k % 3 == 0 else 3000.0, 0.0, None, None)
                     for k in range(n)], mmsi=777)
    ids, _ = identify(tracks, ais, cfg=cfg.ais, region=cfg.region)
    assert ids.height == n // 3  # the stray matches are there
    assert _identity(cfg, tracks, ais, 3) == [None] * n


def test_two_tracks_in_one_gate_give_no_identity(cfg):
    """Two tracks 8 m apart, the AIS point between them: the assignment picks one or the
    other, but the rival term (q_alt - q) / 2 leaves no evidence for either (the old
    vote named the one with most matches)."""
    n = 60
    rng = np.random.default_rng(5)
    tracks = _tracks({1: [(0.0, 0.0)] * n, 2: [(8.0, 0.0)] * n})
    ais = _ais(cfg, [(k * EPOCH_S, 4.0 + rng.normal(0, 3), 0.0, None, None)
                     for k in range(n)], mmsi=999)
    ids, _ = identify(tracks, ais, cfg=cfg.ais, region=cfg.region)
    assert ids.height == n
    assert _identity(cfg, tracks, ais, 1) == [None] * n
    assert _identity(cfg, tracks, ais, 2) == [None] * n


@pytest.mark.parametrize(("key", "value", "message"), [
    ("stray_match_probability", 0.96, "must be below match_probability"),
    ("missed_identification_probability", 0.9995, "must be below 1"),
    ("identity_lag_s", 301.0, "must be at most identity_window_s"),
])
def test_identity_test_parameters_are_checked(tmp_path, key, value, message):
    """The cross-field checks of the [ais] test parameters (each alone is in (0, 1))."""
    import re

    from pipeline.resources import resource_path

    text = (resource_path("config") / "surveil.toml").read_text(encoding="utf-8")
    text, n = re.subn(rf"^{key} = [0-9.]+", f"{key} = {value}", text, flags=re.M)
    assert n == 1
    path = tmp_path / "site.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=message):
        load_config(path)


def _lineage(child: int, parent: int, epoch: int) -> pl.DataFrame:
    return pl.DataFrame({"system_track_id": [child], "parent_track_id": [parent],
                         "split_ns": [T0_NS + round(epoch * EPOCH_S * NS)]})


@pytest.mark.parametrize("lag_s", [0.0, 60.0])
def test_a_split_track_keeps_its_parents_name(cfg, lag_s):
    """Track 7 is named 555 over 20 epochs beside its AIS, then its radar track leaves
    it for a new track 8 (a split) that lives 3 epochs, still beside the AIS: alone, 3
    epochs of evidence do not confirm the name (8 stays unnamed, the "none" of a noisy
    radar's onset); with the lineage 8 starts where 7's test stood, named. (The AIS
    point lies at d^2 = 7 from the tracks: 1.3 of log-likelihood ratio per epoch, 3.8
    over the child's 3 epochs, below Wald's A = 6.9.)"""
    cfg = replace(cfg, ais=replace(cfg.ais, identity_lag_s=lag_s))
    near, n = 20, 23
    tracks = _tracks({7: [(0.0, 0.0)] * near, 8: [(0.0, 0.0)] * n}).filter(
        (pl.col("system_track_id") == 7) | (pl.col("time_ns") >= T0_NS + near * EPOCH_S * NS))
    dx = float(np.sqrt(7.0 * (SIGMA_TRACK_M**2 + cfg.ais.sigma_position_m**2)))
    ais = _ais(cfg, [(k * EPOCH_S, dx, 0.0, None, None) for k in range(n)], mmsi=555)
    assert _identity(cfg, tracks, ais, 7)[-1] == 555
    assert _identity(cfg, tracks, ais, 8) == [None] * (n - near)
    _, fused = identify(tracks, ais, cfg=cfg.ais, region=cfg.region,
                        lineage=_lineage(8, 7, near))
    assert fused.filter(pl.col("system_track_id") == 8)["mmsi"].to_list() == [555] * (n - near)


def test_an_inherited_name_is_withdrawn_by_the_evidence(cfg):
    """The same split, but from the split on the AIS is reported 3 km from track 8: the
    test's misses take the inherited name off, and with the 60 s lag from 8's first
    point (it was never that ship); track 7 keeps its name up to the split."""
    near, n = 20, 40
    tracks = _tracks({7: [(0.0, 0.0)] * near, 8: [(0.0, 0.0)] * n}).filter(
        (pl.col("system_track_id") == 7) | (pl.col("time_ns") >= T0_NS + near * EPOCH_S * NS))
    ais = _ais(cfg, [(k * EPOCH_S, 10.0 if k < near else 3000.0, 0.0, None, None)
                     for k in range(n)], mmsi=555)
    _, fused = identify(tracks, ais, cfg=cfg.ais, region=cfg.region,
                        lineage=_lineage(8, 7, near))
    assert fused.filter(pl.col("system_track_id") == 8)["mmsi"].to_list() == [None] * (n - near)
    assert fused.filter(pl.col("system_track_id") == 7)["mmsi"].to_list() == [555] * near


def test_a_track_named_nothing_passes_nothing_on(cfg):
    """A parent without a confirmed name gives its split nothing: no pair is made up."""
    near, n = 2, 5
    tracks = _tracks({7: [(0.0, 0.0)] * near, 8: [(0.0, 0.0)] * n}).filter(
        (pl.col("system_track_id") == 7) | (pl.col("time_ns") >= T0_NS + near * EPOCH_S * NS))
    ais = _ais(cfg, [(k * EPOCH_S, 3000.0, 0.0, None, None) for k in range(n)], mmsi=555)
    _, fused = identify(tracks, ais, cfg=cfg.ais, region=cfg.region,
                        lineage=_lineage(8, 7, near))
    assert fused["mmsi"].is_null().all()
