"""Faster paths of the maritime stage against the references they replaced (STYLE.md:
a faster path keeps its reference and is tested against it)."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from polars.testing import assert_frame_equal

from pipeline.families import load_config
from pipeline.maritime import identity, score
from pipeline.maritime.associate import assign, assign_grouped, gate_threshold

T0_NS = 1_768_471_200 * 10**9


@pytest.mark.parametrize("seed", range(5))
def test_assign_grouped_equals_assign_per_group(seed: int) -> None:
    rng = np.random.default_rng(seed)
    rows, cols, costs, groups, miss_all = [], [], [], [], []
    r0 = c0 = 0
    expect_r, expect_c = [], []
    for g in range(12):
        n, m = rng.integers(0, 9), rng.integers(0, 9)
        cost = np.where(rng.random((n, m)) < 0.35, rng.uniform(0, 10, (n, m)), np.inf)
        if g % 3 == 0 and n and m:  # ties
            cost[cost < 5] = 2.0
        miss = rng.uniform(1, 12, n)
        if n and m:
            r, c = assign(cost, miss)
            expect_r.append(r0 + r)
            expect_c.append(c0 + c)
        i, j = np.nonzero(np.isfinite(cost))
        rows.append(r0 + i)
        cols.append(c0 + j)
        costs.append(cost[i, j])
        groups.append(np.full(n, g))
        miss_all.append(miss)
        r0, c0 = r0 + n, c0 + m
    perm = rng.permutation(sum(map(len, rows)))  # entries in any order
    r, c = assign_grouped(np.concatenate(rows)[perm], np.concatenate(cols)[perm],
                          np.concatenate(costs)[perm], np.concatenate(miss_all),
                          np.concatenate(groups), c0)
    np.testing.assert_array_equal(r, np.concatenate(expect_r) if expect_r else [])
    np.testing.assert_array_equal(c, np.concatenate(expect_c) if expect_c else [])


def _crowd(seed: int, n_epochs: int = 20, n: int = 120) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Tracks and AIS points crowded enough that gates overlap."""
    rng = np.random.default_rng(seed)
    t = np.repeat(T0_NS + 4 * 10**9 * np.arange(n_epochs), n)
    base = rng.uniform(0, 6000, (n, 2))
    xy = np.tile(base, (n_epochs, 1)) + rng.normal(0, 40, (n * n_epochs, 2))
    sig = rng.choice([10.0, 60.0, 300.0], n * n_epochs)
    tracks = pl.DataFrame({
        "time_ns": t, "system_track_id": np.tile(np.arange(n), n_epochs),
        "x_enu_m": xy[:, 0], "y_enu_m": xy[:, 1], "sigma_x_m": sig, "sigma_y_m": sig * 0.7,
        "cov_xy_m2": sig * sig * 0.2,
    })
    keep = rng.random(n * n_epochs) < 0.8
    ais = pl.DataFrame({
        "time_ns": t[keep], "mmsi": 200_000_000 + np.tile(np.arange(n), n_epochs)[keep],
        "ais_time_ns": t[keep], "x_enu_m": xy[keep, 0] + rng.normal(0, 15, keep.sum()),
        "y_enu_m": xy[keep, 1] + rng.normal(0, 15, keep.sum()), "P_xx": 100.0,
        "P_yy": 100.0, "P_xy": 0.0,
    })
    return tracks.sort("time_ns", "system_track_id"), ais.sort("time_ns", "mmsi")


@pytest.mark.parametrize("seed", range(3))
def test_ais_match_equals_dense_reference(seed: int) -> None:
    tracks, ais = _crowd(seed)
    gate = gate_threshold(0.999)
    fast = identity._match(tracks, ais, gate)
    ref = identity._match_reference(tracks, ais, gate)
    assert ref.height > 1000
    assert_frame_equal(fast, ref)


