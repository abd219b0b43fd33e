"""Radar track reports in protobuf and in ROS 2 CDR -> ``radar_tracks`` + rejects.

The same report as the JSON channels (``schemas/radar_track_report.schema.json``), in the
two binary encodings archives carry:

=================  ===============  =====================================
message encoding   schema encoding  schema name (schema text in ``schemas/``)
=================  ===============  =====================================
``protobuf``       ``protobuf``     ``surveil.RadarTrackReport`` (``radar_track_report.proto``)
``cdr``            ``ros2msg``      ``surveil_msgs/msg/RadarTrackReport`` (``.msg``)
=================  ===============  =====================================

Both decoders are vectorised over the messages of a batch and loop over FIELDS, not
messages: the payloads stay where the reader put them (spans into the decompressed chunk)
and every step reads one field of every message with numpy gathers.

- **Protobuf** (protobuf.dev/programming-guides/encoding): the field numbers and types come
  from the channel's ``FileDescriptorSet``. Step ``k`` reads the ``k``-th (tag, value) of
  every message still open: the tag varint, then by wire type a varint (``int64``,
  ``int32``, ``uint*``, ``bool``, ``enum``; ``sint*`` zig-zag decoded), 8 bytes (``double``,
  ``fixed64``, ``sfixed64``), 4 bytes (``float``, ``fixed32``, ``sfixed32``) or a length and
  the bytes (``string``; ``bytes`` and unknown fields are skipped). A field met twice keeps
  its last value, a field never met its proto3 default (0, 0.0, ""), as the protobuf
  runtime does. A tag with the wrong wire type for its field, a varint longer than 10
  bytes or a field running past the payload -> the message is ``undecodable``.
- **ROS 2 CDR** (OMG XCDR1 as rmw/Fast DDS writes it, little-endian encapsulation
  ``00 01 00 00``): a flat message of primitives and strings (``schema`` text as in
  ``.msg`` files); each field is aligned to its size relative to the end of the 4-byte
  encapsulation header; a string is a ``uint32`` length (including its NUL) and the bytes.
  Another encapsulation, a length running past the payload or a missing NUL ->
  ``undecodable``. Nested messages and arrays are not flat: such a schema is rejected.

Decoded fields map to ``radar_tracks`` by name exactly like the JSON reports
(:data:`pipeline.decode.radar.RADAR`) and pass the same validation. The encoders
(:func:`encode_protobuf`, :func:`encode_cdr`) mirror the decoders; the benchmark writes its
binary variants with them, and the tests check both against the ``protobuf`` runtime and
``mcap_ros2``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache

import numpy as np
import polars as pl
import pyarrow as pa

from pipeline.config import ValidationConfig
from pipeline.decode.json_bulk import JsonKind, kind_checks, split_valid, with_provenance
from pipeline.decode.radar import RADAR, RADAR_LAYOUT
from pipeline.io.mcap_chunks import PAD
from pipeline.io.mcap_read import ChannelBatch
from pipeline.messages import PROTO_TYPE_NUMBERS, RADAR_ROS2_NAME
from pipeline.resources import resource_path
from pipeline.tables import shape

PROTO_SCHEMA = RADAR_LAYOUT.name  # surveil.RadarTrackReport
ROS2_SCHEMA = RADAR_ROS2_NAME  # surveil_msgs/msg/RadarTrackReport
_AR10 = np.arange(10)
_SHIFT7 = (7 * np.arange(10)).astype(np.uint64)
MAX_FIELDS = 256  # tags read per protobuf message before it is declared undecodable
GROUP_MESSAGES = 32_768  # messages validated together (one polars pass)
GROUP_CHUNKS = 32  # chunks a pending group may hold (bounds memory)

# -- protobuf ----------------------------------------------------------------------------

# descriptor field types (google/protobuf/descriptor.proto) -> (wire type, numpy kind)
_PB_TYPES = {
    1: (1, "f8"),  # double
    2: (5, "f4"),  # float
    3: (0, "i8"),  # int64
    4: (0, "u8"),  # uint64
    5: (0, "i4"),  # int32
    6: (1, "u8"),  # fixed64
    7: (5, "u4"),  # fixed32
    8: (0, "bool"),  # bool
    9: (2, "str"),  # string
    13: (0, "u4"),  # uint32
    14: (0, "i4"),  # enum
    15: (5, "i4"),  # sfixed32
    16: (1, "i8"),  # sfixed64
    17: (0, "s4"),  # sint32 (zig-zag)
    18: (0, "s8"),  # sint64 (zig-zag)
}


@dataclass(frozen=True)
class FlatField:
    """One scalar field: ``name``, numpy ``kind`` (``f8 f4 i8 u8 i4 u4 bool str``, ``s4``/
    ``s8`` zig-zag), protobuf field number and wire type (0 for CDR fields)."""

    name: str
    kind: str
    number: int = 0
    wire: int = 0


def protobuf_fields(descriptor_set: bytes, message: str) -> list[FlatField]:
    """The scalar fields of ``message`` (full name, e.g. ``surveil.RadarTrackReport``)
    in a serialized ``FileDescriptorSet``; repeated and message fields are left out."""
    from google.protobuf import descriptor_pb2

    fds = descriptor_pb2.FileDescriptorSet.FromString(descriptor_set)
    for f in fds.file:
        for m in f.message_type:
            full = f"{f.package}.{m.name}" if f.package else m.name
            if full != message:
                continue
            out = []
            for fd in m.field:
                if fd.label == fd.LABEL_REPEATED or fd.type not in _PB_TYPES:
                    continue
                wire, kind = _PB_TYPES[fd.type]
                out.append(FlatField(fd.name, kind, fd.number, wire))
            return out
    raise ValueError(f"message {message!r} not in the descriptor set")


def radar_descriptor_set() -> bytes:
    """``FileDescriptorSet`` of ``schemas/radar_track_report.proto``, built from the
    report's layout (``schemas/radar_track_report.schema.json``, from which that file is
    generated: field ``k`` of the schema is field number ``k``; no ``protoc`` needed)."""
    from google.protobuf import descriptor_pb2

    f = descriptor_pb2.FileDescriptorProto(
        name="radar_track_report.proto", package="surveil", syntax="proto3"
    )
    m = f.message_type.add(name="RadarTrackReport")
    for number, fld in enumerate(RADAR_LAYOUT.fields, start=1):
        ftype = PROTO_TYPE_NUMBERS[fld.proto_type]
        m.field.add(name=fld.name, number=number, type=ftype, label=1, json_name=_camel(fld.name))
    return descriptor_pb2.FileDescriptorSet(file=[f]).SerializeToString()


def _camel(name: str) -> str:
    head, *rest = name.split("_")
    return head + "".join(p[:1].upper() + p[1:] for p in rest)


def _varint(buf: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Varints at ``pos`` (buf padded by >= 10 bytes): (value u64, byte count, too long)."""
    first = buf[pos]
    if len(pos) and int(first.max()) < 0x80:  # one-byte varints: tags, small ints
        return first.astype(np.uint64), np.ones(len(pos), np.int64), np.zeros(len(pos), bool)
    b = buf[pos[:, None] + _AR10]
    more = b >= 0x80
    too_long = more.all(axis=1)
    nbytes = np.argmin(more, axis=1) + 1
    parts = (b & 0x7F).astype(np.uint64) << _SHIFT7
    value = np.where(nbytes[:, None] > _AR10, parts, np.uint64(0)).sum(axis=1, dtype=np.uint64)
    return value, nbytes.astype(np.int64), too_long


