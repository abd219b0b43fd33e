"""channel_faults_by_sector and channel_fault_episodes over every family (issue 22):
airfield channel_health, maritime_channel_health (radar, AIS) and the own ship's GNSS
from nav_solution, on small literal tables whose episodes are known."""

from __future__ import annotations

import math

import duckdb
import polars as pl
import pytest

from pipeline.reports import run_report

NS = 1_000_000_000
FLOATS = {c: pl.Float64 for c in ("range_bias_m", "azimuth_bias_rad", "time_offset_s",
                                   "offset_east_m", "offset_north_m", "innovation_m",
                                   "scan_gap_s")}
T0 = 1_768_435_200 * NS


def epochs(n: int, step_s: float, start_s: float = 0.0) -> list[int]:
    return [T0 + round((start_s + i * step_s) * NS) for i in range(n)]


@pytest.fixture()
def con():
    c = duckdb.connect()
    # airfield: SMR1 on two targets, both excluded at epochs 10-19 (1 Hz)
    t = epochs(40, 1.0)
    air = pl.DataFrame({
        "site": "harbour",
        "time_ns": t * 2, "track_id": ["a"] * 40 + ["b"] * 40, "channel": "SMR1",
        "sensor_kind": "smr", "sector": "runway", "check": "nis",
        "nis": 1.0, "dof": 2, "d1": 0.01003, "d2": 10.5966, "innovation_m": 2.0,
        "eta": [1 if i == 10 else 0 for i in range(40)] * 2,
        "excluded": [10 <= i < 20 for i in range(40)] * 2,
        "error_model": "default smr AR(1) x0.50 (median NIS, 80 checks)",
    })
    # maritime: R1 in inner_channel every 4 s, excluded at epochs 5-9; an AIS transponder
    # with one isolated false alarm (excluded for its next 5 reports)
    r = epochs(30, 4.0)
    radar = pl.DataFrame({
        "site": "harbour",
        "time_ns": r, "channel": "R1", "sensor_kind": "radar", "sector": "inner_channel",
        "check": "nis", "nis": 10.0, "dof": 10, "q": 0.001,
        "eta": [1 if 5 <= i < 10 else 0 for i in range(30)],
        "excluded": [5 <= i < 10 for i in range(30)],
        "range_bias_m": [80.0 if 5 <= i < 10 else 0.0 for i in range(30)],
        "azimuth_bias_rad": 0.0, "time_offset_s": 0.0, "offset_east_m": None,
        "offset_north_m": None, "innovation_m": None, "missed": 0, "expected": 5,
        "scan_gap_s": 1.0,
    }, schema_overrides=FLOATS)
    a = epochs(20, 10.0, 1.0)
    ais = pl.DataFrame({
        "site": "harbour",
        "time_ns": a, "channel": "211000001", "sensor_kind": "ais", "sector": "inner_channel",
        "check": "ais", "nis": 2.0, "dof": 2, "q": 0.01,
        "eta": [1 if i == 3 else 0 for i in range(20)],
        "excluded": [3 <= i < 8 for i in range(20)],
        "range_bias_m": None, "azimuth_bias_rad": None, "time_offset_s": None,
        "offset_east_m": 0.0, "offset_north_m": 12.0, "innovation_m": 12.0, "missed": 0,
        "expected": 0, "scan_gap_s": None,
    }, schema_overrides=FLOATS)
    # GNSS: 1 Hz, an outage (emergency) at steps 50-79
    g = epochs(100, 1.0)
    nav = pl.DataFrame({
        "site": "harbour",
        "time_ns": g, "platform_id": "ownship", "sector": "approach_sw",
        "mode": ["emergency" if 50 <= i < 80 else "main" for i in range(100)],
        "gate": [None if 50 <= i < 80 else "pass" for i in range(100)],
        "gnss_nis": pl.Series([None if 50 <= i < 80 else 2.0 for i in range(100)],
                              dtype=pl.Float64),
        "gnss_eta": [1 if 50 <= i < 80 else 0 for i in range(100)],
        "gnss_excluded": [50 <= i < 80 for i in range(100)],
        "gnss_q": 0.0037,
    })
    c.register("channel_health", air.to_arrow())
    c.register("maritime_channel_health",
               pl.concat([radar, ais], how="vertical_relaxed").to_arrow())
    c.register("nav_solution", nav.to_arrow())
    yield c
    c.close()


def report(con, name, sector=None) -> pl.DataFrame:
    return pl.from_arrow(run_report(con, name, start_ns=T0, end_ns=T0 + 3600 * NS,
                                    sector=sector))


def test_faults_by_sector_has_every_family(con):
    r = report(con, "channel_faults_by_sector")
    rows = {(x["family"], x["channel"]): x for x in r.iter_rows(named=True)}
    assert set(rows) == {("airfield", "SMR1"), ("maritime", "R1"), ("maritime", "211000001"),
                         ("nav", "ownship")}
    # every row says which error model its decisions were made with (issue 35)
    assert rows[("airfield", "SMR1")]["error_model"].startswith("default smr AR(1)")
    assert rows[("maritime", "R1")]["error_model"] == "reported sigmas"
    assert rows[("nav", "ownship")]["error_model"] is None
    smr = rows[("airfield", "SMR1")]
    assert smr["target_episodes"] == 2 and smr["channel_episodes"] == 1
    assert smr["channel_fault_s"] == 10.0 and smr["q"] == pytest.approx(0.01, abs=1e-4)
    r1 = rows[("maritime", "R1")]
    assert (r1["sector"], r1["sensor_kind"], r1["decisions"]) == ("inner_channel", "radar", 30)
    assert r1["channel_episodes"] == 1 and r1["channel_fault_s"] == 20.0
    assert r1["flagged_share"] == pytest.approx(5 / 30, abs=1e-5)
    assert r1["p_chance"] < 1e-6  # 5 flags in 30 decisions at q = 0.001: a fault
    one = rows[("maritime", "211000001")]  # 1 flag in 20 at q = 0.01: chance, 1 - e^-0.2
    assert one["p_chance"] == pytest.approx(1 - math.exp(-0.2), abs=1e-6)
    gnss = rows[("nav", "ownship")]
    assert gnss["channel_fault_s"] == 30.0 and gnss["excluded_share"] == pytest.approx(0.3)
    assert report(con, "channel_faults_by_sector", sector="runway")["family"].to_list() == [
        "airfield"]


def test_episodes_list_each_fault_with_its_evidence(con):
    e = report(con, "channel_fault_episodes")
    assert e.height == 4
    r1 = e.filter(pl.col("channel") == "R1").row(0, named=True)
    assert r1["flags"] == 5 and not r1["isolated"] and r1["range_bias_m"] == 80.0
    assert r1["duration_s"] == 20.0 and r1["checks"] == "nis"
    ais = e.filter(pl.col("channel") == "211000001").row(0, named=True)
    assert ais["isolated"] and ais["offset_north_m"] == 12.0 and ais["duration_s"] == 50.0
    gnss = e.filter(pl.col("family") == "nav").row(0, named=True)
    assert gnss["checks"] == "outage" and gnss["duration_s"] == 30.0
    assert e["start_ns"].is_sorted()
