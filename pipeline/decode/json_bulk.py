"""Bulk decoding of JSON channels: many payloads, one parse, vectorised checks.

First choice, when the C extension is built and the fields are float/int/string/bool:
:func:`parse_columns`, the compiled parser of :mod:`pipeline.decode.json_columns` over
the payloads where they lie in the chunks; it flags every row it cannot decode exactly,
and only those go through :func:`parse_json_payloads` (the reference path below).

Otherwise the payloads of several chunks (and of every JSON channel in them) are turned
into ONE newline-delimited buffer and parsed with ONE ``polars.read_ndjson`` call with the declared
column types (``research/mcap.md`` §3: bulk parsing is 5-10x faster than ``json.loads``
per message). The buffer is built with numpy, without a Python object per message: each
chunk's decompressed records are copied once, every byte that is not a payload of a JSON
message (record headers, other channels' messages) becomes a space and the byte before
each payload a newline. ``read_ndjson`` skips the blank lines, so row ``i`` of the result
is message ``i`` in file order (checked: the row count must equal the message count).

Only when the bulk parse fails (a malformed payload, a wrong field type, a ``NaN`` token,
a payload with a raw newline) does the group fall back to :func:`parse_json_payloads`: one
``json.loads`` per payload to find the bad ones (reason_code ``undecodable``, or
``out_of_range`` for non-finite numbers), then bulk parses of the rest, split in halves
until every payload that breaks the parser is isolated. Both paths give the same rows.

Validation is a list of :class:`Check` (a failure condition and its reason text): the
conditions are evaluated for every row, the reason strings only for the failing ones.
"""

from __future__ import annotations

import functools
import io
import json
import math
from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import polars as pl
import pyarrow as pa

from pipeline.config import ValidationConfig
from pipeline.decode.json_columns import native_kinds, parse_spans
from pipeline.io.mcap_read import ChannelBatch, ChunkData
from pipeline.tables import ConstantStrings, conform, constant_strings, empty, shape

NEWLINE, SPACE = 10, 32
_SHORT_GAP = 64  # gaps up to this many bytes are blanked by one scatter per length


class Check(NamedTuple):
    """One validation rule: ``fails`` is true for a bad row, ``reason`` its text.

    Two facts about a frame let :func:`split_valid` skip work that cannot change the
    outcome: ``null_of`` names the column whose nulls alone make the rule fail (skipped
    when that column has none); for a frame whose float columns hold no NaN or infinity
    (the compiled parser's rows: it flags any other number) ``if_finite`` is the same rule
    without its finiteness test, and ``only_nonfinite`` marks a rule that cannot fail.
    """

    fails: pl.Expr
    reason: pl.Expr
    null_of: str | None = None
    if_finite: pl.Expr | None = None
    only_nonfinite: bool = False


def missing(fields: Sequence[str]) -> list[Check]:
    """A required field is null (absent from the JSON object, or ``null``)."""
    return [
        Check(pl.col(c).is_null(), pl.lit(f"missing required field {c!r}"), null_of=c)
        for c in fields
    ]


def nonfinite(fields: Sequence[str]) -> list[Check]:
    """A numeric field is NaN or infinite."""
    return [
        Check(~pl.col(c).is_finite(), pl.lit(f"non-finite value in {c!r}"), only_nonfinite=True)
        for c in fields
    ]


def outside(col: str, lo: float | None, hi: float | None, *, lo_open: bool = False) -> Check:
    """``col`` is outside [lo, hi] (``(lo, hi]`` with ``lo_open``); NaN is not flagged here."""
    c = pl.col(col)
    cond = pl.lit(False)
    if lo is not None:
        cond = cond | ((c <= lo) if lo_open else (c < lo))
    if hi is not None:
        cond = cond | (c > hi)
    lo_txt = "-inf" if lo is None else f"{lo:g}"
    hi_txt = "inf" if hi is None else f"{hi:g}"
    bracket = "(" if lo_open else "["
    reason = pl.format(f"{col}={{}} outside {bracket}{lo_txt}, {hi_txt}]", c)
    return Check(c.is_finite() & cond, reason, if_finite=cond)


