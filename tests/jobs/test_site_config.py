"""Your own site (issue 35, items 1, 2, 6): `surveil config init` writes a config from
recordings the project has not seen; every family and sensor is optional; a family
without its config or its inputs is skipped with one line; empty results and verdicts
give the real cause; an unknown --site is exit 2. On simulated recordings written the way
real ones arrive (no truth, no scenario metadata, no config), so every figure is checked
against the simulator's truth; tests/realdata/test_site_walk.py walks the real ones."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from jobs.batch import run_batch
from jobs.simulate import run_simulate
from pipeline.convert.importer import run_import
from pipeline.families import declared, load_config
from pipeline.frames import geodetic_to_enu
from pipeline.ingest.driver import run_ingest
from pipeline.requirements import NOT_APPLICABLE, RequirementsConfig, evaluate
from pipeline.siteconfig.init import run_config_init
from pipeline.units import NS
from pipeline.warehouse.delta import read_table
from tests.realdata.site_walk import REPO, write_cat010_capture

START = 1_768_435_200 * NS  # 2026-01-15T00:00:00Z
HOUR = 3600 * NS


def surveil(*args: str, cwd: Path = REPO) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "jobs.cli", *args], capture_output=True,
                          text=True, cwd=cwd, check=False)


def _distance_m(lat: float, lon: float, lat0: float, lon0: float) -> float:
    e, n = geodetic_to_enu(np.array([lat]), np.array([lon]), lat0, lon0)
    return float(np.hypot(e[0], n[0]))


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """10 minutes of the airfield scenario's CAT010 as a raw capture, imported; the
    config `config init` writes for it (the reference point given: the data carry none)."""
    root = tmp_path_factory.mktemp("capture")
    cap = write_cat010_capture(root / "tower.ast", duration_s=600.0, seed=5)
    imp = run_import([cap], root / "archive", base_time_ns=START, site="tower")
    assert imp.exit_code == 0, imp.render()
    cfg_path = root / "tower.toml"
    demo = load_config().family("airfield")
    result = run_config_init(load_config(), [root / "archive"], cfg_path, warehouse=None,
                             name="tower", origin=(demo.reference_lat_deg,
                                                   demo.reference_lon_deg))
    return {"root": root, "config": cfg_path, "result": result, "demo": demo}


def test_config_init_declares_the_airfield_sensors_and_finds_the_smr_antenna(capture):
    """Was: no way in (the only config was the demo's), and an airfield sensor could not be
    declared without AR(2) coefficients only `calibrate` against a reference can give. The
    SMR antenna, which no CAT010 record carries, is found against the MLAT's targets."""
    cfg = load_config(capture["config"])
    a = cfg.family("airfield")
    by_kind = {s.kind: s for s in a.sensors}
    assert set(by_kind) == {"smr", "mlat"}
    assert (by_kind["smr"].sac, by_kind["smr"].sic) == (0, 10)
    assert (by_kind["mlat"].sac, by_kind["mlat"].sic) == (0, 20)
    true_smr = capture["demo"].sensor("SMR1")
    assert _distance_m(by_kind["smr"].lat_deg, by_kind["smr"].lon_deg, true_smr.lat_deg,
                       true_smr.lon_deg) < 5.0
    assert {s.error_model for s in a.sensors} == {"default"}  # no position_ar in the file
    text = capture["config"].read_text()
    assert "position_ar =" not in text and "PROPOSED" in text
    assert "channel_faults" not in text and "airfield.faults" not in text  # the site only
    decl = declared(cfg)
    assert decl.radars == () and decl.airfield
    assert [s.sac_sic for s in decl.sensors] == ["0/10", "0/20"]


def test_a_default_error_model_is_scaled_to_the_data_and_every_row_says_so(capture):
    """Every report row computed with a default model says so (channel_health.error_model),
    and the scaled default finds the injected SMR jamming like the true model does."""
    root = capture["root"]
    cfg = load_config(capture["config"])
    wh = root / "wh"
    assert run_ingest([root / "archive"], cfg, wh, executor="serial").exit_code == 0
    summary = run_batch(cfg, wh, start_ns=START, end_ns=START + HOUR, executor_kind="serial")
    assert summary.exit_code == 0, summary.render()
    text = summary.render()
    assert "maritime: skipped: no rows of radar_tracks, ais_reports in the window" in text
    assert "nav: skipped: no rows of" in text
    health = pl.from_arrow(read_table(wh, "channel_health"))
    assert health.height and health["error_model"].null_count() == 0
    assert health["error_model"].str.starts_with("default ").all()
    assert health["error_model"].str.contains(r"AR\(1\) x\d").all()  # scaled, with its factor
    t = (health["time_ns"] - START) / NS
    smr = health.filter(pl.col("channel").str.starts_with("SMR"))
    # no fault in the first 10 minutes of the demo schedule: the flags stay near q
    assert 0.0 < smr.filter(t.filter(health["channel"].str.starts_with("SMR")) < 600)[
        "eta"].mean() < 0.08


def test_config_init_locates_radars_against_ais(tmp_path):
    """A radar's reports carry no site position; config init finds it against the AIS
    ships it sees (channel scenario: R1 and R2 within 20 m of their true antennas)."""
    files = run_simulate("channel-clean", 600.0, 3, tmp_path / "sim", load_config(),
                         start_ns=START)
    out = tmp_path / "estuary.toml"
    res = run_config_init(load_config(), files, out, warehouse=None, name="estuary")
    assert any("radar R1: located" in line for line in res.lines)
    cfg = load_config(out)
    demo = load_config()
    for site in cfg.radar_sites:
        true = demo.site(site.site_id)
        assert _distance_m(site.lat_deg, site.lon_deg, true.lat_deg, true.lon_deg) < 20.0
        assert site.scan_period_s == true.scan_period_s
    assert cfg.sectors and all(s.name.startswith(("cell_", "traffic_extent"))
                               for s in cfg.sectors)
    # the data's median position: the demo estuary, not 2,000 km away
    assert _distance_m(cfg.region.origin_lat_deg, cfg.region.origin_lon_deg,
                       demo.region.origin_lat_deg, demo.region.origin_lon_deg) < 10_000.0
    # an existing file is not replaced without --force
    with pytest.raises(Exception, match="exists"):
        run_config_init(load_config(), files, out, warehouse=None)


def test_config_init_without_any_position_says_unknown_and_still_loads(tmp_path, capture):
    out = tmp_path / "nowhere.toml"
    res = run_config_init(load_config(), [capture["root"] / "archive"], out, warehouse=None)
    text = out.read_text()
    assert "UNKNOWN" in text and any("WARNING" in line for line in res.lines)
    cfg = load_config(out)
    assert (cfg.region.origin_lat_deg, cfg.region.origin_lon_deg) == (0.0, 0.0)


def test_coastline_file_gives_the_admissible_area(tmp_path):
    """--coastline: GeoJSON land polygons become islands in the traffic's box (the
    vessels' positions tell land from water)."""
    files = run_simulate("channel-clean", 300.0, 3, tmp_path / "sim", load_config(),
                         start_ns=START)
    land = tmp_path / "land.geojson"
    # an island south of the fairway (no ship on it)
    land.write_text('{"type": "FeatureCollection", "features": [{"type": "Feature", '
                    '"properties": {}, "geometry": {"type": "Polygon", "coordinates": '
                    '[[[30.80, 46.30], [30.90, 46.30], [30.90, 46.33], [30.80, 46.33], '
                    '[30.80, 46.30]]]}}]}', encoding="utf-8")
    out = tmp_path / "c.toml"
    run_config_init(load_config(), files, out, warehouse=None, coastline=land)
    g = load_config(out).family("gaps")
    assert len(g.admissible) == 1 and len(g.islands) == 1
    lat = [p[0] for p in g.islands[0].polygon_lat_lon_deg]
    assert min(lat) == pytest.approx(46.30, abs=1e-3) and max(lat) == pytest.approx(46.33,
                                                                                   abs=1e-3)
    assert "they are land" in out.read_text()


def test_unknown_sensor_rejects_name_the_sac_sic_to_declare(tmp_path, capture):
    """Was: 6,666 reports rejected as unknown_sensor 0/7 were only in `rejects`; the batch
    summary said "rejects (batch) 2 rows" and the airfield reports blamed airfield_truth."""
    text = capture["config"].read_text()
    start = text.index("[[airfield.sensors]]\nsensor_id = \"MLAT_0_20\"")
    end = text.index("# Airfield sectors")
    one = tmp_path / "smr_only.toml"
    one.write_text(text[:start] + text[end:], encoding="utf-8")
    cfg = load_config(one)
    wh = tmp_path / "wh"
    run_ingest([capture["root"] / "archive"], cfg, wh, executor="serial")
    summary = run_batch(cfg, wh, start_ns=START, end_ns=START + HOUR, executor_kind="serial")
    out = summary.render()
    assert "unknown_sensor: " in out and "from sensor 0/20 (mlat)" in out
    assert 'kind = "mlat", sac = 0, sic = 20' in out
    # no declared sensor has reports: the empty report names the rejects, not the truth
    none = tmp_path / "none.toml"
    none.write_text(text[:start].replace("sic = 10 ", "sic = 99 ") + text[end:],
                    encoding="utf-8")
    wh2 = tmp_path / "wh2"
    run_ingest([capture["root"] / "archive"], load_config(none), wh2, executor="serial")
    run_batch(load_config(none), wh2, start_ns=START, end_ns=START + HOUR,
              executor_kind="serial")
    res = surveil("report", "surface_accuracy_by_area", "--config", str(none), "--warehouse",
                  str(wh2))
    assert res.returncode == 0, res.stderr
    assert "were not used" in res.stderr and "0/10 (smr)" in res.stderr, res.stderr
    assert "airfield_truth" not in res.stderr and "simulate" not in res.stderr


def test_unknown_site_is_exit_2_for_every_command(e2e, tmp_path):
    """Was: `report --site nosuch` exit 0 blaming the gyro signals, `batch --site nosuch`
    committed empty units."""
    wh = str(e2e.warehouse)
    window = ["--from", "2026-01-15T00:50:00Z", "--to", "2026-01-15T01:10:00Z"]
    for args in (["report", "accuracy_by_sector", *window], ["batch", *window],
                 ["reprocess", *window], ["audit", *window, "--out", str(tmp_path / "a")],
                 ["export", *window, "--out", str(tmp_path / "x.mcap")],
                 ["calibrate", *window], ["calibrate-radars", *window]):
        res = surveil(*args, "--site", "nosuch", "--warehouse", wh)
        assert res.returncode == 2, (args, res.stderr)
        assert "no site 'nosuch'" in res.stderr and "channel-clean" in res.stderr, res.stderr
        assert "Traceback" not in res.stderr
    units = pl.from_arrow(read_table(e2e.warehouse, "batch_units"))
    assert "nosuch" not in units["site"].to_list()


def test_verdicts_say_not_applicable_apart_from_not_enough_samples():
    """Was: "not enough samples" where the truth was "no radar at this site"."""
    req = RequirementsConfig()
    empty = evaluate({}, req, sectors=["a"], legs=["L1"], airfield=False)
    assert {v.status for v in empty} == {"not enough samples"}
    na = evaluate({}, req, sectors=["a"], legs=["L1"], airfield=False,
                  not_applicable={"maritime": "no radar at this site",
                                  "siap": "no radar at this site",
                                  "cross_track": "no radar at this site"})
    assert {v.status for v in na} == {"not applicable: no radar at this site"}
    assert {v.outcome for v in na} == {NOT_APPLICABLE}


def test_a_family_without_its_config_is_skipped_with_one_line_naming_its_data(tmp_path,
                                                                              capture):
    """Every family optional: with [region] alone the airfield family is skipped, and the
    line names the data it would have had (the SAC/SIC to declare)."""
    only = tmp_path / "region_only.toml"
    only.write_text('[region]\nname = "x"\norigin_lat_deg = 46.4268\n'
                    'origin_lon_deg = 30.6765\n', encoding="utf-8")
    cfg = load_config(only)
    wh = tmp_path / "wh"
    run_ingest([capture["root"] / "archive"], cfg, wh, executor="serial")
    summary = run_batch(cfg, wh, start_ns=START, end_ns=START + HOUR, executor_kind="serial")
    text = summary.render()
    line = next(x for x in text.splitlines() if "airfield: skipped" in x)
    assert "no [airfield] section in the config" in line
    assert "0/10 (smr, CAT010" in line and "0/20 (mlat, CAT010" in line
    assert "declare them" in line
    assert summary.units_total == 0 and summary.exit_code == 0
    res = surveil("report", "surface_accuracy_by_area", "--config", str(only), "--warehouse",
                  str(wh))
    assert res.returncode == 0
    assert "not applicable at this site: no airfield is declared" in res.stderr
    assert "config init" in res.stderr and "simulate" not in res.stderr


def test_simulating_the_channel_on_a_site_without_radars_is_exit_2(tmp_path):
    only = tmp_path / "ais_only.toml"
    only.write_text('[region]\nname = "x"\norigin_lat_deg = 50.8\norigin_lon_deg = -1.1\n',
                    encoding="utf-8")
    res = surveil("--config", str(only), "simulate", "--scenario", "channel", "--duration",
                  "60s", "--out", str(tmp_path / "sim"))
    assert res.returncode == 2 and "no [[radar_sites]] and no [[fairway_legs]]" in res.stderr
    assert "Traceback" not in res.stderr
