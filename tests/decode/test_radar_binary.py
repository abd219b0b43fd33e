"""Protobuf and ROS 2 CDR radar reports: the vectorised codecs agree with the protobuf
runtime and mcap_ros2 both ways; damage is rejected per message; the same reports give the
same radar_tracks rows whether they travel as JSON, protobuf or CDR."""

from __future__ import annotations

import math

import numpy as np
import pyarrow.compute as pc
import pytest
from google.protobuf import descriptor_pool, message_factory
from google.protobuf.descriptor_pb2 import FileDescriptorSet
from mcap.writer import Writer
from mcap_fixtures import NS, T0_NS, dumps, radar_report
from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic

from pipeline.config import ValidationConfig
from pipeline.decode.radar_binary import (
    PROTO_SCHEMA,
    ROS2_SCHEMA,
    RadarBinaryChannelDecoder,
    decode_cdr,
    decode_protobuf,
    encode_cdr,
    encode_protobuf,
    protobuf_fields,
    radar_descriptor_set,
    radar_ros2_text,
    ros2_fields,
)
from pipeline.ingest.driver import run_ingest
from pipeline.io.mcap_read import ChannelBatch
from pipeline.warehouse.delta import read_table

FIELDS = list(radar_report(0))  # the JSON report's fields, schema order


def proto_class():
    pool = descriptor_pool.DescriptorPool()
    for f in FileDescriptorSet.FromString(radar_descriptor_set()).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(PROTO_SCHEMA))


def reports(n: int) -> list[dict]:
    out = [radar_report(i, track_id=(i * 7919) % 5000 - 2500) for i in range(n)]
    out[1]["speed_mps"] = 0.0  # a proto3 default: not on the wire, decoded as 0.0
    out[2]["status"] = ""
    out[3]["site_id"] = "Ümit-Süd"  # UTF-8
    out[4]["time_ns"] = -(2**62)  # a 10-byte varint
    return out


def as_columns(reps: list[dict]) -> dict:
    cols = {k: [r[k] for r in reps] for k in FIELDS}
    return {k: (v if isinstance(v[0], str) else np.asarray(v)) for k, v in cols.items()}


