"""MCAP chunks without a Python object per message: fetch, decompress, locate messages.

The ``mcap`` package's reader builds a ``Message`` object per record and heap-merges
chunks that are already in order (``research/mcap.md`` §1, §3: ~10x slower than the file
can be read). Here a chunk is handled as one buffer:

1. :class:`ChunkFetcher` reads each selected chunk record and the MessageIndex records that
   follow it, decompresses (zstd / lz4 / none) and checks size and CRC, in
   ``FETCH_THREADS`` background thread(s) up to ``PREFETCH_BYTES`` ahead of the consumer
   (file reads, ``zstandard``, ``lz4`` and ``crc32`` release the GIL, so this overlaps
   with decoding). The CRC-32 is zlib-ng's (PCLMULQDQ folding, ~3.5x zlib's here: 0.04
   vs 0.14 CPU-s per 471 MB). zstd chunks are decompressed into reused buffers
   (:class:`ChunkBuffers`): a fresh buffer per chunk costs a page fault per 4 KiB, -13%
   of decompression cycles.
2. :func:`indexed_positions` turns the MessageIndex entries into per-channel arrays
   ``(log_time_ns, payload start, payload end)`` with numpy over all messages at once and
   checks them against the record headers in the buffer (opcode, channel id, log time,
   record lengths tiling the chunk). Bytes the index does not cover (Schema and Channel
   records, usually at the start of a chunk) are walked record by record.
3. :func:`walk_records` is that record-by-record walk (``struct.unpack_from``, ints only,
   no bytes copied): the fallback for chunks without a usable index and for the gaps.
4. :func:`native_positions`: the same walk in C (``_mcap_records.c``) over every record;
   when the extension is built it replaces 2 and 3 (a few microseconds per chunk).

MCAP record layout (mcap.dev/spec): ``opcode u8 | length u64 | body``; a Message body is
``channel_id u16 | sequence u32 | log_time u64 | publish_time u64 | data``, so a payload
starts 31 bytes after its record.
"""

from __future__ import annotations

import struct
import sys
import threading
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import BinaryIO

import numpy as np
from mcap.opcode import Opcode
from mcap.records import ChunkIndex

try:
    import zstandard
except ImportError:  # pragma: no cover - zstandard is a dependency of mcap
    zstandard = None
try:
    import lz4.frame as lz4_frame
except ImportError:  # pragma: no cover - lz4 is a dependency of mcap
    lz4_frame = None
try:
    from zlib_ng.zlib_ng import crc32
except ImportError:  # pragma: no cover - zlib-ng is a dependency; same values, slower
    from zlib import crc32
try:
    from pipeline.io import _mcap_records
except ImportError:  # built without a C compiler: the numpy/Python walks are used
    _mcap_records = None

OP_SCHEMA = int(Opcode.SCHEMA)
OP_CHANNEL = int(Opcode.CHANNEL)
OP_MESSAGE = int(Opcode.MESSAGE)
OP_CHUNK = int(Opcode.CHUNK)
OP_MESSAGE_INDEX = int(Opcode.MESSAGE_INDEX)

REC_HEAD = struct.Struct("<BQ")  # opcode, record length
MSG_HEAD = struct.Struct("<HIQQ")  # channel_id, sequence, log_time, publish_time
PAYLOAD_OFFSET = REC_HEAD.size + MSG_HEAD.size  # 31: record start -> message data
_CHUNK_FIXED = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, len(compression)
PAD = 16  # zero bytes after a chunk's records so 8-byte gathers never run off the end
_MSG_RECORD = np.dtype(
    [("op", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"),
     ("log_time", "<u8"), ("publish_time", "<u8")]
)  # fmt: skip
# decompressed bytes fetched ahead of the consumer (at least 2 chunks). The consumer
# submits the fetches as it iterates, so this is also how long the fetch thread can go
# on while the consumer parses: 16 MiB touched fewer fresh pages (-12 k page faults per
# file) but made a 1 M JSON ingest ~0.25 s slower
PREFETCH_BYTES = 64 << 20
FETCH_THREADS = 1  # decompressing threads (2 cost ~5% more CPU for no gain on 2 cores)
POOLED_MAX_BYTES = 16 << 20  # chunks claiming more are decompressed into a fresh buffer

Positions = dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]
"""channel id -> (log_time_ns int64, payload start int64, payload end int64), file order."""


