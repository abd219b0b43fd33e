"""Write zstd-chunked MCAP files: one file atomically (temporary name, fsync, rename),
from (log time, channel, payload) rows, deterministically (no wall clock).

The scenario writers (``pipeline.simulate``) build frames for :func:`write_mcap_file`
(or stream them through :class:`McapFileWriter`); the legacy converters
(``pipeline.convert``) call :func:`write_messages`. This module only writes them.

Two writers give the same bytes for a frame:

- :func:`write_mcap_file_reference`: the ``mcap`` package's ``Writer``, one
  ``add_message`` call per message (~5-20 µs each: a ``Message`` object, a record built
  field by field, a message-index tuple);
- :class:`McapFileWriter` (used by :func:`write_mcap_file`): the same records, chunking,
  indexes and summary, but the Message records of a batch are laid out with numpy (one
  31-byte header per message from a structured array, the payloads joined between them)
  and only the rare records (header, schemas, channels, metadata, chunk index,
  statistics, footer) go through the ``mcap`` record classes. It takes messages in
  batches, so a writer can stream a file of any size slice by slice (the ``region``
  scenario writes hour-long files of ~4 million messages this way).
  ``tests/io/test_mcap_write.py`` checks that both give byte-identical files.

Log times: an MCAP log time is a uint64 and the warehouse keeps int64 ns, so a log time
is representable when it lies in ``[TIME_MIN_NS, TIME_MAX_NS]`` (1970-01-01 to
2262-04-11, :mod:`pipeline.units`). Every writer checks the log times BEFORE it writes
them and raises :class:`LogTimeError` (a ``ValueError`` naming the first bad message)
instead of the ``struct.error`` the mcap writer would raise half-way through (no file is
left behind); the converters divert such messages to rejects beforehand
(:mod:`pipeline.convert.output`).
"""

from __future__ import annotations

import os
import struct
import tempfile
import zlib
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import BinaryIO

import numpy as np
import polars as pl
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.writer import MCAP0_MAGIC, CompressionType, Writer

from pipeline.units import NS, TIME_MAX_NS, TIME_MIN_NS, describe_time

MCAP_PROFILE = ""
MCAP_LIBRARY = "surveil-pipeline/mcap_write"
"""Fixed header strings (the mcap default embeds the library version)."""


class LogTimeError(ValueError):
    """A log time outside the representable range (see the module docstring)."""


def first_bad_log_time(log_times: Sequence[int]) -> tuple[int, int] | None:
    """``(index, value)`` of the first log time outside ``[TIME_MIN_NS, TIME_MAX_NS]``,
    else ``None``. ``log_times``: Python ints (exact) or an int64 array."""
    for i, t in enumerate(log_times):
        if not TIME_MIN_NS <= t <= TIME_MAX_NS:
            return i, int(t)
    return None


def checked_log_times(log_times) -> np.ndarray:
    """``log_times`` (array, series or sequence of ints) as int64, checked without a
    Python loop unless one is out of range (then :func:`check_log_times` names it)."""
    if isinstance(log_times, pl.Series) and log_times.dtype not in (pl.Int64, pl.UInt64):
        log_times = log_times.to_list()  # e.g. Int128: Python ints, exact
    raw = np.asarray(log_times)
    if raw.dtype.kind not in "iu" or (
        raw.size and (raw.min() < TIME_MIN_NS or raw.max() > TIME_MAX_NS)
    ):
        check_log_times([int(v) for v in raw.tolist()])
    return raw.astype(np.int64, copy=False)


def check_log_times(log_times: Sequence[int], what: str = "message") -> None:
    """Raise :class:`LogTimeError` when a log time is not representable."""
    bad = first_bad_log_time(log_times)
    if bad is not None:
        i, t = bad
        raise LogTimeError(
            f"{what} {i}: log time {t} ns ({describe_time(t)}) is outside the representable "
            f"range [{TIME_MIN_NS}, {TIME_MAX_NS}] ns (1970-01-01 .. 2262-04-11 UTC)"
        )


@dataclass(frozen=True)
class ChannelSpec:
    """One channel to write: topic, message encoding, optional schema, metadata."""

    topic: str
    message_encoding: str
    schema_name: str | None = None
    schema_encoding: str = "jsonschema"
    schema_data: bytes = b""
    metadata: Mapping[str, str] = field(default_factory=dict)


