"""Wrap legacy captures into MCAP so that every later stage reads MCAP only.

``import_file(path, out_dir)`` writes ``<out_dir>/<file name>.mcap`` (zstd chunks, fixed
header strings: the bytes depend only on the input and the options; written to a
temporary name and renamed into place). Inputs are recognised by content
(:func:`detect_format`), not by extension:

**NMEA 0183 text logs** (``$``/``!`` sentences, with or without IEC 62320-1 tag blocks or
leading timestamps; CRLF, LF or CR; ``#`` comment lines and blank lines are not messages,
the leading ``#`` header is kept in the file metadata record ``surveil.import``). One
MCAP message per logged line, in file order, payload = the line without its leading
timestamp and line ending. Channels (message encoding ``nmea0183``, no schema): lines
whose first sentence is AIS (``VDM``/``VDO``, any talker) -> ``/ais/nmea``; every other
line, garbage included (ingest rejects it with a reason) -> ``/nav/nmea``. Both carry the
metadata ``platform_id`` (the file name without its extension), ``source_file`` and
``log_time_source``:

- the lines' own times (:mod:`pipeline.time_sources`, in its order of trust): USCG N-AIS
  receiver fields after the checksum (``nais:t``, ``nais:T``, ``nais:epoch``), a Gatehouse
  ``$PGHP`` before an AIS message (``pghp``), the tag block's ``c:`` (``tag_block:c``),
  or a time in front of the sentence (``leading_timestamp``: Unix seconds ``1418169601``
  or ``1418169601.25``, Unix ms (13 digits), or ISO 8601 ``2014-12-10T00:00:01.5Z``, a
  space instead of ``T``, an offset; naive = UTC; optionally in ``[...]`` or quotes, or
  the first cell of a CSV row whose last cell is the sentence, OpenCPN's VDR log); the
  other lines interpolated by line number between them (``log_time_source`` names the
  most frequent own source, ``log_time_sources`` counts them);
- ``nmea:<formatters>``: the UTC time of RMC/ZDA (with their date) and of GGA/GLL on the
  date of the nearest dated sentence, midnight rollover handled; lines between two
  time-bearing lines are interpolated linearly by line number, lines before the first /
  after the last take its time;
- ``ais:base_station``: the UTC date and time of received AIS base station reports
  (messages 4 and 11), the other lines interpolated;
- ``nmea_time_of_day:<base_time|file_name|undated>``: time of day only (no RMC/ZDA date
  anywhere, e.g. a ZDA without date and GLL): the day of ``base_time_ns``, else the date
  in the file name, else 1970-01-01 ("undated": synthetic), one day added at each
  backward jump of more than 12 h; keys ``log_date``, ``log_date_source``;
- ``none:synthetic``: no time at all (the gpsd AIS logs): ``base_time_ns`` + 1 ms per
  line (keys ``synthetic_base_ns``, ``synthetic_step_ns``). Order, not time, is real; the
  file's :class:`ImportedFile` carries a ``warning`` naming ``--base-time``.

The first available source in that order gives the file's times. Channel metadata
``time_source_fallback`` is the ``time_source`` ingest gives a row whose time is its log
time, ``interpolation_gap_s_p99`` the bracket of the interpolated AIS lines
(:func:`pipeline.time_sources.refine_by_utc_second`). ``$PGHP`` lines and lines holding
only a tag block go with the AIS sentences (``/ais/nmea``): they belong to the message
after them.

**AIS CSV tables** of other tools (a header with an MMSI column; columns placed by
header name, :mod:`pipeline.convert.ais_csv`): one JSON message per row on ``/ais/csv``
(schema ``surveil.AisReport``, ``schemas/ais_report.schema.json``), log time = the row's
time (``log_time_source`` ``csv:<column>``, UTC). Source units and not-available codes
are kept; empty-meaning text cells (``''``, ``' '``, ``Unknown``, ``Undefined``) become
null.

**ASTERIX** raw files, framed recordings (GPS, FINAL, IOSS, HDLC, ORADIS) and pcap/pcapng
captures: :func:`pipeline.convert.asterix.wrap_asterix`. **ROS 1 bags**:
:func:`pipeline.convert.rosbag.wrap_ros1_bag`.

Every converter writes through :func:`pipeline.convert.output.write_converted`: a piece
whose log time is outside 1970 .. 2262 (or that carries a reason) goes to the
``/import/rejects`` channel and becomes a ``rejects`` row at ingest, never a traceback.
"""

