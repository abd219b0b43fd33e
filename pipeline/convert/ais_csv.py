"""AIS CSV tables of other tools -> ``surveil.AisReport`` JSON rows, placed by header name.

A CSV is an AIS table when one of its header cells names an MMSI column. Every header
cell is normalised (lower case, only letters and digits: ``"# Timestamp"`` ->
``timestamp``, ``"Latitude_degrees"`` -> ``latitudedegrees``) and looked up in
:data:`COLUMN_NAMES`, a mapping of the names common tools write to the canonical fields
of ``schemas/ais_report.schema.json`` (Stone Soup, NOAA MarineCadastre, the Danish
Maritime Authority's aisdk, aisdb exports, wide message-level exports of AIS decoders
with one column per message field). ``[import.csv] columns`` in the config
(:mod:`pipeline.convert.config`) places any other column: ``"Zeit" = "time"``; its keys
are header cells as written (case and blanks ignored), its values canonical field names
(``time``, ``mmsi``, ``lat``, ``lon``, ... or the schema names ``time_ns``, ``lat_deg``),
or ``ignore``. A table without a time or an MMSI column is refused with the list of the
columns that could not be placed (``ValueError``: ``surveil import`` lists the file as
failed, exit code 1).

Cells: the separator is sniffed from the header line (``,`` ``;`` tab ``|``), quoted cells
(``"a, b"``) are read as one, text cells that mean nothing (``''``, ``' '``, ``Unknown``,
``Undefined``, ``N/A``) become null, the source units and AIS not-available codes are
kept (the ingest decoder converts them). Speeds named ``..._mps`` / ``(m/s)`` are
converted to knots here, because the schema carries knots.

Time: one time column (or a date column plus a time-of-day column), parsed with the first
of these that reads the most of its cells (``[import.csv] time_format`` forces one):
ISO 8601 (``T`` or a space, fraction, ``Z`` or an offset), compact ISO
(``20240131T120000Z``, ``20240131120000``), ``dd/mm/yyyy HH:MM:SS`` (before
``mm/dd/yyyy`` when both read the same number), ``dd.mm.yyyy``, ``yyyy/mm/dd``, or epoch
seconds / milliseconds / microseconds / nanoseconds (by the number of integer digits;
fractions of a second kept). Naive times are UTC. A time that parses but lies outside
the representable range (1970 .. 2262) is rejected per row (``out_of_range``, through
:mod:`pipeline.convert.output`); a cell that does not parse leaves ``time_ns`` null and
ingest rejects the row (``undecodable``, "no time").
"""

from __future__ import annotations

import csv
import io
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import polars as pl

from pipeline.resources import resource_path
from pipeline.units import KNOT_MPS, NS, TIME_MAX_NS

_NULL_TEXT = ["", "unknown", "undefined", "unknown value", "n/a", "na", "none", "null", "nan"]
SEPARATORS = (",", ";", "\t", "|")
DMA_NAV_STATUS = {
    "under way using engine": 0, "at anchor": 1, "not under command": 2,
    "restricted maneuverability": 3, "restricted manoeuvrability": 3,
    "constrained by her draught": 4, "moored": 5, "aground": 6, "engaged in fishing": 7,
    "under way sailing": 8, "reserved for future amendment [hsc]": 9,
    "reserved for future amendment [wig]": 10, "power-driven vessel towing astern": 11,
    "power-driven vessel pushing ahead or towing alongside": 12,
    "reserved for future use": 13, "ais-sart is active": 14, "unknown value": 15,
}  # fmt: skip

