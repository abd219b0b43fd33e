"""A real AIS day as its own site (issue 35, items 3 and 4): Stone Soup's Solent AIS CSV
(18,623 reports, 91 MMSI, 1.4 h) imported and ingested, then batched

- with the shipped demo config (origin 46.4 N 30.9 E, ~2,400 km away): batch refuses,
  exit 2 before any work, naming the distance (against an independent Vincenty
  distance from the data's centre) and ``surveil config init``; ingest warned and kept
  every row;
- with a config written for the place (tests/site_configs.py: origin at the data's
  centroid; ``surveil config init`` will write it), two radars declared at the data
  without any radar data change no decision (a silent radar is no witness): every
  decision is the kinematic self-test, none an ``ais_unmatched`` test with nis = inf;
- and the self-test takes each step on the ellipsoid where the ship is (issue 36, item
  6), so the demo's distant origin changes no decision either (before, its distorted
  frame flagged 21.8 % of the reports against 3.5 % with a local origin).
"""

from __future__ import annotations

import re
from pathlib import Path

import polars as pl
import pytest

from pipeline.batch import run_batch
from pipeline.batch.place import PlaceError
from pipeline.convert.importer import run_import
from pipeline.families import load_config
from pipeline.ingest.driver import run_ingest
from pipeline.units import NS
from pipeline.warehouse.delta import read_table
from tests.conftest import real_data_dir
from tests.site_configs import centroid, expected_km, local_config

pytestmark = pytest.mark.realdata
SITE = "solent"
HOUR_NS = 3600 * NS


@pytest.fixture(scope="module")
def solent(tmp_path_factory) -> tuple[Path, object, int, int]:
    path = real_data_dir() / "ais" / "csv" / "stonesoup_SolentAIS_20160112_130211.csv"
    if not path.is_file():
        pytest.skip(f"{path.name} not in the real recordings")
    root = tmp_path_factory.mktemp("solent")
    assert run_import([path], root / "mcap", site=SITE).exit_code == 0
    wh = root / "wh"
    ingest = run_ingest([root / "mcap"], load_config(), wh, executor="serial")
    assert ingest.exit_code == 0
    ais = pl.from_arrow(read_table(wh, "ais_reports"))
    assert ais.height == ingest.rows["ais_reports"] == 18_623  # nothing lost
    assert len(ingest.place_warnings) == 1 and SITE in ingest.place_warnings[0]
    start = int(ais["time_ns"].min()) // HOUR_NS * HOUR_NS
    return wh, ais, start, int(ais["time_ns"].max()) + 1


def ais_health(wh: Path) -> pl.DataFrame:
    return pl.from_arrow(read_table(wh, "maritime_channel_health")).filter(
        pl.col("sensor_kind") == "ais")


def test_the_demo_config_is_refused_naming_the_distance(solent):
    wh, ais, start, end = solent
    lat, lon = centroid(ais["lat_deg"].to_numpy(), ais["lon_deg"].to_numpy())
    cfg = load_config()
    km = expected_km(cfg, lat, lon)
    with pytest.raises(PlaceError) as err:
        run_batch(cfg, wh, start_ns=start, end_ns=end, executor_kind="serial")
    text = str(err.value)
    said = re.search(r"([0-9,]+) km from the origin", text)
    assert said is not None, text
    assert float(said.group(1).replace(",", "")) == pytest.approx(km, rel=0.005)
    assert "100% of them lie outside it" in text and "surveil config init" in text
    assert read_table(wh, "batch_units").num_rows == 0


def test_neither_the_origin_nor_silent_radars_change_an_ais_decision(solent):
    wh, ais, start, end = solent
    lat, lon = centroid(ais["lat_deg"].to_numpy(), ais["lon_deg"].to_numpy())
    shares = {}
    decisions = {}
    for name, cfg, force in (
        ("demo", load_config(), True),
        ("local", local_config(lat, lon), False),
        ("silent radars", local_config(lat, lon, radars_at_data=True), False),
    ):
        b = run_batch(cfg, wh, start_ns=start, end_ns=end, executor_kind="serial",
                      ignore_place=force)
        assert b.committed and not b.failed_units
        h = ais_health(wh)
        shares[name] = h["eta"].mean()
        decisions[name] = h.sort("time_ns", "channel").select("time_ns", "channel", "check",
                                                               "eta", "excluded")
    assert decisions["demo"].equals(decisions["local"]), shares
    h = decisions["silent radars"]
    assert set(h["check"].unique()) == {"ais_kinematics"}
    assert h.equals(decisions["local"])
