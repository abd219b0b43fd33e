"""A silent radar is out of service, not a witness (issue 35, item 4): a radar declared in
the config without scans in a window or a sector takes no part in the AIS checks there
(pipeline/maritime/integrity.py, ``witness_s``); AIS-only data gets the kinematic
self-test alone."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from maritime_helpers import T0_NS, scenario_tables

from pipeline import frames
from pipeline.families import load_config
from pipeline.family import Window
from pipeline.geometry import assign_sectors
from pipeline.maritime.stage import stage
from pipeline.units import NS

DURATION_S = 900.0
SEED = 5


@pytest.fixture(scope="module")
def cfg():
    return load_config()


@pytest.fixture(scope="module")
def tables(cfg):
    return scenario_tables(cfg, duration_s=DURATION_S, seed=SEED)


def health(cfg, radar: pl.DataFrame, ais: pl.DataFrame, truth: pl.DataFrame) -> pl.DataFrame:
    out = stage({"radar_tracks": radar, "ais_reports": ais, "truth": truth},
                Window(T0_NS, T0_NS + round(DURATION_S * NS)), cfg)
    return out["maritime_channel_health"].filter(pl.col("sensor_kind") == "ais")


def test_declared_radars_without_data_take_no_part_in_the_ais_checks(cfg, tables):
    """The demo's two radars declared, no radar report at all (an AIS-only archive with
    the radars in the config): every AIS decision is the kinematic self-test, none an
    ``ais_unmatched`` test against a radar track that does not exist (nis = inf), and
    the transponders flag about as often as AIS alone (q = 1 %). Before: every report in
    the radars' range after the warm-up was `ais_unmatched` with nis = inf."""
    radar, ais, truth = tables
    h = health(cfg, radar.clear(), ais, truth)
    assert h.height > 1000
    assert set(h["check"].unique()) == {"ais_kinematics"}
    assert not h["nis"].is_infinite().any()
    q = cfg.family("maritime").integrity.ais_q
    share = h["eta"].mean()
    assert share < 3 * q, share
    # excluded decisions only where the self-test failed (a few false alarms)
    assert h["excluded"].mean() < 0.05


def test_a_sector_the_radars_never_see_is_not_tested_against_them(cfg, tables):
    """Both radars see nothing in approach_ne (their reports there removed for the whole
    scene: a sector out of their sight), AIS ships sail there: their reports in that
    sector are not tested against the radars (no ``ais`` / ``ais_unmatched`` decision,
    nothing flagged beyond the self-test's rate), while the sectors the radars see keep
    their radar tests. Before: the transponders there were tested against tracks that
    do not exist and excluded as spoofers."""
    radar, ais, truth = tables
    blind = "approach_ne"
    site = {s.site_id: s for s in cfg.radar_sites}
    rx = np.array([site[s].lat_deg for s in radar["site_id"]])
    ry = np.array([site[s].lon_deg for s in radar["site_id"]])
    sx, sy = frames.geodetic_to_enu(rx, ry, cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
    at = pl.DataFrame({"x_enu_m": sx + radar["x_site_m"].to_numpy(),
                       "y_enu_m": sy + radar["y_site_m"].to_numpy()})
    sector = assign_sectors(at, cfg.sectors, cfg.region)["sector"]
    seen = radar.filter((sector != blind).fill_null(True))
    assert seen.height < radar.height  # the sector held reports
    h = health(cfg, seen, ais, truth)
    there = h.filter(pl.col("sector") == blind)
    assert there.height > 100
    assert set(there["check"].unique()) == {"ais_kinematics"}
    q = cfg.family("maritime").integrity.ais_q
    assert there["eta"].mean() < 3 * q
    elsewhere = h.filter(pl.col("sector") != blind)
    assert elsewhere.filter(pl.col("check") == "ais").height > 100