def applicable(
    data: pl.DataFrame | pa.Table, checks: Sequence[Check], *, finite: bool
) -> list[Check]:
    """The checks that can fail on ``data``, each in its cheapest exact form (``finite``:
    no float of ``data`` is NaN or infinite). ~40 finiteness and null tests over a
    million rows cost more than the rest of the validation."""
    out = []
    for ck in checks:
        if ck.null_of is not None and _null_count(data, ck.null_of) == 0:
            continue
        if finite and ck.only_nonfinite:
            continue
        out.append(ck._replace(fails=ck.if_finite) if finite and ck.if_finite is not None else ck)
    return out


def _null_count(data: pl.DataFrame | pa.Table, column: str) -> int:
    col = data[column]
    return col.null_count if isinstance(col, pa.ChunkedArray) else col.null_count()


def combined_checks(
    data: pl.DataFrame | pa.Table, checks: Sequence[Check], *, finite: bool
) -> tuple[list[Check], pl.Expr | None, list[str]]:
    """The checks that can fail on ``data`` (:func:`applicable`), their failure
    conditions OR-ed into one expression (``None``: none can fail) and the columns they
    read. Built once per list of checks and set of nullable columns that hold nulls:
    building the expression costs more than evaluating it over 100,000 rows."""
    with_nulls = frozenset(
        ck.null_of for ck in checks if ck.null_of is not None and _null_count(data, ck.null_of)
    )
    key = (id(checks), finite, with_nulls)
    hit = _COMBINED_CHECKS.get(key)
    if hit is None or hit[0] is not checks:
        if len(_COMBINED_CHECKS) > 256:
            _COMBINED_CHECKS.clear()
        usable = applicable(data, checks, finite=finite)
        names = sorted({n for ck in usable for n in ck.fails.meta.root_names()})
        expr = pl.any_horizontal([ck.fails.fill_null(False) for ck in usable]) if usable else None
        hit = _COMBINED_CHECKS[key] = (checks, usable, expr, names)  # holds checks: its id
    return hit[1], hit[2], hit[3]


_COMBINED_CHECKS: dict[tuple, tuple[Sequence[Check], list[Check], pl.Expr | None, list[str]]] = {}


def failing_rows(table: pa.Table, checks: Sequence[Check], *, finite: bool) -> np.ndarray:
    """Indexes (int64, ascending) of the rows of ``table`` that fail one of ``checks``.

    Polars evaluates the checks over the columns they read only: a float or integer
    column without nulls is handed over without a copy, and the string columns, which
    polars would convert to its own layout (and back when the rows are written), are not
    converted at all unless a check reads them."""
    if table.num_rows == 0:
        return np.empty(0, np.int64)
    _, expr, names = combined_checks(table, checks, finite=finite)
    if expr is None:
        return np.empty(0, np.int64)
    frame = pl.from_arrow(table.select(names or table.column_names[:1]))
    fails = frame.select(expr).to_series()
    if not fails.any():  # the usual case: a count of the bitmap, no numpy copy
        return np.empty(0, np.int64)
    return np.flatnonzero(fails.to_numpy()).astype(np.int64)


def split_valid(
    frame: pl.DataFrame, checks: Sequence[Check], *, finite: bool = False
) -> tuple[pl.DataFrame, pl.DataFrame]:
    """(valid rows, rejected rows with a ``_reason`` column naming every failed check).

    ``finite``: the caller knows that no float of ``frame`` is NaN or infinite."""
    usable, expr, _ = combined_checks(frame, checks, finite=finite)
    mask = None if expr is None or frame.height == 0 else frame.select(expr).to_series()
    if mask is None or not mask.any():
        return frame, frame.clear().with_columns(pl.lit("").alias("_reason"))
    good, bad = frame.filter(~mask), frame.filter(mask)
    reasons = [pl.when(ck.fails.fill_null(False)).then(ck.reason) for ck in usable]
    bad = bad.with_columns(
        pl.concat_str(reasons, separator="; ", ignore_nulls=True).alias("_reason")
    )
    return good, bad