from __future__ import annotations

import json
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import polars as pl

from pipeline import time_sources as ts
from pipeline.convert.ais_csv import CsvOptions, looks_like_ais_csv, read_ais_csv
from pipeline.convert.asterix_framing import ASTERIX_CATEGORIES, detect_framing
from pipeline.convert.config import ImportOptions
from pipeline.convert.output import REJECTS_TOPIC, Message, site_metadata, write_converted
from pipeline.io.mcap_write import ChannelSpec
from pipeline.resources import resource_path
from pipeline.units import NS, TIME_MAX_NS, describe_time, time_in_range

DAY_NS = 86_400 * NS
SYNTHETIC_STEP_NS = 1_000_000
NAV_TOPIC, AIS_TOPIC, CSV_TOPIC = "/nav/nmea", "/ais/nmea", "/ais/csv"
AIS_SCHEMA_NAME = "surveil.AisReport"
AIS_REPORT_SCHEMA = "ais_report.schema.json"  # the row's fields, in order (pipeline.messages)
_SAMPLE = 65_536
PCAP_MAGICS = (b"\xa1\xb2\xc3\xd4", b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\x3c\x4d",
               b"\x4d\x3c\xb2\xa1", b"\x0a\x0d\x0d\x0a")  # fmt: skip
# an NMEA 0183 address: any 2-character talker (letters or digits: NMEA 2000 gateways write
# "$04HDM", "$24HDG") + a 3-letter formatter, or a proprietary "$P" + maker + sentence
_NMEA_LINE = re.compile(
    rb"(^|[\s\\,;\]\"])[$!](?:[A-Z0-9]{2}[A-Z]{3}|P[A-Z0-9]{3,})[,*]", re.MULTILINE
)
# a time before the sentence: bare, in [...], or the first cell of a CSV row whose last
# cell is the sentence (OpenCPN's VDR log "received_at,protocol,msg_type,source,raw_data",
# LogAIS "timestamp,type,id,message": the cells between are kept out of the payload)
LEADING_TS = (
    r"^\s*\"?\[?(\d{13}|\d{9,10}(?:\.\d+)?|\d{4}-\d{2}-\d{2}[T ]\d{2}:\d{2}:\d{2}(?:\.\d+)?"
    r"(?:Z|[+-]\d{2}:?\d{2})?)\]?\"?(?:[,;\t](?:\"[^\"]*\"|[^,;\t\"$!\\]*))*?[\s,;\t]*\"?"
)
_ANCHOR_FORMATTERS = ("RMC", "ZDA", "GGA", "GLL")
_EOL = re.compile(r"\r\n|\n|\r")


@dataclass(frozen=True)
class ImportedFile:
    """One wrapped file: ``messages`` per topic, ``log_time_source`` per topic, and
    ``skipped`` lines that are not messages (``comment``, ``blank``)."""

    source: str
    output: str
    format: str
    messages: dict[str, int]
    log_time_source: dict[str, str]
    skipped: dict[str, int] = field(default_factory=dict)
    warning: str = ""
    """Why the file's times are not times of the world, and the option that fixes it."""

    @property
    def rejected(self) -> int:
        """Pieces of the input written to ``/import/rejects`` (damaged stretches, lines or
        records whose time cannot be represented): rejects rows once ingested."""
        return self.messages.get(REJECTS_TOPIC, 0)

    @property
    def status(self) -> str:
        """``ok`` (everything wrapped) | ``partial`` (some pieces rejected)."""
        return "partial" if self.rejected else "ok"


# -- detection ---------------------------------------------------------------------------


def _looks_text(sample: bytes) -> bool:
    if not sample or b"\x00" in sample:
        return False
    arr = np.frombuffer(sample, dtype=np.uint8)
    control = (arr < 32) & ~np.isin(arr, [9, 10, 13])
    return bool(control.mean() < 0.05)