# canonical field -> normalised header names that mean it (first match wins per field)
COLUMN_NAMES: dict[str, tuple[str, ...]] = {
    "time": ("time", "timestamp", "basedatetime", "datetime", "datetimeutc", "timestamputc",
             "timeutc", "utc", "utctime", "ts", "eventtime", "msgtime", "messagetime",
             "receivedtime", "receivetime", "rxtime", "reporttime", "postime", "epoch",
             "epochtime", "unixtime", "timeepoch", "tagblocktimestamp", "datetimestamp",
             "epochms", "epochs", "timestampms", "timems", "unixtimems", "unixms",
             "timestamps", "times", "timesec", "unixtimestamp", "epochseconds", "utcseconds",
             "receivedat", "utctimestamp", "timestampz", "datetimeiso", "isotime",
             "recordtime", "dt"),
    "date": ("date", "utcdate", "dateutc"),
    "millisecond": ("millisecond", "milliseconds", "msec", "ms"),
    "time_of_day": ("timeofday", "tod", "utctimeofday", "hhmmss"),
    "mmsi": ("mmsi", "userid", "sourcemmsi", "vesselmmsi", "shipmmsi", "mmsinumber",
             "mmsiid"),
    "lat": ("lat", "latitude", "latitudedegrees", "latdeg", "latdd", "latitudedeg", "ylat"),
    "lon": ("lon", "long", "lng", "longitude", "longitudedegrees", "londeg", "londd",
            "longitudedeg", "xlon"),
    "sog": ("sog", "sogknots", "sogkn", "sogkt", "speedoverground", "speed", "speedknots",
            "speedkn", "speedoverground knots"),
    "sog_mps": ("sogmps", "sogms", "speedmps", "speedms"),
    "cog": ("cog", "cogdegrees", "cogdeg", "courseoverground", "course", "coursedeg"),
    "heading": ("heading", "trueheading", "hdg", "headingdeg", "headingdegrees"),
    "rot": ("rot", "rateofturn", "rotdegmin", "turn", "turnrate"),
    "nav_status": ("navstatus", "navigationalstatus", "navigationstatus", "status",
                   "navstat", "navigationalstatuscode", "statuscode"),
    "msg_type": ("msgtype", "messagetype", "messageid", "msgid", "aismsgtype", "type",
                 "aistype", "msgnum"),
    "imo": ("imo", "imonumber", "imonum", "imono"),
    "callsign": ("callsign", "callsignascii", "call", "radiocallsign"),
    "shipname": ("vesselname", "shipname", "name", "vessel", "shipnameascii", "nameascii"),
    "ship_type": ("vesseltype", "shiptype", "shipandcargotype", "shipcargotype",
                  "typeofship", "shiptypecode", "shipandcargo", "shipcargo",
                  "vesseltypegeneric", "vesseltypecode"),
    "length": ("length", "lengthm", "len", "shiplength", "loa"),
    "width": ("width", "widthm", "beam", "breadth", "shipwidth"),
    "draught": ("draught", "draft", "draughtm", "draftm", "staticdraught"),
    "destination": ("destination", "dest", "destinationascii"),
    "mobile_type": ("typeofmobile", "transceiverclass", "class", "aisclass",
                    "transponderclass", "transceiver", "mobiletype", "classtype"),
    "ignore": (),
}  # fmt: skip
FIELD_ALIASES = {  # config values may also use the schema's own names
    "time_ns": "time", "lat_deg": "lat", "lon_deg": "lon", "sog_kn": "sog",
    "cog_deg": "cog", "heading_deg": "heading", "rot_deg_per_min": "rot", "length_m": "length",
    "width_m": "width", "draught_m": "draught", "ship_type_text": "ship_type",
    "nav_status_text": "nav_status",
}  # fmt: skip
REQUIRED = ("time", "mmsi")
_ISO_FORMATS = (
    "%Y-%m-%dT%H:%M:%S%.f%:z", "%Y-%m-%dT%H:%M:%S%.f", "%Y-%m-%d %H:%M:%S%.f%:z",
    "%Y-%m-%d %H:%M:%S%.f", "%Y%m%dT%H%M%S%.f", "%Y%m%d%H%M%S", "%Y%m%d_%H%M%S",
    "%d/%m/%Y %H:%M:%S%.f",
    "%m/%d/%Y %H:%M:%S%.f", "%d.%m.%Y %H:%M:%S%.f", "%Y/%m/%d %H:%M:%S%.f",
    "%d-%m-%Y %H:%M:%S%.f", "%Y-%m-%dT%H:%M", "%Y-%m-%d %H:%M", "%d/%m/%Y %H:%M",
)  # fmt: skip
_SAMPLE_ROWS = 2000