# -- parsing -----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class JsonParse:
    """Outcome of parsing JSON payloads.

    ``rows``: the parsed rows, a polars frame with an ``_idx`` column (index into the
    payloads) or, when the compiled parser decoded every payload, an Arrow table whose row
    ``i`` is payload ``i`` (:attr:`frame` and :meth:`table_and_idx` give either form);
    ``bad_idx``/``bad_code``/``bad_reason``: payloads rejected while parsing; ``finite``:
    no float of the rows is NaN or infinite (known without looking: the compiled parser
    gives no other; ``False`` means unknown).
    """

    rows: pl.DataFrame | pa.Table
    bad_idx: list[int]
    bad_code: list[str]
    bad_reason: list[str]
    finite: bool = False

    @functools.cached_property
    def frame(self) -> pl.DataFrame:
        """The rows as a polars frame with ``_idx``."""
        if isinstance(self.rows, pl.DataFrame):
            return self.rows
        return _with_idx(pl.from_arrow(self.rows))  # type: ignore[arg-type]

    def table_and_idx(self) -> tuple[pa.Table, np.ndarray]:
        """The rows as an Arrow table (no ``_idx``) and the payload index of each row."""
        if isinstance(self.rows, pa.Table):
            return self.rows, np.arange(self.rows.num_rows, dtype=np.int64)
        return self.rows.drop("_idx").to_arrow(), self.rows["_idx"].to_numpy()


def _bulk(payloads: Sequence[bytes], schema: dict[str, pl.DataType]) -> pl.DataFrame | None:
    """One ndjson parse of all payloads; ``None`` when it fails or loses lines."""
    if not payloads:
        return pl.DataFrame(schema=schema)
    return read_ndjson_exact(b"\n".join(payloads), schema, len(payloads))


def read_ndjson_exact(buf: bytes, schema: dict[str, pl.DataType], rows: int) -> pl.DataFrame | None:
    """``polars.read_ndjson`` of ``buf``; ``None`` when it fails or yields != ``rows`` rows."""
    try:
        df = pl.read_ndjson(io.BytesIO(buf), schema=schema)
    except Exception:  # polars raises ComputeError and friends; caller falls back
        return None
    return df if df.height == rows else None


def _nonfinite_field(obj: dict) -> str | None:
    for k, v in obj.items():
        if isinstance(v, float) and not math.isfinite(v):
            return k
    return None


def _classify(payload: bytes) -> tuple[str, str] | None:
    """Why one payload cannot go through the bulk parser, or ``None`` if it might."""
    if not payload.strip():
        return "undecodable", "empty payload"
    try:
        obj = json.loads(payload)
    except (ValueError, UnicodeDecodeError) as exc:
        return "undecodable", f"invalid JSON: {exc}"
    if not isinstance(obj, dict):
        return "undecodable", f"JSON {type(obj).__name__} where an object was expected"
    bad = _nonfinite_field(obj)
    if bad is not None:
        return "out_of_range", f"non-finite value in {bad!r}"
    return None


def _bisect(
    payloads: Sequence[bytes], idx: list[int], schema: dict[str, pl.DataType], out: JsonParse
) -> list[pl.DataFrame]:
    """Bulk-parse ``idx``; on failure split in halves until the bad payloads are single."""
    df = _bulk([payloads[i] for i in idx], schema)
    if df is not None:
        return [df.with_columns(pl.Series("_idx", idx, dtype=pl.Int64))]
    if len(idx) == 1:
        out.bad_idx.append(idx[0])
        out.bad_code.append("undecodable")
        out.bad_reason.append(_type_error(payloads[idx[0]], schema))
        return []
    mid = len(idx) // 2
    return _bisect(payloads, idx[:mid], schema, out) + _bisect(payloads, idx[mid:], schema, out)


def _type_error(payload: bytes, schema: dict[str, pl.DataType]) -> str:
    try:
        pl.read_ndjson(io.BytesIO(payload), schema=schema)
    except Exception as exc:  # report the parser's own words
        return f"wrong field type: {str(exc).splitlines()[0][:200]}"
    return "payload could not be parsed"


