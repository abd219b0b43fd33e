"""Evaluation without truth (issue 37): the reconstructed reference of the AIS vessels,
scoring against it, and each indicator on a built case with a known answer: a radar
blanked over 30 deg of azimuth is a hole in its coverage map, a 0.5 s clock offset is
latency, a swapped pair is one swap, an impossible track is dubious, a track with no
reference is false. Reports run in real DuckDB over the stage's tables."""

from __future__ import annotations

import math

import duckdb
import numpy as np
import polars as pl
import pytest
from maritime_helpers import T0_NS, scenario_tables

from pipeline.families import load_config
from pipeline.family import Window
from pipeline.maritime.config import ChannelFault, maritime_config, with_faults
from pipeline.maritime.evaluate import radar_detection
from pipeline.maritime.reference import (
    RECONSTRUCTED,
    reconstruct,
    ref_rows_of,
    truth_reference,
)
from pipeline.maritime.stage import stage
from pipeline.reports import run_report
from pipeline.units import NS


@pytest.fixture(scope="module")
def cfg():
    return load_config(None)


def _con(out: dict[str, pl.DataFrame]) -> duckdb.DuckDBPyConnection:
    con = duckdb.connect()
    for name, df in out.items():
        if name.startswith("_") or name == "rejects":
            continue
        con.register(name, df.with_columns(pl.lit("default").alias("site")).to_arrow())
    return con


def _report(con, name: str, w: Window, **params) -> pl.DataFrame:
    return pl.from_arrow(run_report(con, name, start_ns=w.start_ns, end_ns=w.end_ns,
                                    params=params))


def _run(cfg, faults: tuple[ChannelFault, ...], *, duration_s: float, seed: int,
         truth: bool = False) -> tuple[dict[str, pl.DataFrame], Window]:
    c = with_faults(cfg, faults)
    radar, ais, tr = scenario_tables(c, duration_s=duration_s, seed=seed, faults=True)
    inputs = {"radar_tracks": radar, "ais_reports": ais}
    if truth:
        inputs["truth"] = tr
    w = Window(T0_NS + 60 * NS, T0_NS + round((duration_s - 60) * NS))
    return stage(inputs, w, c), w


# --- the reference itself ------------------------------------------------------------------


@pytest.fixture(scope="module")
def clean(cfg):
    radar, ais, truth = scenario_tables(cfg, duration_s=900.0, seed=3)
    return radar, ais, truth


def test_reconstructed_reference_is_close_to_truth_and_says_so(cfg, clean):
    _, ais, truth = clean
    ref, knots = reconstruct(ais, cfg.region, cfg.ais, maritime_config(cfg).reference)
    assert ref.kind == RECONSTRUCTED and ref.rows >= 20
    tr = truth_reference(truth, cfg.region)
    epochs = np.arange(T0_NS + 60 * NS, T0_NS + 840 * NS, 4 * NS)
    at = ref.at_epochs(epochs)
    vessel = dict(truth.select("mmsi", "vessel_id").drop_nulls().unique().iter_rows())
    vid = np.array([vessel[m] for m in at["mmsi"].to_list()])
    row = ref_rows_of(tr, vid, at["time_ns"].to_numpy())
    assert (row >= 0).all()
    t = tr.at(row, at["time_ns"].to_numpy())
    e = np.hypot(at["x"].to_numpy() - t["x"], at["y"].to_numpy() - t["y"])
    # AIS GNSS sigma 3 m: the smoothed reference is better than one report
    assert np.quantile(e, 0.95) < 6.0
    # its own 95 % error holds 90-99 % of the true errors
    assert 0.9 < (e <= at["p95_m"].to_numpy()).mean() < 0.995
    # every report is a knot; the AIS sigma is estimated near the simulator's 3 m
    assert knots.height == ais.unique(["mmsi", "time_ns"]).height
    assert 2.4 < knots.filter(~pl.col("outlier"))["sigma_position_m"].median() < 3.6