def _fixed(buf: np.ndarray, pos: np.ndarray, width: int) -> np.ndarray:
    """(n, width) bytes at ``pos``, C-contiguous (view them as any ``width``-byte type)."""
    return np.ascontiguousarray(buf[pos[:, None] + np.arange(width)])


def _as_kind(raw: np.ndarray, kind: str) -> np.ndarray:
    """Varint u64 or fixed-width bytes -> the field's numpy type."""
    if raw.ndim == 2:  # fixed-width bytes
        code = {"f8": "<f8", "f4": "<f4", "u8": "<u8", "i8": "<i8", "u4": "<u4", "i4": "<i4"}
        return raw.view(code[kind]).ravel()
    if kind in ("s4", "s8"):  # zig-zag: (n >> 1) ^ -(n & 1)
        return ((raw >> np.uint64(1)) ^ (np.uint64(0) - (raw & np.uint64(1)))).view(np.int64)
    if kind == "bool":
        return raw != 0
    return raw.view(np.int64) if kind in ("i8", "i4") else raw


@dataclass
class FlatColumns:
    """Decoded fields of n messages: numeric arrays, string spans, and which messages
    could not be decoded (``bad``) with a reason each (``why``)."""

    n: int
    values: dict[str, np.ndarray] = field(default_factory=dict)
    strings: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    bad: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    why: list[str | None] = field(default_factory=list)

    def fail(self, idx: np.ndarray, reason: str) -> None:
        for i in idx[~self.bad[idx]].tolist():
            self.why[i] = reason
        self.bad[idx] = True