def _one_line(payload: bytes) -> bytes:
    if b"\n" in payload or b"\r" in payload:
        return payload.replace(b"\n", b" ").replace(b"\r", b" ")
    return payload


def _with_idx(df: pl.DataFrame, idx: np.ndarray | None = None) -> pl.DataFrame:
    """``df`` with an ``_idx`` column: ``idx``, or 0..height-1."""
    values = np.arange(df.height, dtype=np.int64) if idx is None else idx
    return df.with_columns(pl.Series("_idx", values, dtype=pl.Int64))


def parse_json_payloads(payloads: Sequence[bytes], schema: dict[str, pl.DataType]) -> JsonParse:
    """Parse JSON-object payloads into typed columns (unknown fields are ignored; a
    missing field is null). Bulk first; per-payload fallback only when that fails."""
    df = _bulk(payloads, schema)
    if df is not None:
        return JsonParse(_with_idx(df), [], [], [])
    out = JsonParse(pl.DataFrame(), [], [], [])
    candidates = []
    for i, p in enumerate(payloads):  # fallback only: one json.loads per payload
        why = _classify(p)
        if why is None:
            candidates.append(i)
        else:
            out.bad_idx.append(i)
            out.bad_code.append(why[0])
            out.bad_reason.append(why[1])
    # json.loads accepted the candidates, so a raw CR/LF in them lies between tokens (not in
    # a string): a space there means the same and keeps each payload on one NDJSON line
    flat = [_one_line(p) for p in payloads]
    frames = _bisect(flat, candidates, schema, out) if candidates else []
    blank = pl.DataFrame(schema={**schema, "_idx": pl.Int64()})
    frame = pl.concat(frames) if frames else blank
    return JsonParse(frame, out.bad_idx, out.bad_code, out.bad_reason)


# -- many batches, one buffer ------------------------------------------------------------


@dataclass(frozen=True)
class MessageOrder:
    """The messages of a group of batches in file order (row ``i`` of a parse).

    ``channel_id``, ``log_time_ns``: int64 per message; ``chunk``/``start``/``end``: the
    payload's chunk (index into ``chunks``) and byte span in it.
    """

    chunks: list[ChunkData]
    channel_id: np.ndarray
    log_time_ns: np.ndarray
    chunk: np.ndarray
    start: np.ndarray
    end: np.ndarray

    def __len__(self) -> int:
        return len(self.chunk)

    def payloads(self, rows: np.ndarray | Sequence[int]) -> list[bytes]:
        """The raw bytes of the given rows (one Python object each: rejects, fallback)."""
        out = []
        for r in np.asarray(rows, dtype=np.int64).tolist():
            raw = self.chunks[int(self.chunk[r])].raw
            out.append(bytes(raw[int(self.start[r]) : int(self.end[r])]))  # raw may be a view
        return out


def message_order(batches: Sequence[ChannelBatch]) -> MessageOrder:
    """Merge the batches' messages into file order: by chunk (first seen first), then by
    byte offset inside the chunk (several channels of one chunk interleave).

    Per-batch values (channel, chunk) are repeated over the whole group at once: one
    array per column, not one per batch and column (~45 batches per group)."""
    if not batches:
        z = np.empty(0, np.int64)
        return MessageOrder([], z, z, z, z, z)
    chunks: list[ChunkData] = []
    seen: dict[int, int] = {}
    chunk_of = []
    for b in batches:
        chunk = b.spans()[0]  # builds the spans of a batch made from a payload list
        ci = seen.setdefault(id(chunk), len(chunks))
        if ci == len(chunks):
            chunks.append(chunk)
        chunk_of.append(ci)
    counts = np.fromiter((len(b) for b in batches), np.int64, len(batches))
    channel_id = np.repeat(np.fromiter((b.channel_id for b in batches), np.int64), counts)
    chunk = np.repeat(np.asarray(chunk_of, dtype=np.int64), counts)
    cols = [
        channel_id,
        np.concatenate([b.log_time_ns for b in batches]),
        chunk,
        np.concatenate([b.start for b in batches]).astype(np.int64, copy=False),
        np.concatenate([b.end for b in batches]).astype(np.int64, copy=False),
    ]
    key = (chunk << 40) + cols[3]  # chunk, then start (chunks are < 1 TiB)
    if len(key) > 1 and np.any(key[1:] < key[:-1]):  # several channels interleave
        order = np.argsort(key, kind="stable")
        cols = [c[order] for c in cols]
    return MessageOrder(chunks, *cols)


