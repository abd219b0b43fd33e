"""JSON ``foxglove.LocationFix`` channels (bulk ndjson parse with a per-payload fallback)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.decode.foxglove import FixContext, decode_location_fix_json
from pipeline.decode.registry import decoder_kind
from pipeline.units import NS

T0 = 1_772_359_200 * NS
CTX = FixContext("f.mcap", "/gps", "vessel1", "LocationFix")


def payload(t_ns: int | None, lat, lon, **extra) -> bytes:
    obj = {"frame_id": "gps", "latitude": lat, "longitude": lon, "altitude": 2.0,
           "position_covariance": [0.25, 0, 0, 0, 1.0, 0, 0, 0, 4.0],
           "position_covariance_type": 2, "color": {"r": 1, "g": 0, "b": 0, "a": 1}}  # fmt: skip
    if t_ns is not None:
        obj["timestamp"] = {"sec": t_ns // NS, "nsec": t_ns % NS}
    obj.update(extra)
    return json.dumps(obj).encode()


def test_registry_kind():
    assert decoder_kind("json", "jsonschema", "foxglove.LocationFix") == "foxglove_json"


def test_bulk_parse_maps_every_field():
    payloads = [payload(T0 + k * NS + 11, 59.0 + k * 1e-6, 18.0) for k in range(100)]
    log = np.arange(100, dtype=np.int64) * NS + T0 + 999
    table, rejects = decode_location_fix_json(payloads, log, CTX)
    assert rejects.num_rows == 0
    rows = table.to_pylist()
    assert [r["time_ns"] for r in rows] == [T0 + k * NS + 11 for k in range(100)]
    assert rows[5]["lat_deg"] == 59.0 + 5e-6 and rows[5]["altitude_m"] == 2.0
    assert (rows[0]["sigma_lon_m"], rows[0]["sigma_lat_m"]) == (0.5, 1.0)
    assert rows[0]["platform_id"] == "vessel1" and rows[0]["log_time_ns"] == T0 + 999


def test_bad_payloads_are_found_and_the_rest_kept():
    payloads = [
        payload(T0, 10.0, 20.0),
        b"{not json",
        payload(T0 + 1, 10.0, 20.0, latitude="north"),  # wrong type
        b"[1, 2]",
        payload(None, 95.0, 20.0),  # out of range
        payload(None, 11.0, 21.0, position_covariance_type=0),
        json.dumps({"timestamp": {"sec": 5, "nanosec": 7}, "latitude": 1.0, "longitude": 2.0})
        .encode(),
    ]
    log = T0 + np.arange(len(payloads), dtype=np.int64)
    table, rejects = decode_location_fix_json(payloads, log, CTX)
    rows = {r["lat_deg"]: r for r in table.to_pylist()}  # rows come sorted by time_ns
    assert sorted(rows) == [1.0, 10.0, 11.0]
    assert rows[11.0]["time_ns"] == T0 + 5 and rows[11.0]["sigma_lat_m"] is None
    assert rows[1.0]["time_ns"] == 5 * NS + 7 and rows[1.0]["altitude_m"] is None
    rej = sorted(rejects.to_pylist(), key=lambda r: r["log_time_ns"])
    assert [(r["log_time_ns"] - T0, r["reason_code"]) for r in rej] == [
        (1, "undecodable"), (2, "undecodable"), (3, "undecodable"), (4, "out_of_range"),
    ]
    assert rej[0]["raw"] == b"{not json"


@pytest.mark.slow
def test_bulk_json_rate():
    """JSON LocationFix -> nav_gnss rows in one bulk parse (printed with ``-s``)."""
    import time

    n = 200_000
    payloads = [payload(T0 + i * NS, 50 + i * 1e-7, 30.0) for i in range(n)]
    log = T0 + np.arange(n, dtype=np.int64)
    t = time.perf_counter()
    table, _ = decode_location_fix_json(payloads, log, CTX)
    dt = time.perf_counter() - t
    assert table.num_rows == n
    print(f"\nJSON LocationFix -> nav_gnss: {n / dt:,.0f} msg/s ({dt:.2f} s)")