class CorruptChunkError(ValueError):
    """A chunk's bytes cannot be turned into records."""


class ChunkData:
    """The decompressed records of one chunk.

    ``raw``: the bytes (``bytes``, or a read-only ``memoryview`` of a pooled buffer: take
    ``bytes(raw[a:b])`` to keep a payload beyond the chunk); ``arr``: a read-only uint8
    view of them; :meth:`padded`: a copy with ``PAD`` zero bytes appended (built once,
    for unaligned 8-byte gathers); ``cache``: derived arrays that several decoders share
    (e.g. comma positions of JSON payloads).
    """

    __slots__ = ("_padded", "arr", "cache", "raw")

    def __init__(self, raw: bytes | memoryview):
        self.raw = raw
        self.arr = np.frombuffer(raw, dtype=np.uint8)
        self._padded: np.ndarray | None = None
        self.cache: dict[str, object] = {}

    @property
    def size(self) -> int:
        return len(self.raw)

    def padded(self) -> np.ndarray:
        if self._padded is None:
            out = np.zeros(len(self.raw) + PAD, dtype=np.uint8)
            out[: len(self.raw)] = self.arr
            self._padded = out
        return self._padded


def unaligned(buf: np.ndarray, dtype: str) -> np.ndarray:
    """View of ``buf`` (uint8) as little-endian ``dtype`` words starting at EVERY byte:
    ``unaligned(buf, "<u8")[p]`` is the 8-byte word at byte ``p`` (no copy)."""
    width = np.dtype(dtype).itemsize
    n = max(len(buf) - width + 1, 0)
    return np.ndarray((n,), dtype=dtype, buffer=buf, offset=0, strides=(1,))


# -- chunk records ---------------------------------------------------------------------


@dataclass(frozen=True)
class ChunkHeader:
    """Fields of a Chunk record; ``records``: the (compressed) records, a memoryview."""

    message_start_time: int
    message_end_time: int
    uncompressed_size: int
    uncompressed_crc: int
    compression: str
    records: memoryview


def parse_chunk(body: memoryview | bytes) -> ChunkHeader:
    """A Chunk record's body (after opcode and length) -> :class:`ChunkHeader`."""
    body = memoryview(body)
    if len(body) < _CHUNK_FIXED.size:
        raise CorruptChunkError("chunk record too short")
    t0, t1, usize, crc, clen = _CHUNK_FIXED.unpack_from(body, 0)
    pos = _CHUNK_FIXED.size
    if pos + clen + 8 > len(body):
        raise CorruptChunkError("chunk compression field runs past the record")
    compression = bytes(body[pos : pos + clen]).decode("utf-8", "replace")
    pos += clen
    (rlen,) = struct.unpack_from("<Q", body, pos)
    pos += 8
    if pos + rlen > len(body):
        raise CorruptChunkError("chunk records run past the record")
    return ChunkHeader(t0, t1, usize, crc, compression, body[pos : pos + rlen])