@pytest.mark.parametrize("seed", range(3))
def test_nearest_truth_equals_polars_reference(seed: int) -> None:
    cfg = load_config()
    rng = np.random.default_rng(seed)
    n_v, n_e = 80, 15
    t = np.repeat(T0_NS + 5 * 10**9 * np.arange(n_e), n_v)
    lat = 46.40 + np.tile(rng.uniform(-0.05, 0.05, n_v), n_e) + rng.normal(0, 1e-5, n_v * n_e)
    lon = 30.90 + np.tile(rng.uniform(-0.05, 0.05, n_v), n_e)
    truth = pl.DataFrame({"time_ns": t, "vessel_id": np.tile(np.arange(n_v), n_e),
                          "mmsi": np.tile(np.arange(n_v), n_e) + 1000, "lat_deg": lat,
                          "lon_deg": lon, "course_rad": 0.0, "speed_mps": 0.0})
    epochs = T0_NS + 4 * 10**9 * np.arange(15)
    at = score.truth_at_epochs(truth, epochs, cfg.region)
    pts = at.sample(400, with_replacement=True, seed=seed).select(
        "time_ns", (pl.col("ref_x_m") + rng.normal(0, 600, 400)).alias("x_enu_m"),
        (pl.col("ref_y_m") + rng.normal(0, 600, 400)).alias("y_enu_m"),
    ).with_row_index("system_track_id").with_columns(pl.col("system_track_id").cast(pl.Int64))
    pts = pts.sort("time_ns", "system_track_id")
    ref = score._truth_reference_reference(pts, truth, cfg.region, 1000.0, 0.0).sort(
        "time_ns", "system_track_id")
    row = score.nearest_truth(pts["time_ns"].to_numpy(), pts["x_enu_m"].to_numpy(),
                              pts["y_enu_m"].to_numpy(), at, 1000.0)
    got = pts.filter(pl.Series(row >= 0)).select(
        "time_ns", "system_track_id",
        pl.Series("reference_id", at["vessel_id"].to_numpy()[row[row >= 0]]))
    assert ref.height > 100
    assert_frame_equal(got, ref.select("time_ns", "system_track_id", "reference_id"))


def test_stage_outputs_come_sorted_by_the_tables_sort_keys() -> None:
    """The family declares sorted_outputs: the batch writes the frames as they are."""
    from maritime_helpers import batch_tables

    from pipeline import tables
    from pipeline.maritime.stage import FAMILY

    assert FAMILY.sorted_outputs
    out = batch_tables(load_config(), duration_s=600.0, seed=3)
    for name, frame in out.items():
        if name == "rejects" or frame.height == 0:
            continue
        shaped = pl.from_arrow(tables.shape(name, frame))
        assert_frame_equal(shaped, pl.from_arrow(tables.conform(name, frame)), check_exact=True)


@pytest.fixture(scope="module")
def region_synced():
    """Ten busy minutes of a small region, aligned (and synchronised) with its config."""
    from pathlib import Path
    from tempfile import mkdtemp

    from pipeline.maritime.align import align_reports
    from pipeline.maritime.config import maritime_config
    from pipeline.maritime.sync import epoch_grid
    from pipeline.simulate.region import RegionSimulation
    from pipeline.simulate.region_layout import region_config, region_layout, toml_text

    path = Path(mkdtemp()) / "region.toml"
    path.write_text(toml_text(region_config(region_layout(5))))
    cfg = load_config(path)
    sim = RegionSimulation(region_layout(5), n_ships=200, seed=9, start_ns=T0_NS,
                           duration_s=600.0)
    radar = pl.concat([s.radar_reports for s in sim.slices()]).rename(
        {"track_id": "local_track_id", "x_m": "x_site_m", "y_m": "y_site_m"})
    aligned, _ = align_reports(radar, cfg)
    mc = maritime_config(cfg)
    epochs = epoch_grid(T0_NS + 10 * 10**9, T0_NS + 600 * 10**9, mc.sync.epoch_period_s)
    return cfg, aligned, epochs


def test_synchronise_equals_polars_reference(region_synced) -> None:
    from pipeline.maritime.config import maritime_config
    from pipeline.maritime.sync import synchronise, synchronise_reference

    cfg, aligned, epochs = region_synced
    sync = maritime_config(cfg).sync
    fast = synchronise(aligned, epochs_ns=epochs, sync=sync)
    assert fast.height > 50_000
    assert_frame_equal(fast, synchronise_reference(aligned, epochs_ns=epochs, sync=sync),
                       check_exact=True)
    shuffled = aligned.sample(fraction=1.0, shuffle=True, seed=1)  # any input order
    assert_frame_equal(synchronise(shuffled, epochs_ns=epochs, sync=sync), fast,
                       check_exact=True)


def test_associate_and_fuse_equal_references(region_synced) -> None:
    """Native epoch loop + numpy leave-one-out and fusion (Kahan group sums, polars'
    trigonometry) give bit for bit the frames of the numpy/polars references."""
    from pipeline.maritime.associate import associate_tracks, associate_tracks_reference
    from pipeline.maritime.config import maritime_config
    from pipeline.maritime.fuse import fuse, fuse_reference
    from pipeline.maritime.sync import synchronise

    cfg, aligned, epochs = region_synced
    mc = maritime_config(cfg)
    synced = synchronise(aligned, epochs_ns=epochs, sync=mc.sync)
    fast = associate_tracks(synced, cfg=mc.association)
    ref = associate_tracks_reference(synced, cfg=mc.association)
    assert_frame_equal(fast, ref, check_exact=True)
    assert_frame_equal(fuse(fast), fuse_reference(ref), check_exact=True)


