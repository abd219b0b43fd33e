"""Cross-track deviation error per leg (multi-radar paper eq. 1-6, figures 1-2): the
geometry recomputed inline on a small frame, and on the channel scenario the fused
error never above the best single radar's along the route, leg L2 (end-on) included."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from pipeline.frames import geodetic_to_enu
from pipeline.maritime.cross_track import cross_track_by_leg, leg_frames
from pipeline.units import NS
from pipeline.warehouse.delta import read_table

ROUTE_BIN_M = 1000.0
MIN_PAIRED = 100


def _frames(cfg):
    """One system track sailing along leg L2 (east-west) 50 m to its north, seen by R1 and
    R2 every 4 s for 100 s, with known errors."""
    legs = leg_frames(cfg.fairway_legs, cfg.region).filter(pl.col("leg_id") == "L2").row(
        0, named=True)
    n = 26
    t = np.arange(n, dtype=np.int64) * 4 * NS
    along = 1000.0 + 5.0 * np.arange(n) * 4
    ref_x = legs["sx"] + along * legs["ux"] + 50.0 * legs["nx"]
    ref_y = legs["sy"] + along * legs["uy"] + 50.0 * legs["ny"]
    rng = np.random.default_rng(1)
    err = {s: rng.normal(0, 20, (n, 2)) for s in ("fused", "R1", "R2")}
    fused = pl.DataFrame({
        "time_ns": t, "system_track_id": 7, "x_enu_m": ref_x + err["fused"][:, 0],
        "y_enu_m": ref_y + err["fused"][:, 1], "sigma_x_m": 10.0, "sigma_y_m": 30.0,
        "cov_xy_m2": 50.0, "n_sources": pl.Series([2] * n, dtype=pl.Int16), "leg_id": "L2",
        "sector": "inner_channel"})
    assoc = pl.concat([pl.DataFrame({
        "time_ns": t, "system_track_id": 7, "site_id": s, "x_enu_m": ref_x + err[s][:, 0],
        "y_enu_m": ref_y + err[s][:, 1], "P_xx": 225.0, "P_yy": 3600.0, "P_xy": -40.0})
        for s in ("R1", "R2")])
    errors = pl.concat([pl.DataFrame({
        "time_ns": t, "system_track_id": 7, "source": s, "reference": "truth",
        "reference_id": 3, "error_east_m": err[s][:, 0], "error_north_m": err[s][:, 1]})
        for s in ("fused", "R1", "R2")])
    return fused, assoc, errors, legs, ref_x, ref_y, err


def test_geometry_and_sliding_rms_recomputed_inline(cfg):
    fused, assoc, errors, leg, ref_x, ref_y, err = _frames(cfg)
    out = cross_track_by_leg(fused, assoc, errors, legs=cfg.fairway_legs, region=cfg.region,
                             sites=cfg.radar_sites)
    assert out.height == 3 * fused.height
    n = np.array([leg["nx"], leg["ny"]])
    for src in ("fused", "R1", "R2"):
        o = out.filter(pl.col("source") == src).sort("time_ns")
        # eq. 1: signed distance from the axis, + to starboard; the ship is 50 m to
        # starboard (south of the eastbound leg)
        assert o["reference_cross_track_m"].to_numpy() == pytest.approx(50.0 * np.ones(26))
        assert o["cross_track_error_m"].to_numpy() == pytest.approx(err[src] @ n)
        e2 = o["cross_track_error_m"].to_numpy() ** 2
        window = [np.sqrt(e2[max(0, i - 14): i + 1].mean()) for i in range(e2.size)]  # 60 s
        assert o["rms_error_60s_m"].to_numpy() == pytest.approx(window)
        assert o["samples_60s"].to_list() == [min(i + 1, 15) for i in range(26)]
    f = out.filter(pl.col("source") == "fused")
    P = np.array([[100.0, 50.0], [50.0, 900.0]])
    assert f["sigma_cross_track_m"].to_numpy() == pytest.approx(np.sqrt(n @ P @ n))
    assert f["aspect_deg"].null_count() == f.height and f["range_m"].null_count() == f.height
    r1 = out.filter(pl.col("source") == "R1").sort("time_ns")
    site = cfg.site("R1")
    sx, sy = geodetic_to_enu(site.lat_deg, site.lon_deg, cfg.region.origin_lat_deg,
                             cfg.region.origin_lon_deg)
    lx = ref_x + err["R1"][:, 0] - sx
    ly = ref_y + err["R1"][:, 1] - sy
    assert r1["range_m"].to_numpy() == pytest.approx(np.hypot(lx, ly))
    cos = np.abs(lx * leg["ux"] + ly * leg["uy"]) / np.hypot(lx, ly)
    assert r1["aspect_deg"].to_numpy() == pytest.approx(np.degrees(np.arccos(cos)))
    assert (r1["aspect_deg"] < 20).all()  # R1 looks along L2: the unfavourable aspect


def _paired(e2e) -> pl.DataFrame:
    """Epochs where the fused point fuses every radar present in the table for it."""
    ct = pl.from_arrow(read_table(e2e.warehouse, "cross_track_by_leg"))
    radars = ct.filter(pl.col("source") != "fused").pivot(
        on="source", index=["time_ns", "system_track_id"],
        values=["cross_track_error_m", "sigma_cross_track_m", "aspect_deg"])
    fused = ct.filter((pl.col("source") == "fused") & (pl.col("n_sources") == 2)).select(
        "time_ns", "system_track_id", "leg_id", "along_track_m",
        pl.col("cross_track_error_m").alias("err_fused"),
        pl.col("sigma_cross_track_m").alias("sigma_fused"))
    return fused.join(radars, on=["time_ns", "system_track_id"]).drop_nulls()


def test_fused_sigma_never_above_the_best_radar(e2e):
    """Matrix-weighted fusion: n^T P_fused n <= n^T P_i n at EVERY paired point."""
    p = _paired(e2e)
    assert p.height > 1000
    best = np.minimum(p["sigma_cross_track_m_R1"], p["sigma_cross_track_m_R2"])
    assert (p["sigma_fused"].to_numpy() <= best.to_numpy() + 1e-6).all()


def test_fused_error_never_above_the_best_radar_along_the_route(e2e):
    """Per leg and 1-km stretch of the route (every ship that passed there, paired
    epochs), the fused RMS cross-track error is not above the best radar's; leg L2,
    seen end-on by both radars, included."""
    p = _paired(e2e).with_columns((pl.col("along_track_m") // ROUTE_BIN_M).alias("bin"))
    rms = p.group_by("leg_id", "bin").agg(
        pl.len().alias("n"),
        *[(pl.col(c) ** 2).mean().sqrt().alias(c) for c in (
            "err_fused", "cross_track_error_m_R1", "cross_track_error_m_R2")],
        pl.col("aspect_deg_R1").mean(), pl.col("aspect_deg_R2").mean(),
    ).filter(pl.col("n") >= MIN_PAIRED).sort("leg_id", "bin")
    assert set(rms["leg_id"]) == {"L1", "L2", "L3"}
    l2 = rms.filter(pl.col("leg_id") == "L2")
    assert l2.height >= 5 and (l2["aspect_deg_R1"] < 20).all() and (l2["aspect_deg_R2"] < 20).all()
    best = np.minimum(rms["cross_track_error_m_R1"], rms["cross_track_error_m_R2"])
    worse = rms.filter(pl.Series(rms["err_fused"].to_numpy() > best.to_numpy()))
    assert worse.height == 0, worse
    # on L2 both radars are poor across the fairway and fusion helps the most
    ratio = l2["err_fused"] / np.minimum(l2["cross_track_error_m_R1"], l2["cross_track_error_m_R2"])
    assert ratio.mean() < 0.8, ratio