_WHITESPACE = np.array([9, 10, 13, 32], dtype=np.uint8)


def ndjson_buffer(order: MessageOrder) -> bytes | None:
    """One buffer holding every payload of ``order`` on its own line, in order, or
    ``None`` when a payload is empty or starts with whitespace (then a blank line could
    shift rows against messages: the caller parses payload by payload instead).

    The chunks are concatenated; bytes outside the payloads become spaces and the byte
    before each payload (the last byte of its record header) a newline. Every line then
    holds one payload that starts with a non-blank byte, so ``read_ndjson`` yields one
    row per line or fails; a payload with an inner newline and two objects gives an
    extra row, which the row-count check catches. Each chunk is blanked right after its
    copy, while it is still in cache.
    """
    sizes = np.array([c.size for c in order.chunks], dtype=np.int64)
    base = np.concatenate([[0], np.cumsum(sizes)]).tolist()
    out = np.empty(base[-1], dtype=np.uint8)
    bounds = np.searchsorted(order.chunk, np.arange(len(order.chunks) + 1)).tolist()
    for c, chunk in enumerate(order.chunks):  # one copy per chunk
        a, b = bounds[c], bounds[c + 1]
        s, e = order.start[a:b], order.end[a:b]
        if len(s) and (np.any(e <= s) or s[0] < 1 or np.isin(chunk.arr[s], _WHITESPACE).any()):
            return None
        view = out[base[c] : base[c + 1]]
        view[:] = chunk.arr
        _blank(view, np.concatenate([[0], e]), np.concatenate([s, [chunk.size]]))
        view[s - 1] = NEWLINE
    return out.tobytes()


def _blank(out: np.ndarray, starts: np.ndarray, stops: np.ndarray) -> None:
    """Fill every range ``[starts[i], stops[i])`` of ``out`` with spaces.

    Ranges of one length ``L`` (record headers: 31 bytes) are filled by one scatter of a
    ``L``-byte blank into a ``V{L}`` view of ``out`` that starts at every byte (a memcpy
    per range, no per-byte index); long ranges (other channels' big messages) with one
    slice assignment each.
    """
    lengths = stops - starts
    short = (lengths > 0) & (lengths <= _SHORT_GAP)
    for width in np.unique(lengths[short]).tolist():
        view = np.ndarray((len(out) - width + 1,), dtype=f"V{width}", buffer=out, strides=(1,))
        view[starts[short & (lengths == width)]] = np.void(b" " * width)
    long = lengths > _SHORT_GAP
    for a, b in zip(starts[long].tolist(), stops[long].tolist(), strict=True):
        out[a:b] = SPACE


def parse_json_batches(
    batches: Sequence[ChannelBatch],
    schema: dict[str, pl.DataType],
    pool: Executor | None = None,
) -> tuple[JsonParse, MessageOrder]:
    """Parse the payloads of ``batches`` (any channels, any chunks) with ``schema``.

    With the compiled parser (:mod:`pipeline.decode.json_columns`): the payloads are read
    where they lie in the chunks, and only the rows it flags go payload by payload
    (:func:`parse_json_payloads`). Without it (no C compiler at install time), or for a
    schema with other than float/int/string/bool fields: one ``read_ndjson`` over a
    buffer built with numpy (:func:`ndjson_buffer`), payload by payload when that fails.

    Row ``_idx`` of the result is message ``_idx`` of the returned order. ``pool``: the
    compiled parser's helper threads (:func:`~pipeline.decode.json_columns.parser_pool`)."""
    order = message_order(batches)
    if len(order) == 0:
        return JsonParse(pl.DataFrame(schema={**schema, "_idx": pl.Int64()}), [], [], []), order
    native = parse_columns(order, schema, pool)
    if native is not None:
        return native, order
    buf = ndjson_buffer(order)
    df = None if buf is None else read_ndjson_exact(buf, schema, len(order))
    if df is not None:
        return JsonParse(_with_idx(df), [], [], []), order
    return parse_json_payloads(order.payloads(np.arange(len(order))), schema), order