def test_stage_siap_pairs_and_cross_track_equal_references() -> None:
    """The channel scenario through the stage, then the polars references of SIAP's
    candidate pairs and of the cross-track table on the same frames."""
    from maritime_helpers import scenario_tables

    from pipeline.family import Window
    from pipeline.maritime import cross_track, siap
    from pipeline.maritime.config import maritime_config
    from pipeline.maritime.stage import stage

    cfg = load_config()
    radar, ais, truth = scenario_tables(cfg, duration_s=900.0, seed=5)
    w = Window(1_768_435_200 * 10**9 + 60 * 10**9, 1_768_435_200 * 10**9 + 840 * 10**9)
    out = stage({"radar_tracks": radar, "ais_reports": ais, "truth": truth}, w, cfg)
    ref = cross_track.cross_track_by_leg_reference(
        out["system_tracks"], out["associations"], out["track_errors"], legs=cfg.fairway_legs,
        region=cfg.region, sites=cfg.radar_sites)
    assert ref.height > 1000
    assert_frame_equal(out["cross_track_by_leg"], ref, check_exact=True)
    tracks = siap._tracks(out["system_tracks"])
    truths = siap.truth_states(truth, out["system_tracks"]["time_ns"].unique().to_numpy(),
                               cfg.region)
    got = siap.candidate_pairs(tracks, truths, maritime_config(cfg).siap)
    want = siap.candidate_pairs_reference(tracks, truths, maritime_config(cfg).siap)
    assert want.height > 1000
    assert_frame_equal(got.drop("_i", "_j"), want, check_exact=True, check_dtypes=False)


def test_one_truth_pairing_scores_and_measures_as_each_step_alone() -> None:
    """The stage pairs its tracks with truth once for the scoring and SIAP: both tables
    equal, to the bit, what each step finds pairing on its own, with points beyond the
    pairing's reach (false tracks: the scoring looks farther) and vessels leaving the
    scene (the truth prolonged for the scoring, not for SIAP)."""
    from maritime_helpers import scenario_tables

    from pipeline.family import Window
    from pipeline.maritime import siap
    from pipeline.maritime.config import maritime_config
    from pipeline.maritime.stage import stage
    from pipeline.maritime.sync import epoch_grid

    cfg = load_config()
    mc = maritime_config(cfg)
    radar, ais, truth = scenario_tables(cfg, duration_s=600.0, seed=5)
    start_ns = 1_768_435_200 * 10**9
    out = stage({"radar_tracks": radar, "ais_reports": ais, "truth": truth},
                Window(start_ns, start_ns + 600 * 10**9), cfg)
    fused, assoc = out["system_tracks"], out["associations"]
    # false tracks 700-1,900 m off a third of the fused points, ids of their own
    rng = np.random.default_rng(2)
    far = fused.gather_every(3)
    far = far.with_columns(pl.col("x_enu_m") + rng.uniform(700, 1900, far.height),
                           pl.col("system_track_id") + 10**15)
    fused = pl.concat([fused, far]).sort("time_ns", "system_track_id")
    last = truth.group_by("vessel_id").agg(pl.col("time_ns").max())
    assert (last["time_ns"] < start_ns + 590 * 10**9).any()  # some leave: truth prolonged
    epochs = epoch_grid(start_ns, start_ns + 600 * 10**9, mc.sync.epoch_period_s)
    pairing = score.pair_with_truth(fused, truth, epochs, cfg.region,
                                    near_m=mc.siap.max_distance_m)
    kw = dict(truth=truth, ais_reports=ais, region=cfg.region, sectors=cfg.sectors,
              sites=cfg.radar_sites)
    alone = score.score_tracks(fused, assoc, **kw)
    assert (alone.filter(pl.col("system_track_id") >= 10**15)["error_m"] > 500).sum() > 100
    assert_frame_equal(score.score_tracks(fused, assoc, **kw, pairing=pairing), alone,
                       check_exact=True)
    kw = dict(epochs_ns=epochs, epoch_period_s=mc.sync.epoch_period_s, region=cfg.region,
              sectors=cfg.sectors, cfg=mc.siap, start_ns=start_ns + 60 * 10**9,
              end_ns=start_ns + 540 * 10**9)
    alone = siap.siap_by_sector(fused, truth, **kw)
    assert alone["associated_track_epochs"].sum() > 1000
    assert_frame_equal(siap.siap_by_sector(fused, truth, **kw, pairing=pairing), alone,
                       check_exact=True)