class ChunkBuffers:
    """Output buffers for decompressed chunks, reused once nothing refers to them.

    Decompressing into a new ``bytes`` per chunk touches fresh pages (the kernel maps and
    zeroes each 4 KiB: 57% of an ingest's page faults, 13% of its decompression cycles).
    A buffer is handed out again only when its reference count shows that no view, array
    or ``ChunkData`` still holds it, so rows that outlive their chunk are never
    overwritten; at most ``limit`` buffers are kept, beyond that a fresh one is used.
    """

    def __init__(self, limit: int):
        self._limit = limit
        self._buffers: list[bytearray] = []
        self._next = 0  # where the search for an idle buffer starts
        self._lock = threading.Lock()  # fetch threads take buffers concurrently

    def take(self, size: int) -> bytearray:
        """An idle buffer of at least ``size`` bytes (a new one if none is idle).

        The search starts after the buffer handed out last: buffers come back in about
        the order they went out, so the first one looked at is usually idle (a scan from
        the start looked at ~30 per chunk)."""
        with self._lock:
            n = len(self._buffers)
            for k in range(n):
                i = (self._next + k) % n
                if _references(self._buffers, i) == _IDLE_REFERENCES:
                    if len(self._buffers[i]) < size:
                        self._buffers[i] = bytearray(_capacity(size))
                    self._next = i + 1
                    return self._buffers[i]
            buf = bytearray(_capacity(size))
            if n < self._limit:
                self._buffers.append(buf)
                self._next = 0  # the new buffer went out last: start after it
            return buf


# buffers a pool keeps: what can be alive at once, the chunks fetched ahead plus those a
# consumer holds (a pending JSON parse keeps up to registry.JSON_MAX_CHUNKS = 64). A job
# that reads many files passes one pool to every reader (pipeline.ingest.IngestContext):
# it touches fresh memory for its first file only
POOL_BUFFERS = (PREFETCH_BYTES >> 20) + 72


_GRAIN = 64 << 10  # pool buffer sizes are multiples of this (see _capacity)


