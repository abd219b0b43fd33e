"""The place check (issue 35, item 3; pipeline/batch/place.py): ingest and batch measure
where a site's positions lie against the config's region, sectors and water; when most
lie far outside, batch exits 2 before any work naming the distance, the share outside and
`surveil config init` (--ignore-place goes on); ingest warns and keeps every row."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from jobs.simulate import run_simulate
from pipeline.batch import run_batch
from pipeline.batch.place import PlaceError, measure, site_place
from pipeline.families import load_config
from pipeline.ingest.driver import run_ingest
from pipeline.units import NS
from pipeline.warehouse.delta import read_table
from tests.site_configs import expected_km, moved_config, moved_raw, write_config

START_NS = 1_768_435_200 * NS  # 2026-01-15T00:00:00Z
DURATION_S = 600.0
# the demo config carried to the Channel Islands: every place in it shifted alike
DLAT, DLON = 3.05, -33.45


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("place")
    return run_simulate("channel-clean", DURATION_S, 3, root / "archive", load_config(),
                        start_ns=START_NS)


@pytest.fixture(scope="module")
def far():
    return moved_config(DLAT, DLON)


def test_positions_of_the_region_are_inside_and_far_ones_outside(far):
    cfg = load_config()
    rng = np.random.default_rng(1)
    lat = cfg.region.origin_lat_deg + rng.normal(0.0, 0.05, 500)
    lon = cfg.region.origin_lon_deg + rng.normal(0.0, 0.05, 500)
    home = measure(lat, lon, cfg, site="s")
    assert home.outside == 0 and not home.refused
    assert home.in_water is not None and home.in_sectors is not None
    away = measure(lat, lon, far, site="s")
    assert away.outside == away.positions == 500 and away.refused
    assert away.in_sectors == 0 and away.in_water == 0
    centre = expected_km(far, float(np.median(lat)), float(np.median(lon)))
    assert away.distance_m / 1000.0 == pytest.approx(centre, rel=0.005)
    text = away.describe() + " " + away.advice()
    assert f"{away.distance_m / 1000.0:,.0f} km" in text and "100%" in text
    assert "surveil config init" in text and "--ignore-place" in text
    # 40 % outside is not most: not refused; a declared radar's coverage is inside
    mixed = measure(np.r_[lat[:300], lat[300:] + DLAT], np.r_[lon[:300], lon[300:] + DLON],
                    cfg)
    assert mixed.outside == 200 and not mixed.refused
    s = cfg.radar_sites[0]
    beyond = measure(np.array([s.lat_deg + 0.1]), np.array([s.lon_deg]), cfg)
    assert beyond.outside == 0
    # a feed of many places centred on the region (a satellite receiver): refused, with
    # what to declare instead
    wide = measure(cfg.region.origin_lat_deg + rng.uniform(-10, 10, 500),
                   cfg.region.origin_lon_deg + rng.uniform(-10, 10, 500), cfg)
    assert wide.refused and wide.distance_m < cfg.region.radius_m
    assert "spread far beyond the region" in wide.advice()


def test_batch_of_another_place_exits_2_before_any_work_and_ingest_warns(tmp_path, archive,
                                                                         far):
    """The demo's own recording with the demo config moved to the Channel Islands: ingest
    keeps every row and warns; batch refuses, naming the distance, before writing a
    row; --ignore-place batches."""
    wh = tmp_path / "wh"
    ingest = run_ingest(archive, far, wh, executor="serial")
    assert ingest.exit_code == 0
    assert ingest.rows["ais_reports"] == read_table(wh, "ais_reports").num_rows > 0
    assert len(ingest.place_warnings) == 1
    assert "km from the origin" in ingest.place_warnings[0]
    assert "batch will refuse" in ingest.render()
    end_ns = START_NS + round(DURATION_S * NS)
    with pytest.raises(PlaceError) as err:
        run_batch(far, wh, start_ns=START_NS, end_ns=end_ns, executor_kind="serial")
    place = site_place(wh, far, "channel-clean", START_NS, end_ns)
    assert f"{place.distance_m / 1000.0:,.0f} km" in str(err.value)
    assert place.distance_m / 1000.0 == pytest.approx(
        expected_km(far, place.centre_lat_deg, place.centre_lon_deg), rel=0.005)
    assert read_table(wh, "batch_units").num_rows == 0  # nothing was batched
    assert read_table(wh, "system_tracks").num_rows == 0
    done = run_batch(far, wh, start_ns=START_NS, end_ns=end_ns, executor_kind="serial",
                     ignore_place=True)
    assert done.committed
    # the config of the recording's own place batches without a word
    home = tmp_path / "home"
    assert run_ingest(archive, load_config(), home, executor="serial").place_warnings == []
    assert run_batch(load_config(), home, start_ns=START_NS, end_ns=end_ns,
                     executor_kind="serial").committed


def test_the_command_line_exits_2_naming_the_distance(tmp_path, archive):
    def surveil(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "jobs.cli", "--config", str(config),
                               "--warehouse", str(tmp_path / "wh"), *args],
                              capture_output=True, text=True, timeout=600)

    config = write_config(moved_raw(DLAT, DLON), tmp_path / "channel-islands.toml")
    ing = surveil("ingest", str(archive[0].parent))
    assert ing.returncode == 0, ing.stderr
    assert "WARNING: site 'channel-clean'" in ing.stdout
    window = ["--from", "2026-01-15T00:00:00Z", "--to", "2026-01-15T00:10:00Z",
              "--executor", "serial"]
    res = surveil("batch", *window)
    assert res.returncode == 2, res.stdout + res.stderr
    assert "Traceback" not in res.stderr
    assert " km from the origin of region 'demo-estuary'" in res.stderr
    assert "100% of them lie outside it" in res.stderr
    assert "surveil config init" in res.stderr and "--ignore-place" in res.stderr
    forced = surveil("batch", *window, "--ignore-place")
    assert forced.returncode == 0, forced.stdout + forced.stderr
