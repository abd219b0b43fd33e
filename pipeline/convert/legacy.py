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

- ``tag_block:c``: the tag block's ``c:`` (lines without a valid one are interpolated);
- ``leading_timestamp``: a time in front of the sentence: Unix seconds (``1418169601`` or
  ``1418169601.25``), Unix ms (13 digits), or ISO 8601 (``2014-12-10T00:00:01.5Z``, a
  space instead of ``T``, an offset; naive = UTC), optionally in ``[...]``;
- ``nmea:<formatters>``: the UTC time of RMC/ZDA (with their date) and of GGA/GLL on the
  date of the nearest dated sentence, midnight rollover handled; lines between two
  time-bearing lines are interpolated linearly by line number, lines before the first /
  after the last take its time;
- ``nmea_time_of_day:undated``: time of day only (no RMC/ZDA date anywhere, e.g. a ZDA
  without date and GLL): the day of ``base_time_ns`` (default 1970-01-01, meaning
  "unknown"), one day added at each backward jump of more than 12 h; key ``log_date``;
- ``none:synthetic``: no time at all (the gpsd AIS logs): ``base_time_ns`` + 1 ms per
  line (keys ``synthetic_base_ns``, ``synthetic_step_ns``). Order, not time, is real.

The first available source in that order is used for the whole file.

**AIS CSV tables** (Stone Soup ``Time,MMSI,Latitude_degrees,...``; NOAA MarineCadastre
``MMSI,BaseDateTime,LAT,...``; Danish Maritime Authority aisdk ``# Timestamp,Type of
mobile,MMSI,...``): one JSON message per row on ``/ais/csv`` (schema
``surveil.AisReport``, ``schemas/ais_report.schema.json``), log time = the row's time
(``log_time_source`` ``csv:<column>``, UTC; DMA dates are dd/mm/yyyy). Source units and
not-available codes are kept; empty-meaning text cells (``''``, ``' '``, ``Unknown``,
``Undefined``) become null.

