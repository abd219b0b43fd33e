"""The chunk-index fast path: spans instead of per-message bytes, message-index positions
checked against the records, window pruning counted in bytes and chunks, the summary."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer
from mcap_fixtures import T0_NS, mixed_file, radar_messages, write_mcap

from pipeline.io.mcap_chunks import (
    ChunkBuffers,
    ChunkData,
    indexed_positions,
    message_index_entries,
    walk_records,
)
from pipeline.io.mcap_read import ChannelBatch, read_mcap_batches, read_mcap_summary
from pipeline.units import NS


def _all(path: Path, **kw) -> tuple[list[tuple[int, int, bytes]], object]:
    scan = read_mcap_batches(path, **kw)
    out = []
    for b in scan:
        out.extend(zip([b.channel_id] * len(b), b.log_time_ns.tolist(), b.payloads, strict=True))
    return out, scan


def _reference(path: Path) -> list[tuple[int, int, bytes]]:
    with open(path, "rb") as f:
        msgs = make_reader(f).iter_messages(log_time_order=False)
        return sorted((m.channel_id, m.log_time, m.data) for _, _, m in msgs)


def test_spans_point_at_the_payloads(tmp_path):
    p = mixed_file(tmp_path / "m.mcap", n_radar=300)
    got, scan = _all(p)
    assert sorted(got) == _reference(p)
    assert scan.status.chunks_decompressed == scan.status.chunks_read == scan.status.chunks_total
    for b in read_mcap_batches(p):
        chunk, start, end = b.spans()
        assert isinstance(chunk, ChunkData) and start.dtype == end.dtype == np.int64
        assert [chunk.raw[s:e] for s, e in zip(start, end, strict=True)] == b.payloads
        assert np.array_equal(b.payload_lengths(), end - start)


def test_prefetch_thread_and_inline_reads_agree(tmp_path):
    p = mixed_file(tmp_path / "m.mcap", n_radar=400)
    a, _ = _all(p, prefetch=True)
    b, _ = _all(p, prefetch=False)
    assert a == b


@pytest.mark.parametrize("window", [None, (T0_NS + 20 * NS, T0_NS + 60 * NS)])
def test_reads_without_the_compiled_walker_agree(tmp_path, monkeypatch, window):
    """An install without a C compiler (no ``_mcap_records``) locates the same messages
    through the message index and the Python walk."""
    import pipeline.io.mcap_chunks as mcap_chunks

    p = mixed_file(tmp_path / "m.mcap", n_radar=400)
    kw = {} if window is None else {"start_ns": window[0], "end_ns": window[1]}
    native, _ = _all(p, **kw)
    monkeypatch.setattr(mcap_chunks, "_mcap_records", None)
    fallback, _ = _all(p, **kw)
    assert native == fallback and len(native) > 0


def test_batch_from_payload_list_has_spans():
    b = ChannelBatch(3, "/t", "json", "", "", b"", np.array([5, 6]), [b"ab", b"{}"])
    chunk, start, end = b.spans()
    assert [chunk.raw[s:e] for s, e in zip(start, end, strict=True)] == [b"ab", b"{}"]
    assert start[0] >= 1 and len(b) == 2 and b.payloads == [b"ab", b"{}"]


def test_index_positions_equal_the_record_walk(tmp_path):
    p = mixed_file(tmp_path / "m.mcap", n_radar=300)
    with open(p, "rb") as f:
        summary = make_reader(f).get_summary()
        for ci in summary.chunk_indexes:
            f.seek(ci.chunk_start_offset)
            from mcap.stream_reader import StreamReader

            from pipeline.io.mcap_chunks import decompress, parse_chunk
            from pipeline.io.mcap_read import _chunk_body

            rec = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
            chunk = ChunkData(decompress(parse_chunk(_chunk_body(rec))))
            f.seek(min(ci.message_index_offsets.values()))
            entries = message_index_entries(f.read(ci.message_index_length))
            fast = indexed_positions(chunk, entries, -(2**63), 2**64, lambda op, body: None)
            walked = walk_records(chunk.raw, -(2**63), 2**64, lambda op, body: None)
            assert fast is not None
            assert set(fast) == set(walked)
            for ch, (t, s, e) in fast.items():
                assert t.tolist() == walked[ch][0]
                assert s.tolist() == walked[ch][1] and e.tolist() == walked[ch][2]


def test_index_that_does_not_fit_the_chunk_falls_back_to_the_walk():
    raw = radar_chunk_bytes()
    chunk = ChunkData(raw)
    walked = walk_records(raw, -(2**63), 2**64, lambda op, body: None)
    (ch,) = walked
    t = np.asarray(walked[ch][0], dtype=np.int64)
    offs = np.asarray(walked[ch][1], dtype=np.int64) - 31
    good = {ch: (t, offs)}
    assert indexed_positions(chunk, good, -(2**63), 2**64, lambda *a: None) is not None
    for bad in ({ch: (t + 1, offs)}, {ch: (t, offs + 1)}, {ch + 1: (t, offs)}):
        assert indexed_positions(chunk, bad, -(2**63), 2**64, lambda *a: None) is None


def radar_chunk_bytes() -> bytes:
    """The records of a chunk holding three radar messages (built with the mcap writer)."""
    import io
    import struct

    msgs = radar_messages(3)
    buf = io.BytesIO()
    w = Writer(buf, compression=CompressionType.NONE)
    w.start()
    ch = w.register_channel("/radar/R1/tracks", "json", 0)
    for seq, (_, t, payload) in enumerate(msgs):
        w.add_message(ch, log_time=t, data=payload, publish_time=t, sequence=seq)
    w.finish()
    data = buf.getvalue()
    pos = data.index(b"\x06", 8 + 9 + 4)  # first chunk record after the header
    (length,) = struct.unpack_from("<Q", data, pos + 1)
    from pipeline.io.mcap_chunks import parse_chunk

    return bytes(parse_chunk(memoryview(data)[pos + 9 : pos + 9 + length]).records)


def test_file_without_message_indexes_is_walked(tmp_path):
    p = tmp_path / "noidx.mcap"
    with open(p, "wb") as f:
        w = Writer(f, chunk_size=2048, index_types=IndexType.CHUNK)
        w.start()
        ch = w.register_channel("/radar/R1/tracks", "json", 0)
        for seq, (_, t, payload) in enumerate(radar_messages(120)):
            w.add_message(ch, log_time=t, data=payload, publish_time=t, sequence=seq)
        w.finish()
    got, scan = _all(p)
    assert sorted(got) == _reference(p) and scan.status.mode == "indexed"
    assert scan.status.chunks_read > 3


def test_window_reads_only_overlapping_chunks_counted_in_bytes(tmp_path):
    p = write_mcap(tmp_path / "w.mcap", radar_messages(2000), chunk_size=8192)
    size = p.stat().st_size
    _, whole = _all(p)
    got, win = _all(p, start_ns=T0_NS + 1000 * NS, end_ns=T0_NS + 1010 * NS)
    assert sorted(t for _, t, _ in got) == [T0_NS + (1000 + i) * NS for i in range(10)]
    assert whole.status.bytes_read >= size * 0.95
    assert win.status.chunks_decompressed <= 2 < whole.status.chunks_decompressed
    summary = read_mcap_summary(p)
    last = summary.chunk_indexes[-1]
    summary_bytes = size - (last.chunk_start_offset + last.chunk_length + last.message_index_length)
    chunk_bytes = max(c.chunk_length + c.message_index_length for c in summary.chunk_indexes)
    assert win.status.bytes_read <= 8 + summary_bytes + 2 * chunk_bytes < size / 5


def test_file_wholly_outside_the_window_reads_footer_and_summary_only(tmp_path):
    p = write_mcap(tmp_path / "w.mcap", radar_messages(2000), chunk_size=8192)
    summary = read_mcap_summary(p)
    assert summary is not None and summary.chunk_indexes
    got, scan = _all(p, start_ns=T0_NS + 10**6 * NS, end_ns=T0_NS + 2 * 10**6 * NS)
    assert got == [] and scan.status.chunks_decompressed == 0 and scan.status.status == "ok"
    summary_bytes = p.stat().st_size - summary.chunk_indexes[-1].chunk_start_offset
    assert scan.status.bytes_read <= 8 + summary_bytes  # magic + (footer, summary, ...)
    assert scan.status.bytes_read < p.stat().st_size * 0.2


def test_summary_statistics_and_channels(tmp_path):
    p = mixed_file(tmp_path / "m.mcap", n_radar=300)
    summary = read_mcap_summary(p)
    topics = {c.topic for c in summary.channels.values()}
    assert topics == {"/radar/R1/tracks", "/truth/vessels", "/ais/nmea"}
    assert summary.statistics.message_count == len(_reference(p))
    assert summary.size_bytes == p.stat().st_size
    assert (
        read_mcap_summary(write_mcap(tmp_path / "c.mcap", radar_messages(9), finish=False)) is None
    )


def test_channel_counts_and_spans_in_status(tmp_path):
    p = mixed_file(tmp_path / "m.mcap", n_radar=300)
    got, scan = _all(p)
    by_ch: dict[int, list[int]] = {}
    for ch, t, _ in got:
        by_ch.setdefault(ch, []).append(t)
    assert scan.status.channel_counts == {ch: len(ts) for ch, ts in by_ch.items()}
    assert scan.status.channel_spans == {ch: (min(ts), max(ts)) for ch, ts in by_ch.items()}


@pytest.mark.parametrize("compression", [CompressionType.LZ4, CompressionType.NONE])
def test_other_compressions_keep_spans(tmp_path, compression):
    p = write_mcap(tmp_path / "c.mcap", radar_messages(300), compression=compression)
    got, _ = _all(p)
    assert sorted(got) == _reference(p)


def test_chunk_buffers_are_reused_only_when_nothing_holds_them():
    pool = ChunkBuffers(limit=2)
    first = id(pool.take(100))
    assert id(pool.take(100)) == first  # idle again as soon as the caller dropped it
    view = memoryview(pool.take(100))
    assert id(view.obj) == first and id(pool.take(100)) != first  # the view holds it
    del view
    chunk = ChunkData(memoryview(pool.take(100))[:60].toreadonly())
    assert id(pool.take(100)) != first
    rows = chunk.arr[10:20]  # an array that outlives its chunk
    del chunk
    assert id(pool.take(100)) != first
    del rows
    assert id(pool.take(100)) == first
    held = [pool.take(100), pool.take(100)]  # both pooled buffers in use: a fresh one
    extra = pool.take(100)
    assert all(extra is not h for h in held) and len(pool._buffers) == 2
    del held, extra
    assert len(pool.take(5000)) >= 5000  # an idle buffer too small is replaced


@pytest.mark.parametrize("claimed", [-1, 0, 1])
def test_pooled_zstd_chunk_is_size_checked(claimed):
    import zstandard

    from pipeline.io.mcap_chunks import ChunkHeader, CorruptChunkError, decompress

    records = bytes(range(256)) * 40
    packed = zstandard.ZstdCompressor().compress(records)
    head = ChunkHeader(0, 0, len(records) + claimed, 0, "zstd", packed)
    pool = ChunkBuffers(limit=4)
    if claimed:
        with pytest.raises(CorruptChunkError, match="chunk header says"):
            decompress(head, buffers=pool)
    else:
        data = decompress(head, buffers=pool)
        assert isinstance(data, memoryview) and data.readonly and data == records


def test_pooled_zstd_chunk_of_several_frames_is_read_whole():
    import zstandard

    from pipeline.io.mcap_chunks import ChunkHeader, decompress

    parts = [bytes(range(256)) * 9, b"second frame" * 50]
    packed = b"".join(zstandard.ZstdCompressor().compress(p) for p in parts)
    head = ChunkHeader(0, 0, sum(map(len, parts)), 0, "zstd", memoryview(packed))
    assert decompress(head, buffers=ChunkBuffers(limit=1)) == b"".join(parts)


@pytest.mark.parametrize("pooled_max", [None, 16])
def test_unpooled_zstd_chunk_of_several_frames_is_read_whole(monkeypatch, pooled_max):
    """No pool (the linear scan of a file without a summary) or a chunk over
    POOLED_MAX_BYTES: every frame is read, and a header claiming a byte more or less
    than the frames hold is still caught by the size check."""
    import zstandard

    from pipeline.io import mcap_chunks
    from pipeline.io.mcap_chunks import ChunkHeader, CorruptChunkError, decompress

    if pooled_max is not None:
        monkeypatch.setattr(mcap_chunks, "POOLED_MAX_BYTES", pooled_max)
    buffers = None if pooled_max is None else ChunkBuffers(limit=1)
    parts = [bytes(range(256)) * 9, b"second frame" * 50, b"third"]
    packed = b"".join(zstandard.ZstdCompressor().compress(p) for p in parts)
    whole = b"".join(parts)
    head = ChunkHeader(0, 0, len(whole), 0, "zstd", memoryview(packed))
    assert decompress(head, buffers=buffers) == whole
    for claimed in (len(whole) - 1, len(whole) + 1):
        with pytest.raises(CorruptChunkError):
            decompress(dataclasses.replace(head, uncompressed_size=claimed), buffers=buffers)


def test_chunk_buffers_fit_a_slightly_longer_chunk():
    # a writer's chunks differ in size by up to a message: the idle buffer is reused
    pool = ChunkBuffers(limit=1)
    first = id(pool.take(1_048_600))
    assert id(pool.take(1_048_900)) == first


def test_chunk_buffers_hand_out_the_next_idle_buffer_first():
    pool = ChunkBuffers(limit=3)
    held = [pool.take(10) for _ in range(3)]
    ids = [id(b) for b in held]
    del held
    # all idle again, each dropped at once: they still go out in turn
    assert [id(pool.take(10)) for _ in range(3)] == ids
