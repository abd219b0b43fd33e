"""Decoder choice per channel and the per-file decoder over real MCAP batches."""

from __future__ import annotations

from mcap_fixtures import (
    AIS_TYPE1,
    T0_NS,
    TYPE5_FRAGMENTS,
    dumps,
    radar_messages,
    truth_state,
    write_mcap,
)

from pipeline.config import ValidationConfig
from pipeline.decode.registry import RAW_TABLES, FileDecoder, decoder_kind
from pipeline.io.mcap_read import read_mcap_batches
from pipeline.tables import schema


def test_decoder_kind():
    assert decoder_kind("json", "jsonschema", "surveil.RadarTrackReport") == "radar"
    assert decoder_kind("json", "jsonschema", "surveil.TruthState") == "truth"
    assert decoder_kind("nmea0183", "", "") == "nmea"
    assert decoder_kind("json", "jsonschema", "acme.Other") is None
    assert decoder_kind("protobuf", "protobuf", "surveil.RadarTrackReport") == "radar_binary"
    assert decoder_kind("protobuf", "protobuf", "acme.RadarTrackReport") is None
    assert decoder_kind("cdr", "ros2msg", "") is None


def decode_file(path):
    dec = FileDecoder(source_file=str(path), validation=ValidationConfig())
    scan = read_mcap_batches(path)
    for b in scan:
        dec.feed(b)
    return dec.finish(), dec, scan.status


def test_unknown_channels_one_reject_row_each_with_count(tmp_path):
    msgs = radar_messages(300)
    for i in range(250):  # spread over many chunks
        t = T0_NS + i * 10**9 + 5
        msgs.append(("/acme/secret", t, b"\x00" * 40))
        if i % 50 == 0:
            msgs.append(("/other/proto", t + 1, b"\x01\x02"))
    msgs.sort(key=lambda m: m[1])
    p = write_mcap(
        tmp_path / "u.mcap",
        msgs,
        extra_channels={
            "/acme/secret": ("acmebinary", "acme.Secret", "acmebinary"),
            "/other/proto": ("protobuf", "", ""),
        },
    )
    tables, _, status = decode_file(p)
    assert status.chunks_read > 5
    rej = {r["topic"]: r for r in tables["rejects"].to_pylist()}
    assert set(rej) == {"/acme/secret", "/other/proto"}
    assert rej["/acme/secret"]["reason_code"] == "unknown_schema"
    assert rej["/acme/secret"]["reason"].startswith("250 messages not decoded")
    assert "'acmebinary'" in rej["/acme/secret"]["reason"]
    assert rej["/other/proto"]["reason"].startswith("5 messages not decoded")
    assert rej["/acme/secret"]["log_time_ns"] == T0_NS + 5
    assert tables["radar_tracks"].num_rows == 300


def _split_file(tmp_path, n_before: int):
    msgs = [("/ais/nmea", T0_NS + i, AIS_TYPE1) for i in range(n_before)]
    msgs += [("/ais/nmea", T0_NS + 100 + k, f) for k, f in enumerate(TYPE5_FRAGMENTS)]
    msgs += [("/ais/nmea", T0_NS + 200, AIS_TYPE1)]
    msgs += [("/truth/vessels", T0_NS + 300, dumps(truth_state(0, time_ns=T0_NS + 300)))]
    p = write_mcap(tmp_path / f"ais{n_before}.mcap", msgs, chunk_size=200)
    batch_of = {}
    for k, b in enumerate(read_mcap_batches(p)):
        for payload in b.payloads:
            batch_of.setdefault(payload, k)
    return p, batch_of[TYPE5_FRAGMENTS[0]] != batch_of[TYPE5_FRAGMENTS[1]]


def test_ais_group_split_across_chunks(tmp_path):
    # a tiny chunk size; pick a prefix length that puts the two fragments of the type 5
    # into different chunks (hence different batches)
    p = next(p for n in range(12) for p, split in [_split_file(tmp_path, n)] if split)
    n_before = int(p.stem.removeprefix("ais"))
    tables, _, _ = decode_file(p)
    assert tables["rejects"].num_rows == 0
    assert tables["ais_static"].num_rows == 1
    assert tables["ais_reports"].num_rows == n_before + 1
    assert tables["truth"].num_rows == 1
    assert tables["ais_static"]["time_ns"][0].as_py() == T0_NS + 101
    for name in RAW_TABLES:
        assert tables[name].schema == schema(name)


def test_ais_group_open_at_end_of_file_rejected(tmp_path):
    msgs = [("/ais/nmea", T0_NS, AIS_TYPE1), ("/ais/nmea", T0_NS + 1, TYPE5_FRAGMENTS[0])]
    tables, _, _ = decode_file(write_mcap(tmp_path / "open.mcap", msgs))
    assert tables["rejects"].column("reason_code").to_pylist() == ["truncated_multipart"]
