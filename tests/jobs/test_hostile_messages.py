"""Issue 18, item 1: no message loses more than itself. Hostile messages written with the
``mcap`` writer: each becomes a rejects row with a reason, every other row is kept."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from mcap_fixtures import AIS_TYPE1, T0_NS, dumps, radar_messages, radar_report, write_mcap

from pipeline.decode.registry import MAX_MESSAGE_BYTES
from pipeline.families import load_config
from pipeline.ingest.driver import run_ingest
from pipeline.warehouse.delta import read_table

DEEP = b'{"a":' * 1000 + b"1" + b"}" * 1000  # 2 KB, 1,000 levels
RADAR = "/radar/R1/tracks"


def _ingest(tmp_path: Path, messages: list, **kw) -> tuple[object, list[dict], int]:
    path = write_mcap(tmp_path / "hostile.mcap", messages, **kw)
    summary = run_ingest([path], load_config(), tmp_path / "wh", executor="serial")
    rejects = read_table(tmp_path / "wh", "rejects").to_pylist()
    radar = read_table(tmp_path / "wh", "radar_tracks").num_rows
    return summary, rejects, radar


def _with_bad(bad: list) -> list:
    msgs = radar_messages(40)
    msgs.append(("/ais/nmea", T0_NS + 3, AIS_TYPE1))
    return sorted(msgs + bad, key=lambda m: m[1])


@pytest.mark.parametrize(
    ("case", "bad", "code"),
    [
        ("deep_json_radar", [(RADAR, T0_NS + 5 * 10**9 + 1, DEEP)], None),
        ("x_site_1e308", [(RADAR, T0_NS + 7 * 10**9 + 1,
                           dumps(radar_report(7, x_m=1e308)))], "out_of_range"),
        ("time_ns_zero", [(RADAR, T0_NS + 7 * 10**9 + 1,
                           dumps(radar_report(7, t_ns=0)))], "out_of_range"),
        ("time_ns_int64_max", [(RADAR, T0_NS + 7 * 10**9 + 1,
                                dumps(radar_report(7, t_ns=2**63 - 1)))], "out_of_range"),
        ("site_id_5mb", [(RADAR, T0_NS + 7 * 10**9 + 1,
                          dumps(radar_report(7, site="R" * (5 << 20))))], "too_large"),
        ("site_id_8kb", [(RADAR, T0_NS + 7 * 10**9 + 1,
                          dumps(radar_report(7, site="R" * 8192)))], "out_of_range"),
        ("log_time_beyond_int64", [(RADAR, 2**63 + 5, dumps(radar_report(3)))], "out_of_range"),
        ("log_time_uint64_max", [(RADAR, 2**64 - 1, dumps(radar_report(3)))], "out_of_range"),
    ],
)  # fmt: skip
def test_one_bad_message_costs_one_row(tmp_path, case, bad, code):
    summary, rejects, radar = _ingest(tmp_path, _with_bad(bad))
    assert not summary.failed, summary.render()
    assert radar == 40, case
    assert summary.rows["ais_reports"] == 1
    assert len(rejects) == 1, rejects
    if code is not None:
        assert rejects[0]["reason_code"] == code, rejects[0]
    assert rejects[0]["topic"] == RADAR
    assert rejects[0]["reason"]


def test_deep_json_on_python_json_channels(tmp_path):
    """AIS JSON falls back to ``json.loads`` (``RecursionError`` at 1,000 levels): that
    message is a rejects row. LocationFix JSON parses it (polars: an object without known
    fields, kept as a fix without position, as before): no failure either way."""
    fix = dumps({"timestamp": {"sec": T0_NS // 10**9, "nsec": 0}, "latitude": 46.4,
                 "longitude": 30.9, "altitude": 1.0, "position_covariance_type": 0})  # fmt: skip
    msgs = _with_bad([])
    extra = {"/gnss/fix": ("json", "foxglove.LocationFix", "jsonschema"),
             "/ais/json": ("json", "surveil.AisReport", "jsonschema")}  # fmt: skip
    for i in range(10):
        msgs.append(("/gnss/fix", T0_NS + i * 10**9 + 2, fix))
    msgs.append(("/gnss/fix", T0_NS + 11 * 10**9 + 2, DEEP))
    msgs.append(("/ais/json", T0_NS + 12 * 10**9 + 2, DEEP))
    msgs.sort(key=lambda m: m[1])
    summary, rejects, radar = _ingest(tmp_path, msgs, extra_channels=extra)
    assert not summary.failed, summary.render()
    assert radar == 40
    assert [r["topic"] for r in rejects] == ["/ais/json"], rejects
    assert summary.rows["nav_gnss"] == 11


def test_decoder_exception_isolated_to_its_message(tmp_path, monkeypatch):
    """Any exception a channel decoder raises on a batch (here an injected
    ``struct.error`` on one payload) is a decode_error row for that message alone."""
    import struct

    from pipeline.decode import nmea

    real = nmea.NmeaChannelDecoder.feed

    def feed(self, batch):
        if any(b"POISON" in p for p in batch.payloads):
            raise struct.error("unpack requires a buffer of 4 bytes")
        return real(self, batch)

    monkeypatch.setattr(nmea.NmeaChannelDecoder, "feed", feed)
    msgs = _with_bad([("/ais/nmea", T0_NS + 4, b"!AIVDM,POISON*00")])
    msgs.append(("/ais/nmea", T0_NS + 6, AIS_TYPE1))
    msgs.sort(key=lambda m: m[1])
    summary, rejects, radar = _ingest(tmp_path, msgs)
    assert summary.rows["ais_reports"] == 2 and radar == 40
    [rej] = rejects
    assert rej["reason_code"] == "decode_error" and "error: unpack requires" in rej["reason"]
    assert rej["raw"] == b"!AIVDM,POISON*00"


def test_message_size_limit_keeps_raw_capped(tmp_path):
    big = b"!" + b"A" * (MAX_MESSAGE_BYTES + 10)
    _, rejects, _ = _ingest(tmp_path, _with_bad([("/ais/nmea", T0_NS + 4, big)]))
    [rej] = rejects
    assert rej["reason_code"] == "too_large" and len(rej["raw"]) == 1024
