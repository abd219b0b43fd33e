"""Read an MCAP file as per-channel column batches, chunk by chunk, surviving damage.

``read_mcap_batches(path)`` yields one :class:`ChannelBatch` per (chunk, channel): the
channel's encodings, schema and metadata, ``log_time_ns`` as an int64 numpy array and the
payloads as byte spans ``[start, end)`` into the chunk's decompressed buffer (no Python
object per message; ``batch.payloads`` builds the ``list[bytes]`` on demand for decoders
that work message by message). Memory holds a few chunks at a time (about 1 MiB
uncompressed each with the default writer), not the file. When the iteration ends,
``.status`` says what was read and lost and ``.summary`` what the file's summary declares.

How a file is read (see ``research/mcap.md`` §1 for how ``mcap.reader`` behaves on damage):

- **bad magic** (not an MCAP file, empty file): nothing is yielded; status problem
  ``not_mcap``.
- **summary present** (writer finished): the chunk index is walked
  (:mod:`pipeline.io.mcap_chunks`): each chunk is read with its MessageIndex records,
  decompressed and CRC-checked in a background thread, and its messages located with
  numpy from the index. A chunk that fails (bad zstd/lz4 data, CRC mismatch, a record
  running past the chunk end) is skipped and reported as ``corrupt_chunk`` with the number
  of messages lost (from its message index, when the file has one).
- **time window** ``[start_ns, end_ns)``: only chunks whose index range overlaps are read
  and decompressed; a file whose summary statistics lie wholly outside is not read beyond
  its footer and summary (``status.bytes_read`` counts what was read).
- **no summary** (writer never finished, file cut off, summary damaged): a linear scan with
  ``mcap.stream_reader.StreamReader`` that keeps every record before the first framing
  error, reported as ``truncated``. Chunks whose header time range misses the window are
  not decompressed.

Batches come in file order, which is log-time order for files written by one recorder.
Times are int64 ns (MCAP ``log_time``); windows are half-open ``[start_ns, end_ns)``.
"""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, ChunkIndex, Footer, Message, Schema, Statistics
from mcap.stream_reader import StreamReader

from pipeline.io.mcap_chunks import (
    OP_CHANNEL,
    OP_SCHEMA,
    ChunkBuffers,
    ChunkData,
    ChunkFetcher,
    CorruptChunkError,
    FetchedChunk,
    Positions,
    decompress,
    indexed_positions,
    iter_records,
    message_index_entries,
    native_positions,
    parse_chunk,
    walked_positions,
)

__all__ = [
    "ChannelBatch",
    "ChannelInfo",
    "ChunkBuffers",
    "ChunkData",
    "CorruptChunkError",
    "McapBatches",
    "McapSummary",
    "ReadProblem",
    "ReadStatus",
    "read_mcap_batches",
    "read_mcap_summary",
]

MAGIC = b"\x89MCAP0\r\n"
_FOOTER_RECORD_SIZE = 1 + 8 + 20  # opcode, length, summary_start/offset_start/crc
_LINEAR_FLUSH = 8192  # un-chunked messages per batch in a linear scan
_T_MIN, _T_MAX = -(2**63), 2**64  # an open window bound, as a comparable int

OP_CHUNK_INDEX = int(Opcode.CHUNK_INDEX)
OP_STATISTICS = int(Opcode.STATISTICS)
OP_FOOTER = int(Opcode.FOOTER)


@dataclass(frozen=True)
class ChannelInfo:
    """What a channel carries: its topic, message encoding, schema (may be empty) and the
    channel record's metadata."""

    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    metadata: dict[str, str] = field(default_factory=dict)


_NO_SPANS = np.empty(0, dtype=np.int64)