def _new_columns(fields: Sequence[FlatField], n: int) -> FlatColumns:
    cols = FlatColumns(n, bad=np.zeros(n, bool), why=[None] * n)
    for f in fields:
        if f.kind == "str":
            cols.strings[f.name] = (np.zeros(n, np.int64), np.zeros(n, np.int64))
        else:
            dt = {"f8": np.float64, "f4": np.float32, "bool": bool}.get(f.kind, np.int64)
            if f.kind in ("u8", "u4"):
                dt = np.uint64
            cols.values[f.name] = np.zeros(n, dt)
    return cols


def decode_protobuf(
    buf: np.ndarray, start: np.ndarray, end: np.ndarray, fields: Sequence[FlatField]
) -> FlatColumns:
    """Decode the protobuf messages ``buf[start[i]:end[i]]`` (``buf`` padded by >= 16
    zero bytes); one step per (tag, value) position, over all messages at once."""
    n = len(start)
    cols = _new_columns(fields, n)
    by_number = {f.number: f for f in fields}
    cursor = start.astype(np.int64, copy=True)
    for _ in range(MAX_FIELDS):
        act = np.flatnonzero(~cols.bad & (cursor < end))
        if len(act) == 0:
            break
        tag, tlen, tlong = _varint(buf, cursor[act])
        cols.fail(act[tlong], "tag varint longer than 10 bytes")
        wire = (tag & np.uint64(7)).astype(np.int64)
        number = (tag >> np.uint64(3)).astype(np.int64)
        pos = cursor[act] + tlen
        nxt = np.full(len(act), np.iinfo(np.int64).max)
        _read_wire(buf, act, wire, number, pos, nxt, by_number, cols)
        cursor[act] = nxt
        cols.fail(act[nxt > end[act]], "field runs past the end of the payload")
    else:
        cols.fail(np.flatnonzero(~cols.bad & (cursor < end)), f"more than {MAX_FIELDS} fields")
    return cols


def _read_wire(
    buf: np.ndarray,
    act: np.ndarray,
    wire: np.ndarray,
    number: np.ndarray,
    pos: np.ndarray,
    nxt: np.ndarray,
    by_number: Mapping[int, FlatField],
    cols: FlatColumns,
) -> None:
    """Read one (tag, value) of each message ``act``; store known fields; set ``nxt``."""
    for w, sel in _groups(wire):
        p = pos[sel]
        if w == 0:
            raw, length, too_long = _varint(buf, p)
            cols.fail(act[sel[too_long]], "value varint longer than 10 bytes")
            nxt[sel] = p + length
        elif w in (1, 5):
            width = 8 if w == 1 else 4
            raw = _fixed(buf, p, width)
            nxt[sel] = p + width
        elif w == 2:
            length, llen, too_long = _varint(buf, p)
            cols.fail(act[sel[too_long]], "length varint longer than 10 bytes")
            length = np.minimum(length, np.uint64(2**40)).astype(np.int64)
            raw = (p + llen, length)
            nxt[sel] = p + llen + length
        else:
            cols.fail(act[sel], f"wire type {w} not supported (groups)")
            continue
        _store(w, raw, sel, act, number, by_number, cols)