def normalise(name: str) -> str:
    """Header cell -> lookup key: lower case, letters and digits only."""
    return re.sub(r"[^0-9a-z]", "", name.lower())


_LOOKUP = {n: f for f, names in COLUMN_NAMES.items() for n in names}


def canonical_field(name: str) -> str | None:
    """A config value (``time``, ``lat_deg``, ``ignore``, ...) -> canonical field, or
    ``None`` when it names none."""
    key = name.strip().lower()
    key = FIELD_ALIASES.get(key, key)
    return key if key in COLUMN_NAMES else None


@dataclass(frozen=True)
class CsvOptions:
    """``columns``: header cell -> canonical field (config ``[import.csv] columns``);
    ``time_format``: a strftime format for the time column, else detected."""

    columns: Mapping[str, str] = field(default_factory=dict)
    time_format: str | None = None


def sniff_separator(header: str) -> str:
    """The separator of a header line: the candidate splitting it into most cells."""
    header = re.split(r"\r\n|\n|\r", header, maxsplit=1)[0]
    best, cells = ",", 0
    for sep in SEPARATORS:
        n = len(next(csv.reader([header], delimiter=sep), []))
        if n > cells:
            best, cells = sep, n
    return best


def header_cells(header: str) -> list[str]:
    header = re.split(r"\r\n|\n|\r", header, maxsplit=1)[0]
    cells = next(csv.reader([header.lstrip("\ufeff")], delimiter=sniff_separator(header)), [])
    return [c.strip().lstrip("#").strip() for c in cells]


def place_columns(
    cells: list[str], overrides: Mapping[str, str] | None = None
) -> tuple[dict[str, str], list[str]]:
    """``({canonical field: header cell}, header cells not placed)``: config overrides
    first, then :data:`COLUMN_NAMES`; the first cell wins a field."""
    over = {normalise(k): v for k, v in (overrides or {}).items()}
    placed: dict[str, str] = {}
    unplaced = []
    for cell in cells:
        key = normalise(cell)
        target = canonical_field(over[key]) if key in over else _LOOKUP.get(key)
        if target is None or (target != "ignore" and target in placed):
            unplaced.append(cell)
        elif target != "ignore":
            placed[target] = cell
    return placed, unplaced


def looks_like_ais_csv(first_line: str) -> bool:
    """A header line with an MMSI column and at least two more cells."""
    cells = header_cells(first_line)
    return len(cells) >= 3 and any(_LOOKUP.get(normalise(c)) == "mmsi" for c in cells)


def flavor(cells: list[str]) -> str:
    """The source tool when the header is one we know exactly, else ``csv``."""
    low = [c.lower() for c in cells]
    if low[:4] == ["time", "mmsi", "latitude_degrees", "longitude_degrees"]:
        return "stonesoup"
    if low[:4] == ["mmsi", "basedatetime", "lat", "lon"]:
        return "marinecadastre"
    if low[:3] == ["timestamp", "type of mobile", "mmsi"]:
        return "dma_aisdk"
    return "csv"


# -- cells -------------------------------------------------------------------------------


def _txt(col: str) -> pl.Expr:
    s = pl.col(col).str.strip_chars().str.strip_chars('"').str.strip_chars()
    return pl.when(~s.str.to_lowercase().is_in(_NULL_TEXT)).then(s)


def _f(col: str) -> pl.Expr:
    return _txt(col).str.replace(",", ".", literal=True).cast(pl.Float64, strict=False)


def _i(col: str) -> pl.Expr:
    return _f(col).round(0).cast(pl.Int64, strict=False)


