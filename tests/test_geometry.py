"""Sectors, geodetic coordinates and cross-track deviation (multi-radar paper eq. 1-6)."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from pipeline import frames
from pipeline.config import Config, FairwayLeg, Sector
from pipeline.families import load_config
from pipeline.geometry import (
    add_geodetic,
    assign_sectors,
    cross_track,
    cross_track_xy,
    sector_polygons,
)


@pytest.fixture(scope="module")
def cfg() -> Config:
    return load_config()


def _leg(cfg: Config, leg_id: str, start_xy, end_xy) -> FairwayLeg:
    o = (cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
    (la0, la1), (lo0, lo1) = frames.enu_to_geodetic(
        np.array([start_xy[0], end_xy[0]], float), np.array([start_xy[1], end_xy[1]], float), *o)
    return FairwayLeg(leg_id, la0, lo0, la1, lo1)


def _xy(x, y):
    return np.atleast_1d(np.asarray(x, float)), np.atleast_1d(np.asarray(y, float))


@pytest.mark.parametrize(
    ("start", "end", "point", "expected"),
    [
        ((0, 0), (0, 1000), (30, 500), 30.0),      # heading north: starboard is east
        ((0, 0), (0, 1000), (-20, 500), -20.0),
        ((0, 0), (1000, 0), (500, 40), -40.0),     # heading east: starboard is south
        ((1000, 0), (0, 0), (500, 40), 40.0),      # heading west: starboard is north
        ((0, 0), (1000, 1000), (1000, 0), 1000 / np.sqrt(2)),
    ],
)
def test_cross_track_sign_is_positive_to_starboard(start, end, point, expected):
    x, y = _xy(*point)
    one = np.ones(1)
    _, _, ct, _ = cross_track_xy(x, y, one, one, 0 * one, np.array([start], float),
                                 np.array([end], float))
    assert ct[0] == pytest.approx(expected)


def test_sigma_is_sqrt_nt_p_n_hand_worked():
    x, y = _xy(10, 10)
    P = (np.array([100.0]), np.array([400.0]), np.array([20.0]))
    _, _, _, s_north = cross_track_xy(x, y, *P, np.array([[0.0, 0.0]]), np.array([[0.0, 1e3]]))
    assert s_north[0] == pytest.approx(10.0)  # n = (1, 0): sigma_x
    _, _, _, s_diag = cross_track_xy(x, y, *P, np.array([[0.0, 0.0]]), np.array([[1e3, 1e3]]))
    # n = (1, -1)/sqrt2: (100 - 2*20 + 400) / 2 = 230
    assert s_diag[0] == pytest.approx(np.sqrt(230.0))


def test_eq5_eq6_extremes_of_a_single_radar():
    r, sr, sb = 9000.0, 15.0, np.radians(0.45)
    start, end = np.array([[0.0, 0.0]]), np.array([[0.0, 1e4]])  # leg heading north
    for az, expected in ((0.0, r * sb), (np.pi / 2, sr)):  # along / across the line of sight
        P = frames.polar_covariance(np.array([r]), np.array([az]), sr, sb)
        px, py = frames.polar_to_enu(np.array([r]), np.array([az]))
        _, _, _, s = cross_track_xy(px, py, P[:, 0, 0], P[:, 1, 1], P[:, 0, 1], start, end)
        assert s[0] == pytest.approx(expected)


def test_nearest_segment_not_nearest_line():
    start = np.array([[0.0, 0.0], [300.0, 1800.0]])
    end = np.array([[0.0, 1000.0], [1300.0, 1800.0]])
    # on leg 0's axis (line distance 0) but 800 m beyond its end; leg 1 is 300 m away
    x, y = _xy(0, 1800)
    one = np.ones(1)
    leg, dist, ct, _ = cross_track_xy(x, y, one, one, 0 * one, start, end)
    assert leg[0] == 1 and dist[0] == pytest.approx(300.0)
    assert ct[0] == pytest.approx(0.0)


def test_cross_track_on_frames_both_covariance_forms_and_range_limit(cfg):
    legs = (_leg(cfg, "A", (0, 0), (0, 5000)), _leg(cfg, "B", (0, 5000), (5000, 5000)))
    pts = pl.DataFrame({"x_enu_m": [30.0, 2500.0, -2500.0], "y_enu_m": [1000.0, 5050.0, 0.0]})
    sig = pts.with_columns(sigma_x_m=pl.lit(10.0), sigma_y_m=pl.lit(20.0), cov_xy_m2=pl.lit(5.0))
    cov = pts.with_columns(P_xx=pl.lit(100.0), P_yy=pl.lit(400.0), P_xy=pl.lit(5.0))
    a = cross_track(sig, legs, cfg.region, 2000.0)
    b = cross_track(cov, legs, cfg.region, 2000.0)
    assert a["leg_id"].to_list() == ["A", "B", None]
    np.testing.assert_allclose(a["cross_track_m"][:2], [30.0, -50.0], atol=0.01)
    np.testing.assert_allclose(a["sigma_cross_track_m"][:2], [10.0, 20.0], rtol=1e-4)
    assert a["cross_track_m"][2] is None and a["sigma_cross_track_m"][2] is None
    assert a.select("leg_id", "cross_track_m").equals(b.select("leg_id", "cross_track_m"))


def test_no_legs_gives_null_columns(cfg):
    out = cross_track(pl.DataFrame({"x_enu_m": [0.0], "y_enu_m": [0.0], "P_xx": [1.0],
                                    "P_yy": [1.0], "P_xy": [0.0]}), (), cfg.region, 2000.0)
    assert out["leg_id"].null_count() == 1 and out.schema["cross_track_m"] == pl.Float64


def test_sectors_of_the_default_config(cfg):
    polys = sector_polygons(cfg.sectors, cfg.region)
    c = [p.representative_point() for p in polys]
    pts = pl.DataFrame({"x_enu_m": [p.x for p in c] + [50_000.0],
                        "y_enu_m": [p.y for p in c] + [0.0]})
    out = assign_sectors(pts, cfg.sectors, cfg.region)
    assert out["sector"].to_list() == [s.name for s in cfg.sectors] + [None]


def test_first_matching_sector_wins(cfg):
    o = (cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)

    def square(name, x0, x1):
        lat, lon = frames.enu_to_geodetic(np.array([x0, x1, x1, x0], float),
                                          np.array([-500, -500, 500, 500], float), *o)
        return Sector(name, tuple(zip(lat.tolist(), lon.tolist(), strict=True)))

    sectors = (square("west", -1000, 100), square("east", -100, 1000))
    pts = pl.DataFrame({"x_enu_m": [-500.0, 0.0, 500.0], "y_enu_m": [0.0, 0.0, 0.0]})
    assert assign_sectors(pts, sectors, cfg.region)["sector"].to_list() == ["west", "west", "east"]


def test_add_geodetic_round_trips(cfg):
    pts = pl.DataFrame({"x_enu_m": [0.0, 12_345.0, -8000.0], "y_enu_m": [0.0, -3000.0, 9000.0]})
    out = add_geodetic(pts, cfg.region)
    e, n = frames.geodetic_to_enu(out["lat_deg"].to_numpy(), out["lon_deg"].to_numpy(),
                                  cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
    np.testing.assert_allclose(e, pts["x_enu_m"], atol=0.01)
    np.testing.assert_allclose(n, pts["y_enu_m"], atol=0.01)
    assert out["lat_deg"][0] == pytest.approx(cfg.region.origin_lat_deg)
