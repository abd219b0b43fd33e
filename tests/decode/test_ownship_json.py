"""pipeline.decode.ownship: gyro-signal and own-ship truth JSON -> raw tables + rejects."""

from __future__ import annotations

import json

import numpy as np
import polars as pl

from pipeline.decode.ownship import decode_gyro_signals, decode_ownship_truth
from pipeline.decode.registry import decoder_kind


def _gyro(**kw) -> bytes:
    d = {"time_ns": 5, "accel_signal_rad": 0.01, "amplifier_rad": -0.002, "interval_s": 1.0}
    d.update(kw)
    return json.dumps(d).encode()


def test_registry_routes_the_schemas():
    assert decoder_kind("json", "jsonschema", "surveil.GyroSignals") == "gyro_signals"
    assert decoder_kind("json", "jsonschema", "surveil.OwnshipTruth") == "ownship_truth"


def test_gyro_signals_rows_rejects_and_platform():
    payloads = [
        _gyro(),
        _gyro(platform_id="payload-ship"),
        b"{not json",
        _gyro(interval_s=0.0),
        _gyro(amplifier_rad=3.0),
        json.dumps({"time_ns": 9, "accel_signal_rad": 0.1}).encode(),  # missing fields
    ]
    log = np.arange(10, 16, dtype=np.int64)
    rows, rejects = decode_gyro_signals(payloads, log, source_file="f", topic="/g",
                                        platform_id=None)
    r = pl.from_arrow(rows)
    assert r["log_time_ns"].to_list() == [10, 11]
    assert r["platform_id"].to_list() == ["/g", "payload-ship"]  # topic when none given
    rj = pl.from_arrow(rejects).sort("log_time_ns")
    assert rj["log_time_ns"].to_list() == [12, 13, 14, 15]
    assert rj["reason_code"].to_list() == ["undecodable", "out_of_range", "out_of_range",
                                           "out_of_range"]
    assert "interval_s" in rj["reason"][1] and "amplifier_rad" in rj["reason"][2]
    assert rj["raw"][0] == b"{not json"
    rows2, _ = decode_gyro_signals(payloads[:2], log[:2], source_file="f", topic="/g",
                                   platform_id="meta-ship")
    assert pl.from_arrow(rows2)["platform_id"].to_list() == ["meta-ship", "meta-ship"]


def test_truth_validation():
    good = {"time_ns": 1, "lat_deg": 46.3, "lon_deg": 30.7, "heading_rad": 1.0,
            "gyro_error_rad": 0.01, "speed_water_mps": 9.0, "sog_mps": 9.1, "cog_rad": 1.0,
            "accel_mps2": 0.0, "roll_rad": 0.1, "current_east_mps": 0.2,
            "current_north_mps": -0.1}
    bad_lat = {**good, "lat_deg": 95.0}
    nan = json.dumps(good).replace("0.1,", "NaN,", 1).encode()  # roll_rad: NaN token
    rows, rejects = decode_ownship_truth(
        [json.dumps(good).encode(), json.dumps(bad_lat).encode(), nan],
        np.array([1, 2, 3]), source_file="f", topic="/t", platform_id="ship")
    assert rows.num_rows == 1 and rows["platform_id"][0].as_py() == "ship"
    assert sorted(pl.from_arrow(rejects)["log_time_ns"].to_list()) == [2, 3]
