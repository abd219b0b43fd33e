"""The `gaps` scenario: ships among islands and channels whose AIS goes silent; its MCAP
archive; and the whole chain simulate -> MCAP -> ingest -> Delta -> batch -> report."""

from __future__ import annotations

import json

import numpy as np
import polars as pl
import pytest
from mcap.reader import make_reader
from polars.testing import assert_frame_equal

from jobs.simulate import DEFAULT_START_NS, run_simulate
from pipeline.config import Config
from pipeline.decode.ais import decode_ais_sentences
from pipeline.frames import geodetic_to_enu
from pipeline.gaps.config import gaps_config
from pipeline.gaps.geometry import build_geometry
from pipeline.simulate.gaps import (
    FIRST_SILENCE_S,
    SILENCE_DURATION_S,
    GapsScenario,
    simulate_gaps,
)
from pipeline.units import NS

DURATION_S = 1800.0
SEED = 4


@pytest.fixture(scope="module")
def scenario(cfg: Config) -> GapsScenario:
    return simulate_gaps(cfg, start_ns=DEFAULT_START_NS, duration_s=DURATION_S, seed=SEED)


def test_same_seed_same_scenario_other_seed_other(cfg, scenario):
    again = simulate_gaps(cfg, start_ns=DEFAULT_START_NS, duration_s=DURATION_S, seed=SEED)
    assert_frame_equal(scenario.truth, again.truth)
    assert_frame_equal(scenario.ais_sentences, again.ais_sentences)
    other = simulate_gaps(cfg, start_ns=DEFAULT_START_NS, duration_s=600.0, seed=SEED + 1)
    assert not other.truth.equals(scenario.truth.filter(pl.col("time_ns") < other.end_ns))


def test_every_ship_stays_in_the_admissible_water(cfg, scenario):
    geo = build_geometry(gaps_config(cfg), cfg.region)
    x, y = geodetic_to_enu(
        scenario.truth["lat_deg"].to_numpy(),
        scenario.truth["lon_deg"].to_numpy(),
        cfg.region.origin_lat_deg,
        cfg.region.origin_lon_deg,
    )
    assert geo.inside(x, y).all()


def test_silences_last_10_to_60_minutes_and_nothing_is_sent_in_them(scenario):
    sil = scenario.silences
    assert sil.height >= 10
    d = (sil["end_ns"] - sil["start_ns"]).to_numpy() / NS
    assert np.all((d >= SILENCE_DURATION_S[0]) & (d <= SILENCE_DURATION_S[1]))
    first = sil.group_by("vessel_id").agg(pl.col("start_ns").min())["start_ns"].to_numpy()
    assert np.all((first - DEFAULT_START_NS) / NS >= FIRST_SILENCE_S[0])
    sent_inside = scenario.ais_sentences.join(sil, on="mmsi").filter(
        pl.col("log_time_ns").is_between("start_ns", "end_ns", closed="left")
    )
    assert sent_inside.height == 0
    # ...and the ships do report outside their silences
    for mmsi in sil["mmsi"].unique().to_list():
        assert scenario.ais_sentences.filter(pl.col("mmsi") == mmsi).height > 20


def test_ais_positions_are_the_truth_plus_gnss_noise(cfg, scenario):
    s = scenario.ais_sentences
    rep, _, rejects = decode_ais_sentences(
        [x.encode() for x in s["sentence"].to_list()],
        s["log_time_ns"].to_numpy(),
        source_file="t",
        topic="/ais/nmea",
    )
    assert rejects.num_rows == 0
    ais = pl.from_arrow(rep)
    j = ais.join_asof(
        scenario.truth.sort("time_ns").select(
            "time_ns", "mmsi", pl.col("lat_deg").alias("tl"), pl.col("lon_deg").alias("tn")
        ),
        on="time_ns",
        by="mmsi",
        strategy="nearest",
        check_sortedness=False,
    )
    e, n = geodetic_to_enu(
        j["lat_deg"].to_numpy(), j["lon_deg"].to_numpy(), j["tl"].to_numpy(), j["tn"].to_numpy()
    )
    err = np.hypot(e, n)
    assert np.median(err) < 10.0 and np.quantile(err, 0.99) < 20.0


def test_archive_has_the_channel_conventions(cfg, scenario, tmp_path):
    files = run_simulate("gaps", DURATION_S, SEED, tmp_path, cfg, start_ns=DEFAULT_START_NS)
    assert [f.name for f in files] == ["gaps_20260115T000000Z.mcap"]
    sc = scenario
    with files[0].open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {
            c.topic: (c.message_encoding, summary.schemas.get(c.schema_id))
            for c in summary.channels.values()
        }
        counts = {
            summary.channels[k].topic: v
            for k, v in summary.statistics.channel_message_counts.items()
        }
        first = next(m for _, c, m in reader.iter_messages(topics=["/truth/vessels"]))
    assert set(topics) == {"/ais/nmea", "/truth/vessels"}
    assert topics["/ais/nmea"] == ("nmea0183", None)
    assert topics["/truth/vessels"][1].name == "surveil.TruthState"
    assert counts == {"/ais/nmea": sc.ais_sentences.height, "/truth/vessels": sc.truth.height}
    assert set(json.loads(first.data)) >= {"vessel_id", "mmsi", "time_ns", "lat_deg"}


def test_whole_chain_writes_gap_forecasts_and_the_reports_read_them(cfg, tmp_path):
    """simulate -> MCAP -> ingest -> Delta -> batch (every family) -> DuckDB reports."""
    from jobs.batch import run_batch
    from pipeline.ingest.driver import run_ingest
    from pipeline.reports import run_named_report
    from pipeline.warehouse.delta import read_table

    duration = DURATION_S
    files = run_simulate(
        "gaps", duration, SEED, tmp_path / "archive", cfg, start_ns=DEFAULT_START_NS
    )
    wh = tmp_path / "warehouse"
    ingest = run_ingest(files, cfg, wh, executor="serial")
    assert ingest.exit_code == 0, ingest.render()
    end = DEFAULT_START_NS + int(duration * NS)
    batch = run_batch(cfg, wh, start_ns=DEFAULT_START_NS, end_ns=end, executor_kind="serial")
    assert batch.exit_code == 0, batch.render()
    f = pl.from_arrow(read_table(wh, "gap_forecasts"))
    assert batch.rows["gap_forecasts"] == f.height > 5
    assert f["forecast_time_ns"].is_between(DEFAULT_START_NS, end, closed="left").all()
    assert (f["reference"] == "truth").all()
    assert f["true_zone_probability"].is_not_null().all()
    listing = run_named_report(wh, "gap_forecasts", start_ns=DEFAULT_START_NS, end_ns=end)
    assert listing.num_rows == f.height
    calib = pl.from_arrow(
        run_named_report(wh, "gap_forecast_calibration", start_ns=DEFAULT_START_NS, end_ns=end)
    )
    assert calib["forecasts"].sum() == f.height
    assert calib["in_region90_share"].is_between(0.0, 1.0).all()
    # a sector filter keeps only forecasts whose mean lies in that sector
    inner = run_named_report(
        wh, "gap_forecasts", start_ns=DEFAULT_START_NS, end_ns=end, sector="inner_channel"
    )
    assert inner.num_rows == f.filter(pl.col("sector") == "inner_channel").height