def test_an_outlier_report_is_marked_and_does_not_move_the_reference(cfg, clean):
    _, ais, _ = clean
    rc = maritime_config(cfg).reference
    m = ais.filter(pl.col("ais_class") == "A")["mmsi"].mode()[0]
    rows = ais.with_row_index("_i").filter(pl.col("mmsi") == m)
    bad_i = rows["_i"][rows.height // 2]
    bad = ais.with_columns(
        pl.when(pl.int_range(pl.len()) == bad_i).then(pl.col("lat_deg") + 0.004)
        .otherwise(pl.col("lat_deg")).alias("lat_deg"))  # ~450 m north
    ref0, _ = reconstruct(ais, cfg.region, cfg.ais, rc)
    ref1, knots = reconstruct(bad, cfg.region, cfg.ais, rc)
    t_bad = int(bad["time_ns"][bad_i])
    out = knots.filter(pl.col("outlier"))
    assert (out["reference_id"] == m).all() and t_bad in out["time_ns"].to_list()
    r0 = ref0.at(ref_rows_of(ref0, np.array([m]), np.array([t_bad])), np.array([t_bad]))
    r1 = ref1.at(ref_rows_of(ref1, np.array([m]), np.array([t_bad])), np.array([t_bad]))
    assert abs(r0["y"][0] - r1["y"][0]) < 2.0  # (its own report no longer there: ~1 m)


def test_without_truth_every_score_is_against_the_reconstructed_reference(cfg):
    out, _ = _run(cfg, (), duration_s=900.0, seed=3)
    e = out["track_errors"]
    assert e.height > 1000 and set(e["reference"]) == {"reconstructed"}
    assert (e["reference_p95_m"] > 0).all() and e["reference_p95_m"].max() <= 20.0
    assert (e["reference_id"] == e["reference_mmsi"]).all()
    radar = e.filter(pl.col("source") != "fused")
    assert radar["range_error_m"].null_count() == 0
    assert e.filter(pl.col("source") == "fused")["range_error_m"].null_count() == \
        e.filter(pl.col("source") == "fused").height
    # decomposition: along^2 + across^2 = error^2; range^2 + (range az)^2 = error^2
    mv = e.filter(pl.col("along_track_error_m").is_not_null())
    np.testing.assert_allclose(mv["along_track_error_m"] ** 2 + mv["across_track_error_m"] ** 2,
                               mv["error_m"] ** 2, rtol=1e-9)
    np.testing.assert_allclose(radar["range_error_m"] ** 2
                               + (radar["azimuth_error_rad"] * radar["reference_range_m"]) ** 2,
                               radar["error_m"] ** 2, rtol=1e-9)
    assert out["reference_tracks"].height > 0
    assert set(out["siap_by_sector"]["reference"]) == {"reconstructed"}


# --- detection and the coverage map ------------------------------------------------------


def test_a_radar_blanked_over_30_deg_is_a_hole_in_its_coverage_map(cfg):
    """R1 blind in azimuths [200, 230) deg (the approach leg L1 lies there) for the whole
    scene: its coverage map, scored against the reconstructed reference (no truth), has
    holes in those cells and none elsewhere; R2 has none."""
    blank = ChannelFault("radar_blank", 0.0, 1500.0, site_id="R1",
                         azimuth_from_rad=math.radians(200.0), azimuth_to_rad=math.radians(230.0))
    out, w = _run(cfg, (blank,), duration_s=1500.0, seed=5)
    cov = _report(_con(out), "radar_coverage", w)
    assert set(cov["reference"]) == {"reconstructed"}
    r1 = cov.filter((pl.col("radar") == "R1") & (pl.col("expected_scans") >= 20))
    inside = r1.filter(pl.col("azimuth_from_deg").is_between(200.0, 220.0))
    outside = r1.filter((pl.col("azimuth_from_deg") < 190.0) | (pl.col("azimuth_from_deg") > 230.0))
    assert inside.height >= 3 and outside.height >= 10
    assert inside["hole"].all(), inside
    assert inside["pd"].max() < 0.4
    assert not outside["hole"].any(), outside.filter(pl.col("hole"))
    pd_out = outside["detected_scans"].sum() / outside["expected_scans"].sum()
    assert pd_out > 0.95
    r2 = cov.filter((pl.col("radar") == "R2") & (pl.col("expected_scans") >= 20))
    assert not r2["hole"].any()


def test_detection_counts_missed_scans_from_update_intervals(cfg):
    """A built case: one target moving straight 3 km from a radar with T = 3 s, updates
    at every scan but for 5 missed ones in a gap and 2 at the start: expected = span /
    T, detected = expected - 7."""
    site = cfg.radar_sites[0]
    T = site.scan_period_s
    t_s = np.arange(0.0, 600.0, 1.0)
    from pipeline.frames import enu_to_geodetic, geodetic_to_enu
    sx, sy = geodetic_to_enu(site.lat_deg, site.lon_deg, cfg.region.origin_lat_deg,
                             cfg.region.origin_lon_deg)
    x, y = float(sx) + 3000.0 + 5.0 * t_s, float(sy) - 2000.0 + 0.0 * t_s
    lat, lon = enu_to_geodetic(x, y, cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
    truth = pl.DataFrame({"time_ns": T0_NS + (t_s * NS).astype(np.int64), "vessel_id": 1,
                          "mmsi": None, "lat_deg": lat, "lon_deg": lon, "speed_mps": 5.0,
                          "course_rad": math.pi / 2},
                         schema_overrides={"mmsi": pl.Int64, "vessel_id": pl.Int64})
    ref = truth_reference(truth, cfg.region)
    scans = np.arange(0.2, 599.0, T)               # sweep times, s
    n_scans = scans.size
    keep = np.ones(n_scans, bool)
    keep[:2] = False                               # 2 missed at the start
    keep[100:105] = False                          # a gap of 5 scans
    ts = scans[keep]
    aligned = pl.DataFrame({"time_ns": T0_NS + (ts * NS).astype(np.int64), "site_id": site.site_id,
                            "local_track_id": 7, "x_enu_m": float(sx) + 3000.0 + 5.0 * ts,
                            "y_enu_m": float(sy) - 2000.0})
    assoc = aligned.select("time_ns", pl.lit(1, pl.Int64).alias("system_track_id"), "site_id",
                           "local_track_id")
    errors = assoc.select("time_ns", "system_track_id", pl.col("site_id").alias("source"),
                          pl.lit(1, pl.Int64).alias("reference_id"))
    det = radar_detection(aligned, assoc, errors, ref, sites=cfg.radar_sites[:1],
                          sectors=cfg.sectors, region=cfg.region, classes=None,
                          start_ns=T0_NS, end_ns=T0_NS + 600 * NS, max_distance_m=500.0,
                          range_bin_m=1000.0, azimuth_bin_deg=10.0)
    expected, detected = int(det["expected_scans"].sum()), int(det["detected_scans"].sum())
    assert detected == keep.sum()
    assert expected - detected == 7
    assert abs(expected - n_scans) <= 1
    # a radar that never reports the target in its range misses every scan
    none = radar_detection(aligned.clear(), assoc.clear(), errors.clear(), ref,
                           sites=cfg.radar_sites[:1], sectors=cfg.sectors, region=cfg.region,
                           classes=None, start_ns=T0_NS, end_ns=T0_NS + 600 * NS,
                           max_distance_m=500.0, range_bin_m=1000.0, azimuth_bin_deg=10.0)
    assert none["detected_scans"].sum() == 0
    assert abs(int(none["expected_scans"].sum()) - n_scans) <= 1


# --- latency, swaps, dubious and false tracks ----------------------------------------------


def test_a_half_second_clock_offset_shows_as_latency(cfg):
    late = ChannelFault("radar_time_offset", 0.0, 1500.0, site_id="R2", time_offset_s=0.5)
    out, w = _run(cfg, (late,), duration_s=1500.0, seed=6)
    lat = _report(_con(out), "latency_by_sensor", w)
    by = {r["source"]: r for r in lat.iter_rows(named=True)}
    assert set(lat["reference"]) == {"reconstructed"}
    assert abs(by["R2"]["latency_s"] - 0.5) < 0.15, by["R2"]
    assert by["R2"]["latency_ci_low_s"] < 0.5 < by["R2"]["latency_ci_high_s"] + 0.1
    assert abs(by["R1"]["latency_s"]) < 0.15, by["R1"]
    assert by["R2"]["latency_s"] - by["R1"]["latency_s"] > 0.3


def _built_errors(rows: list[tuple[int, int, int, float]]) -> pl.DataFrame:
    """track_errors fused rows (t s, system track, reference id, error m)."""
    t, trk, ref, err = (np.array(c) for c in zip(*rows, strict=True))
    return pl.DataFrame({"time_ns": T0_NS + (t * NS).astype(np.int64),
                         "system_track_id": trk.astype(np.int64), "source": "fused",
                         "sector": "inner_channel", "reference": "reconstructed",
                         "reference_id": ref.astype(np.int64), "error_m": err.astype(float)})


def test_a_swapped_pair_counts_as_one_swap():
    """Targets 10 and 20 hold tracks 1 and 2 for 40 epochs, then exchange them: one swap,
    two track changes; a third target changing to a new track number is a change, not
    a swap."""
    rows = []
    for k in range(80):
        t = 4 * k
        a, b = (1, 2) if k < 40 else (2, 1)
        rows += [(t, a, 10, 20.0), (t, b, 20, 25.0), (t, 3 if k < 60 else 4, 30, 15.0)]
    con = duckdb.connect()
    con.register("track_errors", _built_errors(rows).with_columns(
        pl.lit("default").alias("site")).to_arrow())
    w = Window(T0_NS, T0_NS + 400 * NS)
    c = _report(con, "track_continuity", w).row(0, named=True)
    assert c["track_swaps"] == 1
    assert c["track_changes"] == 3
    assert c["targets"] == 3 and c["gaps"] == 0 and c["extra_track_share"] == 0.0


def test_gaps_and_extra_tracks_in_the_continuity_report():
    rows = [(4 * k, 1, 10, 5.0) for k in range(50) if not 20 <= k < 25]  # a 24 s gap
    rows += [(4 * k, 2, 10, 50.0) for k in range(30, 40)]                # a second track
    con = duckdb.connect()
    con.register("track_errors", _built_errors(rows).with_columns(
        pl.lit("default").alias("site")).to_arrow())
    c = _report(con, "track_continuity", Window(T0_NS, T0_NS + 400 * NS)).row(0, named=True)
    assert c["gaps"] == 1 and c["longest_gap_s"] == 24.0
    assert c["track_changes"] == 0  # the nearer track stays primary
    assert c["extra_track_share"] == pytest.approx(10 / 45, abs=1e-4)


def test_dubious_and_false_tracks(cfg):
    n = 30
    t = T0_NS + np.arange(n) * 4 * NS
    ok = pl.DataFrame({"time_ns": t, "system_track_id": 1, "speed_mps": 6.0,
                       "course_rad": 1.0, "sector": "inner_channel"})
    fast = ok.with_columns(pl.lit(2).alias("system_track_id"),
                           pl.when(pl.int_range(pl.len()) == 10).then(40.0).otherwise(6.0)
                           .alias("speed_mps"))
    turn = ok.with_columns(pl.lit(3).alias("system_track_id"),
                           (1.0 + pl.int_range(pl.len()) * math.radians(60.0)).alias("course_rad"))
    st = pl.concat([ok, fast, turn]).with_columns(pl.col("system_track_id").cast(pl.Int64),
                                                  pl.lit("default").alias("site"))
    con = duckdb.connect()
    con.register("system_tracks", st.to_arrow())
    errors = _built_errors([(4 * k, 1, 10, 5.0) for k in range(n)])
    con.register("track_errors", errors.with_columns(pl.lit("default").alias("site")).to_arrow())
    w = Window(T0_NS, T0_NS + 400 * NS)
    d = _report(con, "dubious_tracks", w).row(0, named=True)
    assert d["tracks"] == 3 and d["dubious_tracks"] == 2
    assert d["over_speed"] == 1 and d["over_acceleration"] == 1 and d["over_turn_rate"] == 1
    f = _report(con, "false_tracks", w).row(0, named=True)
    assert f["tracks"] == 3 and f["tracks_without_reference"] == 2
    assert f["reference"] == "reconstructed"


def test_truth_and_reference_agree_on_one_scene(cfg):
    """The same scene scored with truth and with it withheld: PD per radar within 0.01;
    fused RMS and p95 per sector within 5 % of the truth-based figures of the same
    vessels (the reference sees the ships carrying AIS only: against every vessel the
    figures differ by what the ships without AIS add, up to ~10 % in a 20-min scene;
    the 10-seed Monte Carlo over hours is tests/maritime/test_reference_montecarlo.py)."""
    c = with_faults(cfg, ())
    radar, ais, truth = scenario_tables(c, duration_s=1200.0, seed=8)
    w = Window(T0_NS + 60 * NS, T0_NS + 1140 * NS)
    a = stage({"radar_tracks": radar, "ais_reports": ais, "truth": truth}, w, c)
    b = stage({"radar_tracks": radar, "ais_reports": ais}, w, c)
    pa = _report(_con(a), "detection_by_sector", w)
    pb = _report(_con(b), "detection_by_sector", w)

    def pd(t: pl.DataFrame) -> dict:
        g = t.filter(pl.col("target_class") == "(all classes)").group_by("radar").agg(
            (1 - pl.col("missed_scans").sum() / pl.col("expected_scans").sum()).alias("pd"))
        return dict(g.iter_rows())

    for radar_id, v in pd(pa).items():
        assert abs(pd(pb)[radar_id] - v) < 0.01
    with_ais = {**a, "track_errors": a["track_errors"].filter(
        pl.col("reference_mmsi").is_not_null())}
    ea = _report(_con(with_ais), "accuracy_by_sector", w).filter(pl.col("source") == "fused")
    eb = _report(_con(b), "accuracy_by_sector", w).filter(pl.col("source") == "fused")
    j = ea.join(eb, on="sector", suffix="_r")
    assert j.height == 3 and set(j["reference_r"]) == {"reconstructed"}
    for col in ("rms_error_m", "p95_error_m"):
        assert ((j[col + "_r"] / j[col] - 1).abs() < 0.05).all(), j


def test_no_point_of_a_ship_without_ais_is_scored_against_another_ship(cfg):
    """The matching rule (radar local tracks take a vessel, fused points their members'):
    the fused points that truth assigns to ships without AIS are not scored at all
    without truth, although AIS ships pass them."""
    c = with_faults(cfg, ())
    radar, ais, truth = scenario_tables(c, duration_s=1200.0, seed=8)
    w = Window(T0_NS + 60 * NS, T0_NS + 1140 * NS)
    a = stage({"radar_tracks": radar, "ais_reports": ais, "truth": truth}, w, c)
    b = stage({"radar_tracks": radar, "ais_reports": ais}, w, c)
    key = ["time_ns", "system_track_id"]
    fused_a = a["track_errors"].filter(pl.col("source") == "fused")
    fused_b = b["track_errors"].filter(pl.col("source") == "fused")
    no_ais = fused_a.filter(pl.col("reference_mmsi").is_null())
    assert no_ais.height > 300
    scored = no_ais.join(fused_b, on=key, how="semi").height
    assert scored <= 0.01 * no_ais.height
    # and the points of AIS ships are scored against their own MMSI
    both = fused_a.filter(pl.col("reference_mmsi").is_not_null()).join(
        fused_b, on=key, suffix="_r")
    assert (both["reference_mmsi"] == both["reference_mmsi_r"]).mean() > 0.98
    assert both.height > 0.8 * fused_a.filter(pl.col("reference_mmsi").is_not_null()).height
