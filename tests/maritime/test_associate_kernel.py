"""The compiled association loop (_associate.c) against the numpy reference: the same
system track for every row, on dense, crossing, coasting and sparse traffic."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import polars as pl
import pytest

from pipeline.families import load_config
from pipeline.maritime import associate
from pipeline.maritime.align import align_reports
from pipeline.maritime.config import maritime_config
from pipeline.maritime.sync import epoch_grid, synchronise
from pipeline.simulate.region import RegionSimulation
from pipeline.simulate.region_layout import region_config, region_layout, toml_text
from pipeline.units import NS

pytestmark = pytest.mark.skipif(associate._associate is None,
                                reason="built without a C compiler: no _associate extension")

T0_NS = 1_768_471_200 * NS  # 10:00 UTC: the busy hours of the region


def _synced(radar: pl.DataFrame, cfg) -> pl.DataFrame:
    mc = maritime_config(cfg)
    aligned, _ = align_reports(radar, cfg)
    t0, t1 = radar["time_ns"].min(), radar["time_ns"].max()
    return synchronise(aligned, epochs_ns=epoch_grid(t0 + 10 * NS, t1, mc.sync.epoch_period_s),
                       sync=mc.sync)


def _both(synced: pl.DataFrame, assoc) -> tuple[np.ndarray, np.ndarray]:
    df, site_idx, n_keys, n_sites = associate.prepare_rows(synced)
    native = associate._assign_ids_native(df, site_idx, n_keys, n_sites, assoc)
    ref = associate._assign_ids_reference(df, site_idx, n_keys, n_sites, assoc)
    return native, ref


@pytest.fixture(scope="module")
def region(tmp_path_factory):
    """Ten busy minutes of a small region (lanes, crossings, anchorages) as canonical
    radar_tracks, and its config."""
    path = tmp_path_factory.mktemp("region") / "region.toml"
    path.write_text(toml_text(region_config(region_layout(4))))
    cfg = load_config(path)
    sim = RegionSimulation(region_layout(4), n_ships=150, seed=3, start_ns=T0_NS,
                           duration_s=600.0)
    radar = pl.concat([s.radar_reports for s in sim.slices()]).rename(
        {"track_id": "local_track_id", "x_m": "x_site_m", "y_m": "y_site_m"})
    return cfg, radar


def test_region_same_ids(region) -> None:
    cfg, radar = region
    native, ref = _both(_synced(radar, cfg), maritime_config(cfg).association)
    assert native.size > 10_000
    np.testing.assert_array_equal(native, ref)


@pytest.mark.parametrize("change", [
    {"gate_probability": 0.9999},                       # wider gates: more ambiguity
    {"gate_probability": 0.9},                          # narrower: more new tracks
    {"track_timeout_s": 8.0},                           # ids forgotten quickly
    {"max_course_difference_rad": 0.05, "course_gate_min_speed_mps": 5.0},
    {"max_speed_difference_mps": 0.3},
    {"velocity_cost": False},                           # the position-only cost, 2 dof
])
def test_region_same_ids_other_gates(region, change) -> None:
    cfg, radar = region
    assoc = replace(maritime_config(cfg).association, **change)
    native, ref = _both(_synced(radar.filter(pl.col("time_ns") < radar["time_ns"].min()
                                             + 240 * NS), cfg), assoc)
    np.testing.assert_array_equal(native, ref)


def test_channel_scenario_same_ids() -> None:
    from maritime_helpers import scenario_tables
    cfg = load_config()
    radar, _, _ = scenario_tables(cfg, duration_s=900.0, seed=4)
    native, ref = _both(_synced(radar, cfg), maritime_config(cfg).association)
    np.testing.assert_array_equal(native, ref)


def test_degenerate_rows_are_compared_with_everything() -> None:
    """Rows with a singular or huge covariance (no gate radius) and far-apart clusters:
    the grid must not skip what the reference would gate."""
    rng = np.random.default_rng(1)
    rows = []
    for e in range(30):
        for site in ("A", "B", "C"):
            for k in range(12):
                big = k == 0
                rows.append({
                    "time_ns": e * 4 * NS, "site_id": site, "local_track_id": k,
                    "x_enu_m": k * 400.0 + rng.normal(0, 30) + (5e5 if k == 11 else 0),
                    "y_enu_m": rng.normal(0, 30), "report_time_ns": e * 4 * NS,
                    "P_xx": 1e8 if big else 900.0, "P_yy": 1e8 if big else 900.0,
                    "P_xy": (1e8 if k == 1 else 0.0), "course_rad": 1.0 + 0.01 * k,
                    "speed_mps": 5.0, "sigma_course_rad": 0.03, "sigma_speed_mps": 0.2,
                })
    synced = pl.DataFrame(rows, schema_overrides={"time_ns": pl.Int64})
    native, ref = _both(synced, maritime_config(load_config()).association)
    np.testing.assert_array_equal(native, ref)


def test_empty() -> None:
    synced = pl.DataFrame(schema={"time_ns": pl.Int64, "site_id": pl.String,
                                  "local_track_id": pl.Int64, "x_enu_m": pl.Float64,
                                  "y_enu_m": pl.Float64, "P_xx": pl.Float64, "P_yy": pl.Float64,
                                  "P_xy": pl.Float64, "course_rad": pl.Float64,
                                  "speed_mps": pl.Float64, "sigma_course_rad": pl.Float64,
                                  "sigma_speed_mps": pl.Float64})
    native, ref = _both(synced, maritime_config(load_config()).association)
    assert native.size == ref.size == 0


def test_libm_sin_cos_are_numpys() -> None:
    """_associate.c takes sin and cos (the velocity cost's v = V (sin C, cos C) and its
    covariance) from libm where the reference calls numpy's float64 ufuncs: the same
    functions. (atan2 and pow of the candidate state are not always: numpy may use its
    own SIMD versions, 1 ulp apart at times; the ids above still agree.)"""
    import math

    rng = np.random.default_rng(2)
    x = np.r_[rng.uniform(-7.0, 7.0, 20_000), rng.normal(0.0, 1e3, 2_000)]
    for f, m in ((np.sin, math.sin), (np.cos, math.cos)):
        np.testing.assert_array_equal(f(x), np.array([m(v) for v in x.tolist()]))