def detect_format(path: Path) -> str:
    """``nmea_text`` | ``ais_csv`` | ``asterix`` (raw blocks, framed recordings, pcap,
    pcapng) | ``ros1_bag`` | ``unknown``."""
    with open(path, "rb") as f:
        sample = f.read(_SAMPLE)
    size = path.stat().st_size
    if sample[:4] in PCAP_MAGICS:
        return "asterix"
    if sample.startswith(b"#ROSBAG V2.0\n"):
        return "ros1_bag"
    if _looks_text(sample):
        first = re.split(rb"\r\n|\n|\r", sample.lstrip(), maxsplit=1)[0].decode("latin-1")
        if looks_like_ais_csv(first):
            return "ais_csv"
        return "nmea_text" if _NMEA_LINE.search(sample) else "unknown"
    if detect_framing(sample) is not None:  # GPS, FINAL, IOSS, HDLC, ORADIS recordings
        return "asterix"
    if len(sample) >= 3 and sample[0] in ASTERIX_CATEGORIES:
        length = int.from_bytes(sample[1:3], "big")
        if 3 <= length <= size:
            return "asterix"
    return "unknown"


def import_file(
    path: Path, out_dir: Path, *, base_time_ns: int | None = None,
    options: ImportOptions | None = None, site: str | None = None,
) -> ImportedFile:  # fmt: skip
    """Wrap one file (see module docstring); raises ``ValueError`` when it is not an
    importable format, or ``base_time_ns`` is not a representable time. ``base_time_ns``:
    ``--base-time`` (None: not given; a recording that needs a date takes the one in its
    file name, else 1970-01-01, and says so in ``warning``). ``options``: the
    config's ``[import.csv]`` / ``[asterix]`` (:mod:`pipeline.convert.config`); ``site``:
    written into the MCAP file's ``surveil.import`` metadata (key ``site``) for ingest."""
    options = options or ImportOptions()
    if base_time_ns is not None and not time_in_range(base_time_ns):
        raise ValueError(f"base time {describe_time(base_time_ns)} is outside 1970-01-01 .. "
                         "2262-04-11 UTC")  # fmt: skip
    path = Path(path)
    kind = detect_format(path)
    if kind == "nmea_text":
        return wrap_nmea_text(path, out_dir, base_time_ns=base_time_ns, site=site)
    if kind == "ais_csv":
        return wrap_ais_csv(path, out_dir, options=options.csv, site=site)
    if kind == "asterix":
        from datetime import UTC, datetime

        from pipeline.convert.asterix import wrap_asterix

        named = file_name_date(path.name)
        if base_time_ns is not None:
            day, day_source = datetime.fromtimestamp(base_time_ns // NS, tz=UTC).date(), \
                "base_time"
        elif named is not None:
            day, day_source = named.astype(object), "file_name"
        else:
            day, day_source = None, "unknown"
        w = wrap_asterix(path, Path(out_dir), day=day, editions=options.asterix_editions,
                         site=site, day_source=day_source)
        undated = day is None and any(
            src != "pcap" and not src.startswith("nmea") for src in w.log_time_source.values())
        warning = (f"{path.name}: its records carry a time of day only and neither "
                   "--base-time nor the file name gives their date: they lie on 1970-01-01 "
                   "and take no part in overlap checks or the batch; import it again with "
                   "--base-time <its UTC date>") if undated else ""
        return ImportedFile(
            str(path), str(w.output), f"asterix:{w.kind}", w.messages, w.log_time_source,
            warning=warning,
        )
    if kind == "ros1_bag":
        from pipeline.convert.rosbag import wrap_ros1_bag

        return wrap_ros1_bag(path, Path(out_dir), site=site)
    raise ValueError(
        f"{path}: not an importable file (neither NMEA 0183 text, an AIS CSV, ASTERIX "
        "(raw, framed or pcap/pcapng) nor a ROS 1 bag)"
    )


def output_path(path: Path, out_dir: Path) -> Path:
    """``<out_dir>/<file name>.mcap``."""
    return Path(out_dir) / f"{Path(path).name}.mcap"


# -- NMEA text ---------------------------------------------------------------------------


def split_lines(text: str) -> list[str]:
    """Lines ended by CRLF, LF or CR only (``str.splitlines`` also splits at U+0085 and
    U+2028, which latin-1 text of a UTF-8 header contains)."""
    lines = _EOL.split(text)
    return lines[:-1] if lines and lines[-1] == "" else lines


def _lines(data: bytes) -> pl.DataFrame:
    """Every physical line: ``line`` (0-based), ``text`` (latin-1), ``kind``
    (content | comment | blank | csv_header)."""
    texts = split_lines(data.decode("latin-1"))
    df = pl.DataFrame({"text": texts}, schema={"text": pl.String}).with_row_index("line")
    stripped = pl.col("text").str.strip_chars()
    kind = (
        pl.when(stripped.str.len_chars() == 0)
        .then(pl.lit("blank"))
        .when(stripped.str.starts_with("#"))
        .then(pl.lit("comment"))
        .otherwise(pl.lit("content"))
    )
    df = df.with_columns(kind=kind)
    # a CSV header before rows of "time,...,sentence" (OpenCPN VDR, LogAIS) is no message
    first = df.filter(pl.col("kind") == "content").head(2)
    if first.height == 2 and re.fullmatch(r"\s*[A-Za-z_][\w \"]*(?:[,;\t][\w \"]*)+\s*",
                                          first["text"][0]) \
            and re.match(LEADING_TS + r"[$!\\]", first["text"][1]):
        df = df.with_columns(kind=pl.when(pl.col("line") == first["line"][0])
                             .then(pl.lit("csv_header")).otherwise("kind"))
    return df


def _leading_ts_ns(ts: pl.Expr) -> pl.Expr:
    """Leading timestamp text -> int64 ns (epoch s / ms / ISO 8601); null when absent or
    outside the representable range (checked BEFORE the multiplication to ns: polars
    int64 arithmetic wraps around silently)."""
    digits = ts.str.contains(r"^\d+(\.\d+)?$")
    int_part = ts.str.extract(r"^(\d+)", 1).cast(pl.Int64, strict=False)
    frac = ts.str.extract(r"\.(\d+)$", 1).str.slice(0, 9).str.pad_end(9, "0")
    frac_ns = frac.cast(pl.Int64, strict=False).fill_null(0)
    is_ms = ts.str.contains(r"^\d{13}$")
    limit = pl.when(is_ms).then(TIME_MAX_NS // 1_000_000).otherwise(TIME_MAX_NS // NS - 1)
    epoch = pl.when(int_part <= limit).then(
        pl.when(is_ms).then(int_part * 1_000_000).otherwise(int_part * NS + frac_ns)
    )
    iso = ts.str.replace(" ", "T").str.replace("Z$", "+00:00")
    iso = iso.str.replace(r"([+-]\d\d)(\d\d)$", "$1:$2")
    iso = pl.when(iso.str.contains(r"[+-]\d\d:\d\d$")).then(iso).otherwise(iso + "+00:00")
    # microseconds first: datetime[ns] covers 1677..2262 only and wraps outside
    us = iso.str.to_datetime(format="%Y-%m-%dT%H:%M:%S%.f%:z", time_unit="us", strict=False)
    us = us.dt.epoch("us")
    ns = pl.when((us >= 0) & (us <= TIME_MAX_NS // 1000)).then(us * 1000)
    ns = ns + iso.str.extract(r"\.\d{6}(\d{1,3})", 1).str.pad_end(3, "0").cast(
        pl.Int64, strict=False
    ).fill_null(0)
    return pl.when(digits).then(epoch).otherwise(ns)


def _split_content(lines: pl.DataFrame) -> pl.DataFrame:
    """Content lines with ``payload`` (line without leading timestamp) and ``lead_ns``."""
    c = lines.filter(pl.col("kind") == "content")
    ts = pl.col("text").str.extract(LEADING_TS + r"(?:[$!\\])", 1)
    prefix = pl.col("text").str.extract(r"(" + LEADING_TS + r")(?:[$!\\])", 1)
    c = (
        c.with_columns(ts=ts, prefix=prefix)
        .with_columns(
            lead_ns=_leading_ts_ns(pl.col("ts")),
        )
        .with_columns(
            lead_bad=pl.col("ts").is_not_null() & pl.col("lead_ns").is_null(),
            payload=pl.when(pl.col("prefix").is_not_null())
            .then(pl.col("text").str.slice(pl.col("prefix").str.len_chars()))
            .otherwise(pl.col("text"))
            .str.strip_chars(),
        )
        .with_columns(  # a CSV cell's closing quote is not part of the sentence
            payload=pl.when(pl.col("prefix").str.ends_with('"').fill_null(False))
            .then(pl.col("payload").str.strip_suffix('"'))
            .otherwise("payload"),
        )
    )
    return c.with_row_index("msg").with_columns(pl.col("msg").cast(pl.Int64))


def _nmea_anchors(pieces: pl.DataFrame, base_time_ns: int) -> tuple[pl.DataFrame, str]:
    """``(msg, t_ns)`` of the first time-bearing sentence of each line, and the source."""
    from pipeline.decode.nav_nmea import decode_formatter

    parts = []
    for f in _ANCHOR_FORMATTERS:
        sel = pieces.filter((pl.col("formatter") == f) & pl.col("code").is_null())
        if sel.height:
            out = decode_formatter(f, sel, 1e9).select(
                "msg", "idx", "formatter", "tod_ns", "date_days"
            )
            parts.append(out.filter(pl.col("tod_ns").is_not_null()))
    if not parts:
        return pl.DataFrame(schema={"msg": pl.Int64, "t_ns": pl.Int64}), ""
    a = pl.concat(parts).sort("idx").unique("msg", keep="first", maintain_order=True)
    dated = pl.col("date_days").is_not_null()
    used = ",".join(sorted(set(a["formatter"].to_list())))
    if a.filter(dated).height:
        own = pl.col("date_days") * DAY_NS + pl.col("tod_ns")
        a = a.with_columns(ref=pl.when(dated).then(own)).with_columns(
            pl.col("ref").forward_fill().backward_fill()
        )
        day = (pl.col("ref") - pl.col("tod_ns") + DAY_NS // 2) // DAY_NS
        a = a.with_columns(t_ns=pl.when(dated).then(own).otherwise(day * DAY_NS + pl.col("tod_ns")))
        return a.select("msg", "t_ns"), f"nmea:{used}"
    back = (pl.col("tod_ns").diff() < -DAY_NS // 2).cast(pl.Int64).fill_null(0).cum_sum()
    base_day = base_time_ns // DAY_NS
    a = a.with_columns(t_ns=(back + base_day) * DAY_NS + pl.col("tod_ns"))
    return a.select("msg", "t_ns"), "nmea_time_of_day:undated"


def _interpolate(n: int, anchors: pl.DataFrame) -> np.ndarray:
    """Times of messages 0..n-1 from anchor (msg, t_ns): exact at anchors, linear by
    message index between them, constant before the first / after the last."""
    x = anchors["msg"].to_numpy()
    t = anchors["t_ns"].to_numpy().astype(np.int64)
    t0 = int(t[0])
    rel = np.interp(np.arange(n), x, (t - t0).astype(np.float64))
    out = np.round(rel).astype(np.int64) + t0
    out[x] = t
    return out


def _line_own_times(content: pl.DataFrame, pieces: pl.DataFrame) -> pl.DataFrame:
    """``(msg, t_ns, source)`` of every line with a time of its own: the first the line's
    sentences carry (:func:`pipeline.decode.nmea.own_times`: N-AIS receiver fields, the
    ``$PGHP`` before a message, tag-block ``c:``), else its leading timestamp."""
    from pipeline.decode.nmea import own_times

    p, _ = own_times(pieces.with_columns(log_time_ns=pl.lit(None, pl.Int64)), None, "")
    own = (p.filter(pl.col("recv_ns").is_not_null()).sort("idx")
           .group_by("msg", maintain_order=True)
           .agg(pl.col("recv_ns").first().alias("t_ns"), pl.col("time_source").first()
                .alias("source")))  # fmt: skip
    lead = content.filter(pl.col("lead_ns").is_not_null()).select(
        "msg", t_ns="lead_ns", source=pl.lit(ts.LEADING))
    lead = lead.join(own.select("msg"), on="msg", how="anti")
    return pl.concat([own, lead]).sort("msg")


def _base_station_anchors(content: pl.DataFrame) -> pl.DataFrame:
    """``(msg, t_ns)`` of single-sentence base station reports (messages 4 and 11: the
    UTC date and time the base station sends, ITU-R M.1371-5 Annex 8 §3.3) whose date
    and time are available; those more than a day from the median are dropped (a base
    station with a wrong clock). pyais per candidate line: a few per cent of an AIS log."""
    from pyais.messages import NMEASentenceFactory

    from pipeline.decode.ais import station_utc_ns

    one = r"^(?:\\[^\\]*\\)?!..VD[MO],1,1,[^,]*,[^,]*,[4;]"  # message 4 or 11, one sentence
    cand = content.filter(pl.col("payload").str.contains(one))
    msgs, times = [], []
    for msg, text in cand.select("msg", "payload").iter_rows():
        try:
            d = NMEASentenceFactory.produce(text.encode("latin-1")).decode()
        except Exception:  # a damaged line is no anchor
            continue
        t = station_utc_ns(d) if getattr(d, "msg_type", None) in (4, 11) else None
        if t is not None:
            msgs.append(msg)
            times.append(t)
    a = pl.DataFrame({"msg": msgs, "t_ns": times}, schema={"msg": pl.Int64, "t_ns": pl.Int64})
    if a.height:
        median = int(np.median(a["t_ns"].to_numpy()))
        a = a.filter((pl.col("t_ns") - median).abs() <= DAY_NS)
    return a


_NAME_DATE = (r"(?<!\d)((?:19[89]|2[0-2]\d)\d)[-_]?(0[1-9]|1[0-2])[-_]?"
              r"(0[1-9]|[12]\d|3[01])(?!\d)")


def file_name_date(name: str) -> np.datetime64 | None:
    """A UTC date written in a file name (``smr_20240131.raw``, ``2024-01-31_ais.log``,
    ``log_2024_01_31``): the first 8-digit ``yyyymmdd`` (or ``yyyy-mm-dd``, ``yyyy_mm_dd``)
    run between 1980 and 2261 that is a real date, else None."""
    for m in re.finditer(_NAME_DATE, name):
        try:
            return np.datetime64(f"{m.group(1)}-{m.group(2)}-{m.group(3)}", "D")
        except ValueError:
            continue
    return None


@dataclass(frozen=True)
class LineTimes:
    """The log time of every content line and where the file's times come from:
    ``source`` (the channels' ``log_time_source``), ``fallback`` (the ``time_source``
    of a line whose time is its log time, :func:`pipeline.time_sources.
    fallback_label`), the interpolated lines' bracket (99th percentile, s), counts of
    lines per own source, and more channel metadata."""

    times: np.ndarray
    source: str
    fallback: str
    gap_s_p99: float | None = None
    own_counts: dict[str, int] = field(default_factory=dict)
    extra: dict[str, str] = field(default_factory=dict)

    @property
    def synthetic(self) -> bool:
        return ts.is_synthetic(self.fallback)


def _gaps_s(n: int, anchors: pl.DataFrame, lines: np.ndarray) -> float | None:
    """99th percentile of the interval between the anchors around each of ``lines``
    (not anchors themselves; lines before the first or after the last are left out)."""
    x = anchors["msg"].to_numpy()
    t = anchors["t_ns"].to_numpy()
    lines = np.setdiff1d(lines, x)
    if not lines.size or x.size < 2:
        return None
    k = np.searchsorted(x, lines)
    inside = (k > 0) & (k < x.size)
    if not inside.any():
        return None
    k = k[inside]
    return float(np.percentile(np.abs(t[k] - t[k - 1]), 99) / NS)


def nmea_log_times(
    content: pl.DataFrame, pieces: pl.DataFrame, base_time_ns: int | None,
    ais_lines: np.ndarray | None = None, file_name: str = "",
) -> LineTimes:  # fmt: skip
    """Log time of every content line, the first of (``docs/ingest_formats.md``):

    1. the lines' own times (N-AIS receiver fields, ``$PGHP``, tag-block ``c:``,
       leading timestamps; :mod:`pipeline.time_sources`), the other lines
       interpolated between them by line number;
    2. RMC/ZDA date and time, GGA/GLL on the nearest dated sentence's date;
    3. the UTC of received base station reports (AIS messages 4, 11);
    4. a time of day without date, on ``base_time_ns``'s day, else the date in the
       file name, else 1970-01-01 ("undated");
    5. nothing: ``base_time_ns`` (0 when None) + 1 ms per line (``none:synthetic``).

    ``ais_lines``: the AIS channel's lines (the interpolation bracket is theirs)."""
    n = content.height
    lines = np.arange(n) if ais_lines is None else ais_lines
    own = _line_own_times(content, pieces)
    if own.height:
        counts = dict(Counter(own["source"].to_list()))
        source = max(sorted(counts), key=lambda k: counts[k])
        anchors = own.select("msg", "t_ns")
        extra = {"log_time_sources": json.dumps(dict(sorted(counts.items())))}
        # ingest sees a sentence's own times but not the logger's stamp before it: the log
        # time of a line is its leading timestamp where the file has them (a line without
        # one among them is interpolated, and labelled so only by the channel's counts)
        fallback = ts.LEADING if ts.LEADING in counts else ts.INTERPOLATED + source
        return LineTimes(_interpolate(n, anchors), source, fallback,
                         _gaps_s(n, anchors, lines), counts, extra)
    known_day = base_time_ns is not None or file_name_date(file_name) is not None
    base = base_time_ns if base_time_ns is not None else _day_ns(file_name_date(file_name))
    anchors, source = _nmea_anchors(pieces, base)
    if anchors.height and not source.startswith("nmea_time_of_day"):
        return LineTimes(_interpolate(n, anchors), source, ts.INTERPOLATED + source,
                         _gaps_s(n, anchors, lines))
    stations = _base_station_anchors(content)
    if stations.height:
        return LineTimes(_interpolate(n, stations), ts.BASE_STATION,
                         ts.INTERPOLATED + ts.BASE_STATION, _gaps_s(n, stations, lines))
    if anchors.height:
        day = str(np.datetime64(base // DAY_NS, "D"))
        extra = {"log_date": day, "log_date_source": "base_time" if base_time_ns is not None
                 else "file_name" if known_day else "unknown"}
        label = ("nmea_time_of_day:undated" if not known_day
                 else f"nmea_time_of_day:{extra['log_date_source']}")
        return LineTimes(_interpolate(n, anchors), label, ts.INTERPOLATED + label,
                         _gaps_s(n, anchors, lines), extra=extra)
    start = base_time_ns or 0
    times = start + np.arange(n, dtype=np.int64) * SYNTHETIC_STEP_NS
    meta = {"synthetic_base_ns": str(start), "synthetic_step_ns": str(SYNTHETIC_STEP_NS)}
    return LineTimes(times, ts.SYNTHETIC, ts.SYNTHETIC, extra=meta)


def _day_ns(day: np.datetime64 | None) -> int:
    return 0 if day is None else int(day.astype("datetime64[D]").astype(np.int64)) * DAY_NS


def wrap_nmea_text(path: Path, out_dir: Path, *, base_time_ns: int | None = None,
                   site: str | None = None) -> ImportedFile:
    """Wrap an NMEA 0183 text log (see module docstring). ``base_time_ns``: the day of a
    log that carries times of day only, and the start of a log without any time (None:
    not given; the date in the file name, else 1970-01-01)."""
    from pipeline.decode.nmea import AIS_FORMATTERS, frame

    path = Path(path)
    lines = _lines(path.read_bytes())
    content = _split_content(lines)
    pieces, _ = frame(content["payload"].to_list())
    pieces = pieces.with_row_index("idx")
    first = pieces.group_by("msg").agg(pl.col("formatter").first())
    content = content.join(first, on="msg", how="left").sort("msg")
    ais_text = content["payload"].str.contains(r"VD[MO],")  # a damaged AIS line
    # a $PGHP stamps the AIS message after it; a tag block alone on its line (DMA logs)
    # belongs to the sentences after it: both travel with the AIS sentences
    lone_tag = content["payload"].str.contains(r"^\\[^\\]*\\$")
    is_ais = (content["formatter"].is_in([*AIS_FORMATTERS, "PGHP"]).fill_null(ais_text)
              | lone_tag).to_numpy()
    if not (is_ais & ~lone_tag.to_numpy()).any():
        is_ais[:] = False
    topics = np.where(is_ais, AIS_TOPIC, NAV_TOPIC)
    lt = nmea_log_times(content, pieces, base_time_ns, np.flatnonzero(is_ais), path.name)
    times, source, extra = lt.times, lt.source, dict(lt.extra)
    platform = path.name.split(".")[0] or path.name
    channel_meta = {
        "platform_id": platform,
        "source_file": path.name,
        "log_time_source": source,
        "time_source_fallback": lt.fallback,
        **({"interpolation_gap_s_p99": f"{lt.gap_s_p99:.3f}"} if lt.gap_s_p99 is not None
           else {}),
        **extra,
    }
    skipped = dict(Counter(lines.filter(pl.col("kind") != "content")["kind"].to_list()))
    header = _header(lines)
    file_meta = {
        **site_metadata(site),
        "format": "nmea_text",
        "source_file": path.name,
        "lines_total": str(lines.height),
        "log_time_source": source,
        **{f"{k}_lines": str(v) for k, v in skipped.items()},
        "header": header,
    }
    payloads = [t.encode("latin-1") for t in content["payload"].to_list()]  # MCAP: bytes
    rejects: list[tuple[str, str] | None] = [None] * content.height
    if source == ts.LEADING:  # a line whose own time cannot be represented
        for i, text in zip(
            np.flatnonzero(content["lead_bad"].to_numpy()).tolist(),
            content.filter(pl.col("lead_bad"))["ts"].to_list(),
            strict=True,
        ):
            rejects[i] = ("out_of_range", f"leading timestamp {text!r} is not a time in "
                          "1970-01-01 .. 2262-04-11 UTC")  # fmt: skip
    messages = [
        Message(str(tp), int(t), p, r)
        for tp, t, p, r in zip(topics.tolist(), times.tolist(), payloads, rejects, strict=True)
    ]
    out = output_path(path, out_dir)
    names = [t for t in (NAV_TOPIC, AIS_TOPIC) if (topics == t).any()]
    channels = [ChannelSpec(t, "nmea0183", metadata=channel_meta) for t in names]
    counts = write_converted(out, channels, messages, metadata={"surveil.import": file_meta})
    return ImportedFile(
        str(path), str(out), "nmea_text", counts, dict.fromkeys(counts, source), skipped,
        time_warning(path.name, lt.fallback, content.height),
    )


def time_warning(name: str, fallback: str, n: int) -> str:
    """The import/ingest warning for a file whose rows have no time of the world
    (:func:`pipeline.time_sources.is_synthetic`), naming the option that fixes it;
    '' otherwise."""
    if fallback == ts.SYNTHETIC:
        return (f"{name}: its {n} lines carry no time (no tag block, receiver fields, "
                "$PGHP, leading timestamp, RMC/ZDA or base station report): their times are "
                "synthetic, 1 ms apart from --base-time (default 1970-01-01), and take no part "
                "in overlap checks or the batch; import it again with --base-time <start of "
                "the recording> to put it on its day")
    if ts.is_synthetic(fallback):
        return (f"{name}: its times of day have no date (none in the file or its name): they "
                "lie on 1970-01-01 and take no part in overlap checks or the batch; import it "
                "again with --base-time <its UTC date>")
    return ""


def _header(lines: pl.DataFrame) -> str:
    """The leading ``#`` comment block (before the first content line), max 4 KiB."""
    first_content = lines.filter(pl.col("kind") == "content")["line"].min()
    head = lines.filter((pl.col("kind") == "comment") & (pl.col("line") < (first_content or 0)))
    return "\n".join(head["text"].to_list())[:4096]


# -- AIS CSV -----------------------------------------------------------------------------


def wrap_ais_csv(path: Path, out_dir: Path, *, options: CsvOptions | None = None,
                 site: str | None = None) -> ImportedFile:
    """Wrap an AIS CSV table (:mod:`pipeline.convert.ais_csv`) as ``surveil.AisReport``
    JSON, one message per row, log time = the row's time (rows whose time is outside the
    representable range go to the rejects channel)."""
    path = Path(path)
    table = read_ais_csv(path, options)
    rows = table.rows
    time_reject = rows["_time_reject"].to_list()
    rows = rows.drop("_time_reject")
    payload = rows.select(pl.struct(pl.all()).struct.json_encode().cast(pl.Binary).alias("p"))
    log = rows["time_ns"].forward_fill().backward_fill().fill_null(0).to_list()
    source = f"csv:{table.time_column}"
    platform = path.name.split(".")[0] or path.name
    meta = {
        "platform_id": platform,
        "source_file": path.name,
        "log_time_source": source,
        "source_format": table.flavor,
    }
    file_meta = {
        **site_metadata(site),
        "format": "ais_csv",
        "source_file": path.name,
        "source_format": table.flavor,
        "rows": str(rows.height),
        "log_time_source": source,
        "time_parser": table.time_parser,
        "columns_not_placed": json.dumps(table.unplaced),
    }
    out = output_path(path, out_dir)
    schema = (resource_path("schemas") / "ais_report.schema.json").read_bytes()
    channel = ChannelSpec(CSV_TOPIC, "json", AIS_SCHEMA_NAME, schema_data=schema, metadata=meta)
    messages = [
        Message(CSV_TOPIC, t, p, None if why is None else ("out_of_range", why))
        for t, p, why in zip(log, payload["p"].to_list(), time_reject, strict=True)
    ]
    counts = write_converted(out, [channel], messages, metadata={"surveil.import": file_meta})
    return ImportedFile(str(path), str(out), "ais_csv", counts, dict.fromkeys(counts, source))
