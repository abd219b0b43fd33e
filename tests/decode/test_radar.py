"""Radar report decoder: column mapping, provenance, every reject reason, bulk vs fallback."""

from __future__ import annotations

import math

import numpy as np
import pyarrow as pa
import pytest
from mcap_fixtures import T0_NS, dumps, radar_report

from pipeline.config import ValidationConfig
from pipeline.decode.radar import decode_radar_reports
from pipeline.tables import schema

VAL = ValidationConfig(max_speed_mps=40.0, max_range_m=60000.0)
TOPIC = "/radar/R1/tracks"


def decode(payloads: list[bytes]) -> tuple[pa.Table, pa.Table]:
    t = T0_NS + np.arange(len(payloads), dtype=np.int64) * 1000
    return decode_radar_reports(payloads, t, source_file="/a/f.mcap", topic=TOPIC, validation=VAL)


def test_good_rows_mapped_with_provenance():
    reps = [radar_report(i) for i in range(20)]
    rows, rejects = decode([dumps(r) for r in reps])
    assert rejects.num_rows == 0 and rows.schema == schema("radar_tracks")
    got = sorted(rows.to_pylist(), key=lambda r: r["time_ns"])
    for i, (row, rep) in enumerate(zip(got, reps, strict=True)):
        assert row["local_track_id"] == rep["track_id"]
        assert row["x_site_m"] == rep["x_m"] and row["y_site_m"] == rep["y_m"]
        assert row["range_m"] == rep["range_m"] and row["azimuth_rad"] == rep["azimuth_rad"]
        assert row["time_ns"] == rep["time_ns"] and row["site_id"] == "R1"
        assert row["source_file"] == "/a/f.mcap" and row["topic"] == TOPIC
        assert row["log_time_ns"] == T0_NS + i * 1000
        assert str(row["date"]) == "2026-01-01"


def _missing(field: str) -> bytes:
    r = radar_report(0)
    del r[field]
    return dumps(r)


BAD = [
    (dumps(radar_report(1, range_m=math.nan)), "out_of_range", "non-finite value in 'range_m'"),
    (dumps(radar_report(2, course_rad=math.inf)), "out_of_range", "non-finite"),
    (b'{"site_id":"R1","track_id":1,"x_m":1e999}', "out_of_range", "non-finite"),
    (dumps(radar_report(3, range_m=-1.0)), "out_of_range", "range_m=-1.0 outside [0, 60000]"),
    (dumps(radar_report(4, range_m=60001.0)), "out_of_range", "range_m=60001.0 outside"),
    (dumps(radar_report(5, azimuth_rad=-0.1)), "out_of_range", "azimuth_rad=-0.1 outside"),
    (dumps(radar_report(6, azimuth_rad=6.3)), "out_of_range", "azimuth_rad=6.3 outside"),
    (dumps(radar_report(7, speed_mps=-0.5)), "out_of_range", "speed_mps=-0.5 outside"),
    (dumps(radar_report(8, speed_mps=41.0)), "out_of_range", "speed_mps=41.0 outside [0, 40]"),
    (dumps(radar_report(9, sigma_range_m=0.0)), "out_of_range", "sigma_range_m=0.0 outside (0"),
    (dumps(radar_report(9, sigma_azimuth_rad=-1e-3)), "out_of_range", "sigma_azimuth_rad"),
    (_missing("sigma_speed_mps"), "out_of_range", "missing required field 'sigma_speed_mps'"),
    (_missing("site_id"), "out_of_range", "missing required field 'site_id'"),
    (dumps(radar_report(10, range_m=None)), "out_of_range", "missing required field 'range_m'"),
    (b'{"site_id":"R1","track_id":', "undecodable", "invalid JSON"),
    (b"", "undecodable", "empty payload"),
    (b"[1, 2, 3]", "undecodable", "JSON list where an object was expected"),
    (dumps(radar_report(11, range_m="far")), "undecodable", "wrong field type"),
    (dumps(radar_report(12, track_id=1.5)), "undecodable", "wrong field type"),
    (b"\xff\xfe garbage", "undecodable", "invalid JSON"),
]


@pytest.mark.parametrize(("payload", "code", "reason"), BAD)
def test_each_reject_reason(payload, code, reason):
    good = [dumps(radar_report(i)) for i in range(3)]
    rows, rejects = decode([*good[:2], payload, good[2]])
    assert rows.num_rows == 3
    (rej,) = rejects.to_pylist()
    assert rej["reason_code"] == code
    assert reason in rej["reason"], rej["reason"]
    assert rej["raw"] == payload  # raw bytes kept
    assert rej["log_time_ns"] == T0_NS + 2 * 1000
    assert rej["topic"] == TOPIC and rej["stage"] == "ingest"


def test_several_failed_checks_all_named():
    _, rejects = decode([dumps(radar_report(0, range_m=-5.0, speed_mps=99.0))])
    (rej,) = rejects.to_pylist()
    assert "range_m=-5.0" in rej["reason"] and "speed_mps=99.0" in rej["reason"]


def test_fallback_keeps_the_same_good_rows():
    good = [dumps(radar_report(i)) for i in range(50)]
    mixed = good[:25] + [payload for payload, _, _ in BAD] + good[25:]
    rows_good, _ = decode(good)
    rows_mixed, rejects = decode(mixed)
    drop = ["log_time_ns"]
    assert rows_mixed.drop_columns(drop).equals(rows_good.drop_columns(drop))
    assert rejects.num_rows == len(BAD)


def test_empty_batch():
    rows, rejects = decode([])
    assert rows.num_rows == 0 and rejects.num_rows == 0
    assert rows.schema == schema("radar_tracks") and rejects.schema == schema("rejects")


def test_unknown_fields_ignored():
    rows, rejects = decode([dumps(radar_report(0, extra={"a": [1, 2]}, status="lost"))])
    assert rows.num_rows == 1 and rejects.num_rows == 0


def test_pruned_checks_give_the_same_rows_and_reasons():
    """split_valid skips the null tests of columns without nulls and, for a frame known to
    hold no NaN or infinity, the finiteness tests: same rows and reason texts as all
    checks; only a frame that does hold them must not be called finite."""
    import polars as pl

    from pipeline.decode.json_bulk import applicable, split_valid
    from pipeline.decode.radar import RADAR_FIELDS, radar_checks

    rng = np.random.default_rng(5)
    n = 2000
    cols = {
        c: rng.uniform(-0.01, 6.5, n) if t == pl.Float64() else rng.integers(0, 9, n)
        for c, t in RADAR_FIELDS.items()
        if c != "site_id"
    }
    frame = pl.DataFrame({"site_id": ["R1"] * n, **cols, "_idx": np.arange(n)})
    frame = frame.with_columns(  # a few nulls in one column, none in the others
        pl.when(pl.col("_idx") % 97 == 0)
        .then(None)
        .otherwise(pl.col("speed_mps"))
        .alias("speed_mps")
    )
    checks = radar_checks(VAL)
    pruned = applicable(frame, checks, finite=True)
    assert len(pruned) < len(checks) // 2
    assert [ck.null_of for ck in pruned if ck.null_of] == ["speed_mps"]
    good_all, bad_all = split_valid(frame, checks)
    good, bad = split_valid(frame, checks, finite=True)
    assert 0 < bad.height < n
    assert good.equals(good_all) and bad.equals(bad_all)

    inf = frame.with_columns(pl.lit(math.inf).alias("range_m"))
    assert split_valid(inf, checks)[0].height == 0
    assert "non-finite value in 'range_m'" in split_valid(inf, checks)[1]["_reason"][0]
