"""The compiled MCAP record walker (``pipeline/io/_mcap_records.c``) against the Python walk.

``mcap_chunks.native_positions`` must give exactly what ``mcap_chunks.walked_positions``
gives (same channels, same int64 arrays, same Schema/Channel callbacks) on real chunks
written by ``mcap.writer.Writer`` and on hand-built record bytes, and must raise
``CorruptChunkError`` where the Python walk does.
"""

from __future__ import annotations

import io
import json
import struct

import numpy as np
import pytest
import zstandard
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from pipeline.io import mcap_chunks
from pipeline.io.mcap_chunks import (
    OP_CHANNEL,
    OP_SCHEMA,
    ChunkData,
    CorruptChunkError,
    native_positions,
    walk_chunk,
    walked_positions,
)

pytestmark = pytest.mark.skipif(
    mcap_chunks._mcap_records is None,
    reason="C extension pipeline.io._mcap_records not built (no C compiler at install)",
)

OPEN = (-(2**63), 2**64)  # the reader's "no window" bounds (mcap_read._T_MIN, _T_MAX)
T0 = 1_767_225_600 * 10**9
OP_METADATA = 0x0C


# -- building chunks -----------------------------------------------------------------------


def message(channel: int, log_time: int, data: bytes, seq: int = 0) -> bytes:
    """One Message record: opcode u8 | length u64 | channel u16 | seq u32 | log u64 | pub u64."""
    body = struct.pack("<HIQQ", channel, seq, log_time, log_time % 2**64) + data
    return struct.pack("<BQ", 0x05, len(body)) + body


def record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _string_bytes(b: bytes) -> bytes:
    return struct.pack("<I", len(b)) + b


def _string(s: str) -> bytes:
    return _string_bytes(s.encode())


def schema_record(sid: int, name: str) -> bytes:
    data = b'{"type":"object"}'
    return record(
        OP_SCHEMA,
        struct.pack("<H", sid) + _string(name) + _string("jsonschema") + _string_bytes(data),
    )


def channel_record(cid: int, sid: int, topic: str) -> bytes:
    return record(
        OP_CHANNEL,
        struct.pack("<HH", cid, sid) + _string(topic) + _string("json") + struct.pack("<I", 0),
    )


def mcap_chunks_of(messages: list[tuple[str, int, bytes]], compression: CompressionType) -> list:
    """Decompressed chunk records of an MCAP file written by ``mcap.writer.Writer``;
    ``messages``: (topic, log_time, data) in write order, channels registered on first use
    (so Schema/Channel records land inside the chunks, between messages)."""
    buf = io.BytesIO()
    w = Writer(buf, chunk_size=2048, compression=compression)
    w.start()
    channels: dict[str, int] = {}
    for seq, (topic, t, data) in enumerate(messages):
        if topic not in channels:
            sid = w.register_schema(f"s{topic}", "jsonschema", b'{"type":"object"}')
            channels[topic] = w.register_channel(topic, "json", sid)
        w.add_message(channels[topic], log_time=t, data=data, publish_time=t, sequence=seq)
    w.finish()
    buf.seek(0)
    out = []
    for rec in StreamReader(buf, skip_magic=False, emit_chunks=True).records:
        if isinstance(rec, Chunk):
            if rec.compression == "zstd":
                raw = zstandard.ZstdDecompressor().decompress(
                    rec.data, max_output_size=rec.uncompressed_size
                )
            else:
                assert rec.compression == ""
                raw = bytes(rec.data)
            assert len(raw) == rec.uncompressed_size
            out.append(raw)
    return out


# -- comparing -----------------------------------------------------------------------------


def _recorder() -> tuple[list[tuple[int, bytes]], object]:
    seen: list[tuple[int, bytes]] = []
    return seen, lambda op, body: seen.append((op, bytes(body)))


def assert_same_positions(raw: bytes, lo: int, hi: int) -> dict:
    chunk = ChunkData(raw)
    seen_n, on_n = _recorder()
    seen_w, on_w = _recorder()
    got = native_positions(chunk, lo, hi, on_n)
    want = walked_positions(chunk, lo, hi, on_w)
    assert got is not None
    assert sorted(got) == sorted(want)
    for ch in want:
        for a, b, what in zip(got[ch], want[ch], ("log_time", "start", "end"), strict=True):
            assert a.dtype == b.dtype == np.int64, (ch, what)
            np.testing.assert_array_equal(a, b, err_msg=f"channel {ch} {what}")
    assert seen_n == seen_w
    return got