**ASTERIX** raw files and pcap/pcapng captures:
:func:`pipeline.convert.asterix.wrap_asterix_file`.
"""

from __future__ import annotations

import os
import re
import tempfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import polars as pl
from mcap.writer import CompressionType, Writer

from pipeline.io.mcap_write import MCAP_LIBRARY, MCAP_PROFILE
from pipeline.messages import message_layout
from pipeline.units import NS

DAY_NS = 86_400 * NS
SYNTHETIC_STEP_NS = 1_000_000
NAV_TOPIC, AIS_TOPIC, CSV_TOPIC = "/nav/nmea", "/ais/nmea", "/ais/csv"
AIS_SCHEMA_NAME = "surveil.AisReport"
AIS_REPORT_SCHEMA = "ais_report.schema.json"  # the row's fields, in order (pipeline.messages)
_SAMPLE = 65_536
PCAP_MAGICS = (b"\xa1\xb2\xc3\xd4", b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\x3c\x4d",
               b"\x4d\x3c\xb2\xa1", b"\x0a\x0d\x0d\x0a")  # fmt: skip
ASTERIX_CATEGORIES = frozenset(
    {1, 2, 4, 8, 9, 10, 11, 15, 16, 17, 18, 19, 20, 21, 23, 25, 30, 31, 32, 34, 48, 62, 63,
     65, 150, 205, 238, 239, 240, 247, 252}
)  # fmt: skip
_NMEA_LINE = re.compile(rb"(^|[\s\\,;\]])[$!][A-Z][A-Z0-9]{2,5},", re.MULTILINE)
LEADING_TS = (
    r"^\s*\[?(\d{13}|\d{9,10}(?:\.\d+)?|\d{4}-\d{2}-\d{2}[T ]\d{2}:\d{2}:\d{2}(?:\.\d+)?"
    r"(?:Z|[+-]\d{2}:?\d{2})?)\]?[\s,;]*"
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


# -- detection ---------------------------------------------------------------------------


def _looks_text(sample: bytes) -> bool:
    if not sample or b"\x00" in sample:
        return False
    arr = np.frombuffer(sample, dtype=np.uint8)
    control = (arr < 32) & ~np.isin(arr, [9, 10, 13])
    return bool(control.mean() < 0.05)


def _csv_flavor(first_line: str) -> str | None:
    cols = [c.strip().lstrip("#").strip().lower() for c in first_line.split(",")]
    if cols[:4] == ["time", "mmsi", "latitude_degrees", "longitude_degrees"]:
        return "stonesoup"
    if cols[:4] == ["mmsi", "basedatetime", "lat", "lon"]:
        return "marinecadastre"
    if cols[:3] == ["timestamp", "type of mobile", "mmsi"]:
        return "dma_aisdk"
    return None


def detect_format(path: Path) -> str:
    """``nmea_text`` | ``ais_csv`` | ``asterix`` (raw blocks, pcap, pcapng) | ``unknown``."""
    with open(path, "rb") as f:
        sample = f.read(_SAMPLE)
    size = path.stat().st_size
    if sample[:4] in PCAP_MAGICS:
        return "asterix"
    if _looks_text(sample):
        first = sample.lstrip().split(b"\n", 1)[0].decode("latin-1")
        if _csv_flavor(first):
            return "ais_csv"
        return "nmea_text" if _NMEA_LINE.search(sample) else "unknown"
    if len(sample) >= 3 and sample[0] in ASTERIX_CATEGORIES:
        length = int.from_bytes(sample[1:3], "big")
        if 3 <= length <= size:
            return "asterix"
    return "unknown"


def import_file(path: Path, out_dir: Path, *, base_time_ns: int = 0) -> ImportedFile:
    """Wrap one file (see module docstring); raises ``ValueError`` when it is not an
    importable format."""
    path = Path(path)
    kind = detect_format(path)
    if kind == "nmea_text":
        return wrap_nmea_text(path, out_dir, base_time_ns=base_time_ns)
    if kind == "ais_csv":
        return wrap_ais_csv(path, out_dir)
    if kind == "asterix":
        from pipeline.convert.asterix import wrap_asterix_file

        out = wrap_asterix_file(path, Path(out_dir))
        return ImportedFile(str(path), str(out), "asterix", {}, {})
    raise ValueError(
        f"{path}: not an importable file (neither NMEA 0183 text, a known AIS CSV, raw "
        "ASTERIX nor a pcap/pcapng capture)"
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
    (content | comment | blank)."""
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
    return df.with_columns(kind=kind)


def _leading_ts_ns(ts: pl.Expr) -> pl.Expr:
    """Leading timestamp text -> int64 ns (epoch s / ms / ISO 8601)."""
    digits = ts.str.contains(r"^\d+(\.\d+)?$")
    int_part = ts.str.extract(r"^(\d+)", 1).cast(pl.Int64, strict=False)
    frac = ts.str.extract(r"\.(\d+)$", 1).str.slice(0, 9).str.pad_end(9, "0")
    frac_ns = frac.cast(pl.Int64, strict=False).fill_null(0)
    epoch = (
        pl.when(ts.str.contains(r"^\d{13}$"))
        .then(int_part * 1_000_000)
        .otherwise(int_part * NS + frac_ns)
    )
    iso = ts.str.replace(" ", "T").str.replace("Z$", "+00:00")
    iso = iso.str.replace(r"([+-]\d\d)(\d\d)$", "$1:$2")
    iso = pl.when(iso.str.contains(r"[+-]\d\d:\d\d$")).then(iso).otherwise(iso + "+00:00")
    dt = iso.str.to_datetime(format="%Y-%m-%dT%H:%M:%S%.f%:z", time_unit="ns", strict=False)
    return pl.when(digits).then(epoch).otherwise(dt.dt.epoch("ns"))


