"""Read an MCAP file as per-channel column batches, chunk by chunk, surviving damage.

``read_mcap_batches(path)`` yields one :class:`ChannelBatch` per (chunk, channel): the
channel's encodings and schema, ``log_time_ns`` as an int64 numpy array and the raw
payloads. Memory holds one chunk at a time (about 1 MiB uncompressed with the default
writer), not the file. When the iteration ends, ``.status`` says what was read and lost.

How a file is read (see ``research/mcap.md`` §1 for how ``mcap.reader`` behaves on damage):

- **bad magic** (not an MCAP file, empty file): nothing is yielded; status problem
  ``not_mcap``.
- **summary present** (writer finished): the chunk index is walked; each chunk is read,
  decompressed, CRC-checked and its records parsed on its own. A chunk that fails (bad
  zstd/lz4 data, CRC mismatch, a record running past the chunk end) is skipped and reported
  as ``corrupt_chunk`` with the number of messages lost (from its message index, when the
  file has one). With a time window only chunks whose index range overlaps are read.
- **no summary** (writer never finished, file cut off, summary damaged): a linear scan with
  ``mcap.stream_reader.StreamReader`` that keeps every record before the first framing
  error, reported as ``truncated``. Chunks whose header time range misses the window are
  not decompressed.

Records inside a chunk are parsed with ``struct.unpack_from`` on the decompressed buffer,
without a Python object per message (the ``mcap`` reader builds one per message and
heap-merges chunks: ~10x slower, measured in ``research/mcap.md`` §3). Batches come in file
order, which is log-time order for files written by one recorder.

Times are int64 ns (MCAP ``log_time``); windows are half-open ``[start_ns, end_ns)``.
"""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, ChunkIndex, Footer, Message, Schema
from mcap.stream_reader import StreamReader

try:
    import zstandard
except ImportError:  # pragma: no cover - zstandard is a dependency of mcap
    zstandard = None
try:
    import lz4.frame as lz4_frame
except ImportError:  # pragma: no cover - lz4 is a dependency of mcap
    lz4_frame = None

MAGIC = b"\x89MCAP0\r\n"
_FOOTER_RECORD_SIZE = 1 + 8 + 20  # opcode, length, summary_start/offset_start/crc
_REC_HEAD = struct.Struct("<BQ")  # opcode, record length
_MSG_HEAD = struct.Struct("<HIQQ")  # channel_id, sequence, log_time, publish_time
_MSG_HEAD_SIZE = _MSG_HEAD.size  # 22
_LINEAR_FLUSH = 8192  # un-chunked messages per batch in a linear scan

OP_SCHEMA = int(Opcode.SCHEMA)
OP_CHANNEL = int(Opcode.CHANNEL)
OP_MESSAGE = int(Opcode.MESSAGE)
OP_CHUNK = int(Opcode.CHUNK)
OP_MESSAGE_INDEX = int(Opcode.MESSAGE_INDEX)
OP_CHUNK_INDEX = int(Opcode.CHUNK_INDEX)
OP_FOOTER = int(Opcode.FOOTER)


class CorruptChunkError(ValueError):
    """A chunk's bytes cannot be turned into records."""


@dataclass(frozen=True)
class ChannelInfo:
    """What a channel carries: its topic, message encoding and schema (may be empty)."""

    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes


@dataclass(frozen=True)
class ChannelBatch:
    """Messages of one channel from one chunk, in file order.

    ``log_time_ns``: int64 array of MCAP log times, ns; ``payloads``: raw message bytes.
    """

    channel_id: int
    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    log_time_ns: np.ndarray
    payloads: list[bytes]

    def __len__(self) -> int:
        return len(self.payloads)


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


@dataclass
class ReadStatus:
    """Outcome of reading one file, complete once the batch iterator is exhausted.

    ``mode``: ``indexed`` (chunk index walk), ``linear`` (stream scan) or ``none`` (not
    read); ``messages_read``: messages yielded (inside the window);
    ``chunks_read``/``chunks_skipped``: chunks decoded / skipped as corrupt;
    ``start_time_ns``/``end_time_ns``: min/max log time yielded.
    """

    path: str
    mode: str = "none"
    messages_read: int = 0
    chunks_total: int = 0
    chunks_read: int = 0
    chunks_skipped: int = 0
    start_time_ns: int | None = None
    end_time_ns: int | None = None
    problems: list[ReadProblem] = field(default_factory=list)
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

    def _note_times(self, times: np.ndarray) -> None:
        if not len(times):
            return
        lo, hi = int(times.min()), int(times.max())
        self.start_time_ns = lo if self.start_time_ns is None else min(self.start_time_ns, lo)
        self.end_time_ns = hi if self.end_time_ns is None else max(self.end_time_ns, hi)