class ChannelBatch:
    """Messages of one channel from one chunk, in file order.

    ``log_time_ns``: int64 array of MCAP log times, ns; ``metadata``: the channel record's
    metadata (e.g. ``sensor_id``, ``platform_id``). The payloads are either spans
    ``chunk.raw[start[i]:end[i]]`` of a decompressed chunk (what the reader yields) or a
    ``list[bytes]`` given to the constructor. ``payloads`` always answers a
    ``list[bytes]`` (built once, on first use); bulk decoders use :meth:`spans`.
    """

    __slots__ = (
        "_payloads",
        "channel_id",
        "chunk",
        "end",
        "log_time_ns",
        "message_encoding",
        "metadata",
        "schema_data",
        "schema_encoding",
        "schema_name",
        "start",
        "topic",
    )

    def __init__(
        self,
        channel_id: int,
        topic: str,
        message_encoding: str,
        schema_name: str,
        schema_encoding: str,
        schema_data: bytes,
        log_time_ns: np.ndarray,
        payloads: list[bytes] | None = None,
        metadata: dict[str, str] | None = None,
        *,
        chunk: ChunkData | None = None,
        start: np.ndarray | None = None,
        end: np.ndarray | None = None,
    ):
        if payloads is None and chunk is None:
            raise ValueError("a ChannelBatch needs payloads or a chunk with spans")
        self.channel_id = channel_id
        self.topic = topic
        self.message_encoding = message_encoding
        self.schema_name = schema_name
        self.schema_encoding = schema_encoding
        self.schema_data = schema_data
        self.log_time_ns = np.asarray(log_time_ns, dtype=np.int64)
        self.metadata = dict(metadata or {})
        self._payloads = payloads
        self.chunk = chunk
        self.start = _NO_SPANS if start is None else start
        self.end = _NO_SPANS if end is None else end

    def __len__(self) -> int:
        return len(self.log_time_ns)

    def __repr__(self) -> str:
        return f"ChannelBatch(channel_id={self.channel_id}, topic={self.topic!r}, n={len(self)})"

    @property
    def payloads(self) -> list[bytes]:
        """The raw message bytes (a Python object per message: built on first use)."""
        if self._payloads is None:
            raw = self.chunk.raw  # type: ignore[union-attr]
            self._payloads = [
                bytes(raw[a:b])  # raw may be a view of a pooled buffer
                for a, b in zip(self.start.tolist(), self.end.tolist(), strict=True)
            ]
        return self._payloads

    def spans(self) -> tuple[ChunkData, np.ndarray, np.ndarray]:
        """``(chunk, start, end)``: payload ``i`` is ``chunk.raw[start[i]:end[i]]``. A batch
        built from a payload list gets a buffer of the payloads, each after a newline."""
        if self.chunk is None:
            payloads = self._payloads or []
            lengths = np.fromiter((len(p) for p in payloads), dtype=np.int64, count=len(payloads))
            starts = 1 + np.concatenate([[0], np.cumsum(lengths + 1)[:-1]]).astype(np.int64)
            self.chunk = ChunkData(b"\n" + b"\n".join(payloads))
            self.start, self.end = starts, starts + lengths
        return self.chunk, self.start, self.end

    def payload_lengths(self) -> np.ndarray:
        """Bytes per payload, int64."""
        if self.chunk is not None:
            return self.end - self.start
        return np.fromiter((len(p) for p in self.payloads), dtype=np.int64, count=len(self))


@dataclass(frozen=True)
class ReadProblem:
    """Something that could not be read.

    reason_code: ``not_mcap`` | ``corrupt_chunk`` | ``truncated``; ``offset``: byte offset
    in the file; ``log_time_ns``: first log time concerned (chunk start, or the last good
    message before a truncation), ``None`` when unknown; ``messages_lost``: count when
    known (from the chunk's message index), else ``None``.
    """

    reason_code: str
    detail: str
    offset: int | None = None
    log_time_ns: int | None = None
    messages_lost: int | None = None


@dataclass(frozen=True)
class McapSummary:
    """What a finished file's summary section declares.

    ``statistics``: the Statistics record (``None`` when the writer left it out);
    ``channels``: channel id -> :class:`ChannelInfo`; ``chunk_indexes``: in file order.
    """

    size_bytes: int
    statistics: Statistics | None
    channels: dict[int, ChannelInfo]
    chunk_indexes: list[ChunkIndex]