def _split_content(lines: pl.DataFrame) -> pl.DataFrame:
    """Content lines with ``payload`` (line without leading timestamp) and ``lead_ns``."""
    c = lines.filter(pl.col("kind") == "content")
    ts = pl.col("text").str.extract(LEADING_TS + r"(?:[$!\\])", 1)
    prefix = pl.col("text").str.extract(r"(" + LEADING_TS + r")(?:[$!\\])", 1)
    c = c.with_columns(ts=ts, prefix=prefix).with_columns(
        lead_ns=_leading_ts_ns(pl.col("ts")),
        payload=pl.when(pl.col("prefix").is_not_null())
        .then(pl.col("text").str.slice(pl.col("prefix").str.len_chars()))
        .otherwise(pl.col("text"))
        .str.strip_chars(),
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


def nmea_log_times(
    content: pl.DataFrame, pieces: pl.DataFrame, base_time_ns: int
) -> tuple[np.ndarray, str, dict[str, str]]:
    """Log time of every content line, the source name and extra metadata."""
    n = content.height
    tag = (
        pieces.filter(pl.col("code").is_null() & pl.col("tag_c_ns").is_not_null())
        .group_by("msg")
        .agg(pl.col("tag_c_ns").first().alias("t_ns"))
        .sort("msg")
    )
    if tag.height:
        return _interpolate(n, tag), "tag_block:c", {}
    lead = content.filter(pl.col("lead_ns").is_not_null()).select("msg", t_ns="lead_ns")
    if lead.height:
        return _interpolate(n, lead), "leading_timestamp", {}
    anchors, source = _nmea_anchors(pieces, base_time_ns)
    if anchors.height:
        extra = {}
        if source.startswith("nmea_time_of_day"):
            extra["log_date"] = str(np.datetime64(base_time_ns // DAY_NS, "D"))
        return _interpolate(n, anchors), source, extra
    times = base_time_ns + np.arange(n, dtype=np.int64) * SYNTHETIC_STEP_NS
    meta = {"synthetic_base_ns": str(base_time_ns), "synthetic_step_ns": str(SYNTHETIC_STEP_NS)}
    return times, "none:synthetic", meta


def wrap_nmea_text(path: Path, out_dir: Path, *, base_time_ns: int = 0) -> ImportedFile:
    """Wrap an NMEA 0183 text log (see module docstring)."""
    from pipeline.decode.nmea import AIS_FORMATTERS, frame

    path = Path(path)
    lines = _lines(path.read_bytes())
    content = _split_content(lines)
    pieces, _ = frame(content["payload"].to_list())
    pieces = pieces.with_row_index("idx")
    times, source, extra = nmea_log_times(content, pieces, base_time_ns)
    first = pieces.group_by("msg").agg(pl.col("formatter").first())
    content = content.join(first, on="msg", how="left").sort("msg")
    ais_text = content["payload"].str.contains(r"VD[MO],")  # a damaged AIS line
    is_ais = content["formatter"].is_in(list(AIS_FORMATTERS)).fill_null(ais_text).to_numpy()
    topics = np.where(is_ais, AIS_TOPIC, NAV_TOPIC)
    platform = path.name.split(".")[0] or path.name
    channel_meta = {
        "platform_id": platform,
        "source_file": path.name,
        "log_time_source": source,
        **extra,
    }
    skipped = dict(Counter(lines.filter(pl.col("kind") != "content")["kind"].to_list()))
    header = _header(lines)
    file_meta = {
        "format": "nmea_text",
        "source_file": path.name,
        "lines_total": str(lines.height),
        "log_time_source": source,
        **{f"{k}_lines": str(v) for k, v in skipped.items()},
        "header": header,
    }
    payloads = [t.encode("latin-1") for t in content["payload"].to_list()]  # MCAP: bytes
    out = output_path(path, out_dir)
    counts = _write_text_mcap(out, topics, times, payloads, channel_meta, file_meta)
    return ImportedFile(
        str(path), str(out), "nmea_text", counts, dict.fromkeys(counts, source), skipped
    )


def _header(lines: pl.DataFrame) -> str:
    """The leading ``#`` comment block (before the first content line), max 4 KiB."""
    first_content = lines.filter(pl.col("kind") == "content")["line"].min()
    head = lines.filter((pl.col("kind") == "comment") & (pl.col("line") < (first_content or 0)))
    return "\n".join(head["text"].to_list())[:4096]


# -- AIS CSV -----------------------------------------------------------------------------

_NULL_TEXT = ["", "unknown", "undefined", "unknown value", "n/a", "na"]
DMA_NAV_STATUS = {
    "under way using engine": 0, "at anchor": 1, "not under command": 2,
    "restricted maneuverability": 3, "restricted manoeuvrability": 3,
    "constrained by her draught": 4, "moored": 5, "aground": 6, "engaged in fishing": 7,
    "under way sailing": 8, "reserved for future amendment [hsc]": 9,
    "reserved for future amendment [wig]": 10, "power-driven vessel towing astern": 11,
    "power-driven vessel pushing ahead or towing alongside": 12,
    "reserved for future use": 13, "ais-sart is active": 14, "unknown value": 15,
}  # fmt: skip


def _txt(col: str) -> pl.Expr:
    s = pl.col(col).str.strip_chars()
    return pl.when(~s.str.to_lowercase().is_in(_NULL_TEXT)).then(s)


def _f(col: str) -> pl.Expr:
    return _txt(col).cast(pl.Float64, strict=False)


def _i(col: str) -> pl.Expr:
    return _f(col).round(0).cast(pl.Int64, strict=False)


def _time(col: str, fmt: str) -> pl.Expr:
    dt = _txt(col).str.to_datetime(format=fmt, time_unit="ns", strict=False)
    return dt.dt.epoch("ns")


def _csv_columns(flavor: str) -> tuple[list[pl.Expr], str]:
    """Expressions of the ``surveil.AisReport`` fields, and the time column's name."""
    if flavor == "stonesoup":
        return [
            _time("Time", "%Y-%m-%d %H:%M:%S%.f").alias("time_ns"), _i("MMSI").alias("mmsi"),
            _f("Latitude_degrees").alias("lat_deg"), _f("Longitude_degrees").alias("lon_deg"),
            _f("SOG_knots").alias("sog_kn"), _f("COG_degrees").alias("cog_deg"),
        ], "Time"  # fmt: skip
    if flavor == "marinecadastre":
        cls = _txt("TransceiverClass")
        return [
            _time("BaseDateTime", "%Y-%m-%dT%H:%M:%S%.f").alias("time_ns"),
            _i("MMSI").alias("mmsi"), cls.alias("mobile_type"), cls.alias("ais_class"),
            _f("LAT").alias("lat_deg"), _f("LON").alias("lon_deg"), _f("SOG").alias("sog_kn"),
            _f("COG").alias("cog_deg"), _f("Heading").alias("heading_deg"),
            _i("Status").alias("nav_status"), _txt("VesselName").alias("shipname"),
            _txt("IMO").str.replace("^IMO", "").cast(pl.Int64, strict=False).alias("imo"),
            _txt("CallSign").alias("callsign"), _i("VesselType").alias("ship_type"),
            _f("Length").alias("length_m"), _f("Width").alias("width_m"),
            _f("Draft").alias("draught_m"),
        ], "BaseDateTime"  # fmt: skip
    mobile = _txt("Type of mobile")
    status = _txt("Navigational status")
    return [
        _time("Timestamp", "%d/%m/%Y %H:%M:%S").alias("time_ns"), _i("MMSI").alias("mmsi"),
        mobile.alias("mobile_type"),
        mobile.str.extract(r"^Class ([AB])$", 1).alias("ais_class"),
        _f("Latitude").alias("lat_deg"), _f("Longitude").alias("lon_deg"),
        _f("SOG").alias("sog_kn"), _f("COG").alias("cog_deg"), _f("Heading").alias("heading_deg"),
        _f("ROT").alias("rot_deg_per_min"),
        pl.col("Navigational status").str.strip_chars().str.to_lowercase()
        .replace_strict(DMA_NAV_STATUS, default=None, return_dtype=pl.Int64).alias("nav_status"),
        status.alias("nav_status_text"), _i("IMO").alias("imo"),
        _txt("Callsign").alias("callsign"), _txt("Name").alias("shipname"),
        _txt("Ship type").alias("ship_type_text"), _f("Length").alias("length_m"),
        _f("Width").alias("width_m"), _f("Draught").alias("draught_m"),
        _txt("Destination").alias("destination"),
    ], "Timestamp"  # fmt: skip


def read_ais_csv(path: Path) -> tuple[pl.DataFrame, str, str]:
    """``(rows with the surveil.AisReport fields, flavor, time column)``."""
    raw = path.read_bytes()
    try:
        data = raw.decode("utf-8")
    except UnicodeDecodeError:
        data = raw.decode("latin-1")
    raw_lines = [ln for ln in split_lines(data) if ln.strip()]
    flavor = _csv_flavor(raw_lines[0]) if raw_lines else None
    if flavor is None:
        raise ValueError(f"{path}: not a known AIS CSV layout")
    df = pl.read_csv(data.encode(), infer_schema=False, truncate_ragged_lines=True)
    df = df.rename({c: c.strip().lstrip("#").strip() for c in df.columns})
    exprs, time_col = _csv_columns(flavor)
    rows = raw_lines[1:] if len(raw_lines) - 1 == df.height else None
    out = df.select(exprs).with_columns(
        source_format=pl.lit(flavor),
        raw=pl.Series(rows, dtype=pl.String)
        if rows is not None
        else pl.concat_str(pl.all(), separator=",", ignore_nulls=True),
    )
    fields = [f for f in _schema_fields() if f in out.columns]
    return out.select(fields), flavor, time_col


def _schema_fields() -> list[str]:
    return message_layout(AIS_REPORT_SCHEMA).names


def wrap_ais_csv(path: Path, out_dir: Path) -> ImportedFile:
    """Wrap an AIS CSV table (see module docstring) as ``surveil.AisReport`` JSON."""
    path = Path(path)
    rows, flavor, time_col = read_ais_csv(path)
    payload = rows.select(pl.struct(pl.all()).struct.json_encode().cast(pl.Binary).alias("p"))
    log = rows["time_ns"].forward_fill().fill_null(0).to_numpy().astype(np.int64)
    source = f"csv:{time_col}"
    platform = path.name.split(".")[0] or path.name
    meta = {
        "platform_id": platform,
        "source_file": path.name,
        "log_time_source": source,
        "source_format": flavor,
    }
    file_meta = {
        "format": "ais_csv",
        "source_file": path.name,
        "source_format": flavor,
        "rows": str(rows.height),
        "log_time_source": source,
    }
    out = output_path(path, out_dir)
    schema = message_layout(AIS_REPORT_SCHEMA).data
    _write_mcap(
        out,
        [(CSV_TOPIC, "json", AIS_SCHEMA_NAME, schema, meta)],
        np.zeros(rows.height, np.int64),
        log,
        payload["p"].to_list(),
        file_meta,
    )
    return ImportedFile(
        str(path), str(out), "ais_csv", {CSV_TOPIC: rows.height}, {CSV_TOPIC: source}
    )


# -- MCAP writing ------------------------------------------------------------------------

_Channel = tuple[str, str, str | None, bytes | None, dict[str, str]]


def _write_text_mcap(
    out: Path,
    topics: np.ndarray,
    times: np.ndarray,
    payloads: list[bytes],
    channel_meta: dict[str, str],
    file_meta: dict[str, str],
) -> dict[str, int]:
    names = [t for t in (NAV_TOPIC, AIS_TOPIC) if (topics == t).any()]
    channels: list[_Channel] = [(t, "nmea0183", None, None, channel_meta) for t in names]
    index = np.zeros(len(topics), dtype=np.int64)
    for i, t in enumerate(names):
        index[topics == t] = i
    _write_mcap(out, channels, index, times, payloads, file_meta)
    return {t: int((topics == t).sum()) for t in names}


def _write_mcap(
    out: Path,
    channels: list[_Channel],
    channel_index: np.ndarray,
    times: np.ndarray,
    payloads: list[bytes],
    file_meta: dict[str, str],
) -> None:
    """Write messages in the given order (file order of the source), temp file + rename."""
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            w = Writer(f, compression=CompressionType.ZSTD)
            w.start(profile=MCAP_PROFILE, library=MCAP_LIBRARY)
            ids = []
            for topic, encoding, schema_name, schema_data, meta in channels:
                sid = 0
                if schema_name is not None:
                    sid = w.register_schema(schema_name, "jsonschema", schema_data or b"")
                ids.append(w.register_channel(topic, encoding, sid, metadata=meta))
            w.add_metadata("surveil.import", file_meta)
            seq = [0] * len(ids)
            # one add_message call per message: the mcap writer has no bulk API
            for ch, t, p in zip(channel_index.tolist(), times.tolist(), payloads, strict=True):
                w.add_message(ids[ch], t, p, t, seq[ch])
                seq[ch] += 1
            w.finish()
        os.replace(tmp, out)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
