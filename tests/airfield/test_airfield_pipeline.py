"""The airfield family end to end on real files: `surveil simulate --scenario airfield`
(zstd MCAP: CAT010 for SMR/MLAT, JSON for VASN and truth) -> ingest (the CAT010 decoder
of pipeline.decode.asterix) -> calibrate -> batch -> both SQL reports."""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest
from airfield_helpers import START_NS
from mcap.reader import make_reader

from jobs.batch import run_batch
from jobs.common import UsageError
from jobs.simulate import run_simulate
from pipeline.batch.calibrate import run_calibrate
from pipeline.ingest.driver import run_ingest
from pipeline.reports import open_warehouse, run_report
from pipeline.units import NS
from pipeline.warehouse.delta import read_table

DURATION_S = 600.0
CAL_END_NS = START_NS + 300 * NS
END_NS = START_NS + int(DURATION_S * NS)


@pytest.fixture(scope="module")
def warehouse(tmp_path_factory, cfg) -> Path:
    root = tmp_path_factory.mktemp("airfield")
    files = run_simulate("airfield", DURATION_S, 5, root / "archive", cfg, start_ns=START_NS)
    wh = root / "wh"
    ingest = run_ingest(files, cfg, wh, executor="serial")
    assert ingest.exit_code == 0, ingest.render()
    return wh


@pytest.fixture(scope="module")
def batched(warehouse, cfg) -> Path:
    run_calibrate(cfg, warehouse, start_ns=START_NS, end_ns=CAL_END_NS)
    summary = run_batch(cfg, warehouse, start_ns=START_NS, end_ns=END_NS, executor_kind="serial")
    assert summary.exit_code == 0, summary.render()
    return warehouse


def table(wh: Path, name: str, **kw) -> pl.DataFrame:
    return pl.from_arrow(read_table(wh, name, **kw))


def test_the_archive_has_the_channels_of_the_issue(tmp_path, cfg):
    (f,) = run_simulate("airfield", 30.0, 1, tmp_path, cfg, start_ns=START_NS)
    with open(f, "rb") as fh:
        summary = make_reader(fh).get_summary()
    chans = {c.topic: c for c in summary.channels.values()}
    assert chans["/airfield/SMR1/cat010"].message_encoding == "asterix"
    assert chans["/airfield/SMR1/cat010"].metadata == {"sensor_id": "SMR1", "sensor_kind": "smr"}
    assert chans["/airfield/MLAT1/cat010"].metadata["sensor_kind"] == "mlat"
    assert chans["/airfield/VASN1/vasn"].message_encoding == "json"
    schemas = {s.id: s.name for s in summary.schemas.values()}
    assert schemas[chans["/airfield/VASN1/vasn"].schema_id] == "surveil.VasnReport"
    assert schemas[chans["/airfield/truth"].schema_id] == "surveil.AirfieldTruth"


def test_ingest_fills_airfield_obs_from_cat010_and_json(warehouse):
    obs = table(warehouse, "airfield_obs")
    kinds = obs.group_by("sensor_id", "sensor_kind", "asterix_category").len().sort("sensor_id")
    assert kinds.select("sensor_id", "sensor_kind", "asterix_category").rows() == [
        ("MLAT1", "mlat", 10), ("SMR1", "smr", 10), ("VASN1", "vasn", None)]
    assert table(warehouse, "airfield_truth").height > 5000
    assert table(warehouse, "rejects").height == 0


def test_calibrate_stores_models_for_every_channel(batched):
    models = table(batched, "sensor_error_models")
    fits = models.group_by("sensor_id", "quantity").agg(pl.col("order").first()).sort(
        "sensor_id", "quantity")
    assert fits.rows() == [("MLAT1", "position", 2), ("SMR1", "position", 2),
                           ("VASN1", "position", 2), ("VASN1", "velocity", 1)]
    assert (models["fit_end_ns"] == CAL_END_NS).all()


def test_calibrate_without_a_reference_is_a_usage_error(warehouse, cfg):
    with pytest.raises(UsageError, match="no airfield_obs"):
        run_calibrate(cfg, warehouse, start_ns=END_NS + 3600 * NS, end_ns=END_NS + 7200 * NS)


def test_batch_writes_tracks_and_channel_health(batched):
    tracks = table(batched, "airfield_tracks")
    health = table(batched, "channel_health")
    assert tracks["time_ns"].min() >= START_NS and tracks["time_ns"].max() < END_NS
    assert tracks["error_m"].quantile(0.95) < 7.5
    assert set(health["check"]) >= {"nis", "birth"}
    assert health.filter(pl.col("eta").is_not_null())["eta"].mean() < 0.03


def test_reports_answer_per_area_and_per_sector(batched):
    con = open_warehouse(batched)
    try:
        acc = pl.from_arrow(run_report(con, "surface_accuracy_by_area", start_ns=START_NS,
                                       end_ns=END_NS))
        faults = pl.from_arrow(run_report(con, "channel_faults_by_sector", start_ns=START_NS,
                                          end_ns=END_NS, sector="runway"))
    finally:
        con.close()
    fused = acc.filter(pl.col("source") == "fused")
    assert set(fused["area"]) >= {"manoeuvring", "apron_taxiway", "stand"}
    assert fused["meets_ed87"].all()
    assert fused.filter(pl.col("area") == "manoeuvring")["ed87_p95_req_m"].item() == 12.0
    assert (fused["p_identification"] > 0.99).all()
    assert set(faults["sector"]) == {"runway"}
    assert set(faults["channel"]) <= {"SMR1", "MLAT1", "VASN1"}


def test_rerunning_the_batch_replaces_the_window(batched, cfg):
    before = table(batched, "airfield_tracks").height
    summary = run_batch(cfg, batched, start_ns=START_NS, end_ns=END_NS, executor_kind="serial")
    assert summary.exit_code == 0
    assert table(batched, "airfield_tracks").height == before
