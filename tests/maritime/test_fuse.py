"""Inverse-variance fusion (multi-radar paper eq. 14) and the eq. 15 comparison."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from pipeline.maritime.fuse import FUSED_COLUMNS, fuse, fused_sigma, paper_eq15_sigma


def _rows(**cols) -> pl.DataFrame:
    n = len(cols["x_enu_m"])
    base = {
        "time_ns": [0] * n, "system_track_id": [7] * n, "site_id": [f"R{i + 1}" for i in range(n)],
        "P_xy": [0.0] * n, "course_rad": [1.0] * n, "speed_mps": [5.0] * n,
        "sigma_course_rad": [0.03] * n, "sigma_speed_mps": [0.25] * n,
        "y_enu_m": [0.0] * n, "P_yy": [100.0] * n,
    }
    return pl.DataFrame({**base, **cols}, schema_overrides={"system_track_id": pl.Int64})


def test_eq14_weights_and_sum_of_weights_sigma_inline():
    rows = _rows(x_enu_m=[10.0, 40.0], P_xx=[100.0, 400.0], y_enu_m=[5.0, -5.0],
                 P_yy=[900.0, 225.0], P_xy=[30.0, -20.0], speed_mps=[5.0, 6.0],
                 sigma_speed_mps=[0.2, 0.4], site_id=["R2", "R1"])
    f = fuse(rows).row(0, named=True)
    # position: eq. 14 with matrix weights P_i^-1 (information form), recomputed inline
    P = [np.array([[100.0, 30.0], [30.0, 900.0]]), np.array([[400.0, -20.0], [-20.0, 225.0]])]
    p = [np.array([10.0, 5.0]), np.array([40.0, -5.0])]
    P_hat = np.linalg.inv(sum(np.linalg.inv(Pi) for Pi in P))
    p_hat = P_hat @ sum(np.linalg.solve(Pi, pi) for Pi, pi in zip(P, p, strict=True))
    assert [f["x_enu_m"], f["y_enu_m"]] == pytest.approx(p_hat.tolist())
    assert f["sigma_x_m"] == pytest.approx(P_hat[0, 0] ** 0.5)
    assert f["sigma_y_m"] == pytest.approx(P_hat[1, 1] ** 0.5)
    assert f["cov_xy_m2"] == pytest.approx(P_hat[0, 1])
    # with diagonal covariances it is eq. 14 per axis, sigma (sum w)^-1/2
    diag = fuse(rows.with_columns(pl.lit(0.0).alias("P_xy"))).row(0, named=True)
    wx = np.array([1 / 100, 1 / 400])
    assert diag["x_enu_m"] == pytest.approx((10 * wx[0] + 40 * wx[1]) / wx.sum())
    assert diag["sigma_x_m"] == pytest.approx(wx.sum() ** -0.5)
    wv = np.array([0.2, 0.4]) ** -2
    assert f["speed_mps"] == pytest.approx((5 * wv[0] + 6 * wv[1]) / wv.sum())
    assert f["sigma_speed_mps"] == pytest.approx(wv.sum() ** -0.5)
    assert f["n_sources"] == 2 and f["sources"] == "R1,R2"


def test_output_columns_and_types():
    f = fuse(_rows(x_enu_m=[0.0, 1.0, 2.0], P_xx=[1.0, 1.0, 1.0]))
    assert f.columns == list(FUSED_COLUMNS)
    assert f.schema["n_sources"] == pl.Int16
    assert f["sources"][0] == "R1,R2,R3"


def test_course_is_a_weighted_circular_mean_across_north():
    rows = _rows(x_enu_m=[0.0, 0.0], P_xx=[1.0, 1.0],
                 course_rad=[np.radians(359.0), np.radians(3.0)],
                 sigma_course_rad=[np.radians(2.0), np.radians(2.0)])
    f = fuse(rows).row(0, named=True)
    assert np.degrees(f["course_rad"]) == pytest.approx(1.0, abs=1e-9)
    assert f["sigma_course_rad"] == pytest.approx(np.radians(2.0) / np.sqrt(2))


def test_single_source_passes_through():
    rows = _rows(x_enu_m=[3.0], P_xx=[49.0], P_xy=[5.0])
    f = fuse(rows).row(0, named=True)
    assert f["x_enu_m"] == 3.0 and f["sigma_x_m"] == pytest.approx(7.0)
    assert f["cov_xy_m2"] == pytest.approx(5.0) and f["n_sources"] == 1


def test_eq15_underestimates_when_channels_differ():
    assert paper_eq15_sigma([10.0, 10.0]) == pytest.approx(fused_sigma([10.0, 10.0]))
    assert paper_eq15_sigma([10.0, 10.0]) == pytest.approx(10.0 / np.sqrt(2))
    for sig in ([10.0, 40.0], [15.0, 70.0], [5.0, 6.0, 30.0]):
        assert paper_eq15_sigma(sig) < fused_sigma(sig)


def test_monte_carlo_fused_beats_each_radar_and_is_calibrated():
    """Two radars with different, correlated covariances (polar-like), 4000 trials."""
    rng = np.random.default_rng(2024)
    n = 4000
    P1 = np.array([[20.0**2, 600.0], [600.0, 70.0**2]])
    P2 = np.array([[60.0**2, -900.0], [-900.0, 25.0**2]])
    e1 = rng.multivariate_normal([0, 0], P1, n)
    e2 = rng.multivariate_normal([0, 0], P2, n)
    rows = pl.DataFrame({
        "time_ns": np.repeat(np.arange(n), 2), "system_track_id": 1,
        "site_id": np.tile(["R1", "R2"], n),
        "x_enu_m": np.column_stack([e1[:, 0], e2[:, 0]]).ravel(),
        "y_enu_m": np.column_stack([e1[:, 1], e2[:, 1]]).ravel(),
        "P_xx": np.tile([P1[0, 0], P2[0, 0]], n), "P_yy": np.tile([P1[1, 1], P2[1, 1]], n),
        "P_xy": np.tile([P1[0, 1], P2[0, 1]], n), "course_rad": 0.5, "speed_mps": 4.0,
        "sigma_course_rad": 0.03, "sigma_speed_mps": 0.25,
    })
    f = fuse(rows)
    ex, ey = f["x_enu_m"].to_numpy(), f["y_enu_m"].to_numpy()
    rms = np.sqrt(np.mean(ex**2 + ey**2))
    assert rms < np.sqrt(np.mean((e1**2).sum(1))) and rms < np.sqrt(np.mean((e2**2).sum(1)))
    sx, sy, cxy = (f[c].to_numpy() for c in ("sigma_x_m", "sigma_y_m", "cov_xy_m2"))
    nees = (sy**2 * ex**2 - 2 * cxy * ex * ey + sx**2 * ey**2) / (sx**2 * sy**2 - cxy**2)
    assert 1.9 < nees.mean() < 2.1
    assert np.std(ex) == pytest.approx(sx[0], rel=0.05)
    # eq. 15 reports a smaller sigma than the spread actually seen of the per-axis
    # eq. 14 mean it describes (east weights 1/20^2, 1/60^2)
    w = np.array([20.0, 60.0]) ** -2
    ex_axis = (w[0] * e1[:, 0] + w[1] * e2[:, 0]) / w.sum()
    assert paper_eq15_sigma([20.0, 60.0]) < 0.95 * np.std(ex_axis)
    # matrix weights: no direction is worse than the better radar's
    for a in np.radians([0.0, 45.0, 90.0, 135.0]):
        n = np.array([np.sin(a), np.cos(a)])
        proj = ex * n[0] + ey * n[1]
        assert np.std(proj) < min(np.std(e1 @ n), np.std(e2 @ n))