def _epoch_ns(s: pl.Expr) -> pl.Expr:
    """Epoch digits -> ns by the count of integer digits (s: <= 10, ms: 11-13, µs:
    14-16, ns: 17-19), range-checked before any multiplication."""
    whole = s.str.extract(r"^(\d+)", 1)
    digits = whole.str.len_chars()
    n = whole.cast(pl.Int64, strict=False)
    frac = s.str.extract(r"^\d+\.(\d+)$", 1).str.slice(0, 9).str.pad_end(9, "0")
    frac_ns = frac.cast(pl.Int64, strict=False).fill_null(0)
    return (
        pl.when((digits <= 10) & (n <= TIME_MAX_NS // NS - 1)).then(n * NS + frac_ns)
        .when((digits <= 13) & (n <= TIME_MAX_NS // 1_000_000)).then(n * 1_000_000)
        .when((digits <= 16) & (n <= TIME_MAX_NS // 1000)).then(n * 1000)
        .when(digits <= 19).then(n)
    )  # fmt: skip


def _clean_time(s: pl.Expr) -> pl.Expr:
    """``Z`` / `` UTC`` -> ``+00:00``, ``+0000`` -> ``+00:00`` (chrono's ``%:z``)."""
    s = s.str.replace(r"(?i)\s*(Z|UTC|GMT)$", "+00:00")
    return s.str.replace(r"([+-]\d\d)(\d\d)$", "$1:$2")


def _parse_us(s: pl.Expr, fmt: str) -> pl.Expr:
    """Text -> µs since the epoch with ``fmt`` (µs: datetime[ns] wraps outside
    1677..2262); a format without an offset reads the offset-stripped text as UTC."""
    if "%:z" in fmt or "%z" in fmt:
        return s.str.to_datetime(fmt, time_unit="us", strict=False).dt.epoch("us")
    naive = s.str.replace(r"\+00:00$", "")
    return naive.str.to_datetime(fmt, time_unit="us", strict=False).dt.epoch("us")


def time_parser(df: pl.DataFrame, col: str, forced: str | None) -> tuple[str, pl.Expr]:
    """``(name, expression -> int64 µs or null)`` of the parser that reads the most
    cells of ``col`` (module docstring); epoch digits give ns (name ``epoch``)."""
    cell = _clean_time(_txt(col))
    if forced:
        return forced, _parse_us(cell, forced)
    sample = df.head(_SAMPLE_ROWS).select(cell.alias("t"))
    best, best_n = _ISO_FORMATS[0], -1
    for fmt in _ISO_FORMATS:  # calendar formats first: "20240131120000" is a date
        n = sample.select(_parse_us(pl.col("t"), fmt).is_not_null().sum()).item()
        if n > best_n:
            best, best_n = fmt, n
    epoch_n = sample.select(
        _epoch_ns(pl.col("t")).is_not_null().sum()
        * pl.col("t").str.contains(r"^\d+(\.\d+)?$").all()
    ).item()
    if epoch_n > best_n:
        best = "epoch"
    return best, (_epoch_ns(cell) if best == "epoch" else _parse_us(cell, best))


def time_ns(
    df: pl.DataFrame, placed: dict[str, str], forced: str | None
) -> tuple[pl.DataFrame, str]:
    """``df`` with ``_t_ns`` (null: no time or does not parse), ``_t_us`` (a parsed
    time in µs, possibly out of range) and the parser's name."""
    if "time" not in placed and {"date", "time_of_day"} <= set(placed):
        df = df.with_columns(
            pl.concat_str(_txt(placed["date"]), _txt(placed["time_of_day"]), separator=" ").alias(
                "_datetime"
            )
        )
        placed = {**placed, "time": "_datetime"}
    name, expr = time_parser(df, placed["time"], forced)
    if name == "epoch":  # _t_us marks "digits present" (a time, maybe not representable)
        digits = _txt(placed["time"]).str.contains(r"^\d+(\.\d+)?$")
        df = df.with_columns(_t_ns=expr, _t_us=pl.when(digits).then(pl.lit(0, pl.Int64)))
        return df, name
    if "millisecond" in placed:  # exactEarth / aisdb: "Time" to the second + "Millisecond"
        ms = _f(placed["millisecond"])
        expr = expr + pl.when(ms.is_between(0, 999)).then(ms * 1000).otherwise(0).cast(pl.Int64)
    df = df.with_columns(_t_us=expr)
    ok = pl.col("_t_us").is_between(0, TIME_MAX_NS // 1000)
    sub_us = _txt(placed["time"]).str.extract(r"[.,]\d{6}(\d{1,3})", 1).str.pad_end(3, "0")
    df = df.with_columns(
        _t_ns=pl.when(ok).then(
            pl.col("_t_us") * 1000 + sub_us.cast(pl.Int64, strict=False).fill_null(0)
        )
    )
    return df, name


# -- the table -------------------------------------------------------------------------


def _field_exprs(placed: dict[str, str]) -> list[pl.Expr]:
    """Expressions of the ``surveil.AisReport`` fields from the placed columns."""
    out: list[pl.Expr] = [pl.col("_t_ns").alias("time_ns")]

    def col(field: str) -> str | None:
        return placed.get(field)

    def add(field: str, expr_of, name: str) -> None:
        c = col(field)
        if c is not None:
            out.append(expr_of(c).alias(name))

    add("mmsi", _i, "mmsi")
    add("lat", _f, "lat_deg")
    add("lon", _f, "lon_deg")
    add("cog", _f, "cog_deg")
    add("heading", _f, "heading_deg")
    add("rot", _f, "rot_deg_per_min")
    add("imo", lambda c: _txt(c).str.replace(r"(?i)^IMO\s*", "").cast(pl.Float64, strict=False)
        .round(0).cast(pl.Int64, strict=False), "imo")  # fmt: skip
    add("callsign", _txt, "callsign")
    add("shipname", _txt, "shipname")
    add("length", _f, "length_m")
    add("width", _f, "width_m")
    add("draught", _f, "draught_m")
    add("destination", _txt, "destination")
    add("msg_type", _i, "msg_type")
    if col("sog") is not None:
        out.append(_f(col("sog")).alias("sog_kn"))
    elif col("sog_mps") is not None:
        out.append((_f(col("sog_mps")) / KNOT_MPS).alias("sog_kn"))
    if col("ship_type") is not None:  # a code, or the type as text (DMA "Ship type")
        c = col("ship_type")
        out += [_i(c).alias("ship_type"),
                pl.when(_i(c).is_null()).then(_txt(c)).alias("ship_type_text")]  # fmt: skip
    if col("nav_status") is not None:  # a code, or the status as text (DMA)
        c = col("nav_status")
        text = pl.col(c).str.strip_chars().str.strip_chars('"').str.to_lowercase()
        code = pl.coalesce(
            _i(c), text.replace_strict(DMA_NAV_STATUS, default=None, return_dtype=pl.Int64)
        )
        out += [code.alias("nav_status"),
                pl.when(_i(c).is_null()).then(_txt(c)).alias("nav_status_text")]  # fmt: skip
    if col("mobile_type") is not None:
        m = _txt(col("mobile_type"))
        out += [m.alias("mobile_type"),
                m.str.extract(r"(?i)^(?:class\s*)?([AB])$", 1).str.to_uppercase()
                .alias("ais_class")]  # fmt: skip
    return out


@dataclass(frozen=True)
class CsvTable:
    """``rows``: the ``surveil.AisReport`` fields, plus ``_time_reject`` (why a row's
    time cannot be used, else null); ``flavor``; the time column and its parser; the
    header cells not placed."""

    rows: pl.DataFrame
    flavor: str
    time_column: str
    time_parser: str
    unplaced: list[str]


def read_ais_csv(path: Path, options: CsvOptions | None = None) -> CsvTable:
    """Read an AIS CSV (module docstring); ``ValueError`` when it is not one, or its time
    or MMSI column cannot be placed (the message lists the columns not placed)."""
    options = options or CsvOptions()
    raw = Path(path).read_bytes()
    try:
        data = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        data = raw.decode("latin-1")
    lines = [ln for ln in re.split(r"\r\n|\n|\r", data) if ln.strip()]
    if not lines:
        raise ValueError(f"{path}: empty file, not an AIS CSV")
    sep = sniff_separator(lines[0])
    cells = header_cells(lines[0])
    placed, unplaced = place_columns(cells, options.columns)
    missing = [f for f in REQUIRED if f not in placed]
    if "time" in missing and {"date", "time_of_day"} <= set(placed):
        missing.remove("time")
    if missing:
        raise ValueError(
            f"{path}: AIS CSV: no column for {', '.join(missing)}; columns that could not "
            f"be placed: {', '.join(repr(c) for c in unplaced) or 'none'} (name them in "
            '[import.csv] columns of the config, e.g. "Zeit" = "time")'
        )
    df = _read_cells(data, sep, cells)
    columns = list(df.columns)
    placed = _message_or_ship_type(df, placed)
    df, parser = time_ns(df, placed, options.time_format)
    time_col = placed.get("time", "_datetime")
    kind = flavor(cells)
    rows = lines[1:] if len(lines) - 1 == df.height else None
    out = df.select(
        *_field_exprs(placed),
        _time_reject=pl.when(pl.col("_t_ns").is_null() & pl.col("_t_us").is_not_null()).then(
            pl.format("time {} is outside 1970-01-01 .. 2262-04-11 UTC", _txt(time_col))
        ),
        source_format=pl.lit(kind),
        raw=pl.Series(rows, dtype=pl.String)
        if rows is not None
        else pl.concat_str([pl.col(c) for c in columns], separator=sep, ignore_nulls=True),
    )
    fields = [f for f in schema_fields() if f in out.columns]
    if time_col == "_datetime":
        time_col = f"{placed['date']}+{placed['time_of_day']}"
    return CsvTable(out.select(*fields, "_time_reject"), kind, time_col, parser, unplaced)


def _message_or_ship_type(df: pl.DataFrame, placed: dict[str, str]) -> dict[str, str]:
    """A bare ``type`` column is the AIS message id in message-level exports but the ship
    type in vessel tables (AISHub): values above 27 (ship type codes are 20..99) make it
    the ship type, when no other column is."""
    col = placed.get("msg_type")
    if col is None or normalise(col) != "type" or "ship_type" in placed:
        return placed
    values = df.head(_SAMPLE_ROWS).select(_i(col).alias("v"))["v"].drop_nulls()
    if len(values) and (values > 27).any():
        out = {k: v for k, v in placed.items() if k != "msg_type"}
        out["ship_type"] = col
        return out
    return placed


def _read_cells(data: str, sep: str, cells: list[str]) -> pl.DataFrame:
    """Every cell as text, columns named by the header cells. polars reads the file in
    one go; a file it refuses (a stray character after a closing quote, ...) is read by
    the more lenient ``csv`` module instead, row by row."""
    names = [f"{c}#{i}" if c in cells[:i] else c for i, c in enumerate(cells)]
    try:
        df = pl.read_csv(
            io.BytesIO(data.encode()), separator=sep, infer_schema=False,
            truncate_ragged_lines=True, quote_char='"', has_header=True,
        )  # fmt: skip
        return df.rename(dict(zip(df.columns, names, strict=False)))
    except pl.exceptions.PolarsError:
        pass
    rows = list(csv.reader(io.StringIO(data), delimiter=sep))[1:]  # per row: the fallback
    rows = [r for r in rows if any(c.strip() for c in r)]
    cols = {name: [r[i] if i < len(r) else None for r in rows] for i, name in enumerate(names)}
    return pl.DataFrame(cols, schema=dict.fromkeys(names, pl.String))


def schema_fields() -> list[str]:
    doc = json.loads((resource_path("schemas") / "ais_report.schema.json").read_text())
    return list(doc["properties"])