# -- real files ----------------------------------------------------------------------------


@pytest.mark.parametrize("compression", [CompressionType.NONE, CompressionType.ZSTD])
def test_one_channel_real_file(compression):
    msgs = [("/radar", T0 + i * 10**8, json.dumps({"i": i}).encode()) for i in range(300)]
    chunks = mcap_chunks_of(msgs, compression)
    assert len(chunks) > 1
    total = 0
    for raw in chunks:
        got = assert_same_positions(raw, *OPEN)
        total += sum(len(v[0]) for v in got.values())
    assert total == 300


@pytest.mark.parametrize("compression", [CompressionType.NONE, CompressionType.ZSTD])
def test_interleaved_channels_real_file(compression):
    rng = np.random.default_rng(7)
    topics = ["/a", "/b", "/c", "/d"]
    msgs = []
    for i in range(400):
        # channels appear one after the other, so Channel/Schema records sit between messages
        topic = topics[int(rng.integers(0, min(4, 1 + i // 50)))]
        size = int(rng.integers(0, 120))  # zero-length payloads included
        msgs.append((topic, T0 + int(rng.integers(0, 10**12)), rng.bytes(size)))
    chunks = mcap_chunks_of(msgs, compression)
    seen_channels: set[int] = set()
    callbacks = 0
    payloads = []
    for raw in chunks:
        got = assert_same_positions(raw, *OPEN)
        seen_channels.update(got)
        seen, on = _recorder()
        walked_positions(ChunkData(raw), *OPEN, on)
        callbacks += len(seen)
        for ch, (_t, s, e) in got.items():
            payloads += [(ch, raw[a:b]) for a, b in zip(s.tolist(), e.tolist(), strict=True)]
    assert seen_channels == {1, 2, 3, 4}
    assert callbacks >= 8  # a Schema and a Channel record per channel (repeated per chunk)
    assert sorted(p for _, p in payloads) == sorted(d for _, _, d in msgs)


def test_windowed_real_chunk():
    msgs = [("/a" if i % 3 else "/b", T0 + i * 1000, b"x" * (i % 5)) for i in range(200)]
    raw = mcap_chunks_of(msgs, CompressionType.NONE)[0]
    for lo, hi in [(T0 + 10_000, T0 + 50_000), (T0, T0 + 1), (T0 + 150_000, 2**64), (0, 2**63)]:
        assert_same_positions(raw, lo, hi)


# -- hand-built records ----------------------------------------------------------------------


def test_empty_chunk_and_chunk_without_messages():
    assert native_positions(ChunkData(b""), *OPEN, lambda *a: None) == {}
    raw = schema_record(1, "s") + channel_record(1, 1, "/t") + record(OP_METADATA, b"abc")
    got = assert_same_positions(raw, *OPEN)
    assert got == {}


def test_interleaved_channels_and_other_records():
    raw = b"".join(
        [
            schema_record(1, "one"),
            channel_record(1, 1, "/one"),
            message(1, 10, b"first"),
            schema_record(2, "two"),
            channel_record(7, 2, "/seven"),
            message(7, 5, b""),
            message(1, 11, b"{}"),
            record(OP_METADATA, b"not a schema or channel"),  # no callback for it
            message(7, 12, b"x" * 1000),
            message(65535, 3, b"max channel id"),
            channel_record(3, 0, "/three"),
        ]
    )
    got = assert_same_positions(raw, *OPEN)
    assert sorted(got) == [1, 7, 65535]
    t, s, e = got[7]
    assert t.tolist() == [5, 12]
    assert raw[s[0] : e[0]] == b"" and raw[s[1] : e[1]] == b"x" * 1000
    seen, on = _recorder()
    native_positions(ChunkData(raw), *OPEN, on)
    assert [op for op, _ in seen] == [OP_SCHEMA, OP_CHANNEL, OP_SCHEMA, OP_CHANNEL, OP_CHANNEL]


def test_empty_messages():
    raw = b"".join(message(2, 100 + i, b"") for i in range(5)) + message(2, 200, b"z")
    got = assert_same_positions(raw, *OPEN)
    _t, s, e = got[2]
    assert (e - s).tolist() == [0, 0, 0, 0, 0, 1]


def test_log_times_beyond_int64_without_window():
    times = [0, 5, 2**63 - 1, 2**63, 2**63 + 7, 2**64 - 1]
    raw = b"".join(message(1 + i % 2, t, bytes([i])) for i, t in enumerate(times))
    got = assert_same_positions(raw, *OPEN)
    both = np.sort(np.concatenate([got[1][0], got[2][0]]))
    assert both.tolist() == sorted(np.array(times, dtype=np.uint64).astype(np.int64).tolist())


def test_window_cuts_the_chunk():
    raw = b"".join(message(1 + i % 3, 1000 + 10 * i, b"p" * i) for i in range(60))
    for lo, hi in [
        (1100, 1300),
        (1000, 1001),
        (0, 1000),  # nothing
        (1590, 2**64),
        (-(2**63), 1200),
        (1200, 2**63 - 1),
        (1200, 2**63),
    ]:
        assert_same_positions(raw, lo, hi)
    got = native_positions(ChunkData(raw), 1100, 1300, lambda *a: None)
    assert got[1][0].tolist() == list(range(1120, 1300, 30))  # channel 1: i % 3 == 0


@pytest.mark.parametrize(
    "lo, hi", [(10, 2**64), (2**63, 2**64), (-(2**63), 0), (-(2**63), 2**63 - 1)]
)
def test_window_with_log_times_beyond_int64(lo, hi):
    raw = message(1, 5, b"a") + message(1, 2**63 + 7, b"bb") + message(2, 2**64 - 1, b"")
    assert_same_positions(raw, lo, hi)


# -- damaged bytes ---------------------------------------------------------------------------


GOOD = channel_record(1, 0, "/t") + message(1, 10, b"ok")


@pytest.mark.parametrize(
    "raw, what",
    [
        (GOOD + b"\x05\x01\x00", "record header cut"),
        (b"\x05", "record header cut"),
        (GOOD + struct.pack("<BQ", 5, 100) + b"\x00" * 40, "runs past the chunk end"),
        (GOOD + struct.pack("<BQ", 1, 2**64 - 1), "runs past the chunk end"),
        (GOOD + struct.pack("<BQ", 5, 2**63) + b"\x00" * 30, "runs past the chunk end"),
        (GOOD + struct.pack("<BQ", 5, 21) + b"\x00" * 21, "message record too short"),
        (struct.pack("<BQ", 5, 0), "message record too short"),
        (GOOD + message(1, 11, b"x")[:-1], "runs past the chunk end"),
    ],
)
def test_damaged_bytes_raise_like_the_walk(raw, what):
    chunk = ChunkData(raw)
    with pytest.raises(CorruptChunkError) as walked:
        walked_positions(chunk, *OPEN, lambda *a: None)
    with pytest.raises(CorruptChunkError) as native:
        native_positions(chunk, *OPEN, lambda *a: None)
    assert what in str(walked.value)
    assert str(native.value) == str(walked.value)
    err = walk_chunk(raw)  # as the fetch thread runs it: the error is returned, not raised
    assert isinstance(err, ValueError) and what in str(err)


def test_zero_length_non_message_record_is_fine():
    raw = record(OP_METADATA, b"") + message(1, 1, b"") + record(0x7F, b"")
    assert_same_positions(raw, *OPEN)


def test_damaged_chunk_callbacks_before_the_damage():
    raw = schema_record(1, "s") + channel_record(1, 1, "/t") + b"\x05\x01"
    seen_w, on_w = _recorder()
    seen_n, on_n = _recorder()
    with pytest.raises(CorruptChunkError):
        walked_positions(ChunkData(raw), *OPEN, on_w)
    with pytest.raises(CorruptChunkError):
        native_positions(ChunkData(raw), *OPEN, on_n)
    assert seen_n == seen_w