def _groups(values: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """``(value, positions)`` per distinct value; one group without sorting when all are
    equal (the common case: every message holds the same field at the same step)."""
    if not len(values):
        return []
    lo, hi = int(values.min()), int(values.max())
    if lo == hi:
        return [(lo, np.arange(len(values)))]
    return [(int(v), np.flatnonzero(values == v)) for v in np.unique(values).tolist()]


def _store(
    w: int,
    raw: object,
    sel: np.ndarray,
    act: np.ndarray,
    number: np.ndarray,
    by_number: Mapping[int, FlatField],
    cols: FlatColumns,
) -> None:
    for num, k in _groups(number[sel]):
        f = by_number.get(num)
        if f is None:
            continue  # unknown field: skipped, as the protobuf runtime keeps it aside
        rows = act[sel[k]]
        if f.wire != w:
            cols.fail(rows, f"field {f.name} has wire type {w}, expected {f.wire}")
        elif w == 2:
            s, length = raw  # type: ignore[misc]
            cols.strings[f.name][0][rows] = s[k]
            cols.strings[f.name][1][rows] = length[k]
        else:
            part = raw[k]  # type: ignore[index]
            cols.values[f.name][rows] = _as_kind(part, f.kind)


def _zigzag(v: np.ndarray) -> np.ndarray:
    v = v.astype(np.int64)
    return ((v << 1) ^ (v >> 63)).view(np.uint64)


def _varint_bytes(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Varint encoding of u64 values: ((n, 10) bytes, byte counts)."""
    v = v.astype(np.uint64)
    shifted = v[:, None] >> _SHIFT7
    groups = shifted & np.uint64(0x7F)
    nbytes = np.maximum(1, np.count_nonzero(shifted, axis=1))
    cont = (nbytes[:, None] - 1) > _AR10
    return (groups | (cont.astype(np.uint64) << np.uint64(7))).astype(np.uint8), nbytes


def encode_protobuf(
    columns: Mapping[str, np.ndarray | Sequence[str]], fields: Sequence[FlatField]
) -> tuple[np.ndarray, np.ndarray]:
    """Encode n messages (one array or string list per field) -> (bytes, offsets (n+1)).

    Fields are written in field-number order; proto3 defaults (0, 0.0, "") are left out,
    as the protobuf runtime does."""
    n = len(next(iter(columns.values())))
    pieces: list[tuple[np.ndarray, np.ndarray]] = []  # per field: (n, w) bytes, lengths
    for f in sorted(fields, key=lambda f: f.number):
        tag, tag_len = _varint_bytes(np.full(n, (f.number << 3) | f.wire, np.uint64))
        tag_len0 = int(tag_len[0])
        if f.kind == "str":
            data = [s.encode() for s in columns[f.name]]  # type: ignore[union-attr]
            lengths = np.fromiter(map(len, data), np.int64, n)
            lv, ll = _varint_bytes(lengths.astype(np.uint64))
            width = tag_len0 + int(ll.max()) + int(lengths.max())
            out = np.zeros((n, width), np.uint8)
            out[:, :tag_len0] = tag[:, :tag_len0]
            for k in range(int(ll.max())):
                out[:, tag_len0 + k] = np.where(k < ll, lv[:, k], 0)
            for i, d in enumerate(data):  # strings: short, copied one by one
                out[i, tag_len0 + ll[i] : tag_len0 + ll[i] + len(d)] = np.frombuffer(d, np.uint8)
            total = np.where(lengths > 0, tag_len0 + ll + lengths, 0)
            pieces.append((out, total))
            continue
        v = np.asarray(columns[f.name])
        if f.wire == 0:
            u = _zigzag(v) if f.kind in ("s4", "s8") else v.astype(np.int64).view(np.uint64)
            vb, vl = _varint_bytes(u)
            out = np.concatenate([tag[:, :tag_len0], vb], axis=1)
            total = tag_len0 + vl
        else:
            width = 8 if f.wire == 1 else 4
            code = {"f8": "<f8", "f4": "<f4", "u8": "<u8", "i8": "<i8", "u4": "<u4", "i4": "<i4"}[
                f.kind
            ]
            vb = np.ascontiguousarray(v.astype(code)).view(np.uint8).reshape(n, width)
            out = np.concatenate([tag[:, :tag_len0], vb], axis=1)
            total = np.full(n, tag_len0 + width)
        pieces.append((out, np.where(v != 0, total, 0)))
    return _pack(pieces, n)


def _pack(pieces: list[tuple[np.ndarray, np.ndarray]], n: int) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate per-field byte pieces (only the first ``length`` bytes of each row)."""
    lengths = np.stack([p[1] for p in pieces], axis=1)
    msg_len = lengths.sum(axis=1)
    offsets = np.concatenate([[0], np.cumsum(msg_len)]).astype(np.int64)
    out = np.empty(int(offsets[-1]), np.uint8)
    field_off = offsets[:-1, None] + np.concatenate(
        [np.zeros((n, 1), np.int64), np.cumsum(lengths, axis=1)[:, :-1]], axis=1
    )
    for j, (bytes_, length) in enumerate(pieces):
        width = bytes_.shape[1]
        for k in range(width):  # one column of bytes of every message per step
            sel = np.flatnonzero(length > k)
            out[field_off[sel, j] + k] = bytes_[sel, k]
    return out, offsets


# -- ROS 2 CDR ---------------------------------------------------------------------------

_ROS2_TYPES = {
    "bool": ("bool", 1), "byte": ("u1", 1), "char": ("u1", 1), "uint8": ("u1", 1),
    "int8": ("i1", 1), "int16": ("i2", 2), "uint16": ("u2", 2), "int32": ("i4", 4),
    "uint32": ("u4", 4), "int64": ("i8", 8), "uint64": ("u8", 8), "float32": ("f4", 4),
    "float64": ("f8", 8), "string": ("str", 4),
}  # fmt: skip
_MSG_LINE = re.compile(r"^\s*([A-Za-z0-9_/]+)(\[[^\]]*\])?\s+([A-Za-z_][A-Za-z0-9_]*)\s*(=)?")


def ros2_fields(text: str) -> list[FlatField]:
    """Fields of a flat ``.msg`` definition (constants and comments skipped; a nested
    type or an array raises ``ValueError``: not a flat message)."""
    out = []
    for line in text.split("\n"):
        line = line.split("#", 1)[0].strip()
        if not line or line.startswith("==="):
            if line.startswith("==="):
                break  # dependency definitions follow: not used by a flat message
            continue
        m = _MSG_LINE.match(line)
        if m is None:
            raise ValueError(f"cannot read .msg line {line!r}")
        ftype, array, name, const = m.groups()
        if const:
            continue
        if array or ftype not in _ROS2_TYPES:
            raise ValueError(f"field {name!r} ({ftype}{array or ''}) is not a flat primitive")
        out.append(FlatField(name, _ROS2_TYPES[ftype][0]))
    return out


def decode_cdr(
    buf: np.ndarray, start: np.ndarray, end: np.ndarray, fields: Sequence[FlatField]
) -> FlatColumns:
    """Decode little-endian XCDR1 messages ``buf[start[i]:end[i]]`` of a flat type, one
    field of every message per step (positions differ only through string lengths)."""
    n = len(start)
    cols = _new_columns(fields, n)
    head = _fixed(buf, start, 4) if n else np.zeros((0, 4), np.uint8)
    cols.fail(np.flatnonzero(end - start < 4), "payload shorter than the CDR header")
    cols.fail(
        np.flatnonzero((head[:, 0] != 0) | (head[:, 1] != 1)),
        "not little-endian CDR (encapsulation 00 01)",
    )
    body = start + 4
    rel = np.zeros(n, np.int64)
    for f in fields:
        if f.kind == "str":
            rel += -rel % 4
            length = _fixed(buf, body + rel, 4).view("<u4").ravel().astype(np.int64)
            data_at = body + rel + 4
            over = (length < 1) | (data_at + length > end)
            cols.fail(np.flatnonzero(over), f"string {f.name} runs past the payload")
            length = np.where(over, 1, length)
            no_nul = buf[data_at + length - 1] != 0
            cols.fail(np.flatnonzero(no_nul), f"string {f.name} has no NUL terminator")
            cols.strings[f.name] = (data_at, length - 1)
            rel += 4 + length
            continue
        width = {"bool": 1}.get(f.kind, int(f.kind[1]))
        rel += -rel % width
        raw = _fixed(buf, body + rel, width)
        code = "u1" if f.kind == "bool" else f.kind
        v = raw.view("<" + code).ravel()
        cols.values[f.name] = (
            (v != 0) if f.kind == "bool" else v.astype(np.float64 if f.kind[0] == "f" else np.int64)
        )
        rel += width
    cols.fail(np.flatnonzero(body + rel > end), "fields run past the end of the payload")
    return cols


def encode_cdr(
    columns: Mapping[str, np.ndarray | Sequence[str]], fields: Sequence[FlatField]
) -> tuple[np.ndarray, np.ndarray]:
    """Encode n flat messages as little-endian XCDR1 -> (bytes, offsets (n+1))."""
    n = len(next(iter(columns.values())))
    pieces: list[tuple[np.ndarray, np.ndarray]] = [
        (np.tile(np.array([0, 1, 0, 0], np.uint8), (n, 1)), np.full(n, 4))
    ]
    rel = np.zeros(n, np.int64)
    for f in fields:
        align = 4 if f.kind == "str" else ({"bool": 1}.get(f.kind) or int(f.kind[1]))
        pad = -rel % align
        if f.kind == "str":
            data = [s.encode() + b"\0" for s in columns[f.name]]  # type: ignore[union-attr]
            lengths = np.fromiter(map(len, data), np.int64, n)
            width = int(pad.max()) + 4 + int(lengths.max())
            out = np.zeros((n, width), np.uint8)
            lb = lengths.astype("<u4").view(np.uint8).reshape(n, 4)
            for i, d in enumerate(data):  # strings: short, copied one by one
                p = int(pad[i])
                out[i, p : p + 4] = lb[i]
                out[i, p + 4 : p + 4 + len(d)] = np.frombuffer(d, np.uint8)
            total = pad + 4 + lengths
        else:
            code = "u1" if f.kind == "bool" else f.kind
            vb = (
                np.ascontiguousarray(np.asarray(columns[f.name]).astype("<" + code))
                .view(np.uint8)
                .reshape(n, align)
            )
            width = int(pad.max()) + align
            out = np.zeros((n, width), np.uint8)
            for p in np.unique(pad).tolist():
                rows = np.flatnonzero(pad == p)
                out[rows, p : p + align] = vb[rows]
            total = pad + align
        pieces.append((out, total))
        rel += total
    return _pack(pieces, n)


# -- to radar_tracks ---------------------------------------------------------------------


def _string_column(
    buf: np.ndarray, spans: tuple[np.ndarray, np.ndarray], ok: np.ndarray
) -> pa.Array:
    """Strings from (start, length) spans of ``buf`` (UTF-8 checked; bad rows -> '')."""
    s, length = spans
    length = np.where(ok, length, 0)
    offsets = np.concatenate([[0], np.cumsum(length)]).astype(np.int64)
    total = int(offsets[-1])
    idx = np.repeat(s - offsets[:-1], length) + np.arange(total)
    data = buf[idx] if total else np.zeros(0, np.uint8)
    arr = pa.Array.from_buffers(
        pa.large_binary(), len(s), [None, pa.py_buffer(offsets), pa.py_buffer(data)]
    )
    return arr.cast(pa.large_string())  # raises on invalid UTF-8


def columns_frame(buf: np.ndarray, cols: FlatColumns, kind: JsonKind) -> pl.DataFrame:
    """Decoded columns -> a frame with ``kind``'s fields (absent ones null) and ``_idx``."""
    ok = ~cols.bad
    data: dict[str, object] = {}
    for name, dtype in kind.fields.items():
        if name in cols.values:
            data[name] = pl.Series(name, cols.values[name]).cast(dtype)
        elif name in cols.strings:
            data[name] = pl.from_arrow(_string_column(buf, cols.strings[name], ok)).cast(dtype)
        else:
            data[name] = pl.Series(name, [None] * cols.n, dtype=dtype)
    data["_idx"] = pl.Series("_idx", np.arange(cols.n, dtype=np.int64))
    return pl.DataFrame(data).filter(pl.Series(ok))


@dataclass
class RadarBinaryChannelDecoder:
    """Channel decoder (registry protocol) for protobuf and ROS 2 radar reports."""

    encoding: str  # protobuf | cdr
    fields: list[FlatField]
    source_file: str
    topic: str
    validation: ValidationConfig
    error: str | None = None
    pending: list[ChannelBatch] = field(default_factory=list)
    pending_count: int = 0

    takes_validation = True  # registry: for_channel(batch, source_file, validation)

    @classmethod
    def for_channel(
        cls, batch: ChannelBatch, source_file: str, validation: ValidationConfig | None = None
    ) -> RadarBinaryChannelDecoder:
        val = validation or ValidationConfig()
        enc = "protobuf" if batch.message_encoding == "protobuf" else "cdr"
        try:
            if enc == "protobuf":
                fields = protobuf_fields(batch.schema_data, batch.schema_name)
            else:
                fields = ros2_fields(batch.schema_data.decode("utf-8"))
        except Exception as exc:  # a schema we cannot use: every message is rejected
            return cls(enc, [], source_file, batch.topic, val, f"{type(exc).__name__}: {exc}")
        return cls(enc, fields, source_file, batch.topic, val)

    def feed(self, batch: ChannelBatch) -> dict[str, pa.Table]:
        """Buffer the batch; decode when ``GROUP_MESSAGES`` messages (or ``GROUP_CHUNKS``
        chunks) are pending, so that validation runs on large groups."""
        self.pending.append(batch)
        self.pending_count += len(batch)
        chunks = len({id(b.chunk) for b in self.pending})
        if self.pending_count < GROUP_MESSAGES and chunks <= GROUP_CHUNKS:
            return {}
        return self._flush()

    def finish(self) -> dict[str, pa.Table]:
        return self._flush()

    def _flush(self) -> dict[str, pa.Table]:
        batches, self.pending, self.pending_count = self.pending, [], 0
        return _merge([self._decode(batches)]) if batches else {}

    def _decode(self, batches: list[ChannelBatch]) -> dict[str, pa.Table]:
        """Decode, validate and map a group of batches (numpy per batch, polars per group)."""
        if self.error is not None:
            why = f"schema unusable: {self.error}"
            return {
                "rejects": pa.concat_tables(
                    _rejects(b, np.arange(len(b)), [why] * len(b), self.source_file)
                    for b in batches
                )
            }
        buf, start, end = _joined(batches)
        decode = decode_protobuf if self.encoding == "protobuf" else decode_cdr
        cols = decode(buf, start, end, self.fields)
        try:
            frame = columns_frame(buf, cols, RADAR)
        except pa.ArrowInvalid:  # invalid UTF-8 in a string field: message by message
            if len(batches) == 1 and len(batches[0]) == 1:
                raise
            return _merge([self._decode_slowly(b) for b in batches])
        outs = [self._validate(batches, frame)]
        undecodable = np.flatnonzero(cols.bad)
        if len(undecodable):
            why = np.asarray([cols.why[i] or "undecodable" for i in undecodable.tolist()], object)
            outs.append({"rejects": _group_rejects(batches, undecodable, why, self.source_file)})
        return _merge(outs)

    def _validate(self, batches: list[ChannelBatch], frame: pl.DataFrame) -> dict[str, pa.Table]:
        times = np.concatenate([b.log_time_ns for b in batches])
        good, bad = split_valid(frame, kind_checks(RADAR, self.validation))
        rows = with_provenance(good, times, source_file=self.source_file, topic=self.topic)
        out = {"radar_tracks": shape("radar_tracks", rows.rename(RADAR.rename))}
        if bad.height:
            reasons = np.asarray(bad["_reason"].to_list(), dtype=object)
            out["rejects"] = _group_rejects(
                batches, bad["_idx"].to_numpy(), reasons, self.source_file, code="out_of_range"
            )
        return out

    def _decode_slowly(self, batch: ChannelBatch) -> dict[str, pa.Table]:
        """One message at a time (only after invalid UTF-8 in a batch)."""
        outs = []
        for i in range(len(batch)):
            one = ChannelBatch(
                batch.channel_id, batch.topic, batch.message_encoding, batch.schema_name,
                batch.schema_encoding, batch.schema_data, batch.log_time_ns[i : i + 1],
                [batch.payloads[i]],
            )  # fmt: skip
            try:
                outs.append(self._decode([one]))
            except pa.ArrowInvalid:
                why = ["string field is not UTF-8"]
                outs.append({"rejects": _rejects(one, np.array([0]), why, self.source_file)})
        return _merge(outs)


def _joined(batches: list[ChannelBatch]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One padded buffer holding the batches' chunks, and the payload spans in it (one
    decode per group instead of one per chunk: fewer, larger array operations)."""
    if len(batches) == 1:
        chunk, start, end = batches[0].spans()
        return chunk.padded(), start, end
    chunks, starts, ends = {}, [], []
    total = 0
    for b in batches:
        chunk, start, end = b.spans()
        if id(chunk) not in chunks:
            chunks[id(chunk)] = (chunk, total)
            total += chunk.size
        offset = chunks[id(chunk)][1]
        starts.append(start + offset)
        ends.append(end + offset)
    buf = np.zeros(total + PAD, np.uint8)
    for chunk, offset in chunks.values():
        buf[offset : offset + chunk.size] = chunk.arr
    return buf, np.concatenate(starts), np.concatenate(ends)


def _group_rejects(
    batches: list[ChannelBatch],
    idx: np.ndarray,
    reasons: np.ndarray,
    source_file: str,
    *,
    code: str = "undecodable",
) -> pa.Table:
    """Rejects for messages ``idx`` of the concatenated batches (raw bytes kept)."""
    starts = np.cumsum([0] + [len(b) for b in batches])
    which = np.searchsorted(starts, idx, side="right") - 1
    return pa.concat_tables(
        _rejects(
            batches[k],
            idx[which == k] - starts[k],
            list(reasons[which == k]),
            source_file,
            code=code,
        )
        for k in np.unique(which).tolist()
    )


def _merge(outs: list[dict[str, pa.Table]]) -> dict[str, pa.Table]:
    parts: dict[str, list[pa.Table]] = {}
    for out in outs:
        for k, v in out.items():
            parts.setdefault(k, []).append(v)
    return {k: pa.concat_tables(v) for k, v in parts.items()}


def _rejects(
    batch: ChannelBatch,
    idx: np.ndarray,
    reasons: list[str],
    source_file: str,
    *,
    code: str = "undecodable",
) -> pa.Table:
    from pipeline.decode.registry import make_rejects

    chunk, start, end = batch.spans()
    raw = [bytes(chunk.raw[int(start[i]) : int(end[i])]) for i in np.asarray(idx).tolist()]
    return make_rejects(
        batch.log_time_ns[idx],
        source_file=source_file,
        topic=batch.topic,
        reason_code=code,
        reason=reasons,
        raw=raw,
    )


@cache
def radar_ros2_text() -> str:
    """``schemas/radar_track_report.msg``: the ROS 2 definition of the report (generated
    from its JSON schema by :mod:`pipeline.messages`)."""
    return (resource_path("schemas") / "radar_track_report.msg").read_text()
