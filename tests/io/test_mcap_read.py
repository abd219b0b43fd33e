"""MCAP reading: healthy files agree with the mcap reader; damaged files give back exactly
the intact messages (checked against mcap's own chunk parser on the undamaged file)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType
from mcap_fixtures import T0_NS, mixed_file, radar_messages, write_mcap

from pipeline.io.mcap_read import ChannelBatch, read_mcap_batches
from pipeline.units import NS


def read_all(path: Path, **window) -> tuple[list[tuple[str, int, bytes]], object]:
    scan = read_mcap_batches(path, **window)
    out = []
    for b in scan:
        assert isinstance(b, ChannelBatch)
        assert b.log_time_ns.dtype == np.int64 and len(b.log_time_ns) == len(b.payloads)
        out.extend(zip([b.topic] * len(b), b.log_time_ns.tolist(), b.payloads, strict=True))
    assert scan.status.finished
    return out, scan.status


def by_topic(msgs: list[tuple[str, int, bytes]]) -> dict[str, list[tuple[int, bytes]]]:
    """Messages per topic in file order (batches group a chunk's messages by channel)."""
    out: dict[str, list[tuple[int, bytes]]] = {}
    for topic, t, payload in msgs:
        out.setdefault(topic, []).append((t, payload))
    return out


def reference_messages(path: Path) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as f:
        return [
            (ch.topic, m.log_time, m.data)
            for _, ch, m in make_reader(f).iter_messages(log_time_order=False)
        ]


def chunk_layout(path: Path) -> list[tuple[int, int, list[tuple[str, int, bytes]]]]:
    """(start offset, end offset, messages) per chunk, from mcap's own chunk parser."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {cid: ch.topic for cid, ch in summary.channels.items()}
        out = []
        for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            f.seek(ci.chunk_start_offset)
            from mcap.stream_reader import StreamReader

            chunk = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
            msgs = [
                (topics[r.channel_id], r.log_time, r.data)
                for r in breakup_chunk(chunk)
                if hasattr(r, "log_time")
            ]
            out.append((ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length, msgs))
    return out


@pytest.fixture()
def healthy(tmp_path) -> Path:
    return mixed_file(tmp_path / "healthy.mcap", n_radar=400)


def test_healthy_file_matches_mcap_reader(healthy):
    got, status = read_all(healthy)
    assert by_topic(got) == by_topic(reference_messages(healthy))
    assert status.status == "ok" and status.mode == "indexed" and not status.problems
    assert status.chunks_read == status.chunks_total > 5
    assert status.messages_read == len(got)
    assert status.start_time_ns == min(t for _, t, _ in got)
    assert status.end_time_ns == max(t for _, t, _ in got)


def test_batches_are_per_chunk_and_channel(healthy):
    scan = read_mcap_batches(healthy)
    batches = list(scan)
    per_chunk_max = max(len(msgs) for _, _, msgs in chunk_layout(healthy))
    assert max(len(b) for b in batches) <= per_chunk_max
    assert len(batches) >= scan.status.chunks_read
    radar = next(b for b in batches if b.topic == "/radar/R1/tracks")
    assert (radar.message_encoding, radar.schema_encoding, radar.schema_name) == (
        "json",
        "jsonschema",
        "surveil.RadarTrackReport",
    )
    assert b"RadarTrackReport" in radar.schema_data
    ais = next(b for b in batches if b.topic == "/ais/nmea")
    assert (ais.message_encoding, ais.schema_name, ais.schema_encoding) == ("nmea0183", "", "")


@pytest.mark.parametrize("compression", [CompressionType.LZ4, CompressionType.NONE])
def test_other_compressions(tmp_path, compression):
    p = write_mcap(tmp_path / "c.mcap", radar_messages(200), compression=compression)
    got, status = read_all(p)
    assert by_topic(got) == by_topic(reference_messages(p)) and status.status == "ok"


def test_window_reads_only_overlapping_chunks(healthy):
    start, end = T0_NS + 100 * NS, T0_NS + 150 * NS
    got, status = read_all(healthy, start_ns=start, end_ns=end)
    expected = [m for m in reference_messages(healthy) if start <= m[1] < end]
    assert by_topic(got) == by_topic(expected) and len(got) > 50
    assert status.chunks_read < status.chunks_total / 2


def test_not_mcap_and_empty_file(tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_text("time,lat,lon\n1,2,3\n")
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    for p in (junk, empty):
        got, status = read_all(p)
        assert got == []
        assert status.status == "quarantined" and status.not_mcap
        assert [pr.reason_code for pr in status.problems] == ["not_mcap"]


def test_truncated_at_several_offsets_keeps_exactly_complete_chunks(healthy):
    data = healthy.read_bytes()
    layout = chunk_layout(healthy)
    cuts = [
        layout[0][0] + 5,  # inside the first chunk
        layout[2][1] - 1,  # last byte of the third chunk missing
        layout[2][1],  # exactly after the third chunk
        (layout[3][0] + layout[3][1]) // 2,  # middle of a chunk
        len(data) // 2,
        layout[-1][1] + 3,  # after the last chunk (in its message index)
    ]
    for cut in cuts:
        p = healthy.with_name(f"cut_{cut}.mcap")
        p.write_bytes(data[:cut])
        got, status = read_all(p)
        expected = [m for start, end, msgs in layout if end <= cut for m in msgs]
        assert by_topic(got) == by_topic(expected), f"cut at {cut}"
        assert status.mode == "linear"
        assert [pr.reason_code for pr in status.problems] == ["truncated"], cut
        assert status.status == ("partial" if expected else "quarantined")


def test_footer_cut_off_keeps_everything(healthy):
    data = healthy.read_bytes()
    p = healthy.with_name("nofooter.mcap")
    p.write_bytes(data[:-20])
    got, status = read_all(p)
    assert by_topic(got) == by_topic(reference_messages(healthy))
    assert status.status == "partial" and status.problems[0].reason_code == "truncated"


def test_writer_never_finished(tmp_path):
    p = write_mcap(tmp_path / "crash.mcap", radar_messages(500), finish=False)
    got, status = read_all(p)
    flushed = len(got)
    assert 400 < flushed < 500  # the open chunk was still in the writer's memory
    assert got == radar_messages(500)[:flushed]
    assert status.mode == "linear" and status.status == "partial"


@pytest.mark.parametrize("victim", [0, 3, -1])
def test_flipped_byte_in_compressed_chunk_skips_only_that_chunk(healthy, victim):
    layout = chunk_layout(healthy)
    start, end, lost = layout[victim]
    data = bytearray(healthy.read_bytes())
    data[(start + end) // 2] ^= 0xFF
    p = healthy.with_name("flipped.mcap")
    p.write_bytes(bytes(data))
    got, status = read_all(p)
    expected = [
        m for i, (_, _, msgs) in enumerate(layout) if i != victim % len(layout) for m in msgs
    ]
    assert by_topic(got) == by_topic(expected)
    assert status.status == "partial" and status.chunks_skipped == 1
    (problem,) = status.problems
    assert problem.reason_code == "corrupt_chunk" and problem.offset == start
    assert problem.messages_lost == len(lost)


def test_window_on_damaged_file_counts_lost_in_window(healthy):
    layout = chunk_layout(healthy)
    start, end, lost = layout[4]
    data = bytearray(healthy.read_bytes())
    data[(start + end) // 2] ^= 0xFF
    p = healthy.with_name("flipped_window.mcap")
    p.write_bytes(bytes(data))
    t_lo = lost[0][1]
    got, status = read_all(p, start_ns=t_lo, end_ns=t_lo + 1)
    assert got == [] or all(t_lo <= t < t_lo + 1 for _, t, _ in got)
    assert status.problems[0].messages_lost == sum(1 for m in lost if m[1] == t_lo)


def test_bad_window_rejected(healthy):
    with pytest.raises(ValueError):
        read_mcap_batches(healthy, start_ns=10, end_ns=10)


def test_chunk_with_good_crc_but_broken_records_skips_only_that_chunk(tmp_path):
    """The record walk runs in the fetch thread: a chunk whose bytes pass the CRC but whose
    records do not tile it (a message length cut by one) is skipped with the walker's
    reason, and every other chunk is read."""
    import struct
    import zlib

    p = write_mcap(tmp_path / "plain.mcap", radar_messages(300), compression=CompressionType.NONE)
    layout = chunk_layout(p)
    start, _, lost = layout[2]
    data = bytearray(p.read_bytes())
    body = start + 9  # chunk record: opcode, length, then the body
    records_at = body + 8 + 8 + 8 + 4 + 4 + 8  # times, size, crc, "" compression, length
    assert data[records_at] in (0x01, 0x03, 0x05)  # a schema, channel or message record
    first = records_at
    while data[first] != 0x05:  # the chunk's first message record
        first += 9 + struct.unpack_from("<Q", data, first + 1)[0]
    (length,) = struct.unpack_from("<Q", data, first + 1)
    struct.pack_into("<Q", data, first + 1, length + 1)  # the records no longer tile the chunk
    (records_len,) = struct.unpack_from("<Q", data, records_at - 8)
    records = bytes(data[records_at : records_at + records_len])
    struct.pack_into("<I", data, body + 24, zlib.crc32(records))  # a CRC that passes
    bad = tmp_path / "broken_records.mcap"
    bad.write_bytes(bytes(data))
    got, status = read_all(bad)
    expected = [m for i, (_, _, msgs) in enumerate(layout) if i != 2 for m in msgs]
    assert by_topic(got) == by_topic(expected)
    assert status.status == "partial" and status.chunks_skipped == 1
    (problem,) = status.problems
    assert problem.reason_code == "corrupt_chunk" and problem.offset == start
    assert problem.messages_lost == len(lost)
    assert "runs past the chunk end" in problem.detail, problem.detail
