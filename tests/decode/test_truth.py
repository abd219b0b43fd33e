"""Truth decoder: bulk parse, nullable MMSI, rejects (lat 123, NaN, missing, bad JSON)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from mcap_fixtures import T0_NS, dumps, truth_state

from pipeline.decode.truth import decode_truth_states
from pipeline.tables import schema


def decode(payloads):
    t = T0_NS + np.arange(len(payloads), dtype=np.int64)
    return decode_truth_states(payloads, t, source_file="/f.mcap", topic="/truth/vessels")


def test_good_rows_and_null_mmsi():
    rows, rejects = decode([dumps(truth_state(0)), dumps(truth_state(1, vessel=2, mmsi=None))])
    assert rejects.num_rows == 0 and rows.schema == schema("truth")
    by_vessel = {r["vessel_id"]: r for r in rows.to_pylist()}
    assert by_vessel[1]["mmsi"] == 273000001 and by_vessel[2]["mmsi"] is None
    assert by_vessel[2]["log_time_ns"] == T0_NS + 1 and by_vessel[1]["topic"] == "/truth/vessels"


@pytest.mark.parametrize(
    ("payload", "code", "reason"),
    [
        (dumps(truth_state(0, lat_deg=123.0)), "out_of_range", "lat_deg=123.0 outside [-90, 90]"),
        (dumps(truth_state(0, lon_deg=-181.0)), "out_of_range", "lon_deg=-181.0 outside"),
        (dumps(truth_state(0, speed_mps=math.nan)), "out_of_range", "non-finite value"),
        (dumps(truth_state(0, speed_mps=-1.0)), "out_of_range", "speed_mps=-1.0 outside"),
        (dumps(truth_state(0, vessel_id=None)), "out_of_range", "missing required field"),
        (b'{"vessel_id": 1, "time_ns"', "undecodable", "invalid JSON"),
    ],
)
def test_rejects(payload, code, reason):
    rows, rejects = decode([dumps(truth_state(1)), payload])
    assert rows.num_rows == 1
    (rej,) = rejects.to_pylist()
    assert rej["reason_code"] == code and reason in rej["reason"] and rej["raw"] == payload
