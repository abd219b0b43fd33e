"""Regional alignment: positions, registration correction, covariance rotation, rejects."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from batch_builders import NS, T0_NS, lane_ships, radar_reports, site_with

from pipeline import frames
from pipeline.config import Config
from pipeline.families import load_config
from pipeline.maritime.align import UNKNOWN_SITE, align_reports


@pytest.fixture(scope="module")
def cfg() -> Config:
    return load_config()


def _quiet(cfg: Config) -> Config:
    """Both sites with (almost) noiseless reports."""
    for s in ("R1", "R2"):
        cfg = site_with(cfg, s, sigma_range_m=1e-6, sigma_azimuth_rad=1e-9,
                        sigma_course_rad=1e-9, sigma_speed_mps=1e-9)
    return cfg


def _truth_xy(ships, reports: pl.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.full(reports.height, np.nan), np.full(reports.height, np.nan)
    vessel = reports["local_track_id"].to_numpy() % 100
    t = reports["time_ns"].to_numpy()
    for s in ships:
        m = vessel == s.vessel_id
        x[m], y[m] = s.position(t[m])
    return x, y


def test_noiseless_reports_land_on_truth_in_the_regional_frame(cfg):
    quiet = _quiet(cfg)
    ships = lane_ships(3, np.random.default_rng(1))
    radar = radar_reports(ships, quiet, np.random.default_rng(2), duration_s=60)
    aligned, unknown = align_reports(radar, quiet)
    assert unknown.height == 0 and aligned.height == radar.height
    x, y = _truth_xy(ships, aligned)
    np.testing.assert_allclose(aligned["x_enu_m"], x, atol=0.01)
    np.testing.assert_allclose(aligned["y_enu_m"], y, atol=0.01)
    course = {s.vessel_id: s.course_rad for s in ships}
    expected = [course[lt % 100] for lt in aligned["local_track_id"]]
    np.testing.assert_allclose(frames.wrap_angle(aligned["course_rad"] - np.array(expected)), 0,
                               atol=1e-6)


def test_north_alignment_corrects_azimuth_course_and_scan_end(cfg):
    d = 0.01
    quiet = _quiet(cfg)
    ships = lane_ships(2, np.random.default_rng(1))
    radar = radar_reports(ships, quiet, np.random.default_rng(2), duration_s=30,
                          reported_north_error_rad={"R1": d})
    fixed, _ = align_reports(radar, site_with(quiet, "R1", north_alignment_rad=d))
    raw, _ = align_reports(radar, quiet)
    x, y = _truth_xy(ships, fixed)
    r1 = (fixed["site_id"] == "R1").to_numpy()
    np.testing.assert_allclose(fixed["x_enu_m"], x, atol=0.01)
    np.testing.assert_allclose(fixed["y_enu_m"], y, atol=0.01)
    miss = np.hypot(raw["x_enu_m"].to_numpy() - x, raw["y_enu_m"].to_numpy() - y)
    assert (miss[r1] > 0.9 * d * raw["range_m"].to_numpy()[r1]).all()  # ~ r * d uncorrected
    both = radar.filter(pl.col("site_id") == "R1")
    np.testing.assert_allclose(
        fixed.filter(pl.col("site_id") == "R1")["scan_end_azimuth_rad"],
        np.mod(both["scan_end_azimuth_rad"] + d, 2 * np.pi), atol=1e-12)


def test_covariance_is_polar_covariance_rotated_into_the_region(cfg):
    ships = lane_ships(3, np.random.default_rng(3))
    radar = radar_reports(ships, cfg, np.random.default_rng(4), duration_s=20)
    aligned, _ = align_reports(radar, cfg)
    for site in cfg.radar_sites:
        part = aligned.filter(pl.col("site_id") == site.site_id)
        rho = frames.site_rotation_rad(site.lat_deg, site.lon_deg, cfg.region.origin_lat_deg,
                                       cfg.region.origin_lon_deg)
        assert 1e-4 < abs(rho) < 1e-2
        P = frames.polar_covariance(part["range_m"].to_numpy(), part["azimuth_rad"].to_numpy(),
                                    part["sigma_range_m"].to_numpy(),
                                    part["sigma_azimuth_rad"].to_numpy())
        # az + rho clockwise: x_r = x cos rho + y sin rho, y_r = -x sin rho + y cos rho
        R = np.array([[np.cos(rho), np.sin(rho)], [-np.sin(rho), np.cos(rho)]])
        Pr = R @ P @ R.T
        np.testing.assert_allclose(part["P_xx"], Pr[:, 0, 0], rtol=1e-9)
        np.testing.assert_allclose(part["P_yy"], Pr[:, 1, 1], rtol=1e-9)
        np.testing.assert_allclose(part["P_xy"], Pr[:, 0, 1], rtol=1e-9, atol=1e-9)


def test_unknown_site_reports_are_returned_not_dropped(cfg):
    ships = lane_ships(2, np.random.default_rng(5))
    radar = radar_reports(ships, cfg, np.random.default_rng(6), duration_s=20)
    stray = radar.head(4).with_columns(pl.lit("R9").alias("site_id"))
    aligned, unknown = align_reports(pl.concat([radar, stray]), cfg)
    assert aligned.height == radar.height
    assert unknown.height == 4
    assert set(unknown["reason_code"]) == {UNKNOWN_SITE}
    assert unknown["reason"][0] == "radar site not in config: R9"
    assert {"log_time_ns", "source_file", "topic"} <= set(unknown.columns)


def test_empty_input_gives_empty_frames_with_the_new_columns(cfg):
    radar = radar_reports(lane_ships(1, np.random.default_rng(0)), cfg,
                          np.random.default_rng(0), duration_s=10).clear()
    aligned, unknown = align_reports(radar, cfg)
    assert aligned.height == 0 and unknown.height == 0
    assert {"x_enu_m", "y_enu_m", "P_xx", "P_yy", "P_xy"} <= set(aligned.columns)


def test_report_time_is_not_changed(cfg):
    radar = radar_reports(lane_ships(2, np.random.default_rng(7)), cfg,
                          np.random.default_rng(8), duration_s=20)
    aligned, _ = align_reports(radar, cfg)
    assert aligned["time_ns"].sort().to_list() == radar["time_ns"].sort().to_list()
    assert aligned["time_ns"].min() >= T0_NS - 10 * NS