@contextmanager
def atomic_output(path: Path) -> Iterator[BinaryIO]:
    """A binary file that becomes ``path`` only when the block ends without error: a
    temporary name beside it, fsync, rename; removed on any error (nothing half written)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_messages(
    path: Path,
    channels: Sequence[ChannelSpec],
    channel_index: Sequence[int],
    log_times: Sequence[int],
    payloads: Sequence[bytes],
    *,
    metadata: Mapping[str, Mapping[str, str]] | None = None,
    library: str = MCAP_LIBRARY,
) -> dict[str, int]:
    """Write messages in the given order (a source file's order), atomically; returns the
    message count per topic. ``channel_index[i]`` indexes ``channels``; ``metadata``:
    name -> key/value metadata records. Raises :class:`LogTimeError` (nothing written)
    when a log time is not representable."""
    check_log_times(log_times)
    if not len(channel_index) == len(log_times) == len(payloads):
        raise ValueError("channel_index, log_times and payloads differ in length")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile=MCAP_PROFILE, library=library)
        schema_ids: dict[tuple[str, str, bytes], int] = {}
        ids = []
        for c in channels:
            sid = 0
            if c.schema_name is not None:
                key = (c.schema_name, c.schema_encoding, c.schema_data)
                if key not in schema_ids:
                    schema_ids[key] = w.register_schema(*key)
                sid = schema_ids[key]
            ids.append(w.register_channel(c.topic, c.message_encoding, sid,
                                          metadata=dict(c.metadata)))  # fmt: skip
        for name, record in (metadata or {}).items():
            w.add_metadata(name, dict(record))
        seq = [0] * len(ids)
        # one add_message call per message: the mcap writer has no bulk API
        for ch, t, p in zip(channel_index, log_times, payloads, strict=True):
            w.add_message(ids[ch], int(t), p, int(t), seq[ch])
            seq[ch] += 1
        w.finish()
    return {c.topic: n for c, n in zip(channels, seq, strict=True) if n}


def json_payloads(df: pl.DataFrame, fields: list[str]) -> pl.Series:
    """Compact JSON object per row with exactly ``fields``, as bytes."""
    return df.select(
        pl.struct([pl.col(f) for f in fields]).struct.json_encode().cast(pl.Binary).alias("p")
    )["p"]


def archive_file_name(scenario_name: str, period_start_ns: int) -> str:
    """``<scenario>_<YYYYMMDDTHHMMSSZ>.mcap`` for the file period starting at the given ns."""
    stamp = datetime.fromtimestamp(period_start_ns // NS, tz=UTC).strftime("%Y%m%dT%H%M%SZ")
    return f"{scenario_name}_{stamp}.mcap"


def write_mcap_file(
    path: Path,
    channels: list[tuple],
    schemas: dict[str, bytes],
    metadata: dict[str, str],
    df: pl.DataFrame,
    *,
    library: str = MCAP_LIBRARY,
) -> None:
    """Write one zstd-chunked MCAP file atomically (temp file, fsync, rename).

    ``channels``: (topic, message encoding, JSON-schema name or None[, channel metadata])
    per channel id; ``df``: log_time_ns, channel (index into ``channels``), payload (bytes),
    in log-time order. Deterministic for the same inputs (no wall-clock anywhere).
    Byte for byte the file of :func:`write_mcap_file_reference`. Raises
    :class:`LogTimeError` (no file written) when a log time is not representable.
    """
    times = checked_log_times(df["log_time_ns"])
    with McapFileWriter(path, channels, schemas, metadata, library=library) as w:
        w.add(times, df["channel"], df["payload"])


def write_mcap_file_reference(
    path: Path,
    channels: list[tuple],
    schemas: dict[str, bytes],
    metadata: dict[str, str],
    df: pl.DataFrame,
    *,
    library: str = MCAP_LIBRARY,
) -> None:
    """:func:`write_mcap_file` through the ``mcap`` package's ``Writer``, one call per
    message: the reference the batched writer is tested against."""
    check_log_times(df["log_time_ns"].to_list())
    with atomic_output(path) as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile=MCAP_PROFILE, library=library)
        schema_ids: dict[str, int] = {}
        channel_ids = []
        for topic, encoding, schema_name, *channel_meta in channels:
            sid = 0
            if schema_name is not None:
                if schema_name not in schema_ids:
                    schema_ids[schema_name] = writer.register_schema(
                        schema_name, "jsonschema", schemas[schema_name]
                    )
                sid = schema_ids[schema_name]
            meta = channel_meta[0] if channel_meta else {}
            channel_ids.append(writer.register_channel(topic, encoding, sid, metadata=meta))
        writer.add_metadata("surveil.scenario", metadata)
        sequence = [0] * len(channels)
        add = writer.add_message
        # one call per message: the mcap writer has no bulk API
        for t, ch, payload in zip(
            df["log_time_ns"].to_list(),
            df["channel"].to_list(),
            df["payload"].to_list(),
            strict=True,
        ):
            add(channel_ids[ch], t, payload, t, sequence[ch])
            sequence[ch] += 1
        writer.finish()


# -- the batched writer ------------------------------------------------------------------

CHUNK_SIZE = 1024 * 1024
"""Uncompressed chunk size at which a chunk is closed (the ``mcap`` Writer's default)."""
_MESSAGE_HEADER = np.dtype(
    [("op", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"),
     ("log_time", "<u8"), ("publish_time", "<u8")]
)  # a Message record's fixed part, 31 bytes packed
_INDEX_ENTRY = np.dtype([("log_time", "<u8"), ("offset", "<u8")])


def _record(write) -> bytes:
    """Bytes of one record written by an ``mcap.records`` class's ``write``."""
    b = RecordBuilder()
    write(b)
    return b.end()


class McapFileWriter:
    """A zstd-chunked MCAP file written atomically, messages added in batches.

    Produces exactly the bytes of ``mcap.writer.Writer(f, compression=ZSTD)`` fed the same
    messages one ``add_message`` at a time (chunks closed after the message that takes the
    uncompressed size past ``CHUNK_SIZE``, publish time = log time, sequence = the
    message's ordinal on its channel in this file). Use as a context manager: the file
    appears under ``path`` (temp file, fsync, rename) only when the block exits without
    an exception.
    """

    def __init__(
        self,
        path: Path,
        channels: list[tuple],
        schemas: dict[str, bytes],
        metadata: dict[str, str],
        *,
        library: str = MCAP_LIBRARY,
    ) -> None:
        self.path = Path(path)
        fd, self._tmp = tempfile.mkstemp(
            prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent
        )
        self._f: BinaryIO = os.fdopen(fd, "wb")
        self._f.write(MCAP0_MAGIC)
        self._f.write(_record(Header(MCAP_PROFILE, library).write))
        self._schemas: list[Schema] = []
        schema_ids: dict[str, int] = {}
        self._channels: list[Channel] = []
        for topic, encoding, schema_name, *channel_meta in channels:
            sid = 0
            if schema_name is not None:
                if schema_name not in schema_ids:
                    schema_ids[schema_name] = len(self._schemas) + 1
                    self._schemas.append(
                        Schema(id=schema_ids[schema_name], name=schema_name,
                               encoding="jsonschema", data=schemas[schema_name])
                    )
                sid = schema_ids[schema_name]
            meta = channel_meta[0] if channel_meta else {}
            self._channels.append(
                Channel(id=len(self._channels) + 1, topic=topic, message_encoding=encoding,
                        schema_id=sid, metadata=meta)
            )
        # the Writer puts schema and channel records into the first chunk...
        self._pieces: list[bytes] = [
            *(_record(s.write) for s in self._schemas),
            *(_record(c.write) for c in self._channels),
        ]
        self._count = sum(map(len, self._pieces))
        # ...and the metadata record before it
        offset = self._f.tell()
        meta_record = _record(Metadata("surveil.scenario", metadata).write)
        self._f.write(meta_record)
        self._metadata_index = MetadataIndex(offset=offset, length=len(meta_record),
                                             name="surveil.scenario")
        self._sequence = np.zeros(len(channels), np.int64)
        self._chunk_messages = 0
        self._chunk_index: dict[int, list[np.ndarray]] = {}  # channel id -> entries
        self._chunk_times: list[tuple[int, int]] = []
        self._chunk_indexes: list[ChunkIndex] = []
        self._counts: dict[int, int] = {}
        self._n = 0
        self._start_time = 0
        self._end_time = 0
        self._zstd = zstandard.ZstdCompressor()

    def __enter__(self) -> McapFileWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self._finish()
        else:
            self._f.close()
            if os.path.exists(self._tmp):
                os.unlink(self._tmp)

    def add(self, log_time_ns, channel, payload) -> None:
        """Append messages: ``log_time_ns`` (int64), ``channel`` (index into the
        ``channels`` given at construction) and ``payload`` (binary), equal lengths, in
        the order they go into the file."""
        t = checked_log_times(log_time_ns)
        ch = np.asarray(channel, np.int64)
        data = payload.to_list() if hasattr(payload, "to_list") else list(payload)
        n = t.size
        if n == 0:
            return
        lens = np.fromiter(map(len, data), np.int64, n)
        seq = np.empty(n, np.int64)
        for c in np.unique(ch):
            idx = np.flatnonzero(ch == c)
            seq[idx] = self._sequence[c] + np.arange(idx.size)
            self._sequence[c] += idx.size
        hdr = np.empty(n, _MESSAGE_HEADER)
        hdr["op"] = Opcode.MESSAGE
        hdr["length"] = lens + 22
        hdr["channel"] = ch + 1
        hdr["sequence"] = seq
        hdr["log_time"] = t
        hdr["publish_time"] = t
        hb = hdr.tobytes()
        size = lens + 31
        _, first = np.unique(ch, return_index=True)
        for c in ch[np.sort(first)].tolist():  # first appearance, as the Writer's dict
            self._counts.setdefault(c + 1, 0)
        if self._n == 0:
            self._start_time = int(t.min())
            self._end_time = int(t.max())
        else:
            self._start_time = min(self._start_time, int(t.min()))
            self._end_time = max(self._end_time, int(t.max()))
        self._n += n
        a = 0
        while a < n:
            # the chunk closes after the first message that takes it past CHUNK_SIZE
            ends = self._count + np.cumsum(size[a:])
            b = a + int(np.searchsorted(ends, CHUNK_SIZE, side="right")) + 1
            b = min(b, n)
            offsets = self._count + np.concatenate([[0], np.cumsum(size[a : b - 1])])
            self._index(ch[a:b], t[a:b], offsets)
            pieces = self._pieces
            for i in range(a, b):
                pieces.append(hb[31 * i : 31 * i + 31])
                pieces.append(data[i])
            self._count = int(ends[b - a - 1])
            self._chunk_messages += b - a
            self._chunk_times.append((int(t[a:b].min()), int(t[a:b].max())))
            for c, k in zip(*np.unique(ch[a:b], return_counts=True), strict=True):
                self._counts[int(c) + 1] += int(k)
            if self._count > CHUNK_SIZE:
                self._close_chunk()
            a = b

    def _index(self, ch: np.ndarray, t: np.ndarray, offsets: np.ndarray) -> None:
        # channels in order of first appearance in the chunk, as the Writer's dict
        _, first = np.unique(ch, return_index=True)
        for c in ch[np.sort(first)].tolist():
            sel = ch == c
            e = np.empty(int(sel.sum()), _INDEX_ENTRY)
            e["log_time"] = t[sel]
            e["offset"] = offsets[sel]
            self._chunk_index.setdefault(c + 1, []).append(e)

    def _close_chunk(self) -> None:
        if self._chunk_messages == 0:
            return
        data = b"".join(self._pieces)
        compressed = self._zstd.compress(data)
        start = min(a for a, _ in self._chunk_times)
        end = max(b for _, b in self._chunk_times)
        chunk = Chunk(compression="zstd", data=compressed, message_end_time=end,
                      message_start_time=start, uncompressed_crc=zlib.crc32(data),
                      uncompressed_size=len(data))
        chunk_start = self._f.tell()
        record = _record(chunk.write)
        self._f.write(record)
        index_start = self._f.tell()
        offsets: dict[int, int] = {}
        pos = 0
        parts = []
        for cid, entries in self._chunk_index.items():
            e = np.concatenate(entries).tobytes()
            offsets[cid] = index_start + pos
            part = struct.pack("<BQHI", Opcode.MESSAGE_INDEX, 6 + len(e), cid, len(e)) + e
            parts.append(part)
            pos += len(part)
        self._f.write(b"".join(parts))
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=start,
                message_end_time=end,
                chunk_start_offset=chunk_start,
                chunk_length=len(record),
                message_index_offsets=offsets,
                message_index_length=pos,
                compression="zstd",
                compressed_size=len(compressed),
                uncompressed_size=len(data),
            )
        )
        self._pieces = []
        self._count = 0
        self._chunk_messages = 0
        self._chunk_index = {}
        self._chunk_times = []

    def _finish(self) -> None:
        try:
            self._close_chunk()
            f = self._f
            f.write(_record(DataEnd(data_section_crc=0).write))
            summary_start = f.tell()
            b = RecordBuilder()
            offsets = []

            def group(opcode: int, records: list) -> None:
                start = b.count
                for r in records:
                    r.write(b)
                offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + start,
                                             group_length=b.count - start))

            stats = Statistics(
                attachment_count=0,
                channel_count=len(self._channels),
                channel_message_counts={c: k for c, k in self._counts.items() if k},
                chunk_count=len(self._chunk_indexes),
                message_count=self._n,
                message_end_time=self._end_time,
                message_start_time=self._start_time,
                metadata_count=1,
                schema_count=len(self._schemas),
            )
            group(Opcode.SCHEMA, self._schemas)
            group(Opcode.CHANNEL, self._channels)
            group(Opcode.STATISTICS, [stats])
            group(Opcode.CHUNK_INDEX, self._chunk_indexes)
            group(Opcode.ATTACHMENT_INDEX, [])
            group(Opcode.METADATA_INDEX, [self._metadata_index])
            summary_offset_start = summary_start + b.count
            for o in offsets:
                o.write(b)
            summary = b.end()
            crc = zlib.crc32(summary)
            crc = zlib.crc32(
                struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start),
                crc,
            )
            f.write(summary)
            footer = Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                            summary_crc=crc)
            f.write(_record(footer.write))
            f.write(MCAP0_MAGIC)
            f.flush()
            os.fsync(f.fileno())
            f.close()
            os.replace(self._tmp, self.path)
        except BaseException:
            self._f.close()
            if os.path.exists(self._tmp):
                os.unlink(self._tmp)
            raise
