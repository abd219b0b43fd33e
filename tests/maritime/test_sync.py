"""Two-step synchronisation (multi-radar paper eq. 7-9, 12-13), recomputed inline."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from batch_builders import NS, T0_NS, epochs_for, lane_ships, radar_reports

from pipeline.config import Config
from pipeline.families import load_config
from pipeline.maritime.align import align_reports
from pipeline.maritime.config import SyncConfig, maritime_config
from pipeline.maritime.sync import (
    SCAN_TOLERANCE_S,
    SYNCED_COLUMNS,
    epoch_grid,
    extrapolation_covariance,
    scan_end_offset_s,
    synchronise,
)

DURATION_S = 300.0


@pytest.fixture(scope="module")
def cfg() -> Config:
    return load_config()


@pytest.fixture(scope="module")
def run(cfg):
    ships = lane_ships(4, np.random.default_rng(11))
    radar = radar_reports(ships, cfg, np.random.default_rng(12), duration_s=DURATION_S,
                          scan_end_azimuth_rad={"R1": 0.0, "R2": 2.5})
    aligned, _ = align_reports(radar, cfg)
    epochs = epochs_for(DURATION_S, cfg)
    synced = synchronise(aligned, epochs_ns=epochs, sync=maritime_config(cfg).sync)
    joined = synced.join(
        aligned.rename({"time_ns": "report_time_ns"}),
        on=["site_id", "local_track_id", "report_time_ns"], suffix="_0",
    )
    return ships, aligned, epochs, synced, joined


def test_epoch_grid_is_aligned_to_multiples_of_the_period():
    g = epoch_grid(5_500_000_000, 20 * NS, 4.0)
    assert g.tolist() == [8 * NS, 12 * NS, 16 * NS]
    assert g.dtype == np.int64
    assert epoch_grid(8 * NS, 8 * NS, 4.0).size == 0


def test_eq7_equals_the_paper_when_beta_below_beta_last_and_wraps_clockwise():
    T = 3.0
    beta, last = np.array([0.3, 1.0, 2.0]), np.array([2.0, 2.0, 2.0])
    np.testing.assert_allclose(scan_end_offset_s(beta, last, T),
                               np.abs(beta - last) / (2 * np.pi) * T)
    # scan ends at north: a target at 270 deg is swept a quarter turn before the end
    np.testing.assert_allclose(scan_end_offset_s(np.array([1.5 * np.pi]), 0.0, T), T / 4)


def test_inflation_terms_are_the_variance_form_of_eq12():
    V, C, dt, sv, sc, sdt = 6.0, np.radians(30.0), 5.0, 0.25, np.radians(2.0), 0.1
    dxx, dyy, dxy = extrapolation_covariance(V, C, dt, sv, sc, sdt)
    # eq. 12 terms in our ENU (x east): x* = x + V dt sin C, y* = y + V dt cos C
    tx = np.array([sv * dt * np.sin(C), sc * V * dt * np.cos(C), sdt * V * np.sin(C)])
    ty = np.array([sv * dt * np.cos(C), -sc * V * dt * np.sin(C), sdt * V * np.cos(C)])
    assert dxx == pytest.approx(np.sum(tx**2))
    assert dyy == pytest.approx(np.sum(ty**2))
    assert dxy == pytest.approx(np.sum(tx * ty))
    assert np.sqrt(dxx) < np.sum(np.abs(tx))  # the paper's linear sum is a bound


def test_inflation_grows_with_dt():
    dts = np.linspace(0.0, 8.0, 9)
    dxx, dyy, _ = extrapolation_covariance(5.0, 1.0, dts, 0.25, 0.035, 0.1)
    assert np.all(np.diff(dxx + dyy) > 0)


def test_every_row_is_at_an_epoch_once_per_track(run):
    _, _, epochs, synced, _ = run
    assert synced.columns == list(SYNCED_COLUMNS)
    assert synced["time_ns"].is_in(epochs.tolist()).all()
    assert not synced.select("time_ns", "site_id", "local_track_id").is_duplicated().any()
    assert synced.select("site_id", "local_track_id").n_unique() == 8
    # nearly every track is in every epoch's picture
    assert synced.height >= 0.98 * 8 * epochs.size


def test_report_time_before_epoch_within_two_scans(run, cfg):
    _, _, _, synced, joined = run
    age = (synced["time_ns"] - synced["report_time_ns"]).to_numpy() / NS
    T = joined["scan_period_s"].to_numpy()
    assert (age >= 0).all()
    assert (age < 2 * joined.sort(synced.columns[:3])["scan_period_s"].to_numpy()
            + SCAN_TOLERANCE_S).all()
    assert T.max() <= 4.0


def test_positions_are_eq9_over_both_steps(run):
    *_, j = run
    dt = (j["time_ns"] - j["report_time_ns"]).to_numpy() / NS  # dt1 + dt2
    C, V = j["course_rad"].to_numpy(), j["speed_mps"].to_numpy()
    np.testing.assert_allclose(j["x_enu_m"], j["x_enu_m_0"] + V * dt * np.sin(C), atol=1e-6)
    np.testing.assert_allclose(j["y_enu_m"], j["y_enu_m_0"] + V * dt * np.cos(C), atol=1e-6)


def test_covariance_inflated_at_both_steps(run, cfg):
    *_, j = run
    dt = (j["time_ns"] - j["report_time_ns"]).to_numpy() / NS
    C, V = j["course_rad"].to_numpy(), j["speed_mps"].to_numpy()
    sv, sc = j["sigma_speed_mps"].to_numpy(), j["sigma_course_rad"].to_numpy()
    sdt = maritime_config(cfg).sync.sigma_dt_s
    along = (sv * dt) ** 2 + 2 * (sdt * V) ** 2  # one speed error, two interval errors
    across = (sc * V * dt) ** 2
    s, c = np.sin(C), np.cos(C)
    np.testing.assert_allclose(j["P_xx"] - j["P_xx_0"], along * s * s + across * c * c,
                               rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(j["P_yy"] - j["P_yy_0"], along * c * c + across * s * s,
                               rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(j["P_xy"] - j["P_xy_0"], (along - across) * s * c,
                               rtol=1e-9, atol=1e-9)
    grow = (j["P_xx"] + j["P_yy"] - j["P_xx_0"] - j["P_yy_0"]).to_numpy()
    late = dt > np.median(dt)
    assert (grow > 0).all() and grow[late].mean() > grow[~late].mean()


def test_vectorised_selection_matches_a_scalar_reference(run, cfg):
    _, aligned, epochs, synced, _ = run
    one = aligned.filter((pl.col("site_id") == "R2") & (pl.col("local_track_id") == 202))
    t_to = one["time_ns"].to_numpy() + np.round(scan_end_offset_s(
        one["azimuth_rad"].to_numpy(), one["scan_end_azimuth_rad"].to_numpy(),
        one["scan_period_s"].to_numpy()) * NS).astype(np.int64)
    T = 4.0
    expected = {}
    for e in epochs.tolist():  # scalar reference: latest scan end in (e - T - tol, e]
        ok = (t_to <= e) & (t_to > e - (T + SCAN_TOLERANCE_S) * NS)
        if ok.any():
            expected[e] = int(one["time_ns"][int(np.flatnonzero(ok)[np.argmax(t_to[ok])])])
    got = synced.filter((pl.col("site_id") == "R2") & (pl.col("local_track_id") == 202))
    assert dict(zip(got["time_ns"].to_list(), got["report_time_ns"].to_list(),
                    strict=True)) == expected


def test_synchronised_positions_are_calibrated(run):
    ships, _, _, synced, _ = run
    t = synced["time_ns"].to_numpy()
    v = synced["local_track_id"].to_numpy() % 100
    ex, ey = synced["x_enu_m"].to_numpy().copy(), synced["y_enu_m"].to_numpy().copy()
    for s in ships:
        m = v == s.vessel_id
        x, y = s.position(t[m])
        ex[m] -= x
        ey[m] -= y
    Pxx, Pyy, Pxy = (synced[c].to_numpy() for c in ("P_xx", "P_yy", "P_xy"))
    nees = (Pyy * ex * ex - 2 * Pxy * ex * ey + Pxx * ey * ey) / (Pxx * Pyy - Pxy**2)
    assert 1.7 < nees.mean() < 2.3


def test_missing_scan_is_bridged_only_within_one_period(cfg):
    ships = lane_ships(1, np.random.default_rng(1))
    radar = radar_reports(ships, cfg, np.random.default_rng(2), duration_s=60)
    r2 = radar.filter(pl.col("site_id") == "R2")
    t_drop = r2["time_ns"][5]
    aligned, _ = align_reports(r2.filter(pl.col("time_ns") != t_drop), cfg)
    epochs = epoch_grid(T0_NS, T0_NS + 60 * NS, 4.0)
    synced = synchronise(aligned, epochs_ns=epochs, sync=SyncConfig())
    age = (synced["time_ns"] - synced["report_time_ns"]).to_numpy() / NS
    assert age.max() < 2 * 4.0 + SCAN_TOLERANCE_S


def test_empty_input(cfg):
    radar = radar_reports(lane_ships(1, np.random.default_rng(0)), cfg,
                          np.random.default_rng(0), duration_s=10).clear()
    aligned, _ = align_reports(radar, cfg)
    synced = synchronise(aligned, epochs_ns=epochs_for(60, cfg), sync=maritime_config(cfg).sync)
    assert synced.height == 0 and synced.columns == list(SYNCED_COLUMNS)
