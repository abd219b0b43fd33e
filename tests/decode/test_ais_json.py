"""surveil.AisReport JSON (AIS CSV imports) -> ais_reports / ais_static / rejects:
not-available codes, non-vessel stations, damaged payloads (pipeline/decode/ais_json.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pipeline.decode.ais_json import KNOT_MPS, decode_ais_json
from pipeline.tables import schema

T0 = 1_527_811_200 * 10**9


def doc(**kw) -> bytes:
    base = {
        "time_ns": T0,
        "mmsi": 215810000,
        "lat_deg": 55.9,
        "lon_deg": 17.3,
        "sog_kn": 12.5,
        "cog_deg": 255.5,
        "heading_deg": 256.0,
        "source_format": "dma_aisdk",
        "raw": "r",
    }
    return json.dumps({**base, **kw}).encode()  # fmt: skip


def run(payloads: list[bytes]):
    t = T0 + np.arange(len(payloads), dtype=np.int64)
    return decode_ais_json(payloads, t, source_file="/a/x.csv.mcap", topic="/ais/csv")


def test_units_and_defaults():
    (tables, not_stored) = run([doc(ais_class=None, nav_status=5)])
    (r,) = tables["ais_reports"].to_pylist()
    assert tables["ais_reports"].schema == schema("ais_reports") and not_stored == {}
    assert r["sog_mps"] == pytest.approx(12.5 * KNOT_MPS)
    assert r["cog_rad"] == pytest.approx(math.radians(255.5))
    assert r["heading_rad"] == pytest.approx(math.radians(256))
    assert (r["msg_type"], r["ais_class"], r["nav_status"], r["nmea"]) == (0, "A", 5, "r")
    assert r["time_ns"] == T0 and r["log_time_ns"] == T0


def test_not_available_codes_become_null():
    (tables, _) = run([doc(sog_kn=102.3, cog_deg=360.0, heading_deg=511.0, ais_class="B")])
    (r,) = tables["ais_reports"].to_pylist()
    assert (r["sog_mps"], r["cog_rad"], r["heading_rad"], r["ais_class"]) == (None, None, None, "B")


def test_static_rows_and_their_codes():
    (tables, _) = run([doc(shipname="NAME A", imo=0, ship_type=70, callsign="OW2"), doc()])
    (s,) = tables["ais_static"].to_pylist()
    assert (s["shipname"], s["imo"], s["ship_type"], s["callsign"]) == ("NAME A", None, 70, "OW2")
    (tables, _) = run([doc(shipname="X", ship_type=0)])
    assert tables["ais_static"].to_pylist()[0]["ship_type"] is None


def test_rejects_and_non_vessel_stations():
    payloads = [
        doc(lat_deg=91.0, lon_deg=181.0),
        doc(lat_deg=None),
        doc(lat_deg=123.0),
        doc(sog_kn=900.0),
        doc(mmsi=None),
        b"{not json",
        doc(mobile_type="Base Station"),
        doc(mobile_type="AtoN"),
        doc(shipname="KEPT", lat_deg=91.0, lon_deg=181.0),
    ]
    (tables, not_stored) = run(payloads)
    rej = tables["rejects"].to_pylist()
    assert [r["reason_code"] for r in sorted(rej, key=lambda r: r["log_time_ns"])] == [
        "no_position", "no_position", "out_of_range", "out_of_range", "undecodable",
        "undecodable", "no_position",
    ]  # fmt: skip
    assert not_stored == {}  # stations that are not vessels: their own table (issue 36)
    other = tables["ais_other_messages"].to_pylist()
    assert [(r["msg_type"], r["ais_class"]) for r in other] == [(4, "base_station"),
                                                                (21, "aton")]
    assert tables["ais_reports"].num_rows == 0
    assert [s["shipname"] for s in tables["ais_static"].to_pylist()] == ["KEPT"]
    assert b"{not json" in [r["raw"] for r in rej]