@pytest.mark.parametrize("seed", range(4))
def test_nearest_slots_equal_dense_reference_in_the_gate(seed: int) -> None:
    """Grid-gated AIS -> slot candidates: every gated candidate (d2 < gate) as the dense
    reference's, same slot, same d2 to the bit, same order; the rest -1 / inf."""
    from types import SimpleNamespace

    from pipeline.maritime import integrity

    rng = np.random.default_rng(seed)
    n_epochs, per = 15, rng.integers(0, 150, 15)
    bounds = np.r_[0, np.cumsum(per)]
    N = int(bounds[-1])
    centre = rng.uniform(0, 5000, (N, 2))
    sig = rng.choice([5.0, 40.0, 400.0, 3000.0], N)
    P = np.column_stack([sig**2, (0.6 * sig) ** 2, 0.3 * sig * 0.6 * sig])
    P[rng.random(N) < 0.02] = np.nan  # a slot without a position estimate
    rad = SimpleNamespace(slot_bounds=bounds, p_all=centre, P_all=P)
    n = 900
    k = np.sort(rng.integers(0, n_epochs, n))
    xy = rng.uniform(0, 5000, (n, 2))
    near = rng.random(n) < 0.7  # most AIS points near a slot of their epoch
    for i in np.flatnonzero(near & (per[k] > 0)):
        s = bounds[k[i]] + rng.integers(0, per[k[i]])
        xy[i] = centre[s] + rng.normal(0, 30, 2)
    gate = gate_threshold(0.999)
    cand, d2 = integrity.nearest_slots(xy, k, rad, 100.0, gate)
    ref_c, ref_d2 = integrity.nearest_slots_dense(xy, k, rad, 100.0)
    gated = ref_d2 < gate
    assert gated.sum() > 500
    np.testing.assert_array_equal(d2 < gate, gated)
    np.testing.assert_array_equal(cand[gated], ref_c[gated])
    np.testing.assert_array_equal(d2[gated], ref_d2[gated])
    assert (cand[~gated] == -1).all() and np.isinf(d2[~gated]).all()


@pytest.mark.parametrize("seed", range(3))
def test_shift_masked_by_same_key_equals_shift_over(seed: int) -> None:
    """integrity._same_as_previous: on rows sorted by the key, shift(1) masked by it is
    shift(1).over(key), null keys included."""
    from pipeline.maritime.integrity import _same_as_previous

    rng = np.random.default_rng(seed)
    n = 500
    a = pl.Series("a", rng.integers(0, 5, n)).set(pl.Series(rng.random(n) < 0.1), None)
    df = pl.DataFrame({"a": a, "b": rng.integers(0, 3, n), "v": rng.normal(size=n)}).sort(
        "a", "b")
    got = df.with_columns(pl.when(_same_as_previous(["a", "b"])).then(pl.col("v").shift(1)))
    want = df.with_columns(pl.col("v").shift(1).over(["a", "b"]))
    assert_frame_equal(got, want, check_exact=True)


@pytest.mark.parametrize("seed", range(4))
def test_coasted_reports_equals_the_polars_reference(seed: int) -> None:
    """integrity.coasted_reports (one numpy lexsort) against coasted_reports_polars:
    repeats, NaN (equal to NaN in polars), -0.0, nulls, null sites, duplicate times."""
    from pipeline.maritime.integrity import coasted_reports, coasted_reports_polars

    rng = np.random.default_rng(seed)
    n = 2000
    values = np.array([0.5, 0.5, 1.0, np.nan, -0.0, 0.0])

    def column(name: str) -> pl.Series:
        v = pl.Series(name, values[rng.integers(0, values.size, n)])
        return v.set(pl.Series(rng.random(n) < 0.05), None)

    site = pl.Series("site_id", rng.choice(["R1", "R2", "R10"], n)).set(
        pl.Series(rng.random(n) < 0.03), None)
    df = pl.DataFrame({"site_id": site, "local_track_id": rng.integers(0, 6, n),
                       "time_ns": rng.integers(0, 300, n),
                       "course_rad": column("course_rad"), "speed_mps": column("speed_mps")})
    key = ["site_id", "local_track_id", "time_ns"]
    got = coasted_reports(df).sort(key, nulls_last=True)
    want = coasted_reports_polars(df).sort(key, nulls_last=True)
    assert got["coasted"].sum() > 50
    assert_frame_equal(got, want, check_exact=True)


@pytest.mark.parametrize("seed", range(3))
def test_rank_within_equals_int_range_over(seed: int) -> None:
    from pipeline.maritime.integrity import _rank_within

    rng = np.random.default_rng(seed)
    df = pl.DataFrame({"k": np.sort(rng.integers(0, 20, 3000)),
                       "m": rng.integers(0, 40, 3000)})
    want = df.select(pl.int_range(pl.len()).over("k", "m"))["literal"].to_numpy()
    np.testing.assert_array_equal(_rank_within(df["k"].to_numpy(), df["m"].to_numpy()), want)