def buffer(payloads: list[bytes]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    b = ChannelBatch(1, "/t", "x", "", "", b"", np.zeros(len(payloads), np.int64), payloads)
    chunk, start, end = b.spans()
    return chunk.padded(), start, end


def check(cols, reps):
    assert not cols.bad.any(), [w for w in cols.why if w]
    buf = cols
    for k in FIELDS:
        if k in ("site_id", "status"):
            continue
        got = buf.values[k]
        assert got.tolist() == [r[k] for r in reps], k


def strings(buf: np.ndarray, cols, name: str) -> list[str]:
    s, length = cols.strings[name]
    return [
        bytes(buf[a : a + n]).decode() for a, n in zip(s.tolist(), length.tolist(), strict=True)
    ]


def test_protobuf_decoder_reads_what_the_runtime_writes():
    reps = reports(60)
    cls = proto_class()
    payloads = [cls(**r).SerializeToString() for r in reps]
    payloads[7] = payloads[7] + cls(range_m=123.5).SerializeToString()  # merge: last wins
    reps[7]["range_m"] = 123.5
    payloads[8] = b"\xa8\x1f\x05" + payloads[8]  # unknown varint field 501 first: skipped
    buf, start, end = buffer(payloads)
    fields = protobuf_fields(radar_descriptor_set(), PROTO_SCHEMA)
    cols = decode_protobuf(buf, start, end, fields)
    check(cols, reps)
    assert strings(buf, cols, "site_id") == [r["site_id"] for r in reps]
    assert strings(buf, cols, "status") == [r["status"] for r in reps]


def test_protobuf_encoder_writes_what_the_runtime_reads():
    reps = reports(40)
    fields = protobuf_fields(radar_descriptor_set(), PROTO_SCHEMA)
    data, offsets = encode_protobuf(as_columns(reps), fields)
    cls = proto_class()
    for i, r in enumerate(reps):
        m = cls.FromString(data[offsets[i] : offsets[i + 1]].tobytes())
        assert m.SerializeToString() == cls(**r).SerializeToString()  # byte-identical


def test_cdr_both_ways_against_mcap_ros2():
    reps = reports(40)
    text = radar_ros2_text()
    fields = ros2_fields(text)
    assert [f.name for f in fields] == FIELDS
    enc = serialize_dynamic(ROS2_SCHEMA, text)[ROS2_SCHEMA]
    dec = generate_dynamic(ROS2_SCHEMA, text)[ROS2_SCHEMA]
    payloads = [enc(r) for r in reps]
    buf, start, end = buffer(payloads)
    cols = decode_cdr(buf, start, end, fields)
    check(cols, reps)
    assert strings(buf, cols, "site_id") == [r["site_id"] for r in reps]
    data, offsets = encode_cdr(as_columns(reps), fields)
    for i, r in enumerate(reps):
        ours = data[offsets[i] : offsets[i + 1]].tobytes()
        assert ours == payloads[i]  # byte-identical to mcap_ros2's encoder
        assert dec(ours).range_m == r["range_m"]


def test_flat_msg_parsing():
    text = "# comment\nint32 A=1\nfloat64 x  # east\nstring name\nuint8 flag 0\n"
    assert [(f.name, f.kind) for f in ros2_fields(text)] == [
        ("x", "f8"),
        ("name", "str"),
        ("flag", "u1"),
    ]
    with pytest.raises(ValueError):
        ros2_fields("geometry_msgs/Point p\n")
    with pytest.raises(ValueError):
        ros2_fields("float64[9] cov\n")


def decode_batch(encoding: str, payloads: list[bytes]):
    schema = radar_descriptor_set() if encoding == "protobuf" else radar_ros2_text().encode()
    name = PROTO_SCHEMA if encoding == "protobuf" else ROS2_SCHEMA
    senc = "protobuf" if encoding == "protobuf" else "ros2msg"
    t = T0_NS + np.arange(len(payloads), dtype=np.int64)
    b = ChannelBatch(1, "/radar/R1/pb", encoding, name, senc, schema, t, payloads)
    dec = RadarBinaryChannelDecoder.for_channel(b, "/f.mcap", ValidationConfig(max_range_m=60000.0))
    assert dec.feed(b) == {}  # buffered until a group is full or the file ends
    return dec.finish()


@pytest.mark.parametrize("encoding", ["protobuf", "cdr"])
def test_damaged_and_invalid_messages_are_rejected_with_raw_bytes(encoding):
    reps = [radar_report(i) for i in range(6)]
    reps[2]["range_m"] = 90000.0  # impossible: out_of_range
    reps[3]["course_rad"] = math.nan
    fields = (
        protobuf_fields(radar_descriptor_set(), PROTO_SCHEMA)
        if encoding == "protobuf"
        else ros2_fields(radar_ros2_text())
    )
    data, off = (encode_protobuf if encoding == "protobuf" else encode_cdr)(
        as_columns(reps), fields
    )
    payloads = [data[off[i] : off[i + 1]].tobytes() for i in range(len(reps))]
    payloads[4] = payloads[4][:-9]  # cut inside the last fields
    payloads[5] = (
        (b"\x11" + payloads[5][1:]) if encoding == "protobuf" else b"\x00\x00" + payloads[5][2:]
    )
    out = decode_batch(encoding, payloads)
    assert sorted(out["radar_tracks"]["local_track_id"].to_pylist()) == [100, 101]
    rej = {r["log_time_ns"] - T0_NS: r for r in out["rejects"].to_pylist()}
    assert set(rej) == {2, 3, 4, 5}
    assert rej[2]["reason_code"] == "out_of_range" and "range_m=90000" in rej[2]["reason"]
    assert rej[3]["reason_code"] == "out_of_range" and "non-finite" in rej[3]["reason"]
    assert rej[4]["reason_code"] == rej[5]["reason_code"] == "undecodable"
    assert rej[4]["raw"] == payloads[4] and rej[5]["raw"] == payloads[5]


def test_json_protobuf_and_cdr_give_the_same_rows(tmp_path, cfg):
    reps = [radar_report(i, t_ns=T0_NS + i * NS // 10) for i in range(3000)]
    cols = as_columns(reps)
    variants = {
        "json": ("json", "jsonschema", "surveil.RadarTrackReport", b"{}", [dumps(r) for r in reps]),
        "pb": ("protobuf", "protobuf", PROTO_SCHEMA, radar_descriptor_set(), None),
        "cdr": ("cdr", "ros2msg", ROS2_SCHEMA, radar_ros2_text().encode(), None),
    }
    tables = {}
    for name, (enc, senc, sname, sdata, payloads) in variants.items():
        if payloads is None:
            fields = (
                protobuf_fields(sdata, sname) if enc == "protobuf" else ros2_fields(sdata.decode())
            )
            data, off = (encode_protobuf if enc == "protobuf" else encode_cdr)(cols, fields)
            payloads = [data[off[i] : off[i + 1]].tobytes() for i in range(len(reps))]
        p = tmp_path / f"{name}.mcap"
        with open(p, "wb") as f:
            w = Writer(f, chunk_size=16384)
            w.start()
            ch = w.register_channel("/radar/R1/tracks", enc, w.register_schema(sname, senc, sdata))
            for i, payload in enumerate(payloads):
                t = reps[i]["time_ns"]
                w.add_message(ch, log_time=t, data=payload, publish_time=t)
            w.finish()
        wh = tmp_path / f"wh_{name}"
        s = run_ingest([p], cfg, wh, executor="serial")
        assert s.exit_code == 0 and s.rows["radar_tracks"] == 3000, s.render()
        t = read_table(wh, "radar_tracks").drop_columns(["source_file"])
        tables[name] = t.sort_by([("time_ns", "ascending")])
    assert tables["pb"].equals(tables["json"]) and tables["cdr"].equals(tables["json"])
    assert pc.min(tables["json"]["range_m"]).as_py() == 1000.0


def test_string_field_that_is_not_utf8_rejects_only_its_message():
    cls = proto_class()
    payloads = [cls(**radar_report(i)).SerializeToString() for i in range(4)]
    bad = payloads[1].replace(b"R1", b"\xff\xfe", 1)  # same length: still a valid message
    payloads[1] = bad
    out = decode_batch("protobuf", payloads)
    assert sorted(out["radar_tracks"]["local_track_id"].to_pylist()) == [100, 102, 103]
    (rej,) = out["rejects"].to_pylist()
    assert rej["raw"] == bad and "UTF-8" in rej["reason"] and rej["reason_code"] == "undecodable"
