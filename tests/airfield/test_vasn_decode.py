"""VASN JSON reports -> airfield_obs and airfield reference states -> airfield_truth."""

from __future__ import annotations

import json

import numpy as np
import polars as pl

from pipeline.decode.registry import CHANNEL_DECODERS, RAW_TABLES, decoder_kind
from pipeline.decode.vasn import decode_airfield_truth, decode_vasn_reports
from pipeline.tables import schema
from pipeline.units import NS


def vasn(i: int, **over) -> bytes:
    doc = {"sensor_id": "VASN1", "track_id": 2000 + i, "time_ns": 1_768_435_200 * NS + i * NS,
           "x_m": 10.5 + i, "y_m": -3.25, "vx_mps": 7.125, "vy_mps": -0.5, "sigma_x_m": 2.4,
           "sigma_y_m": 2.2, "last": False}
    doc.update(over)
    return json.dumps(doc).encode()


def test_registered_for_its_schema_names():
    assert decoder_kind("json", "jsonschema", "surveil.VasnReport") == "vasn"
    assert decoder_kind("json", "jsonschema", "surveil.AirfieldTruth") == "airfield_truth"
    assert {"vasn", "airfield_truth"} <= set(CHANNEL_DECODERS)
    assert "airfield_truth" in RAW_TABLES


def test_vasn_reports_become_airfield_obs_rows():
    payloads = [vasn(i) for i in range(3)]
    t = np.arange(3, dtype=np.int64) + 5
    rows, rejects = decode_vasn_reports(payloads, t, source_file="f.mcap", topic="/a/VASN1/vasn")
    assert rejects.num_rows == 0 and rows.schema == schema("airfield_obs")
    df = pl.from_arrow(rows)
    assert df["sensor_kind"].to_list() == ["vasn"] * 3
    assert df["track_number"].to_list() == [2000, 2001, 2002]
    np.testing.assert_array_equal(df["x_m"], [10.5, 11.5, 12.5])
    assert df["vx_mps"].to_list() == [7.125] * 3 and df["log_time_ns"].to_list() == [5, 6, 7]
    assert df["asterix_category"].null_count() == 3


def test_channel_metadata_names_the_sensor():
    rows, _ = decode_vasn_reports([vasn(0)], np.array([1]), source_file="f", topic="t",
                                  sensor_id="VASN-EAST")
    assert rows["sensor_id"].to_pylist() == ["VASN-EAST"]


def test_bad_vasn_payloads_are_rejected_with_reasons():
    payloads = [vasn(0), vasn(1, x_m=None), b"{not json", vasn(3, sigma_x_m=-1.0),
                vasn(4, vx_mps="fast")]
    rows, rejects = decode_vasn_reports(payloads, np.arange(5), source_file="f", topic="t")
    assert rows.num_rows == 1
    rej = pl.from_arrow(rejects).sort("log_time_ns")
    assert rej["log_time_ns"].to_list() == [1, 2, 3, 4]
    assert "missing required field 'x_m'" in rej["reason"][0]
    assert rej["reason_code"][1] == "undecodable"
    assert "sigma_x_m" in rej["reason"][2]
    assert rej["raw"][0] == payloads[1]


def test_reference_states_become_airfield_truth_rows():
    doc = {"time_ns": 7, "target_id": 3, "kind": "vehicle", "callsign": "VEH01",
           "target_address": 0x4B0001, "lat_deg": 46.43, "lon_deg": 30.67, "vx_mps": 1.0,
           "vy_mps": 0.0, "engines_on": True, "transponder_on": True}
    bad = {**doc, "lat_deg": 123.0}
    payloads = [json.dumps(doc).encode(), json.dumps(bad).encode()]
    rows, rejects = decode_airfield_truth(payloads, np.array([7, 8]), source_file="f",
                                          topic="/airfield/truth")
    assert rows.num_rows == 1 and rejects.num_rows == 1
    assert rows.schema == schema("airfield_truth")
    assert pl.from_arrow(rows)["callsign"].to_list() == ["VEH01"]
    assert "lat_deg=123.0 outside" in rejects["reason"][0].as_py()