@dataclass
class ReadStatus:
    """Outcome of reading one file, complete once the batch iterator is exhausted.

    ``mode``: ``indexed`` (chunk index walk), ``linear`` (stream scan) or ``none`` (not
    read); ``messages_read``: messages yielded (inside the window);
    ``chunks_read``/``chunks_skipped``: chunks decoded / skipped as corrupt;
    ``chunks_decompressed``: chunks actually decompressed; ``bytes_read``: bytes read
    from the file; ``start_time_ns``/``end_time_ns``: min/max log time yielded;
    ``channel_counts``/``channel_spans``: messages and (first, last) log time yielded per
    channel id.
    """

    path: str
    mode: str = "none"
    messages_read: int = 0
    chunks_total: int = 0
    chunks_read: int = 0
    chunks_skipped: int = 0
    chunks_decompressed: int = 0
    bytes_read: int = 0
    start_time_ns: int | None = None
    end_time_ns: int | None = None
    problems: list[ReadProblem] = field(default_factory=list)
    channel_counts: dict[int, int] = field(default_factory=dict)
    channel_spans: dict[int, tuple[int, int]] = field(default_factory=dict)
    finished: bool = False

    @property
    def not_mcap(self) -> bool:
        return any(p.reason_code == "not_mcap" for p in self.problems)

    @property
    def messages_lost(self) -> int | None:
        """Messages known lost in skipped chunks (``None`` if some loss is uncounted)."""
        counts = [p.messages_lost for p in self.problems if p.reason_code != "not_mcap"]
        return None if any(c is None for c in counts) else sum(counts)  # type: ignore[misc]

    @property
    def status(self) -> str:
        """``ok`` | ``partial`` (something lost) | ``quarantined`` (not MCAP, or damaged
        with nothing readable)."""
        if self.not_mcap:
            return "quarantined"
        if not self.problems:
            return "ok"
        nothing_read = self.messages_read == 0 and self.chunks_read == 0
        return "quarantined" if nothing_read else "partial"

    @property
    def error(self) -> str | None:
        """One-line description of the problems, ``None`` when there were none."""
        if not self.problems:
            return None
        return "; ".join(f"{p.reason_code}: {p.detail}" for p in self.problems[:5]) + (
            f"; ... {len(self.problems) - 5} more" if len(self.problems) > 5 else ""
        )

    def note(self, channel_id: int, times: np.ndarray) -> None:
        """Count a batch of ``times`` (int64 ns) read from ``channel_id``."""
        if not len(times):
            return
        lo, hi = int(times.min()), int(times.max())
        self.messages_read += len(times)
        self.start_time_ns = lo if self.start_time_ns is None else min(self.start_time_ns, lo)
        self.end_time_ns = hi if self.end_time_ns is None else max(self.end_time_ns, hi)
        self.channel_counts[channel_id] = self.channel_counts.get(channel_id, 0) + len(times)
        old = self.channel_spans.get(channel_id)
        self.channel_spans[channel_id] = (
            (lo, hi) if old is None else (min(old[0], lo), max(old[1], hi))
        )


class _CountingFile:
    """A read-only binary file that counts the bytes it hands out."""

    def __init__(self, f: BinaryIO):
        self._f = f
        self.read_bytes = 0

    def read(self, n: int = -1) -> bytes:
        data = self._f.read(n)
        self.read_bytes += len(data)
        return data

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        return self._f.seek(offset, whence)

    def tell(self) -> int:
        return self._f.tell()