def parse_columns(
    order: MessageOrder, schema: dict[str, pl.DataType], pool: Executor | None = None
) -> JsonParse | None:
    """The compiled parser over ``order`` (``None`` when it is not built or ``schema`` has
    a field type it does not decode); its flagged rows go through
    :func:`parse_json_payloads`, which gives the same rows or the exact reject reasons."""
    kinds = native_kinds(schema)
    if kinds is None:
        return None
    table, flagged = parse_spans(
        [c.raw for c in order.chunks], order.chunk, order.start, order.end, schema, kinds, pool
    )
    if len(flagged) == 0:
        return JsonParse(table, [], [], [], finite=True)
    frame = _with_idx(pl.from_arrow(table))  # type: ignore[arg-type]
    good = np.ones(len(order), dtype=bool)
    good[flagged] = False
    slow = parse_json_payloads(order.payloads(flagged), schema)
    again = slow.frame.with_columns(
        pl.Series("_idx", flagged[slow.frame["_idx"].to_numpy()], dtype=pl.Int64)
    )
    merged = pl.concat([frame.filter(pl.Series(good)), again]).sort("_idx")
    bad_idx = flagged[np.asarray(slow.bad_idx, dtype=np.int64)].tolist()
    return JsonParse(merged, bad_idx, slow.bad_code, slow.bad_reason)


# -- kinds of JSON channels ---------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class JsonKind:
    """A JSON message type we decode: its fields and types, the checks a row must pass,
    the output table and the field -> column renames."""

    table: str
    fields: dict[str, pl.DataType]
    checks: Callable[[ValidationConfig], list[Check]]
    rename: dict[str, str]


def union_schema(kinds: Sequence[JsonKind]) -> dict[str, pl.DataType]:
    """Every field of ``kinds``; a name declared with two types raises ``ValueError``."""
    out: dict[str, pl.DataType] = {}
    for k in kinds:
        for name, dtype in k.fields.items():
            if out.setdefault(name, dtype) != dtype:
                raise ValueError(f"field {name!r} is {out[name]} in one kind, {dtype} in another")
    return out


def decode_json_batches(
    batches: Sequence[ChannelBatch],
    kinds: dict[int, JsonKind],
    *,
    source_file: str,
    validation: ValidationConfig,
    parse_pool: Executor | None = None,
    strings: ConstantStrings | None = None,
) -> dict[str, pa.Table]:
    """Rows per table (each ``kind.table``, and ``rejects``) of JSON batches of several
    channels. ``kinds``: channel id -> its :class:`JsonKind`; the kinds' fields must not
    conflict (they share one parse). ``parse_pool``, ``strings``: the caller's parser
    threads and provenance columns to reuse (``None``: made for this call)."""
    schema = union_schema(list(dict.fromkeys(kinds.values())))
    parsed, order = parse_json_batches(batches, schema, parse_pool)
    topic = {b.channel_id: b.topic for b in batches}
    out: dict[str, list[pa.Table]] = {}
    bad_idx = np.asarray(parsed.bad_idx, dtype=np.int64)
    if len(bad_idx):
        out["rejects"] = [
            _rejects(order, bad_idx, parsed.bad_code, parsed.bad_reason, topic, source_file)
        ]
    table, idx = parsed.table_and_idx()
    row_channel = order.channel_id[idx]
    single = len(kinds) == 1
    for ch, kind in kinds.items():
        mine = None if single else row_channel == ch
        rows = (table if mine is None else table.filter(mine)).select(list(kind.fields))
        rows_idx = idx if mine is None else idx[mine]
        if rows.num_rows == 0:
            continue
        checks = kind_checks(kind, validation)
        failing = failing_rows(rows, checks, finite=parsed.finite)
        if len(failing):
            bad_rows = _with_idx(pl.from_arrow(rows.take(failing)), rows_idx[failing])
            bad = split_valid(bad_rows, checks, finite=parsed.finite)[1]
            keep = np.ones(rows.num_rows, dtype=bool)
            keep[failing] = False
            rows, rows_idx = rows.filter(keep), rows_idx[keep]
            codes = ["out_of_range"] * bad.height
            reasons = bad["_reason"].to_list()
            rejects = _rejects(order, bad["_idx"].to_numpy(), codes, reasons, topic, source_file)
            out.setdefault("rejects", []).append(rejects)
        if rows.num_rows:
            every = rows.num_rows == len(order)  # every message, in order: no gather
            times = order.log_time_ns if every else order.log_time_ns[rows_idx]
            good = table_with_provenance(
                rows, times, source_file=source_file, topic=topic[ch], strings=strings
            )
            renames = {k: v for k, v in kind.rename.items() if k in good.column_names}
            out.setdefault(kind.table, []).append(shape(kind.table, good.rename_columns(renames)))
    return {name: pa.concat_tables(parts) for name, parts in out.items()}


