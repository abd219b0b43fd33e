"""Protobuf ``foxglove.LocationFix`` channels, written with the official
``mcap_protobuf.writer`` and the ``foxglove-schemas-protobuf`` classes."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.writer import Writer

from pipeline.config import ValidationConfig
from pipeline.decode.registry import FileDecoder, decoder_kind
from pipeline.io.mcap_read import read_mcap_batches
from pipeline.units import NS

fsp = pytest.importorskip("foxglove_schemas_protobuf.LocationFix_pb2")
mcap_pb = pytest.importorskip("mcap_protobuf.writer")

T0 = 1_772_359_200 * NS


def fix(t_ns: int | None, lat: float, lon: float, cov_type: int = 2):
    m = fsp.LocationFix(latitude=lat, longitude=lon, altitude=7.5, frame_id="gnss",
                        position_covariance=[9.0, 0, 0, 0, 4.0, 0, 0, 0, 1.0],
                        position_covariance_type=cov_type)  # fmt: skip
    if t_ns is not None:
        m.timestamp.seconds, m.timestamp.nanos = t_ns // NS, t_ns % NS
    return m


def decode_file(path: Path) -> dict:
    dec = FileDecoder(source_file=str(path), validation=ValidationConfig())
    for b in read_mcap_batches(path):
        dec.feed(b)
    return dec.finish()


def test_registry_kind():
    assert decoder_kind("protobuf", "protobuf", "foxglove.LocationFix") == "protobuf"
    assert decoder_kind("protobuf", "protobuf", "foxglove.PoseInFrame") is None


def test_location_fix_round_trip_and_rejects(tmp_path):
    path = tmp_path / "pb.mcap"
    with open(path, "wb") as f:
        w = mcap_pb.Writer(f, chunk_size=2048)
        for k in range(200):  # many chunks
            w.write_message("/gnss", fix(T0 + k * NS + 3, 60.0 + k * 1e-6, 24.9),
                            log_time=T0 + k * NS + 500, publish_time=T0)  # fmt: skip
        w.write_message("/gnss", fix(None, 60.0, 24.9, cov_type=0), log_time=T0 + 900 * NS)
        w.write_message("/gnss", fix(T0, -91.0, 24.9), log_time=T0 + 901 * NS)
        w.finish()
    out = decode_file(path)
    rows = out["nav_gnss"].to_pylist()
    assert len(rows) == 201
    assert [r["time_ns"] for r in rows[:200]] == [T0 + k * NS + 3 for k in range(200)]
    assert rows[7]["lat_deg"] == 60.0 + 7e-6 and rows[7]["altitude_m"] == 7.5
    assert (rows[0]["sigma_lon_m"], rows[0]["sigma_lat_m"]) == (3.0, 2.0)
    assert rows[0]["sentence"] == "LocationFix" and rows[0]["platform_id"] == "/gnss"
    assert rows[0]["fix_quality"] is None
    assert rows[200]["time_ns"] == T0 + 900 * NS  # no timestamp -> log time
    assert rows[200]["sigma_lat_m"] is None  # covariance type UNKNOWN
    (rej,) = out["rejects"].to_pylist()
    assert rej["reason_code"] == "out_of_range" and rej["log_time_ns"] == T0 + 901 * NS


def test_undecodable_payload_and_other_protobuf_schema(tmp_path):
    from mcap_protobuf.schema import register_schema

    path = tmp_path / "bad.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = register_schema(w, fsp.LocationFix)
        ch = w.register_channel("/gnss", "protobuf", sid, metadata={"platform_id": "ship"})
        w.add_message(ch, T0, fix(T0, 1.0, 2.0).SerializeToString(), T0)
        w.add_message(ch, T0 + 1, b"\xff\xff\xff\xff", T0 + 1)  # not a valid message
        other = w.register_schema("acme.Thing", "protobuf", b"")
        ch2 = w.register_channel("/thing", "protobuf", other)
        for k in range(5):
            w.add_message(ch2, T0 + k, b"\x08\x01", T0 + k)
        w.finish()
    out = decode_file(path)
    assert out["nav_gnss"]["platform_id"].to_pylist() == ["ship"]
    rej = sorted(out["rejects"].to_pylist(), key=lambda r: r["reason_code"])
    assert [r["reason_code"] for r in rej] == ["undecodable", "unknown_schema"]
    assert rej[0]["raw"] == b"\xff\xff\xff\xff"
    assert rej[1]["reason"].startswith("5 messages") and rej[1]["topic"] == "/thing"


@pytest.mark.slow
def test_location_fix_decode_rate():
    """Protobuf LocationFix -> nav_gnss rows (printed with ``-s``)."""
    import time

    import numpy as np
    from mcap_protobuf.schema import build_file_descriptor_set

    from pipeline.decode.protobuf import ProtobufChannelDecoder
    from pipeline.io.mcap_read import ChannelBatch

    n = 100_000
    payloads = [fix(T0 + i * NS, 50 + i * 1e-7, 30.0).SerializeToString() for i in range(n)]
    fds = build_file_descriptor_set(fsp.LocationFix).SerializeToString()
    batch = ChannelBatch(1, "/pb", "protobuf", "foxglove.LocationFix", "protobuf", fds,
                         T0 + np.arange(n, dtype=np.int64), payloads)  # fmt: skip
    dec = ProtobufChannelDecoder.for_channel(batch, "f")
    t = time.perf_counter()
    out = dec.feed(batch)
    dt = time.perf_counter() - t
    assert out["nav_gnss"].num_rows == n
    print(f"\nprotobuf LocationFix -> nav_gnss: {n / dt:,.0f} msg/s ({dt:.2f} s)")