class McapBatches(Iterator[ChannelBatch]):
    """Iterator of :class:`ChannelBatch`; ``status`` is final once it is exhausted.

    ``prefetch``: read and decompress chunks in a background thread (default on);
    ``buffers``: the pool chunks are decompressed into (``None``: the reader's own).
    """

    def __init__(
        self,
        path: str | Path,
        start_ns: int | None,
        end_ns: int | None,
        *,
        prefetch: bool = True,
        buffers: ChunkBuffers | None = None,
    ):
        if start_ns is not None and end_ns is not None and end_ns <= start_ns:
            raise ValueError(f"empty time window [{start_ns}, {end_ns})")
        self.path = Path(path)
        self.start_ns = start_ns
        self.end_ns = end_ns
        self.prefetch = prefetch
        self.buffers = buffers
        self.status = ReadStatus(path=str(path))
        self.summary: McapSummary | None = None
        self._channels: dict[int, ChannelInfo] = {}
        self._schemas: dict[int, Schema] = {}
        self._lo = _T_MIN if start_ns is None else start_ns
        self._hi = _T_MAX if end_ns is None else end_ns
        self._chunks_left: int | None = None
        self._gen = self._run()

    def __iter__(self) -> McapBatches:
        return self

    def __next__(self) -> ChannelBatch:
        return next(self._gen)

    @property
    def chunks_left(self) -> int | None:
        """Chunks still to be read after the one the last batch came from (``None`` when
        unknown: linear scan without a summary)."""
        return self._chunks_left

    @property
    def channels(self) -> dict[int, ChannelInfo]:
        """Every channel met so far (summary and in-file records), by id."""
        return dict(self._channels)

    # -- top level ---------------------------------------------------------------------

    def _run(self) -> Iterator[ChannelBatch]:
        size = self.path.stat().st_size
        with open(self.path, "rb") as raw:
            f = _CountingFile(raw)
            try:
                head = f.read(len(MAGIC))
                if head != MAGIC:
                    self.status.problems.append(
                        ReadProblem("not_mcap", f"bad magic {head[:8]!r} (file size {size} B)", 0)
                    )
                else:
                    chunk_indexes, why = self._read_summary(f, size)
                    if chunk_indexes:
                        yield from self._indexed(f, size, chunk_indexes)
                    elif self.summary is not None and self._summary_outside():
                        self.status.mode = "indexed"  # no chunks, nothing in the window
                    else:
                        f.seek(len(MAGIC))
                        yield from self._linear(f, size, why)
            finally:
                self.status.bytes_read += f.read_bytes
        self.status.finished = True

    def _overlaps(self, t0: int, t1: int) -> bool:
        """Does the closed range [t0, t1] of a chunk meet the window [start, end)?"""
        return t1 >= self._lo and t0 < self._hi

    def _inside(self, t0: int, t1: int) -> bool:
        """Is the closed range [t0, t1] entirely inside the window?"""
        return t0 >= self._lo and t1 < self._hi

    def _summary_outside(self) -> bool:
        """Do the summary statistics put every message of the file outside the window?"""
        st = self.summary.statistics if self.summary else None
        if st is None or st.message_count == 0:
            return st is not None  # an empty file has nothing in any window
        return not self._overlaps(st.message_start_time, st.message_end_time)

    # -- summary -----------------------------------------------------------------------

    def _read_summary(self, f: _CountingFile, size: int) -> tuple[list[ChunkIndex], str]:
        """Chunk indexes from the summary section (schemas and channels are registered on
        the way), or ``([], why)`` when there is no usable summary."""
        tail = len(MAGIC) + _FOOTER_RECORD_SIZE
        if size < len(MAGIC) + tail:
            return [], "file too short for a footer"
        f.seek(size - tail)
        end = f.read(tail)
        if end[-len(MAGIC) :] != MAGIC or end[0] != OP_FOOTER:
            return [], "no footer (writer never finished or file cut off)"
        summary_start, _offset_start, summary_crc = struct.unpack_from("<QQI", end, 9)
        footer_at = size - tail
        if summary_start == 0:
            return [], "file has no summary section"
        if not len(MAGIC) <= summary_start <= footer_at:
            return [], f"footer points outside the file (summary_start={summary_start})"
        f.seek(summary_start)
        section = f.read(footer_at - summary_start)
        if summary_crc and zlib.crc32(section + end[: 1 + 8 + 16]) != summary_crc:
            return [], "summary CRC mismatch"
        try:
            indexes, stats = self._parse_summary(section)
        except Exception as exc:  # any damage in the summary -> fall back to a scan
            return [], f"summary unreadable ({type(exc).__name__}: {exc})"
        self.summary = McapSummary(size, stats, dict(self._channels), indexes)
        if not indexes and not self._summary_outside():
            return [], "summary has no chunk index"
        return indexes, ""

    def _parse_summary(self, section: bytes) -> tuple[list[ChunkIndex], Statistics | None]:
        indexes: list[ChunkIndex] = []
        stats = None
        for op, body in iter_records(section):
            if op in (OP_SCHEMA, OP_CHANNEL):
                self._on_record(op, body)
            elif op == OP_CHUNK_INDEX:
                indexes.append(ChunkIndex.read(_stream(body)))
            elif op == OP_STATISTICS:
                stats = Statistics.read(_stream(body))
        return sorted(indexes, key=lambda c: c.chunk_start_offset), stats

    def _on_record(self, op: int, body: memoryview | bytes) -> None:
        """Register a Schema or Channel record met in the summary or inside a chunk."""
        if op == OP_SCHEMA:
            self._add_schema(Schema.read(_stream(bytes(body))))
        elif op == OP_CHANNEL:
            self._add_channel(Channel.read(_stream(bytes(body))))

    def _add_schema(self, schema: Schema) -> None:
        self._schemas[schema.id] = schema

    def _add_channel(self, ch: Channel) -> None:
        schema = self._schemas.get(ch.schema_id)
        self._channels[ch.id] = ChannelInfo(
            topic=ch.topic,
            message_encoding=ch.message_encoding,
            schema_name=schema.name if schema else "",
            schema_encoding=schema.encoding if schema else "",
            schema_data=bytes(schema.data) if schema else b"",
            metadata=dict(ch.metadata or {}),
        )

    # -- indexed walk ------------------------------------------------------------------

    def _indexed(
        self, f: _CountingFile, size: int, indexes: list[ChunkIndex]
    ) -> Iterator[ChannelBatch]:
        self.status.mode = "indexed"
        self.status.chunks_total = len(indexes)
        if self._summary_outside():
            return  # the whole file lies outside the window: footer + summary only
        wanted = [
            ci for ci in indexes if self._overlaps(ci.message_start_time, ci.message_end_time)
        ]
        threaded = self.prefetch and len(wanted) > 1
        fetcher = ChunkFetcher(f, size, wanted, threaded=threaded, buffers=self.buffers)
        self._chunks_left = len(wanted)
        try:
            for got in fetcher:
                self._chunks_left -= 1
                yield from self._indexed_chunk(got)
        finally:
            self.status.chunks_decompressed += fetcher.decompressed

    def _indexed_chunk(self, got: FetchedChunk) -> Iterator[ChannelBatch]:
        ci = got.index
        if got.data is None:
            self._skip_chunk(ci, got.error or CorruptChunkError("unreadable"), got.message_index)
            return
        chunk = ChunkData(got.data)
        try:
            positions = self._chunk_positions(chunk, ci, got.message_index, got.walked)
        except Exception as exc:  # skip this chunk only; see module docstring
            self._skip_chunk(ci, exc, got.message_index)
            return
        self.status.chunks_read += 1
        yield from self._emit(chunk, positions)

    def _chunk_positions(
        self, chunk: ChunkData, ci: ChunkIndex, mi: bytes, walked: object = None
    ) -> Positions:
        lo, hi = (
            (_T_MIN, _T_MAX)
            if self._inside(ci.message_start_time, ci.message_end_time)
            else (
                self._lo,
                self._hi,
            )
        )
        positions = native_positions(chunk, lo, hi, self._on_record, walked)
        if positions is None and mi:
            try:
                entries = message_index_entries(mi)
            except CorruptChunkError:
                entries = {}
            positions = indexed_positions(chunk, entries, lo, hi, self._on_record)
        if positions is None:
            positions = walked_positions(chunk, lo, hi, self._on_record)
        return positions

    def _skip_chunk(self, ci: ChunkIndex, exc: Exception, mi: bytes) -> None:
        self.status.chunks_skipped += 1
        self.status.problems.append(
            ReadProblem(
                "corrupt_chunk",
                f"chunk at byte {ci.chunk_start_offset} skipped ({type(exc).__name__}: {exc})",
                offset=ci.chunk_start_offset,
                log_time_ns=ci.message_start_time,
                messages_lost=self._count_indexed(mi),
            )
        )

    def _count_indexed(self, mi: bytes) -> int | None:
        """Messages of a chunk inside the window, from its MessageIndex records."""
        if not mi:
            return None
        try:
            entries = message_index_entries(mi)
        except Exception:  # an unreadable index only makes the loss uncounted
            return None
        if not entries:
            return None
        return sum(
            int(np.count_nonzero((t >= self._lo) & (t < self._hi))) for t, _ in entries.values()
        )

    # -- batches -----------------------------------------------------------------------

    def _info(self, ch_id: int) -> ChannelInfo:
        return self._channels.get(ch_id) or ChannelInfo(
            f"<unknown channel {ch_id}>", "", "", "", b""
        )

    def _batch(self, ch_id: int, times: np.ndarray, **payloads: Any) -> ChannelBatch:
        """A batch of channel ``ch_id`` (payloads as spans or as a list), counted."""
        info = self._info(ch_id)
        self.status.note(ch_id, times)
        return ChannelBatch(
            ch_id,
            info.topic,
            info.message_encoding,
            info.schema_name,
            info.schema_encoding,
            info.schema_data,
            times,
            metadata=info.metadata,
            **payloads,
        )

    def _emit(self, chunk: ChunkData, positions: Positions) -> Iterator[ChannelBatch]:
        for ch_id in sorted(positions):
            times, start, end = positions[ch_id]
            if len(times):
                yield self._batch(ch_id, times, chunk=chunk, start=start, end=end)

    def _emit_lists(
        self, pending: dict[int, tuple[list[int], list[bytes]]]
    ) -> Iterator[ChannelBatch]:
        """Batches of un-chunked messages collected by the linear scan."""
        for ch_id in sorted(pending):
            times_list, payloads = pending[ch_id]
            if payloads:
                times = np.asarray(times_list, dtype=np.uint64).astype(np.int64)
                yield self._batch(ch_id, times, payloads=payloads)
        pending.clear()

    # -- linear scan -------------------------------------------------------------------

    def _linear(self, f: _CountingFile, size: int, why: str) -> Iterator[ChannelBatch]:
        """Scan records from the start until the footer or the first framing error."""
        self.status.mode = "linear"
        reader = StreamReader(f, skip_magic=True, emit_chunks=True, record_size_limit=size)  # type: ignore[arg-type]
        pending: dict[int, tuple[list[int], list[bytes]]] = {}
        records = reader.records
        while True:
            try:
                record = next(records)
            except StopIteration:
                break
            except Exception as exc:  # damaged bytes: any parse error is the stop point
                yield from self._emit_lists(pending)
                self._truncated(f, why, exc)
                return
            if isinstance(record, Footer):
                break
            yield from self._linear_record(f, record, pending)
        yield from self._emit_lists(pending)

    def _linear_record(
        self,
        f: _CountingFile,
        record: object,
        pending: dict[int, tuple[list[int], list[bytes]]],
    ) -> Iterator[ChannelBatch]:
        if isinstance(record, Schema):
            self._add_schema(record)
        elif isinstance(record, Channel):
            self._add_channel(record)
        elif isinstance(record, Message):
            # un-chunked messages only (rare): one object per message from StreamReader
            if self._lo <= record.log_time < self._hi:
                lists = pending.setdefault(record.channel_id, ([], []))
                lists[0].append(record.log_time)
                lists[1].append(bytes(record.data))
                if len(lists[1]) >= _LINEAR_FLUSH:
                    yield from self._emit_lists({record.channel_id: pending.pop(record.channel_id)})
        elif isinstance(record, Chunk):
            yield from self._linear_chunk(f, record)

    def _linear_chunk(self, f: _CountingFile, record: Chunk) -> Iterator[ChannelBatch]:
        self.status.chunks_total += 1
        if not self._overlaps(record.message_start_time, record.message_end_time):
            return
        try:
            data = decompress(parse_chunk(_chunk_body(record)))
            self.status.chunks_decompressed += 1
            chunk = ChunkData(data)
            inside = self._inside(record.message_start_time, record.message_end_time)
            lo, hi = (_T_MIN, _T_MAX) if inside else (self._lo, self._hi)
            positions = native_positions(chunk, lo, hi, self._on_record)
            if positions is None:
                positions = walked_positions(chunk, lo, hi, self._on_record)
        except Exception as exc:  # skip this chunk only
            self.status.chunks_skipped += 1
            self.status.problems.append(
                ReadProblem(
                    "corrupt_chunk",
                    f"chunk before byte {f.tell()} skipped ({type(exc).__name__}: {exc})",
                    offset=f.tell(),
                    log_time_ns=record.message_start_time,
                )
            )
            return
        self.status.chunks_read += 1
        yield from self._emit(chunk, positions)

    def _truncated(self, f: _CountingFile, why: str, exc: Exception) -> None:
        at = f.tell()
        self.status.problems.append(
            ReadProblem(
                "truncated",
                f"{why}; scan stopped at byte {at} ({type(exc).__name__}: {exc}); "
                f"kept {self.status.messages_read} messages before it",
                offset=at,
                log_time_ns=self.status.end_time_ns,
            )
        )