def _capacity(size: int) -> int:
    """A buffer's size for ``size`` bytes: rounded up to 64 KiB, so that chunks of about
    the same size fit each other's buffers (a writer closes a chunk once it passes its
    target size: the sizes differ by up to a message; replacing a buffer whenever a
    slightly longer chunk came allocated 40-70 MiB anew per 1 M-message file)."""
    return -(-size // _GRAIN) * _GRAIN


def _references(buffers: list[bytearray], i: int) -> int:
    return sys.getrefcount(buffers[i])


# what _references counts for a buffer held by its list alone (the interpreter's own
# count of the call's argument differs between CPython versions, so it is measured)
_IDLE_REFERENCES = _references([bytearray(1)], 0)


def decompress(
    head: ChunkHeader, zstd: object | None = None, buffers: ChunkBuffers | None = None
) -> bytes | memoryview:
    """Uncompressed records of a chunk, size- and CRC-checked (``CorruptChunkError``).

    ``zstd``: a ``zstandard.ZstdDecompressor`` to reuse (one per thread); ``buffers``:
    where zstd chunks of at most ``POOLED_MAX_BYTES`` are decompressed (the result is
    then a read-only view of a pooled buffer)."""
    if head.compression == "zstd":
        if zstandard is None:
            raise CorruptChunkError("zstd chunk but the zstandard module is missing")
        dz = zstd if zstd is not None else zstandard.ZstdDecompressor()
        if buffers is not None and head.uncompressed_size <= POOLED_MAX_BYTES:
            data = _zstd_into(dz, head, buffers)
        else:
            data = _zstd_fresh(dz, head)
    elif head.compression == "lz4":
        if lz4_frame is None:
            raise CorruptChunkError("lz4 chunk but the lz4 module is missing")
        data = lz4_frame.decompress(head.records)
    elif head.compression == "":
        data = bytes(head.records)
    else:
        raise CorruptChunkError(f"unknown compression {head.compression!r}")
    if len(data) != head.uncompressed_size:
        raise CorruptChunkError(
            f"decompressed {len(data)} B, chunk header says {head.uncompressed_size} B"
        )
    if head.uncompressed_crc and crc32(data) != head.uncompressed_crc:
        raise CorruptChunkError("uncompressed CRC mismatch")
    return data


def _zstd_into(dz: object, head: ChunkHeader, buffers: ChunkBuffers) -> memoryview:
    """The zstd frame(s) of ``head`` decompressed into a pooled buffer: a read-only view of
    what they hold, up to one byte more than the header claims (a longer frame then
    fails the size check)."""
    cap = head.uncompressed_size + 1
    out = memoryview(buffers.take(cap))
    got = 0
    size = max(len(head.records), 1)
    with dz.stream_reader(head.records, read_size=size, read_across_frames=True) as reader:
        while got < cap:
            n = reader.readinto(out[got:cap])
            if n == 0:
                break
            got += n
    return out[:got].toreadonly()


def _zstd_fresh(dz: object, head: ChunkHeader) -> memoryview:
    """The zstd frame(s) of ``head`` decompressed into a new buffer (a read-only view of
    it), up to one byte more than the header claims (``ZstdDecompressor.decompress``
    would stop after the first frame). It grows by at most 16 MiB per read, as the data
    comes: a header claiming more than the frames hold allocates no more than they do."""
    cap = head.uncompressed_size + 1
    out = bytearray()
    with dz.stream_reader(head.records, read_across_frames=True) as reader:
        while len(out) < cap:
            part = reader.read(min(cap - len(out), 16 << 20))
            if not part:
                break
            out += part
    return memoryview(out).toreadonly()


def iter_records(buf: bytes | memoryview) -> Iterator[tuple[int, memoryview]]:
    """``(opcode, body)`` of consecutive records in ``buf``; raises on a cut record."""
    view = memoryview(buf)
    pos, n = 0, len(view)
    while pos < n:
        if pos + 9 > n:
            raise CorruptChunkError(f"record header cut at byte {pos}")
        op, length = REC_HEAD.unpack_from(view, pos)
        end = pos + 9 + length
        if end > n:
            raise CorruptChunkError(f"record at byte {pos} runs past the end")
        yield op, view[pos + 9 : end]
        pos = end


def message_index_entries(buf: bytes | memoryview) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """MessageIndex records -> ``{channel_id: (log_time_ns int64, record offset int64)}``
    (numpy over each record's entry array; other records in ``buf`` are ignored)."""
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for op, body in iter_records(buf):
        if op != OP_MESSAGE_INDEX or len(body) < 6:
            continue
        ch, nbytes = struct.unpack_from("<HI", body, 0)
        if 6 + nbytes > len(body) or nbytes % 16:
            raise CorruptChunkError(f"message index of channel {ch} is cut")
        pairs = np.frombuffer(body, dtype="<u8", count=nbytes // 8, offset=6).reshape(-1, 2)
        times, offsets = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
        if ch in out:  # a second index record for the same channel: append
            times = np.concatenate([out[ch][0], times])
            offsets = np.concatenate([out[ch][1], offsets])
        out[ch] = (times, offsets)
    return out


# -- message positions -----------------------------------------------------------------

OnRecord = Callable[[int, memoryview], None]
"""Called with (opcode, body) for every Schema/Channel record met inside a chunk."""


def walk_records(
    raw: bytes, lo: int, hi: int, on_record: OnRecord, *, start: int = 0, stop: int | None = None
) -> dict[int, tuple[list[int], list[int], list[int]]]:
    """Walk the records of ``raw[start:stop]`` one by one (the fallback path).

    Returns per channel the log times and payload spans of the messages with log time in
    ``[lo, hi)``; Schema and Channel records go to ``on_record``. Per-record Python work
    (ints only, no bytes copied) is the price of not having a usable message index.
    """
    out: dict[int, tuple[list[int], list[int], list[int]]] = {}
    unpack_rec, unpack_msg = REC_HEAD.unpack_from, MSG_HEAD.unpack_from
    pos = start
    n = len(raw) if stop is None else stop
    while pos < n:
        if pos + 9 > n:
            raise CorruptChunkError(f"record header cut at chunk byte {pos}")
        op, length = unpack_rec(raw, pos)
        end = pos + 9 + length
        if end > n:
            raise CorruptChunkError(f"record at chunk byte {pos} runs past the chunk end")
        if op == OP_MESSAGE:
            if length < MSG_HEAD.size:
                raise CorruptChunkError(f"message record too short at chunk byte {pos}")
            ch, _seq, t, _pub = unpack_msg(raw, pos + 9)
            if lo <= t < hi:
                lists = out.get(ch)
                if lists is None:
                    lists = out[ch] = ([], [], [])
                lists[0].append(t)
                lists[1].append(pos + PAYLOAD_OFFSET)
                lists[2].append(end)
        elif op in (OP_SCHEMA, OP_CHANNEL):
            on_record(op, memoryview(raw)[pos + 9 : end])
        pos = end
    return out


def _as_positions(lists: dict[int, tuple[list[int], list[int], list[int]]]) -> Positions:
    return {
        ch: (
            np.asarray(t, dtype=np.uint64).astype(np.int64),
            np.asarray(s, dtype=np.int64),
            np.asarray(e, dtype=np.int64),
        )
        for ch, (t, s, e) in lists.items()
    }


def walk_chunk(data: bytes | memoryview) -> tuple | ValueError | None:
    """The compiled record walker's result for decompressed chunk ``data`` (the
    ``ValueError`` it raised, for a damaged chunk); ``None`` when it is not built."""
    if _mcap_records is None:
        return None
    try:
        return _mcap_records.walk_chunk(data)
    except ValueError as exc:
        return exc


def native_positions(
    chunk: ChunkData, lo: int, hi: int, on_record: OnRecord, walked: object = None
) -> Positions | None:
    """Message positions by the compiled record walker (``_mcap_records.c``): every
    record of the chunk, no index needed; ``None`` when the extension is not built.
    ``walked``: :func:`walk_chunk` of the chunk when the fetch thread ran it already."""
    walked = walked if walked is not None else walk_chunk(chunk.raw)
    if walked is None:
        return None
    if isinstance(walked, ValueError):  # damaged: the Python walk reports the records
        return walked_positions(chunk, lo, hi, on_record)  # before the damage, then raises
    ch, lt, st, en, others = walked
    for op, a, b in others:  # a few per chunk: Schema/Channel records
        if op in (OP_SCHEMA, OP_CHANNEL):
            on_record(op, memoryview(chunk.raw)[a:b])
    chans, times = np.frombuffer(ch, np.int64), np.frombuffer(lt, np.int64)
    starts, ends = np.frombuffer(st, np.int64), np.frombuffer(en, np.int64)
    if len(chans) == 0:
        return {}
    if lo > 0 or hi < 2**64:  # a windowed read: drop the messages outside (log times u64)
        unsigned = times.view(np.uint64)
        keep = np.ones(len(times), dtype=bool)
        if lo > 0:
            keep &= unsigned >= np.uint64(min(lo, 2**64 - 1))
        if hi < 2**64:
            keep &= unsigned < np.uint64(max(hi, 0))
        chans, times, starts, ends = chans[keep], times[keep], starts[keep], ends[keep]
        if len(chans) == 0:
            return {}
    return _by_channel(chans, times, starts, ends)


def _by_channel(
    chans: np.ndarray, times: np.ndarray, starts: np.ndarray, ends: np.ndarray
) -> Positions:
    """Split message arrays (file order) per channel id."""
    if len(chans) == 0:
        return {}
    first = int(chans[0])
    if not (chans != first).any():  # the usual chunk: one channel
        return {first: (times, starts, ends)}
    out: Positions = {}
    for c in np.unique(chans).tolist():
        sel = chans == c
        out[c] = (times[sel], starts[sel], ends[sel])
    return out


def walked_positions(chunk: ChunkData, lo: int, hi: int, on_record: OnRecord) -> Positions:
    """:func:`walk_records` over the whole chunk, as numpy arrays."""
    return _as_positions(walk_records(chunk.raw, lo, hi, on_record))


def indexed_positions(
    chunk: ChunkData,
    entries: dict[int, tuple[np.ndarray, np.ndarray]],
    lo: int,
    hi: int,
    on_record: OnRecord,
) -> Positions | None:
    """Message positions from the chunk's MessageIndex entries, checked against the records.

    Every indexed offset must hold a Message record of that channel and log time, and the
    records must not overlap; bytes between them (Schema/Channel records, messages the
    index left out) are walked. ``None`` when the index does not fit the chunk (the caller
    walks the whole chunk instead). Only messages with log time in ``[lo, hi)`` are kept.
    """
    if not entries:
        return None
    chans = np.concatenate([np.full(len(v[1]), ch, dtype=np.int64) for ch, v in entries.items()])
    times = np.concatenate([v[0] for v in entries.values()])
    offs = np.concatenate([v[1] for v in entries.values()])
    size = chunk.size
    if len(offs) == 0 or offs.min() < 0 or offs.max() + PAYLOAD_OFFSET > size:
        return None
    order = np.argsort(offs, kind="stable")
    chans, times, offs = chans[order], times[order], offs[order]
    # the 31-byte headers of all indexed records in one gather (a void view at every
    # byte), then their fields from the packed copy
    head = unaligned(chunk.arr, "V31")[offs].view(_MSG_RECORD)
    lengths = head["length"].astype(np.int64)
    ends = offs + 9 + lengths
    ok = (
        (head["op"] == OP_MESSAGE)
        & (lengths >= MSG_HEAD.size)
        & (lengths <= size)
        & (head["channel"] == chans)
        & (head["log_time"].astype(np.int64) == times)
    )
    if not ok.all() or ends[-1] > size or np.any(offs[1:] < ends[:-1]):
        return None
    extra = _walk_gaps(chunk, offs, ends, lo, hi, on_record)
    keep = (times >= lo) & (times < hi)
    out = _by_channel(chans[keep], times[keep], offs[keep] + PAYLOAD_OFFSET, ends[keep])
    return _merge_positions(out, extra) if extra else out


def _walk_gaps(
    chunk: ChunkData, offs: np.ndarray, ends: np.ndarray, lo: int, hi: int, on_record: OnRecord
) -> Positions:
    """Walk the byte ranges of the chunk that no indexed message covers."""
    starts = np.concatenate([[0], ends])
    stops = np.concatenate([offs, [chunk.size]])
    gaps = np.flatnonzero(stops > starts)
    found: dict[int, tuple[list[int], list[int], list[int]]] = {}
    for g in gaps.tolist():  # a handful per chunk: Schema/Channel records at its start
        part = walk_records(chunk.raw, lo, hi, on_record, start=int(starts[g]), stop=int(stops[g]))
        for ch, (t, s, e) in part.items():
            lists = found.setdefault(ch, ([], [], []))
            lists[0].extend(t)
            lists[1].extend(s)
            lists[2].extend(e)
    return _as_positions(found)


def _merge_positions(a: Positions, b: Positions) -> Positions:
    out = dict(a)
    for ch, (t, s, e) in b.items():
        if ch in out:
            t0, s0, e0 = out[ch]
            t, s, e = np.concatenate([t0, t]), np.concatenate([s0, s]), np.concatenate([e0, e])
            order = np.argsort(s, kind="stable")
            t, s, e = t[order], s[order], e[order]
        out[ch] = (t, s, e)
    return out


# -- background fetching ---------------------------------------------------------------


@dataclass(frozen=True)
class FetchedChunk:
    """One chunk as fetched: ``data`` (or ``error``) and the MessageIndex bytes, if any."""

    index: ChunkIndex
    data: bytes | memoryview | None  # a view of a pooled buffer for zstd chunks
    error: Exception | None
    message_index: bytes
    walked: object = None  # walk_chunk(data), run in the fetch thread while data is in cache


class ChunkFetcher:
    """Read and decompress the given chunks, yielded in the given (file) order, up to
    ``PREFETCH_BYTES`` of decompressed data ahead of the consumer, in ``FETCH_THREADS``
    background threads; file reads are serialised by a lock (they alone use ``f``).

    ``buffers``: the pool zstd chunks are decompressed into (the caller's, so that its
    later files reuse it; ``None``: a pool of this fetcher's own). ``read_bytes`` counts
    every byte read from the file. Iterate once; the end of the iteration (or closing the
    generator) stops the threads.
    """

    def __init__(
        self,
        f: BinaryIO,
        size: int,
        chunks: Sequence[ChunkIndex],
        *,
        threaded: bool,
        buffers: ChunkBuffers | None = None,
    ):
        self._f = f
        self._size = size
        self._chunks = list(chunks)
        self._threaded = threaded
        self._lock = threading.Lock()
        self._zstd = threading.local()
        self._buffers = buffers if buffers is not None else ChunkBuffers(limit=POOL_BUFFERS)
        self.read_bytes = 0
        self.decompressed = 0

    def _read(self, offset: int, length: int) -> bytes:
        with self._lock:
            self._f.seek(offset)
            data = self._f.read(length)
            self.read_bytes += len(data)
        return data

    def _decompressor(self) -> zstandard.ZstdDecompressor | None:
        if zstandard is None:
            return None
        if not hasattr(self._zstd, "d"):  # one per thread: a decompressor is not shared
            self._zstd.d = zstandard.ZstdDecompressor()
        return self._zstd.d

    def _fetch(self, ci: ChunkIndex) -> FetchedChunk:
        mi_offsets = sorted(ci.message_index_offsets.values())
        chunk_end = ci.chunk_start_offset + ci.chunk_length
        contiguous = bool(mi_offsets) and mi_offsets[0] == chunk_end
        mi_len = ci.message_index_length if mi_offsets else 0
        try:
            if chunk_end > self._size:
                raise CorruptChunkError("chunk index points past the end of the file")
            span = ci.chunk_length + (mi_len if contiguous else 0)
            buf = self._read(ci.chunk_start_offset, min(span, self._size - ci.chunk_start_offset))
            mi = buf[ci.chunk_length :] if contiguous else b""
            if mi_offsets and not contiguous:
                mi = self._read(mi_offsets[0], mi_len)
        except Exception as exc:  # the file could not even be read there
            return FetchedChunk(ci, None, exc, b"")
        try:
            view = memoryview(buf)[: ci.chunk_length]
            if len(view) < 9 or view[0] != OP_CHUNK:
                raise CorruptChunkError("no chunk record at the indexed offset")
            (length,) = struct.unpack_from("<Q", view, 1)
            if 9 + length > len(view):
                raise CorruptChunkError("chunk record longer than its index says")
            head = parse_chunk(view[9 : 9 + length])
            data = decompress(head, self._decompressor(), self._buffers)
            with self._lock:
                self.decompressed += 1
            return FetchedChunk(ci, data, None, bytes(mi), walk_chunk(data))
        except Exception as exc:  # corrupt chunk: reported, the walk goes on
            return FetchedChunk(ci, None, exc, bytes(mi))

    def __iter__(self) -> Iterator[FetchedChunk]:
        if not self._threaded:
            for ci in self._chunks:
                yield self._fetch(ci)
            return
        pool = ThreadPoolExecutor(max_workers=FETCH_THREADS, thread_name_prefix="mcap-fetch")
        pending: deque[tuple[Future, int]] = deque()
        ahead = 0  # decompressed bytes submitted and not yet yielded
        todo = deque(self._chunks)
        try:
            while todo or pending:
                while todo and (len(pending) < FETCH_THREADS or ahead < PREFETCH_BYTES):
                    ci = todo.popleft()
                    # what the chunk may occupy: its claimed size (decompress() holds it
                    # to that) or the bytes read, whichever is larger
                    nbytes = max(ci.uncompressed_size, ci.chunk_length, 1)
                    pending.append((pool.submit(self._fetch, ci), nbytes))
                    ahead += nbytes
                fut, nbytes = pending.popleft()
                ahead -= nbytes
                yield fut.result()
        finally:
            for fut, _ in pending:
                fut.cancel()
            pool.shutdown(wait=True)
