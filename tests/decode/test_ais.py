"""AIS decoder: real samples, multi-part assembly, every reject reason, SI conversions,
not-available codes, carry-over across batches, and the pyais sample file's exact counts."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest
from mcap_fixtures import (
    AIS_EMPTY,
    AIS_TYPE1,
    AIS_TYPE3,
    AIS_TYPE18,
    T0_NS,
    TYPE5_FRAGMENTS,
    nmea,
    real_data_root,
)
from pyais.encode import encode_dict

from pipeline.decode.ais import KNOT_MPS, decode_ais, decode_ais_sentences
from pipeline.tables import schema

SRC, TOPIC = "/arch/f.mcap", "/ais/nmea"


def enc(seq_id: int | None = None, **fields) -> list[bytes]:
    out = encode_dict(fields, talker_id="AI", sentence_type="VDM", radio_channel="B", seq_id=seq_id)
    return [s.encode() for s in out]


def times(n: int) -> np.ndarray:
    return T0_NS + np.arange(n, dtype=np.int64) * 10**6


def run(sentences: list[bytes], **kw):
    return decode_ais(sentences, times(len(sentences)), source_file=SRC, topic=TOPIC, **kw)


def test_real_position_reports():
    out = run([AIS_TYPE1, AIS_TYPE3, AIS_TYPE18])
    assert out.rejects.num_rows == 0 and out.reports.schema == schema("ais_reports")
    rows = {r["msg_type"]: r for r in out.reports.to_pylist()}
    r1 = rows[1]  # pyais: MessageType1(mmsi=244670316, lat=52.3, lon=4.85...)
    assert r1["ais_class"] == "A" and rows[18]["ais_class"] == "B"
    assert r1["radio_channel"] == "A" and rows[18]["radio_channel"] == "B"
    assert r1["nmea"] == AIS_TYPE1.decode()
    assert r1["source_file"] == SRC and r1["topic"] == TOPIC
    assert r1["time_ns"] == r1["log_time_ns"] == T0_NS
    for r in rows.values():
        assert -90 <= r["lat_deg"] <= 90 and -180 <= r["lon_deg"] <= 180


def test_units_and_not_available_codes():
    good = enc(
        msg_type=1,
        mmsi=211000001,
        lat=54.5,
        lon=10.25,
        speed=12.3,
        course=90.0,
        heading=45,
        second=30,
        status=5,
        accuracy=1,
    )
    na = enc(
        msg_type=1,
        mmsi=211000002,
        lat=54.0,
        lon=10.0,
        speed=102.3,
        course=360.0,
        heading=511,
        second=60,
        status=0,
    )
    out = run(good + na)
    rows = {r["mmsi"]: r for r in out.reports.to_pylist()}
    g, n = rows[211000001], rows[211000002]
    assert g["sog_mps"] == pytest.approx(12.3 * 1852 / 3600)
    assert g["cog_rad"] == pytest.approx(math.pi / 2)
    assert g["heading_rad"] == pytest.approx(math.radians(45))
    assert g["utc_second"] == 30 and g["nav_status"] == 5 and g["position_accuracy"] is True
    assert g["lat_deg"] == pytest.approx(54.5) and g["lon_deg"] == pytest.approx(10.25)
    assert n["sog_mps"] is None and n["cog_rad"] is None and n["heading_rad"] is None
    assert n["utc_second"] is None


def test_type27_scaling_and_codes():
    out = run(
        enc(msg_type=27, mmsi=211000005, lat=54.5, lon=10.25, speed=12, course=270, status=1)
        + enc(msg_type=27, mmsi=211000006, lat=54.5, lon=10.25, speed=63, course=511, status=1)
    )
    rows = {r["mmsi"]: r for r in out.reports.to_pylist()}
    assert rows[211000005]["sog_mps"] == pytest.approx(12 * KNOT_MPS)
    assert rows[211000005]["cog_rad"] == pytest.approx(math.radians(270))
    assert rows[211000005]["lat_deg"] == pytest.approx(54.5)
    assert rows[211000006]["sog_mps"] is None and rows[211000006]["cog_rad"] is None
    assert rows[211000006]["heading_rad"] is None and rows[211000006]["utc_second"] is None


def test_multipart_type5_assembled_time_of_last_fragment():
    sentences = [AIS_TYPE1, *TYPE5_FRAGMENTS, AIS_TYPE3]
    reports, static, rejects = decode_ais_sentences(
        sentences, times(4), source_file=SRC, topic=TOPIC
    )
    assert rejects.num_rows == 0 and reports.num_rows == 2
    (s,) = static.to_pylist()
    assert s["msg_type"] == 5 and s["mmsi"] == 351759000 and s["imo"] == 9134270
    assert s["shipname"] == "EVER DIADEM" and s["callsign"] == "3FOF8"
    assert s["destination"] == "NEW YORK" and s["ship_type"] == 70
    assert (s["to_bow_m"], s["to_stern_m"], s["to_port_m"], s["to_starboard_m"]) == (225, 70, 1, 31)
    assert s["time_ns"] == s["log_time_ns"] == times(4)[2]
    assert s["nmea"] == b"\n".join(TYPE5_FRAGMENTS).decode()


def test_type19_and_type24_go_to_static():
    t19 = enc(
        msg_type=19,
        mmsi=211000003,
        lat=54.0,
        lon=10.0,
        speed=1.0,
        course=10.0,
        heading=20,
        shipname="SAILOR",
        ship_type=37,
        to_bow=5,
        to_stern=6,
        to_port=2,
        to_starboard=2,
    )
    t24a = enc(msg_type=24, mmsi=211000007, partno=0, shipname="PART A")
    t24b = enc(
        msg_type=24,
        mmsi=211000007,
        partno=1,
        ship_type=36,
        callsign="PB123",
        to_bow=4,
        to_stern=5,
        to_port=1,
        to_starboard=1,
    )
    out = run(t19 + t24a + t24b)
    assert out.reports.column("mmsi").to_pylist() == [211000003]
    static = {(r["mmsi"], r["msg_type"], r["shipname"]): r for r in out.static.to_pylist()}
    assert static[(211000003, 19, "SAILOR")]["ship_type"] == 37
    assert static[(211000007, 24, "PART A")]["callsign"] is None
    b = static[(211000007, 24, None)]
    assert b["callsign"] == "PB123" and b["to_bow_m"] == 4 and b["ship_type"] == 36


def test_other_types_go_to_their_own_table_not_rejected():
    out = run([*enc(msg_type=4, mmsi=2110000), AIS_TYPE1])
    assert out.not_stored == {} and out.rejects.num_rows == 0 and out.reports.num_rows == 1
    (row,) = out.other.to_pylist()
    assert (row["mmsi"], row["msg_type"], row["ais_class"]) == (2110000, 4, "base_station")


def _reject(sentences):
    out = run(sentences)
    return [(r["reason_code"], r["reason"], r["raw"]) for r in out.rejects.to_pylist()], out


def test_bad_checksum():
    bad = AIS_TYPE1[:-2] + b"00"
    (rej,), out = _reject([bad, AIS_TYPE3])
    assert rej[0] == "bad_checksum" and rej[2] == bad and out.reports.num_rows == 1
    (rej,), _ = _reject([AIS_TYPE1.split(b"*")[0]])  # no checksum at all
    assert rej[0] == "bad_checksum"


def test_truncated_multipart_variants():
    f1, f2 = TYPE5_FRAGMENTS
    (rej,), _ = _reject([f1])  # group never completed
    assert rej[0] == "truncated_multipart" and "1 of 2" in rej[1] and rej[2] == f1
    (rej,), _ = _reject([f2])  # second fragment alone
    assert rej[0] == "truncated_multipart" and "without its preceding" in rej[1]
    rejs, out = _reject([f1, f1, f2])  # restarted group: first one incomplete
    assert [r[0] for r in rejs] == ["truncated_multipart"] and out.static.num_rows == 1
    rejs, out = _reject([f1] + [AIS_TYPE1] * 9 + [f2])  # fragment too late
    assert sorted(r[0] for r in rejs) == ["truncated_multipart"] * 2
    assert out.reports.num_rows == 9 and out.static.num_rows == 0


def test_multipart_interleaved_with_other_sentences():
    f1, f2 = TYPE5_FRAGMENTS
    out = run([f1, AIS_TYPE1, AIS_TYPE18, f2])
    assert out.rejects.num_rows == 0 and out.static.num_rows == 1 and out.reports.num_rows == 2


def test_fragment_with_bad_checksum_breaks_its_group():
    f1, f2 = TYPE5_FRAGMENTS
    rejs, out = _reject([f1, f2[:-2] + b"00"])
    assert sorted(r[0] for r in rejs) == ["bad_checksum", "truncated_multipart"]
    assert out.static.num_rows == 0


def test_positions_not_available_or_impossible():
    rejs, out = _reject(
        enc(msg_type=1, mmsi=211000010, lat=91.0, lon=181.0)
        + enc(msg_type=1, mmsi=211000011, lat=100.0, lon=10.0)
        + enc(msg_type=1, mmsi=211000012, lat=10.0, lon=200.0)
        + enc(msg_type=1, mmsi=211000013, lat=-100.0, lon=10.0)
    )
    assert [(c, r) for c, r, _ in rejs] == [
        ("no_position", "position not available (lat 91, lon 181)"),
        ("out_of_range", "lat_deg=100 outside [-90, 90]"),
        ("out_of_range", "lon_deg=200 outside [-180, 180]"),
        ("out_of_range", "lat_deg=-100 outside [-90, 90]"),
    ]
    assert out.reports.num_rows == 0


def test_type19_without_position_keeps_static():
    rejs, out = _reject(enc(msg_type=19, mmsi=211000003, lat=91, lon=181, shipname="NOPOS"))
    assert [c for c, _, _ in rejs] == ["no_position"]
    assert out.static.column("shipname").to_pylist() == ["NOPOS"]


def test_unsupported_and_undecodable():
    type30 = nmea("AIVDM,1,1,,A,N0000000000000000000000000000,0")
    not_ais = b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A"
    too_short = nmea("AIVDM,1,1,,A,13RlIW?04F,0")
    rejs, out = _reject([type30, not_ais, AIS_EMPTY, too_short, b"garbage", b""])
    codes = [c for c, _, _ in rejs]
    assert codes == [
        "unsupported_type",
        "unsupported_type",
        "undecodable",
        "undecodable",
        "unsupported_type",
        "undecodable",
    ], rejs
    assert out.reports.num_rows == 0 and out.not_stored == {}


def test_tag_block_accepted():
    tagged = b"\\s:42809,c:1635731889*6A\\" + AIS_TYPE1
    out = run([tagged])
    assert out.reports.num_rows == 1 and out.rejects.num_rows == 0


def test_carry_over_between_batches_equals_one_batch():
    f1, f2 = TYPE5_FRAGMENTS
    all_s = [AIS_TYPE1, AIS_TYPE3, f1, f2, AIS_TYPE18]
    t = times(len(all_s))
    whole = decode_ais(all_s, t, source_file=SRC, topic=TOPIC)
    first = decode_ais(all_s[:3], t[:3], source_file=SRC, topic=TOPIC, final=False)
    assert first.carry == 1 and first.rejects.num_rows == 0 and first.static.num_rows == 0
    k = 3 - first.carry
    second = decode_ais(all_s[k:], t[k:], source_file=SRC, topic=TOPIC, final=True)
    assert first.reports.num_rows + second.reports.num_rows == whole.reports.num_rows
    assert second.static.equals(whole.static)


@pytest.mark.realdata
def test_pyais_sample_file_exact_counts(real_ais_sample):
    lines = [ln for ln in real_ais_sample.read_bytes().splitlines() if ln.strip()]
    # 898 !AIVDM lines: 100 with an empty payload, 20 first fragments whose second
    # fragment is absent from the file (no ",2,2," line), the rest single sentences.
    assert len(lines) == 898
    assert sum(1 for ln in lines if ln.split(b",")[5] == b"") == 100
    assert sum(1 for ln in lines if ln.startswith(b"!AIVDM,2,1,")) == 20
    assert not any(ln.startswith(b"!AIVDM,2,2,") for ln in lines)
    out = run(lines)
    assert Counter(out.reports.column("msg_type").to_pylist()) == {1: 663, 3: 76, 18: 19}
    assert Counter(out.static.column("msg_type").to_pylist()) == {24: 2}
    assert Counter(out.rejects.column("reason_code").to_pylist()) == {
        "undecodable": 100,  # empty payload
        "truncated_multipart": 20,
        "no_position": 4,  # type 1 with lat 91 / lon 181
    }
    assert out.not_stored == {}
    assert Counter(out.other.column("msg_type").to_pylist()) == {4: 6, 15: 7, 20: 1}
    n_out = (out.reports.num_rows + out.static.num_rows + out.rejects.num_rows
             + out.other.num_rows)
    assert n_out == 898  # every sentence accounted for


@pytest.fixture()
def real_ais_sample():
    path = real_data_root() / "ais" / "pyais_nmea_data_sample.txt"
    if not path.is_file():
        pytest.skip(f"real data absent: {path} not found (set SURVEIL_REAL_DATA)")
    return path