def read_mcap_batches(
    path: str | Path,
    *,
    start_ns: int | None = None,
    end_ns: int | None = None,
    prefetch: bool = True,
    buffers: ChunkBuffers | None = None,
) -> McapBatches:
    """Per-channel batches of the messages with log time in ``[start_ns, end_ns)``.

    Iterate the result; afterwards ``result.status`` (:class:`ReadStatus`) holds messages
    read, chunks skipped and what was lost, and ``result.summary`` the file's summary
    (``None`` when it has none). Never raises on damaged content (only on an unreadable
    path, e.g. ``FileNotFoundError``). ``buffers``: a pool of decompression buffers to
    reuse (a job reading many files passes one; ``None``: the reader makes its own).
    """
    return McapBatches(path, start_ns, end_ns, prefetch=prefetch, buffers=buffers)


def read_mcap_summary(path: str | Path) -> McapSummary | None:
    """The summary of a finished MCAP file (footer and summary section only), or ``None``
    when the file has none (or is not MCAP)."""
    scan = McapBatches(path, 0, 1)  # a window no chunk is read for: summary only
    with open(path, "rb") as raw:
        f = _CountingFile(raw)
        if f.read(len(MAGIC)) != MAGIC:
            return None
        scan._read_summary(f, Path(path).stat().st_size)
    return scan.summary


# -- record helpers ----------------------------------------------------------------------


def _stream(body: bytes) -> ReadDataStream:
    return ReadDataStream(io.BytesIO(body))


def _chunk_body(record: Chunk) -> bytes:
    """Re-pack a Chunk read by ``StreamReader`` into the record body :func:`parse_chunk`
    reads (the stream reader has already split it into fields)."""
    comp = record.compression.encode()
    head = struct.pack(
        "<QQQII",
        record.message_start_time,
        record.message_end_time,
        record.uncompressed_size,
        record.uncompressed_crc,
        len(comp),
    )
    return head + comp + struct.pack("<Q", len(record.data)) + bytes(record.data)
