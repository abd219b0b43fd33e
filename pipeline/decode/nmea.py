"""NMEA 0183 text -> canonical tables: sentence framing, tag blocks, routing, timing.

Every MCAP message of an NMEA text channel is one line as a receiver logged it. This
module frames the lines and routes each sentence:

- ``!xxVDM`` / ``!xxVDO`` (any talker: AI, AB, BS, ...) -> :mod:`pipeline.decode.ais`
  (pyais) -> ``ais_reports`` / ``ais_static``;
- GGA RMC VTG GSA GLL ZDA -> ``nav_gnss``; HDT HDG HDM THS ROT -> ``nav_heading``;
  VHW VBW -> ``nav_speed_log``; TTM TLL -> ``arpa_targets``; OSD -> ``arpa_own_ship``
  (field decoding in :mod:`pipeline.decode.nav_nmea`);
- any other well-formed sentence (GSV, MWV, DBT, proprietary ``$P...``, ...): valid but
  not used, so it is COUNTED per sentence type in ``not_stored`` (``nmea_GSV``,
  ``nmea_PGRME``; the ingest ledger's ``not_stored_json``), not stored as a reject;
- what cannot be used -> ``rejects``.

Framing (NMEA 0183 v4.10 §5.3; IEC 61162-1): a sentence starts with ``$`` or ``!``, its
address field is a talker of any 2 characters, letters or digits (NMEA 2000 gateways
write ``$04HDM``, ``$24HDG``) + a 3-letter formatter, or ``P`` + a proprietary sentence
name (``$PGRME``, ``$PASHR``), and ends
with ``*hh``, the XOR of every character between the start character and ``*``. An IEC
62320-1 / NMEA 4 tag block ``\\s:src,c:unix_s,g:1-2-9*hh\\`` may precede it; its ``*hh``
is the XOR of its content. A line holding several sentences (``$GPGGA...*hh$GPRMC...*hh``,
a lost line feed) is split and each sentence judged on its own, so the intact ones are
kept; characters outside any sentence are rejected as garbage (the sentence next to them
is kept). One-digit or lower-case checksums are accepted when their value is right
(OpenCPN writes ``*b``); receiver fields after the checksum (USCG NAIS
``*hh,s36310,d-081,...``) give the sentence's time and are otherwise not decoded.

Rejects (``reason_code``): ``undecodable`` (garbage, empty line, bad address field, a
field that is not a number, a bad hemisphere/time), ``bad_checksum`` (sentence or tag
block checksum missing or wrong), ``out_of_range`` (latitude beyond
±90°, longitude beyond ±180°, a speed above ``NmeaLimits.max_speed_mps``, a heading
outside [0°, 360°], and a sentence UTC time that goes backwards against the previous
sentence of the same talker+formatter by more than ``max_time_backstep_s``),
``no_data`` (a well-formed sentence whose measurement fields are all empty, e.g.
``$IIHDT,,T``), plus the AIS decoder's codes (``truncated_multipart``, ``no_position``,
``unsupported_type``, ...). ``raw`` holds the sentence bytes with their tag block.

Time (``time_ns``):

- reception time ``recv_ns`` = the first time the sentence carries in the order of
  :data:`pipeline.time_sources.OWN_ORDER` (USCG N-AIS receiver fields ``t``/``T`` with
  their UNIX time, the ``$PGHP`` before its AIS message, the tag block's ``c:`` in Unix
  seconds or milliseconds above 1e11, the N-AIS UNIX time alone), else the MCAP log
  time; each AIS row keeps what gave it (``time_source``, :func:`own_times`);
- a sentence with a UTC time of day (GGA RMC GLL ZDA TTM TLL) gets that time on the date of
  the latest preceding dated sentence (RMC ``ddmmyy``, ZDA ``dd,mm,yyyy``) advanced by the
  reception time elapsed since it, else on the UTC date of its reception time; the day is
  the one that puts the time of day nearest that reference, which handles midnight
  rollover both ways;
- RMC/ZDA with a date: exactly their own date and time;
- other sentences (VTG, HDT, VHW, ...) and AIS: ``recv_ns``.

Per-message Python is limited to ``bytes.decode('latin-1')`` (to enter polars: its
binary->string cast rejects non-UTF-8 bytes, which occur in damaged logs), the reverse
``encode`` for reject rows and AIS sentences, and the AIS decoder (pyais, one message
per call, see :mod:`pipeline.decode.ais`). Framing, checksums
(``numpy.bitwise_xor.reduceat`` over one buffer), field splitting and unit conversion run
on whole columns.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa

from pipeline import time_sources as ts
from pipeline.decode.registry import make_rejects
from pipeline.tables import conform, empty
from pipeline.time_sources import nais_time, pghp_time, tag_block_time
from pipeline.units import NS

DAY_NS = 86_400 * NS
AIS_FORMATTERS = frozenset({"VDM", "VDO"})
NAV_TABLES = ("nav_gnss", "nav_heading", "nav_speed_log", "arpa_targets", "arpa_own_ship")
NMEA_TABLES = (*NAV_TABLES, "ais_reports", "ais_static", "ais_other_messages", "rejects")

# a sentence (optionally behind a tag block) runs to the next start character
PIECE_RE = r"(?:\\[^\\]*\\)?[$!][^$!\\\r\n]*"
_TAG_RE = r"^\\([^\\]*)\\"
_CK_BODY_RE = r"^[$!]([^*]*)\*"
_CK_HEX_RE = r"\*([0-9A-Fa-f]{1,2})$"
_TAG_CK_RE = r"^(.*)\*([0-9A-Fa-f]{1,2})$"
_TRAILER_RE = r"^([^*]*\*[0-9A-Fa-f]{1,2}),.*$"
_JUNK_RE = r"^((?:\\[^\\]*\\)?[^*\\]*\*[0-9A-Fa-f]{1,2})([^,0-9A-Fa-f].*)$"


@dataclass(frozen=True)
class NmeaLimits:
    """Plausibility limits for NMEA values.

    ``max_speed_mps``: any speed above is ``out_of_range`` (default 40 m/s, ~78 kn, the
    default of ``[validation] max_speed_mps``; ingest uses these defaults because the
    registry's per-channel decoders are built without the config);
    ``max_time_backstep_s``: a sentence whose UTC time is earlier than the previous one of
    the same talker+formatter by more than this is ``out_of_range``.
    """

    max_speed_mps: float = 40.0
    max_time_backstep_s: float = 0.0


@dataclass(frozen=True)
class NmeaCarry:
    """What a channel's next batch needs from the previous one.

    ``ais``: trailing AIS sentences of a multi-part message still open (bytes, log time,
    reception time, time source); ``anchor_ns``/``anchor_recv_ns``: the latest dated
    sentence's time and its reception time; ``last_time_ns``: latest UTC sentence time
    per talker+formatter.
    """

    ais: tuple[tuple[bytes, int, int, str], ...] = ()
    anchor_ns: int | None = None
    anchor_recv_ns: int | None = None
    last_time_ns: Mapping[str, int] = field(default_factory=dict)
    pghp: tuple[int, int, int] | None = None
    """A ``$PGHP`` whose message has not ended yet: (its time, AIS sentences after it
    so far, the fragment count of the first of them, 0 before it)."""


@dataclass(frozen=True)
class NmeaDecoded:
    """Rows per table (every name of ``NMEA_TABLES``, conformed), valid messages decoded
    but not stored (``ais_type_<id>`` / ``nmea_<formatter>`` -> count), and the carry for
    the channel's next batch."""

    tables: dict[str, pa.Table]
    not_stored: dict[str, int]
    carry: NmeaCarry


# -- framing -----------------------------------------------------------------------------


def _to_text(sentences: Sequence[bytes | str]) -> list[str]:
    # per message: polars cannot cast non-UTF-8 binary to text; latin-1 maps every byte
    return [s if isinstance(s, str) else bytes(s).decode("latin-1") for s in sentences]


def xor_checksums(texts: pl.Series) -> np.ndarray:
    """XOR of the characters of each string (the NMEA checksum), as uint8.

    One buffer for the whole column and ``numpy.bitwise_xor.reduceat`` over the offsets;
    empty strings give 0."""
    lens = texts.fill_null("").str.len_chars().to_numpy().astype(np.int64)
    if not len(lens):
        return np.zeros(0, np.uint8)
    joined = texts.fill_null("").str.join("").item()
    buf = np.frombuffer(joined.encode("latin-1") + b"\x00", dtype=np.uint8)
    starts = np.concatenate([[0], np.cumsum(lens)[:-1]])
    out = np.bitwise_xor.reduceat(buf, starts)
    out[lens == 0] = 0
    return out


def _checksum_ok(content: pl.Series, hexes: pl.Series) -> np.ndarray:
    want = hexes.fill_null("100").str.to_integer(base=16, strict=False).to_numpy()
    return xor_checksums(content) == np.asarray(want, dtype=np.int64)


def frame(texts: Sequence[str]) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Split messages into sentences: ``(pieces, garbage)``.

    ``pieces``: one row per sentence: ``msg`` (message index), ``piece`` (text with its
    tag block), ``tag`` (tag block content or null), ``talker``, ``formatter``,
    ``fields`` (list of field strings after the address), ``code``/``reason`` (a framing
    problem, null when the sentence is well formed), ``tag_c_ns`` (tag-block ``c:`` time),
    ``tag_source`` (tag-block ``s:``). ``garbage``: ``msg``, ``text`` of messages with no
    sentence or with characters outside every sentence."""
    df = pl.DataFrame({"text": list(texts)}, schema={"text": pl.String}).with_row_index("msg")
    df = df.with_columns(pl.col("msg").cast(pl.Int64))
    garbage = (
        df.with_columns(
            pieces=pl.col("text").str.count_matches(PIECE_RE),
            rest=pl.col("text").str.replace_all(PIECE_RE, "").str.strip_chars(),
        )
        .filter((pl.col("pieces") == 0) | (pl.col("rest").str.len_chars() > 0))
        .select("msg", "text", "pieces", "rest")
    )
    pieces = (
        df.with_columns(piece=pl.col("text").str.extract_all(PIECE_RE))
        .explode("piece")
        .drop_nulls("piece")
        .select("msg", pl.col("piece").str.strip_chars())
    )
    # text glued after a checksum (a literal "<0x0D>"): the sentence is kept, the text is not
    junk = pieces.with_columns(rest=pl.col("piece").str.extract(_JUNK_RE, 2)).filter(
        pl.col("rest").is_not_null()
    )
    junk = junk.select("msg", text=pl.col("piece"), pieces=pl.lit(1, pl.UInt32), rest="rest")
    pieces = pieces.with_columns(pl.col("piece").str.replace(_JUNK_RE, "$1"))
    garbage = pl.concat([garbage, junk.cast(garbage.schema)]) if junk.height else garbage
    return _parse_pieces(pieces), garbage


def _parse_pieces(pieces: pl.DataFrame) -> pl.DataFrame:
    p = pieces.with_columns(
        tag=pl.col("piece").str.extract(_TAG_RE, 1),
        body=pl.col("piece").str.replace(_TAG_RE, ""),
    )
    nais_ns, nais_src = nais_time(pl.col("body"))
    p = (
        p.with_columns(nais_ns=nais_ns, nais_source=nais_src)
        .with_columns(
            # receiver fields after the checksum (USCG NAIS ",d-077,S1832,...,1272415370")
            body=pl.col("body").str.replace(_TRAILER_RE, "$1"),
        )
        .with_columns(
            sentence=pl.when(pl.col("tag").is_not_null())
            .then(pl.concat_str(pl.lit("\\"), "tag", pl.lit("\\"), "body"))
            .otherwise("body"),
            ck_text=pl.col("body").str.extract(_CK_BODY_RE, 1),
            ck_hex=pl.col("body").str.extract(_CK_HEX_RE, 1),
            tag_text=pl.col("tag").str.extract(_TAG_CK_RE, 1),
            tag_hex=pl.col("tag").str.extract(_TAG_CK_RE, 2),
            star=pl.col("body").str.contains(r"\*", literal=False),
        )
    )
    body_ok = _checksum_ok(p["ck_text"], p["ck_hex"]) & p["ck_hex"].is_not_null().to_numpy()
    tag_ok = _checksum_ok(p["tag_text"], p["tag_hex"]) & p["tag_hex"].is_not_null().to_numpy()
    p = p.with_columns(
        body_ok=pl.Series(body_ok), tag_ok=pl.Series(tag_ok) | pl.col("tag").is_null()
    )
    parts = pl.col("ck_text").str.split(",")
    p = p.with_columns(
        address=parts.list.first(),
        fields=parts.list.slice(1),
        tag_source=pl.col("tag_text").str.extract(r"(?:^|,)s:([^,*]*)", 1),
    )
    tag_c_ns, tag_c_bad = tag_block_time(pl.col("tag_text"))
    # talker: any 2 characters, letters or digits ("04HDM" from an NMEA 2000 gateway)
    proprietary = pl.col("address").str.contains(r"^P[A-Z0-9]+$")
    std = pl.col("address").str.contains(r"^[A-Z0-9]{2}[A-Z]{3}$")
    p = p.with_columns(
        talker=pl.when(proprietary)
        .then(pl.lit("P"))
        .when(std)
        .then(pl.col("address").str.slice(0, 2)),
        formatter=pl.when(proprietary)
        .then(pl.col("address"))
        .when(std)
        .then(pl.col("address").str.slice(2, 3)),
        # the c: digits are checked against the range BEFORE the multiplication (polars
        # int64 arithmetic wraps around silently); 20+ digits do not even cast
        tag_c_ns=tag_c_ns,
        tag_c_bad=tag_c_bad,
    ).with_columns(
        pghp_ns=pl.when(pl.col("formatter") == "PGHP").then(pghp_time(pl.col("fields"))),
    )
    code, reason = _framing_problem()
    return p.with_columns(code=code, reason=reason).select(
        "msg",
        "piece",
        "sentence",
        "tag",
        "talker",
        "formatter",
        "fields",
        "code",
        "reason",
        "tag_c_ns",
        "tag_source",
        "nais_ns",
        "nais_source",
        "pghp_ns",
    )


def _framing_problem() -> tuple[pl.Expr, pl.Expr]:
    c = pl.col
    cases = [
        (~c("tag_ok") & c("tag_hex").is_null(), "bad_checksum", pl.lit("tag block without *hh")),
        (~c("tag_ok"), "bad_checksum", pl.format("tag block checksum *{} is wrong", "tag_hex")),
        (~c("star"), "bad_checksum", pl.lit("sentence without checksum (cut off?)")),
        (
            c("ck_hex").is_null(),
            "undecodable",
            pl.lit("no 1-2 hex digit checksum at the end of the sentence"),
        ),
        (~c("body_ok"), "bad_checksum", pl.format("NMEA checksum *{} is wrong", "ck_hex")),
        (
            c("tag_c_bad"),
            "out_of_range",
            pl.format(
                "tag block time c:{} is outside 1970-01-01 .. 2262-04-11 UTC",
                c("tag_text").str.extract(r"(?:^|,)c:(\d+)", 1).str.slice(0, 24),
            ),
        ),
        (
            c("talker").is_null(),
            "undecodable",
            pl.format("bad address field '{}'", "address"),
        ),
    ]
    code: pl.Expr = pl.lit(None, pl.String)
    reason: pl.Expr = pl.lit(None, pl.String)
    for cond, k, why in reversed(cases):
        code = pl.when(cond).then(pl.lit(k)).otherwise(code)
        reason = pl.when(cond).then(why).otherwise(reason)
    return code, reason


# -- decoding ----------------------------------------------------------------------------


def decode_nmea_sentences(
    sentences: list[bytes],
    log_time_ns: np.ndarray,
    *,
    source_file: str,
    topic: str,
    platform_id: str,
    limits: NmeaLimits | None = None,
) -> dict[str, pa.Table]:
    """Decode a complete batch of NMEA 0183 lines into rows per table.

    ``sentences``: one logged line each (CR/LF and surrounding blanks ignored, a tag
    block in front accepted, several fused sentences split); ``log_time_ns``: their int64
    MCAP log times, ns. Returns every table of ``NMEA_TABLES`` (conformed, possibly
    empty): ``nav_gnss``, ``nav_heading``, ``nav_speed_log``, ``arpa_targets``,
    ``arpa_own_ship``, ``ais_reports``, ``ais_static`` and ``rejects`` (see the module
    docstring for the routing, the reject reasons and the time rules).
    """
    return decode_nmea(
        sentences,
        log_time_ns,
        source_file=source_file,
        topic=topic,
        platform_id=platform_id,
        limits=limits,
    ).tables


def decode_nmea(
    sentences: Sequence[bytes | str],
    log_time_ns: np.ndarray,
    *,
    source_file: str,
    topic: str,
    platform_id: str,
    carry: NmeaCarry | None = None,
    final: bool = True,
    limits: NmeaLimits | None = None,
    fallback_time_source: str = ts.MCAP_LOG_TIME,
    refine_gap_s: float | None = None,
) -> NmeaDecoded:
    """Decode one batch of a channel; ``carry`` comes from the channel's previous batch.

    With ``final=False`` an AIS multi-part message still open at the end is carried to
    the next batch instead of being rejected (see :func:`pipeline.decode.ais.decode_ais`).
    ``fallback_time_source``: the ``time_source`` of rows whose time is the log time
    (:func:`pipeline.time_sources.fallback_label` of the channel's metadata);
    ``refine_gap_s``: the interpolation bracket of such rows when it is an interpolated
    time (:func:`pipeline.time_sources.refine_by_utc_second`).
    """
    carry = carry or NmeaCarry()
    limits = limits or NmeaLimits()
    log = np.asarray(log_time_ns, dtype=np.int64)
    if len(log) != len(sentences):
        raise ValueError(f"{len(sentences)} sentences but {len(log)} log times")
    pieces, garbage = frame(_to_text(sentences))
    log_s = pl.Series(log, dtype=pl.Int64)
    pieces = pieces.with_row_index("idx").with_columns(
        log_time_ns=log_s.gather(pieces["msg"]),
    )
    pieces, pghp_carry = own_times(pieces, carry.pghp, fallback_time_source)
    ctx = _Ctx(source_file, topic, platform_id)
    garbage, lone_tags = _lone_tag_blocks(garbage)
    rejects = [_garbage_rejects(garbage, log, ctx), _framing_rejects(pieces, ctx)]
    good = pieces.filter(pl.col("code").is_null())
    is_ais = pl.col("formatter").is_in(list(AIS_FORMATTERS))
    is_nav = pl.col("formatter").is_in(list(_nav_decoders()))
    not_stored = _not_stored(good.filter(~is_ais & ~is_nav))
    if lone_tags:
        not_stored["nmea_tag_block"] = lone_tags
    ais = _decode_ais(good.filter(is_ais), carry, final, ctx, refine_gap_s)
    nav, nav_rejects, anchor, last = _decode_nav(good.filter(is_nav), carry, limits, ctx)
    rejects += [ais.rejects, nav_rejects]
    tables = {**nav, "ais_reports": ais.reports, "ais_static": ais.static,
              "ais_other_messages": ais.other}
    tables["rejects"] = _concat("rejects", rejects)
    new_carry = NmeaCarry(
        ais=ais.carry, anchor_ns=anchor[0], anchor_recv_ns=anchor[1], last_time_ns=last,
        pghp=pghp_carry,
    )
    not_stored.update({f"ais_type_{k}": v for k, v in ais.not_stored.items()})
    return NmeaDecoded(tables=tables, not_stored=not_stored, carry=new_carry)


def own_times(
    pieces: pl.DataFrame, pending: tuple[int, int, int] | None, fallback: str
) -> tuple[pl.DataFrame, tuple[int, int, int] | None]:
    """Each sentence's reception time ``recv_ns`` and its ``time_source``: the first time
    it carries in the order of :data:`pipeline.time_sources.OWN_ORDER` (N-AIS
    ``t``/``T``, the ``$PGHP`` before its message, tag-block ``c:``, the N-AIS UNIX time),
    else its log time (``fallback``). ``pending``: a ``$PGHP`` of the previous batch whose
    message continues here; returns the one left open at the end of this batch.

    A ``$PGHP`` stamps the AIS sentences of the one message right after it: the first AIS
    sentence and as many more as its fragment count says."""
    ok = pl.col("code").is_null()
    is_pghp = ok & pl.col("pghp_ns").is_not_null()
    is_ais = ok & pl.col("formatter").is_in(list(AIS_FORMATTERS))
    frag_cnt = pl.col("fields").list.get(0, null_on_oob=True).cast(pl.Int64, strict=False)
    p = pieces.with_columns(_grp=is_pghp.cast(pl.Int64).cum_sum(), _ais=is_ais)
    p = p.with_columns(
        _rank=pl.col("_ais").cast(pl.Int64).cum_sum().over("_grp"),
        _first_cnt=pl.when(pl.col("_ais")).then(frag_cnt).drop_nulls().first().over("_grp"),
        _stamp=pl.col("pghp_ns").drop_nulls().first().over("_grp"),
    )
    if pending is not None:  # group 0 continues the previous batch's open message
        ns, taken, first = pending
        grp0 = pl.col("_grp") == 0
        p = p.with_columns(
            _stamp=pl.when(grp0).then(pl.lit(ns, pl.Int64)).otherwise("_stamp"),
            _first_cnt=pl.when(grp0 & (first > 0)).then(pl.lit(first, pl.Int64))
            .otherwise("_first_cnt"),
            _rank=pl.when(grp0).then(pl.col("_rank") + taken).otherwise("_rank"),
        )
    applied = pl.col("_ais") & pl.col("_stamp").is_not_null() & (
        pl.col("_rank") <= pl.col("_first_cnt").fill_null(1))
    p = p.with_columns(_pghp_ns=pl.when(applied).then(pl.col("_stamp")))
    fine = pl.col("nais_source").is_in([ts.NAIS_T, ts.NAIS_T_ONLY])
    own_ns = pl.when(ok).then(
        pl.coalesce(pl.when(fine).then("nais_ns"), "_pghp_ns", "tag_c_ns", "nais_ns"))
    own_src = pl.when(ok).then(pl.coalesce(
        pl.when(fine).then("nais_source"),
        pl.when(pl.col("_pghp_ns").is_not_null()).then(pl.lit(ts.PGHP)),
        pl.when(pl.col("tag_c_ns").is_not_null()).then(pl.lit(ts.TAG_BLOCK)),
        "nais_source",
    ))  # a sentence that is a reject (a wrong tag checksum) has no time to give
    p = p.with_columns(
        recv_ns=pl.coalesce(own_ns, "log_time_ns"),
        time_source=pl.coalesce(own_src, pl.lit(fallback)),
    )
    out = None
    if p.height:
        last = p.filter(pl.col("_grp") == pl.col("_grp").max()).select(
            "_stamp", "_first_cnt", "_rank").tail(1).row(0)
        stamp, first, rank = last
        if stamp is not None and (first is None or (rank or 0) < first):
            out = (int(stamp), int(rank or 0), int(first or 0))
    else:
        out = pending
    return p.drop("_grp", "_ais", "_rank", "_first_cnt", "_stamp", "_pghp_ns"), out


def _lone_tag_blocks(garbage: pl.DataFrame) -> tuple[pl.DataFrame, int]:
    """Lines holding only a tag block with a right checksum (the Danish Maritime
    Authority's logs write ``\\si:AISW*2C\\`` on a line of its own): valid, not
    stored; returns the other garbage and their count."""
    if not garbage.height:
        return garbage, 0
    tag = pl.col("text").str.strip_chars().str.extract(r"^\\([^\\]*)\\$", 1)
    g = garbage.with_columns(_tag=tag).with_columns(
        _text=pl.col("_tag").str.extract(_TAG_CK_RE, 1),
        _hex=pl.col("_tag").str.extract(_TAG_CK_RE, 2),
    )
    lone = g["_hex"].is_not_null().to_numpy() & _checksum_ok(g["_text"], g["_hex"])
    if not lone.any():
        return garbage, 0
    return garbage.filter(pl.Series(~lone)), int(lone.sum())


def _nav_decoders() -> dict:
    from pipeline.decode.nav_nmea import DECODERS

    return DECODERS


@dataclass(frozen=True)
class _Ctx:
    source_file: str
    topic: str
    platform_id: str


def _concat(name: str, parts: list[pa.Table]) -> pa.Table:
    parts = [p for p in parts if p.num_rows]
    return conform(name, pa.concat_tables(parts)) if parts else empty(name)


def _rejects_of(frame_: pl.DataFrame, ctx: _Ctx, raw_col: str) -> pa.Table:
    """Rejects rows from a frame with ``log_time_ns``, ``code``, ``reason`` and a raw
    text column (latin-1 text, turned back into the original bytes)."""
    if not frame_.height:
        return empty("rejects")
    return make_rejects(
        frame_["log_time_ns"].to_numpy(),
        source_file=ctx.source_file,
        topic=ctx.topic,
        reason_code=frame_["code"].to_list(),
        reason=frame_["reason"].to_list(),
        raw=[t.encode("latin-1") for t in frame_[raw_col].to_list()],  # per reject row
    )


def _garbage_rejects(garbage: pl.DataFrame, log: np.ndarray, ctx: _Ctx) -> pa.Table:
    why = (
        pl.when(pl.col("text").str.strip_chars().str.len_chars() == 0)
        .then(pl.lit("empty line"))
        .when(pl.col("pieces") == 0)
        .then(pl.lit("no NMEA sentence ($ or !) in the line"))
        .otherwise(pl.format("text outside any sentence: {}", pl.col("rest").str.slice(0, 40)))
    )
    g = garbage.with_columns(
        log_time_ns=pl.Series(log, dtype=pl.Int64).gather(garbage["msg"]),
        code=pl.lit("undecodable"),
        reason=why,
    )
    return _rejects_of(g, ctx, "text")


def _framing_rejects(pieces: pl.DataFrame, ctx: _Ctx) -> pa.Table:
    return _rejects_of(pieces.filter(pl.col("code").is_not_null()), ctx, "piece")


def _not_stored(pieces: pl.DataFrame) -> dict[str, int]:
    """Well-formed sentences of a formatter we do not decode, counted per sentence type
    (``nmea_GSV``; proprietary ``nmea_PGRME``): valid input, not a reject."""
    if not pieces.height:
        return {}
    counts = pieces.group_by("formatter").len()
    return {f"nmea_{f}": int(n) for f, n in counts.sort("formatter").iter_rows()}


# -- AIS ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class _AisOut:
    reports: pa.Table
    static: pa.Table
    other: pa.Table
    rejects: pa.Table
    not_stored: dict[int, int]
    carry: tuple[tuple[bytes, int, int, str], ...]


def _decode_ais(pieces: pl.DataFrame, carry: NmeaCarry, final: bool, ctx: _Ctx,
                refine_gap_s: float | None) -> _AisOut:
    from pipeline.decode.ais import decode_ais

    # the sentence with its tag block, without receiver fields after the checksum
    sent = [c[0] for c in carry.ais] + [t.encode("latin-1") for t in pieces["sentence"].to_list()]
    if not sent:
        e = empty
        return _AisOut(e("ais_reports"), e("ais_static"), e("ais_other_messages"),
                       e("rejects"), {}, ())
    log = np.concatenate(
        [
            np.asarray([c[1] for c in carry.ais], np.int64),
            pieces["log_time_ns"].to_numpy().astype(np.int64),
        ]
    )
    recv = np.concatenate(
        [
            np.asarray([c[2] for c in carry.ais], np.int64),
            pieces["recv_ns"].to_numpy().astype(np.int64),
        ]
    )
    source = [c[3] for c in carry.ais] + pieces["time_source"].to_list()
    out = decode_ais(
        sent, log, source_file=ctx.source_file, topic=ctx.topic, final=final, time_ns=recv,
        time_source=source, refine_gap_s=refine_gap_s,
    )
    k = len(sent) - out.carry
    kept = tuple(zip(sent[k:], log[k:].tolist(), recv[k:].tolist(), source[k:], strict=True))
    return _AisOut(out.reports, out.static, out.other, out.rejects,
                   dict(Counter(out.not_stored)), kept)


# -- navigation --------------------------------------------------------------------------


def _decode_nav(
    pieces: pl.DataFrame, carry: NmeaCarry, limits: NmeaLimits, ctx: _Ctx
) -> tuple[dict[str, pa.Table], pa.Table, tuple[int | None, int | None], dict[str, int]]:
    """Nav/ARPA sentences -> (rows per table, rejects, new date anchor, last times)."""
    from pipeline.decode.nav_nmea import DECODERS, decode_formatter

    decoded: list[tuple[str, pl.DataFrame]] = []
    for (formatter,), group in pieces.group_by("formatter"):  # one pass per formatter
        out = decode_formatter(str(formatter), group, limits.max_speed_mps)
        decoded.append((DECODERS[str(formatter)][0], out))
    cols = ["idx", "talker", "formatter", "recv_ns", "tod_ns", "date_days", "code", "reason"]
    timing = pl.concat([d.select(cols) for _, d in decoded]) if decoded else pl.DataFrame()
    if timing.height:
        timing, anchor, last = _nav_times(timing.sort("idx"), carry, limits)
    else:
        anchor, last = (carry.anchor_ns, carry.anchor_recv_ns), dict(carry.last_time_ns)
    tables: dict[str, list[pa.Table]] = {name: [] for name in NAV_TABLES}
    rejects = []
    for name, d in decoded:
        d = d.drop("code", "reason").join(
            timing.select("idx", "time_ns", "code", "reason"), on="idx", how="left"
        )
        rejects.append(_rejects_of(d.filter(pl.col("code").is_not_null()), ctx, "piece"))
        tables[name].append(_nav_rows(name, d.filter(pl.col("code").is_null()), ctx))
    out_tables = {name: _concat(name, parts) for name, parts in tables.items()}
    return out_tables, _concat("rejects", rejects), anchor, last


def _nav_rows(name: str, d: pl.DataFrame, ctx: _Ctx) -> pa.Table:
    if not d.height:
        return empty(name)
    d = d.with_columns(
        platform_id=pl.lit(ctx.platform_id),
        source_file=pl.lit(ctx.source_file),
        topic=pl.lit(ctx.topic),
        sentence=pl.col("formatter"),
        raw=pl.col("piece"),
    )
    return conform(name, d.to_arrow())


def _nav_times(
    t: pl.DataFrame, carry: NmeaCarry, limits: NmeaLimits
) -> tuple[pl.DataFrame, tuple[int | None, int | None], dict[str, int]]:
    """``time_ns`` of every nav sentence (module docstring, "Time") and the
    time-going-backwards check; ``t`` sorted by ``idx``."""
    ok = pl.col("code").is_null()
    has_date = ok & pl.col("tod_ns").is_not_null() & pl.col("date_days").is_not_null()
    own = pl.col("date_days") * DAY_NS + pl.col("tod_ns")
    t = t.with_columns(
        anchor=pl.when(has_date).then(own),
        anchor_recv=pl.when(has_date).then(pl.col("recv_ns")),
        key=pl.concat_str("talker", "formatter"),
    ).with_columns(
        pl.col("anchor").forward_fill().fill_null(pl.lit(carry.anchor_ns, pl.Int64)),
        pl.col("anchor_recv").forward_fill().fill_null(pl.lit(carry.anchor_recv_ns, pl.Int64)),
    )
    ref = (
        pl.when(pl.col("anchor").is_not_null())
        .then(pl.col("anchor") + pl.col("recv_ns") - pl.col("anchor_recv"))
        .otherwise(pl.col("recv_ns"))
    )
    day = (ref - pl.col("tod_ns") + DAY_NS // 2) // DAY_NS
    t = t.with_columns(
        time_ns=pl.when(has_date)
        .then(own)
        .when(pl.col("tod_ns").is_not_null())
        .then(day * DAY_NS + pl.col("tod_ns"))
        .otherwise(pl.col("recv_ns"))
    )
    last_anchor = t.filter(pl.col("anchor").is_not_null()).select("anchor", "anchor_recv").tail(1)
    anchor = (
        (int(last_anchor["anchor"][0]), int(last_anchor["anchor_recv"][0]))
        if last_anchor.height
        else (carry.anchor_ns, carry.anchor_recv_ns)
    )
    return _backwards(t, carry, limits, anchor)


def _backwards(
    t: pl.DataFrame, carry: NmeaCarry, limits: NmeaLimits, anchor: tuple[int | None, int | None]
) -> tuple[pl.DataFrame, tuple[int | None, int | None], dict[str, int]]:
    timed = pl.col("code").is_null() & pl.col("tod_ns").is_not_null()
    sub = t.filter(timed).select("idx", "key", "time_ns")
    prior = pl.DataFrame(
        {"key": list(carry.last_time_ns), "prior": list(carry.last_time_ns.values())},
        schema={"key": pl.String, "prior": pl.Int64},
    )
    sub = (
        sub.with_columns(prev=pl.col("time_ns").shift(1).over("key"))
        .join(prior, on="key", how="left")
        .with_columns(prev=pl.coalesce("prev", "prior"))
    )
    tol_ns = int(limits.max_time_backstep_s * NS)
    back = sub.filter(pl.col("time_ns") < pl.col("prev") - tol_ns).select(
        "idx",
        back_reason=pl.format(
            "UTC time goes backwards by {} s against the previous {} sentence",
            ((pl.col("prev") - pl.col("time_ns")) / 1e9).round(3),
            "key",
        ),
    )
    t = t.join(back, on="idx", how="left").with_columns(
        code=pl.when(pl.col("back_reason").is_not_null())
        .then(pl.lit("out_of_range"))
        .otherwise("code"),
        reason=pl.coalesce("back_reason", "reason"),
    )
    last = dict(carry.last_time_ns)
    for key, value in sub.group_by("key").agg(pl.col("time_ns").last()).iter_rows():
        last[key] = int(value)  # one entry per talker+formatter
    return t, anchor, last


# -- registry adapter --------------------------------------------------------------------

NMEA_BATCH = 50_000
"""Lines per decode call: a chunk holds a few thousand; larger calls amortise the fixed
cost of the column operations."""


class NmeaChannelDecoder:
    """Stateful per-channel decoder for :mod:`pipeline.decode.registry`.

    Buffers up to ``NMEA_BATCH`` lines, decodes them with :func:`decode_nmea` and keeps
    the :class:`NmeaCarry` between calls (open AIS groups, date anchor, last UTC times),
    so a file decodes the same whatever its chunking. ``platform_id``: the channel
    metadata ``platform_id``, else the topic.
    """

    def __init__(self, source_file: str, topic: str, platform_id: str, limits: NmeaLimits,
                 metadata: Mapping[str, str] | None = None):
        self.ctx = _Ctx(source_file, topic, platform_id)
        self.limits = limits
        self.fallback_time_source = ts.fallback_label(metadata)
        self.refine_gap_s = ts.refinement_gap_s(metadata)
        self.carry = NmeaCarry()
        self.not_stored: Counter = Counter()
        self._lines: list[bytes] = []
        self._times: list[np.ndarray] = []

    @classmethod
    def for_channel(cls, batch: Any, source_file: str) -> NmeaChannelDecoder:
        meta = getattr(batch, "metadata", None) or {}
        return cls(source_file, batch.topic, meta.get("platform_id") or batch.topic, NmeaLimits(),
                   meta)

    def feed(self, batch: Any) -> dict[str, pa.Table]:
        self._lines.extend(batch.payloads)
        self._times.append(np.asarray(batch.log_time_ns, dtype=np.int64))
        return self._decode(final=False) if len(self._lines) >= NMEA_BATCH else {}

    def finish(self) -> dict[str, pa.Table]:
        return self._decode(final=True)

    def _decode(self, *, final: bool) -> dict[str, pa.Table]:
        times = np.concatenate(self._times) if self._times else np.empty(0, np.int64)
        out = decode_nmea(
            self._lines,
            times,
            source_file=self.ctx.source_file,
            topic=self.ctx.topic,
            platform_id=self.ctx.platform_id,
            carry=self.carry,
            final=final,
            limits=self.limits,
            fallback_time_source=self.fallback_time_source,
            refine_gap_s=self.refine_gap_s,
        )
        self._lines, self._times = [], []
        self.carry = out.carry
        self.not_stored.update(out.not_stored)
        return {k: v for k, v in out.tables.items() if v.num_rows}