class McapBatches(Iterator[ChannelBatch]):
    """Iterator of :class:`ChannelBatch`; ``status`` is final once it is exhausted."""

    def __init__(self, path: str | Path, start_ns: int | None, end_ns: int | None):
        if start_ns is not None and end_ns is not None and end_ns <= start_ns:
            raise ValueError(f"empty time window [{start_ns}, {end_ns})")
        self.path = Path(path)
        self.start_ns = start_ns
        self.end_ns = end_ns
        self.status = ReadStatus(path=str(path))
        self._channels: dict[int, ChannelInfo] = {}
        self._schemas: dict[int, Schema] = {}
        self._gen = self._run()

    def __iter__(self) -> McapBatches:
        return self

    def __next__(self) -> ChannelBatch:
        return next(self._gen)

    # -- top level ---------------------------------------------------------------------

    def _run(self) -> Iterator[ChannelBatch]:
        size = self.path.stat().st_size
        with open(self.path, "rb") as f:
            head = f.read(len(MAGIC))
            if head != MAGIC:
                self.status.problems.append(
                    ReadProblem("not_mcap", f"bad magic {head[:8]!r} (file size {size} B)", 0)
                )
            else:
                chunk_indexes, why = self._read_summary(f, size)
                if chunk_indexes:
                    yield from self._indexed(f, size, chunk_indexes)
                else:
                    f.seek(len(MAGIC))
                    yield from self._linear(f, size, why)
        self.status.finished = True

    def _overlaps(self, t0: int, t1: int) -> bool:
        """Does the closed range [t0, t1] of a chunk meet the window [start, end)?"""
        if self.start_ns is not None and t1 < self.start_ns:
            return False
        return not (self.end_ns is not None and t0 >= self.end_ns)

    def _inside(self, t0: int, t1: int) -> bool:
        """Is the closed range [t0, t1] entirely inside the window?"""
        lo_ok = self.start_ns is None or t0 >= self.start_ns
        return lo_ok and (self.end_ns is None or t1 < self.end_ns)

    # -- summary -----------------------------------------------------------------------

    def _read_summary(self, f: io.BufferedReader, size: int) -> tuple[list[ChunkIndex], str]:
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
            return self._parse_summary(section), ""
        except Exception as exc:  # any damage in the summary -> fall back to a scan
            return [], f"summary unreadable ({type(exc).__name__}: {exc})"

    def _parse_summary(self, section: bytes) -> list[ChunkIndex]:
        indexes: list[ChunkIndex] = []
        for op, body in _iter_records(section):
            if op == OP_SCHEMA:
                self._add_schema(Schema.read(_stream(body)))
            elif op == OP_CHANNEL:
                self._add_channel(Channel.read(_stream(body)))
            elif op == OP_CHUNK_INDEX:
                indexes.append(ChunkIndex.read(_stream(body)))
        return sorted(indexes, key=lambda c: c.chunk_start_offset)

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
        )

    # -- indexed walk ------------------------------------------------------------------

    def _indexed(
        self, f: io.BufferedReader, size: int, indexes: list[ChunkIndex]
    ) -> Iterator[ChannelBatch]:
        self.status.mode = "indexed"
        self.status.chunks_total = len(indexes)
        for ci in indexes:
            if not self._overlaps(ci.message_start_time, ci.message_end_time):
                continue
            try:
                if ci.chunk_start_offset + ci.chunk_length > size:
                    raise CorruptChunkError("chunk index points past the end of the file")
                f.seek(ci.chunk_start_offset)
                chunk = _parse_chunk_record(f.read(ci.chunk_length))
                per_channel = self._chunk_messages(chunk)
            except Exception as exc:  # skip this chunk only; see module docstring
                self._skip_chunk(f, ci, exc)
                continue
            self.status.chunks_read += 1
            yield from self._emit(per_channel)

    def _skip_chunk(self, f: io.BufferedReader, ci: ChunkIndex, exc: Exception) -> None:
        self.status.chunks_skipped += 1
        self.status.problems.append(
            ReadProblem(
                "corrupt_chunk",
                f"chunk at byte {ci.chunk_start_offset} skipped ({type(exc).__name__}: {exc})",
                offset=ci.chunk_start_offset,
                log_time_ns=ci.message_start_time,
                messages_lost=self._count_indexed(f, ci),
            )
        )

    def _count_indexed(self, f: io.BufferedReader, ci: ChunkIndex) -> int | None:
        """Messages of a chunk inside the window, from its MessageIndex records."""
        if not ci.message_index_offsets or ci.message_index_length == 0:
            return None
        try:
            f.seek(min(ci.message_index_offsets.values()))
            buf = f.read(ci.message_index_length)
            n = 0
            for op, body in _iter_records(buf):
                if op != OP_MESSAGE_INDEX:
                    continue
                (rec_len,) = struct.unpack_from("<I", body, 2)
                times = np.frombuffer(body, dtype="<u8", count=rec_len // 8, offset=6)[::2]
                n += int(np.count_nonzero(self._mask(times.astype(np.int64))))
            return n
        except Exception:  # an unreadable index only makes the loss uncounted
            return None

    def _mask(self, times: np.ndarray) -> np.ndarray:
        mask = np.ones(len(times), dtype=bool)
        if self.start_ns is not None:
            mask &= times >= self.start_ns
        if self.end_ns is not None:
            mask &= times < self.end_ns
        return mask

    # -- chunk contents ----------------------------------------------------------------

    def _chunk_messages(self, chunk: Chunk) -> dict[int, tuple[list[int], list[bytes]]]:
        """Decompress and parse a chunk: ``{channel_id: (log_times, payloads)}`` in the
        window. Schema/Channel records inside the chunk are registered."""
        data = _decompress(chunk)
        window = None
        if not self._inside(chunk.message_start_time, chunk.message_end_time):
            lo = -(2**63) if self.start_ns is None else self.start_ns
            hi = 2**63 if self.end_ns is None else self.end_ns
            window = (lo, hi)
        return self._walk_records(data, window)

    def _walk_records(
        self, data: bytes, window: tuple[int, int] | None
    ) -> dict[int, tuple[list[int], list[bytes]]]:
        out: dict[int, tuple[list[int], list[bytes]]] = {}
        unpack_rec, unpack_msg = _REC_HEAD.unpack_from, _MSG_HEAD.unpack_from
        pos, n = 0, len(data)
        while pos < n:
            if pos + 9 > n:
                raise CorruptChunkError(f"record header cut at chunk byte {pos}")
            op, length = unpack_rec(data, pos)
            body, end = pos + 9, pos + 9 + length
            if end > n:
                raise CorruptChunkError(f"record at chunk byte {pos} runs past the chunk end")
            if op == OP_MESSAGE:
                if length < _MSG_HEAD_SIZE:
                    raise CorruptChunkError(f"message record too short at chunk byte {pos}")
                ch, _seq, t, _pub = unpack_msg(data, body)
                if window is None or window[0] <= t < window[1]:
                    lists = out.get(ch)
                    if lists is None:
                        lists = out[ch] = ([], [])
                    lists[0].append(t)
                    lists[1].append(data[body + _MSG_HEAD_SIZE : end])
            elif op == OP_SCHEMA:
                self._add_schema(Schema.read(_stream(data[body:end])))
            elif op == OP_CHANNEL:
                self._add_channel(Channel.read(_stream(data[body:end])))
            pos = end
        return out

    def _emit(
        self, per_channel: dict[int, tuple[list[int], list[bytes]]]
    ) -> Iterator[ChannelBatch]:
        for ch_id in sorted(per_channel):
            times_list, payloads = per_channel[ch_id]
            if not payloads:
                continue
            times = np.asarray(times_list, dtype=np.uint64).astype(np.int64)
            info = self._channels.get(ch_id) or ChannelInfo(
                f"<unknown channel {ch_id}>", "", "", "", b""
            )
            self.status.messages_read += len(payloads)
            self.status._note_times(times)
            yield ChannelBatch(
                channel_id=ch_id,
                topic=info.topic,
                message_encoding=info.message_encoding,
                schema_name=info.schema_name,
                schema_encoding=info.schema_encoding,
                schema_data=info.schema_data,
                log_time_ns=times,
                payloads=payloads,
            )

    # -- linear scan -------------------------------------------------------------------

    def _linear(self, f: io.BufferedReader, size: int, why: str) -> Iterator[ChannelBatch]:
        """Scan records from the start until the footer or the first framing error."""
        self.status.mode = "linear"
        reader = StreamReader(f, skip_magic=True, emit_chunks=True, record_size_limit=size)
        pending: dict[int, tuple[list[int], list[bytes]]] = {}
        records = reader.records
        while True:
            try:
                record = next(records)
            except StopIteration:
                break
            except Exception as exc:  # damaged bytes: any parse error is the stop point
                yield from self._emit(pending)
                self._truncated(f, why, exc)
                return
            if isinstance(record, Footer):
                break
            yield from self._linear_record(f, record, pending)
        yield from self._emit(pending)

    def _linear_record(
        self,
        f: io.BufferedReader,
        record: object,
        pending: dict[int, tuple[list[int], list[bytes]]],
    ) -> Iterator[ChannelBatch]:
        if isinstance(record, Schema):
            self._add_schema(record)
        elif isinstance(record, Channel):
            self._add_channel(record)
        elif isinstance(record, Message):
            if self._overlaps(record.log_time, record.log_time):
                lists = pending.setdefault(record.channel_id, ([], []))
                lists[0].append(record.log_time)
                lists[1].append(bytes(record.data))
                if len(lists[1]) >= _LINEAR_FLUSH:
                    yield from self._emit({record.channel_id: pending.pop(record.channel_id)})
        elif isinstance(record, Chunk):
            self.status.chunks_total += 1
            if not self._overlaps(record.message_start_time, record.message_end_time):
                return
            try:
                per_channel = self._chunk_messages(record)
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
            yield from self._emit(per_channel)

    def _truncated(self, f: io.BufferedReader, why: str, exc: Exception) -> None:
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
    path: str | Path, *, start_ns: int | None = None, end_ns: int | None = None
) -> McapBatches:
    """Per-channel batches of the messages with log time in ``[start_ns, end_ns)``.

    Iterate the result; afterwards ``result.status`` (:class:`ReadStatus`) holds messages
    read, chunks skipped and what was lost. Never raises on damaged content (only on an
    unreadable path, e.g. ``FileNotFoundError``).
    """
    return McapBatches(path, start_ns, end_ns)