@functools.lru_cache(maxsize=64)
def kind_checks(kind: JsonKind, validation: ValidationConfig) -> list[Check]:
    """``kind.checks(validation)``, built once per kind and configuration (polars
    expressions: ~40 per kind, rebuilt per group they cost more than evaluating them)."""
    return kind.checks(validation)


def _rejects(
    order: MessageOrder,
    idx: np.ndarray,
    codes: Sequence[str],
    reasons: Sequence[str],
    topic: dict[int, str],
    source_file: str,
) -> pa.Table:
    """Rejects rows for messages ``idx`` of ``order`` (raw bytes kept), topic per channel."""
    from pipeline.decode.registry import make_rejects

    return make_rejects(
        order.log_time_ns[idx],
        source_file=source_file,
        topic=[topic[c] for c in order.channel_id[idx].tolist()],
        reason_code=list(codes),
        reason=list(reasons),
        raw=order.payloads(idx),
    )


def table_with_provenance(
    table: pa.Table,
    log_time_ns: np.ndarray,
    *,
    source_file: str,
    topic: str,
    strings: ConstantStrings | None = None,
) -> pa.Table:
    """``table`` with source_file, topic (one value each) and ``log_time_ns`` (one per row,
    in row order) appended: the Arrow form of :func:`with_provenance`. ``strings``: where
    the constant columns are kept for reuse."""
    n = table.num_rows
    return (
        table.append_column("source_file", constant_strings(source_file, n, strings))
        .append_column("topic", constant_strings(topic, n, strings))
        .append_column("log_time_ns", pa.array(np.asarray(log_time_ns, dtype=np.int64)))
    )


def with_provenance(
    frame: pl.DataFrame, log_time_ns: np.ndarray, *, source_file: str, topic: str
) -> pl.DataFrame:
    """Add source_file, topic and log_time_ns (looked up by ``_idx``); drop ``_idx``."""
    times = np.asarray(log_time_ns, dtype=np.int64)[frame["_idx"].to_numpy()]
    return frame.with_columns(
        pl.lit(source_file, dtype=pl.String()).alias("source_file"),
        pl.lit(topic, dtype=pl.String()).alias("topic"),
        pl.Series("log_time_ns", times, dtype=pl.Int64),
    ).drop("_idx")


def decode_payloads(
    kind: JsonKind,
    payloads: list[bytes],
    log_time_ns: np.ndarray,
    *,
    source_file: str,
    topic: str,
    validation: ValidationConfig,
) -> tuple[pa.Table, pa.Table]:
    """``(rows of kind.table, rejects)`` of a plain list of payloads of one channel."""
    batch = ChannelBatch(0, topic, "json", "", "", b"", log_time_ns, list(payloads))
    tables = decode_json_batches(
        [batch] if payloads else [], {0: kind}, source_file=source_file, validation=validation
    )
    rows = tables.get(kind.table)
    return (
        conform(kind.table, rows) if rows is not None else empty(kind.table),
        tables.get("rejects", empty("rejects")),
    )
