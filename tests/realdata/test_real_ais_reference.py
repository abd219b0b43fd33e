"""Evaluation without truth on a real AIS recording (issue 37): the Stone Soup demo's
Solent AIS export (../shared/data/real/ais/csv, 91 vessels, 2016-01-12 13:02-14:26 UTC,
real time stamps) through ``surveil import``, ingest and the batch, with a site config
whose region is the Solent (the shipped demo region is 2,000 km away), declared AIS-only
(no radar sites). Every vessel gets a reconstructed reference and the AIS reports are
scored against it (``reference_quality``: each report against a reference made without
it). There is no
radar in the recording, so the radar accuracy reports have nothing to score."""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest

from jobs.batch import run_batch
from pipeline.convert.importer import run_import
from pipeline.ingest.driver import run_ingest
from pipeline.reports import run_named_report

pytestmark = pytest.mark.realdata

CSV = "ais/csv/stonesoup_SolentAIS_20160112_130211.csv"
START_NS = 1_452_603_600 * 10**9  # 2016-01-12T13:00:00Z
END_NS = START_NS + 2 * 3600 * 10**9


def _solent_config():
    from pipeline.families import config_from_mapping, load_config

    base = load_config(None)
    sections = dict(base.sections)
    sections["region"] = {**sections["region"], "name": "solent", "origin_lat_deg": 50.80,
                          "origin_lon_deg": -1.30}
    sections["radar_sites"] = []  # an AIS-only site
    sections["sectors"] = [{"name": "solent", "polygon": [[50.6, -1.7], [50.6, -0.9],
                                                          [51.0, -0.9], [51.0, -1.7]]}]
    return config_from_mapping(sections, "(solent test config)")


@pytest.fixture(scope="module")
def solent(tmp_path_factory) -> tuple[Path, object]:
    from tests.real_data import real_data_dir

    src = real_data_dir() / CSV
    if not src.exists():
        pytest.skip(f"{src} not available")
    tmp = tmp_path_factory.mktemp("solent")
    imp = run_import([src], tmp / "mcap")
    assert imp.exit_code == 0, imp.render()
    cfg = _solent_config()
    wh = tmp / "wh"
    ing = run_ingest(sorted((tmp / "mcap").glob("*.mcap")), cfg, wh, executor="serial")
    assert ing.rows["ais_reports"] == 18623
    res = run_batch(cfg, wh, start_ns=START_NS, end_ns=END_NS, executor_kind="serial",
                    families=("maritime",))
    assert res.exit_code in (0, 1), res.render()
    return wh, cfg


def test_every_real_vessel_gets_a_reconstructed_reference(solent):
    from pipeline.warehouse.delta import read_table

    wh, _ = solent
    knots = pl.from_arrow(read_table(wh, "reference_tracks"))
    assert knots["reference_id"].n_unique() >= 85
    kept = knots.filter(~pl.col("outlier"))
    # smoothed from real receivers: metres, not tens of metres
    assert kept["p95_m"].median() < 5.0
    assert knots["outlier"].mean() < 0.05


def test_the_real_ais_reports_are_scored_against_the_reconstructed_reference(solent):
    wh, cfg = solent
    q = pl.from_arrow(run_named_report(wh, "reference_quality", start_ns=START_NS,
                                       end_ns=END_NS, cfg=cfg))
    assert q.height >= 1
    row = q.row(0, named=True)
    assert row["vessels"] >= 85 and row["reports"] > 10_000
    assert 0.5 <= row["ais_rms_error_m"] < 20.0
    assert row["reference_p95_m"] < 5.0
    # SIAP runs against the references too (no radar: nothing tracked, said so by 0)
    s = pl.from_arrow(run_named_report(wh, "siap_by_sector", start_ns=START_NS, end_ns=END_NS,
                                       cfg=cfg))
    assert set(s["reference"]) == {"reconstructed"}
    assert (s["completeness"] == 0.0).all()
    # no radar: the radar accuracy reports have nothing to score
    for name in ("accuracy_by_sector", "error_decomposition", "latency_by_sensor",
                 "detection_by_sector"):
        assert run_named_report(wh, name, start_ns=START_NS, end_ns=END_NS,
                                cfg=cfg).num_rows == 0