# -- record helpers ----------------------------------------------------------------------


def _stream(body: bytes) -> ReadDataStream:
    return ReadDataStream(io.BytesIO(body))


def _iter_records(buf: bytes) -> Iterator[tuple[int, bytes]]:
    """``(opcode, body)`` of consecutive records in ``buf``; raises on a cut record."""
    pos, n = 0, len(buf)
    while pos < n:
        if pos + 9 > n:
            raise CorruptChunkError(f"record header cut at byte {pos}")
        op, length = _REC_HEAD.unpack_from(buf, pos)
        end = pos + 9 + length
        if end > n:
            raise CorruptChunkError(f"record at byte {pos} runs past the end")
        yield op, buf[pos + 9 : end]
        pos = end


def _parse_chunk_record(buf: bytes) -> Chunk:
    """A Chunk record (opcode, length, fields) from its raw bytes."""
    if len(buf) < 9 or buf[0] != OP_CHUNK:
        raise CorruptChunkError("no chunk record at the indexed offset")
    (length,) = struct.unpack_from("<Q", buf, 1)
    if 9 + length > len(buf):
        raise CorruptChunkError("chunk record longer than its index says")
    return Chunk.read(_stream(buf[9 : 9 + length]))


def _decompress(chunk: Chunk) -> bytes:
    """Uncompressed records of a chunk, size- and CRC-checked."""
    if chunk.compression == "zstd":
        if zstandard is None:
            raise CorruptChunkError("zstd chunk but the zstandard module is missing")
        data = zstandard.ZstdDecompressor().decompress(
            chunk.data, max_output_size=chunk.uncompressed_size
        )
    elif chunk.compression == "lz4":
        if lz4_frame is None:
            raise CorruptChunkError("lz4 chunk but the lz4 module is missing")
        data = lz4_frame.decompress(chunk.data)
    elif chunk.compression == "":
        data = bytes(chunk.data)
    else:
        raise CorruptChunkError(f"unknown compression {chunk.compression!r}")
    if len(data) != chunk.uncompressed_size:
        raise CorruptChunkError(
            f"decompressed {len(data)} B, chunk header says {chunk.uncompressed_size} B"
        )
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise CorruptChunkError("uncompressed CRC mismatch")
    return data
