"""Where the time of an AIS (or NMEA) row comes from: every time a recording carries, in
one documented order of trust, and the label each row keeps in its ``time_source`` column.

A logged line may carry its own reception time in several ways; the first available one
in this order is the row's time (``docs/ingest_formats.md``, "Time sources"):

=====================  =====================================================================
``time_source``        what gave the time
=====================  =====================================================================
``nais:t``             USCG Nationwide AIS (N-AIS) receiver fields after the checksum,
                       ``...*hh,d-109,S2105,t050056.00,T56.13718694,r003669946,1325394060``:
                       the receiver's time of day ``t`` (hhmmss.ss), its seconds replaced by
                       ``T`` (the time of arrival within the minute, slot timing, 8
                       decimals) when present, dated by the trailing UNIX time (the day
                       that puts it nearest that time)
``nais:T``             ``T`` alone with a trailing UNIX time: the minute of that time
``pghp``               a Gatehouse ``$PGHP,1,<yyyy>,<m>,<d>,<h>,<min>,<s>,<ms>,<country>,
                       <region>,<pss>,<online>,<cksum>*hh`` sentence before the message
                       (IALA IWRAP "GH AIS message format"): UTC to the millisecond, for
                       the sentences of the one message that follows it
``tag_block:c``        an NMEA 4 / IEC 61162-1 tag block ``\\c:<unix time>*hh\\`` (seconds;
                       milliseconds when above 1e11; a fraction is kept)
``nais:epoch``         the trailing UNIX time of N-AIS fields alone (the station's log
                       time, whole seconds); with two, the first
``leading_timestamp``  a time the logging computer wrote before the line (import)
``csv:<column>``       the time column of an AIS CSV export (import)
``pcap``               the capture time of the UDP packet that carried the line (import)
``mcap_log_time``      the MCAP log time of a native recording (the recorder's clock)
``interpolated:<src>`` a line without a time of its own, placed by line number between the
                       nearest lines with one (``<src>``: ``tag_block:c``, ``nmea:RMC``, ...;
                       ``ais:base_station``: the UTC of received base station reports,
                       messages 4 and 11)
``none:synthetic``     no time anywhere in the file: ``--base-time`` + 1 ms per line
=====================  =====================================================================

A multi-sentence message takes the time of its last sentence when that one has a time of
its own, else the first own time among its sentences (a tag block ``c:`` on the first
fragment only is common), else the last sentence's log time. ``+utc_second`` is appended
where the AIS report's own time stamp refined an interpolated time
(:func:`refine_by_utc_second`).

Rows whose time is not a time of the world (:func:`is_synthetic`: ``none:*`` and dates
that are unknown, ``*:undated``) are kept but take part in no overlap warning and no
integrity decision (the batch does not read them).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import polars as pl

from pipeline.units import NS, TIME_MAX_NS

DAY_NS = 86_400 * NS
MINUTE_NS = 60 * NS

NAIS_T = "nais:t"
NAIS_T_ONLY = "nais:T"
PGHP = "pghp"
TAG_BLOCK = "tag_block:c"
NAIS_EPOCH = "nais:epoch"
LEADING = "leading_timestamp"
PCAP = "pcap"
MCAP_LOG_TIME = "mcap_log_time"
SYNTHETIC = "none:synthetic"
BASE_STATION = "ais:base_station"
INTERPOLATED = "interpolated:"
REFINED = "+utc_second"

OWN_ORDER = (NAIS_T, NAIS_T_ONLY, PGHP, TAG_BLOCK, NAIS_EPOCH)
"""Times a sentence carries itself (or right before it), most trusted first: slot timing
to 1e-8 s, then milliseconds, then whole seconds."""

REPORT_LATENCY_MAX_S = 2.0
"""How long after its ``utc_second`` a position report may be received (our bound: the
report is generated in the second it is sent; ITU-R M.1371-5 Annex 2 §3.3.7.2)."""


def is_synthetic(label: str | None) -> bool:
    """A time that is not a time of the world: no time in the file (``none:*``), or a
    time of day on an unknown date (``*:undated``)."""
    return bool(label) and (label.startswith("none:") or ":undated" in label)  # type: ignore[union-attr]


def synthetic_expr(col: str = "time_source") -> pl.Expr:
    """:func:`is_synthetic` over a column (null: not synthetic, rows of older ingests)."""
    c = pl.col(col)
    return (c.str.starts_with("none:") | c.str.contains(":undated", literal=True)).fill_null(
        False)


def is_interpolated(label: str | None) -> bool:
    return bool(label) and label.startswith(INTERPOLATED)  # type: ignore[union-attr]


def fallback_label(metadata: Mapping[str, str] | None) -> str:
    """The ``time_source`` of rows whose time is their line's MCAP log time, from the
    channel's metadata: ``time_source_fallback`` (written by ``surveil import``), else
    derived from ``log_time_source`` (imports before the column existed), else
    ``mcap_log_time`` (a native recording)."""
    meta = metadata or {}
    if meta.get("time_source_fallback"):
        return meta["time_source_fallback"]
    src = meta.get("log_time_source") or ""
    if not src:
        return MCAP_LOG_TIME
    if src in (LEADING, PCAP) or src.startswith(("csv:", "none:")):
        return src
    if src == "nmea_time_of_day:undated" and meta.get("log_date", "1970-01-01") != "1970-01-01":
        return INTERPOLATED + "nmea_time_of_day"
    return INTERPOLATED + src


def channel_synthetic(metadata: Mapping[str, str] | None) -> bool:
    """Whether a channel's log times are not times of the world: its rows' fallback time
    source is synthetic, or it holds times of day put on 1970-01-01 because nothing gave
    their date (``log_date`` 1970-01-01 without ``--base-time``: an undated ASTERIX
    recording, a time-of-day NMEA log)."""
    meta = metadata or {}
    if is_synthetic(fallback_label(meta)):
        return True
    return meta.get("log_date") == "1970-01-01" and meta.get("log_date_source") != "base_time"


def refinement_gap_s(metadata: Mapping[str, str] | None) -> float | None:
    """The interpolation bracket the channel's interpolated lines lie in (99th
    percentile, s: ``interpolation_gap_s_p99``); None when unknown (then the refinement
    tolerance is :data:`REPORT_LATENCY_MAX_S` alone)."""
    text = (metadata or {}).get("interpolation_gap_s_p99")
    try:
        return float(text) if text not in (None, "") else None
    except ValueError:
        return None


# -- times carried by the sentence -----------------------------------------------------

_TRAILER = r"^[!$][^*]*\*[0-9A-Fa-f]{1,2},(.*)$"
_EPOCH = r"(?:^|,)(\d{9,10}(?:\.\d+)?|\d{13})(?:,|$)"
_T_OF_DAY = r"(?:^|,)t(\d{2})(\d{2})(\d{2}(?:\.\d+)?)(?:,|$)"
_T_MINUTE = r"(?:^|,)T(\d{1,2}(?:\.\d+)?)(?:,|$)"


def _seconds_ns(text: pl.Expr) -> pl.Expr:
    """``"56.13718694"`` -> int64 ns (9 decimals at most; digits checked by the regex)."""
    whole = text.str.extract(r"^(\d+)", 1).cast(pl.Int64, strict=False)
    frac = text.str.extract(r"\.(\d+)$", 1).str.slice(0, 9).str.pad_end(9, "0")
    return whole * NS + frac.cast(pl.Int64, strict=False).fill_null(0)


def _epoch_ns(text: pl.Expr) -> pl.Expr:
    """10-digit UNIX seconds (a fraction kept) or 13-digit milliseconds -> ns, range
    checked before the multiplication (polars int64 arithmetic wraps silently)."""
    ms = text.str.contains(r"^\d{13}$")
    whole = text.str.extract(r"^(\d+)", 1).cast(pl.Int64, strict=False)
    return (
        pl.when(ms & (whole <= TIME_MAX_NS // 1_000_000)).then(whole * 1_000_000)
        .when(~ms & (whole <= TIME_MAX_NS // NS - 1)).then(_seconds_ns(text))
    )  # fmt: skip


def nais_time(body: pl.Expr) -> tuple[pl.Expr, pl.Expr]:
    """``(time_ns, time_source)`` of USCG N-AIS receiver fields after a sentence's
    checksum (module table: ``nais:t``, ``nais:T``, ``nais:epoch``); null when the line
    has no trailing UNIX time. ``body``: the sentence from its ``!``/``$`` on, trailer
    included.

    The fields (USCG NAIS log format, as libais/noaadata read it): ``S`` slot, ``s``
    RSSI, ``d`` signal strength dBm, ``t`` receiver time of day hhmmss.ss, ``T`` time of
    arrival within the minute, s, ``x`` counter, ``r``/``b``/``B`` station, then the UNIX
    time(s)."""
    trailer = body.str.extract(_TRAILER, 1)
    epoch = _epoch_ns(trailer.str.extract(_EPOCH, 1))
    hh = trailer.str.extract(_T_OF_DAY, 1).cast(pl.Int64, strict=False)
    mm = trailer.str.extract(_T_OF_DAY, 2).cast(pl.Int64, strict=False)
    ss = _seconds_ns(trailer.str.extract(_T_OF_DAY, 3))
    arrival = _seconds_ns(trailer.str.extract(_T_MINUTE, 1))
    arrival = pl.when(arrival < MINUTE_NS).then(arrival)
    have_t = (hh < 24) & (mm < 60) & (ss < 61 * NS)
    # T replaces t's seconds; a T on the other side of a minute boundary moves the minute
    sec = pl.coalesce(arrival, ss)
    sec = (pl.when(sec - ss > 30 * NS).then(sec - MINUTE_NS)
           .when(ss - sec > 30 * NS).then(sec + MINUTE_NS).otherwise(sec))  # fmt: skip
    tod = hh * 3600 * NS + mm * MINUTE_NS + sec
    day = (epoch - tod + DAY_NS // 2).floordiv(DAY_NS)
    t_of_day = day * DAY_NS + tod
    minute = (epoch - arrival + MINUTE_NS // 2).floordiv(MINUTE_NS)
    t_minute = minute * MINUTE_NS + arrival
    t = (pl.when(epoch.is_null()).then(None)
         .when(have_t.fill_null(False)).then(t_of_day)
         .when(arrival.is_not_null()).then(t_minute)
         .otherwise(epoch))  # fmt: skip
    src = (pl.when(epoch.is_null()).then(None)
           .when(have_t.fill_null(False)).then(pl.lit(NAIS_T))
           .when(arrival.is_not_null()).then(pl.lit(NAIS_T_ONLY))
           .otherwise(pl.lit(NAIS_EPOCH)))  # fmt: skip
    ok = t.is_between(0, TIME_MAX_NS)
    return pl.when(ok).then(t), pl.when(ok).then(src)


def tag_block_time(tag_text: pl.Expr) -> tuple[pl.Expr, pl.Expr]:
    """``(time_ns, out-of-range flag)`` of a tag block's ``c:`` (UNIX seconds, a fraction
    kept; milliseconds when the whole part is above 1e11), range-checked before any
    multiplication."""
    whole = tag_text.str.extract(r"(?:^|,)c:(\d+)", 1)
    n = whole.cast(pl.Int64, strict=False)
    frac = tag_text.str.extract(r"(?:^|,)c:\d+\.(\d+)", 1).str.slice(0, 9).str.pad_end(9, "0")
    frac_ns = frac.cast(pl.Int64, strict=False).fill_null(0)
    t = (pl.when(n.is_between(100_000_000_001, TIME_MAX_NS // 1_000_000)).then(n * 1_000_000)
         .when(n.is_between(0, TIME_MAX_NS // NS - 1)).then(n * NS + frac_ns))  # fmt: skip
    bad = tag_text.str.contains(r"(?:^|,)c:\d").fill_null(False) & t.is_null()
    return t, bad


def pghp_time(fields: pl.Expr) -> pl.Expr:
    """UTC ns of a ``$PGHP,1,...`` sentence's date and time (``fields``: the list after
    the address), null when it is not message 1 or a field is out of range."""
    def f(i: int) -> pl.Expr:
        return fields.list.get(i, null_on_oob=True).cast(pl.Int64, strict=False)

    year, month, day, hour, minute, sec, ms = (f(i) for i in range(1, 8))
    ok = ((fields.list.get(0, null_on_oob=True) == "1") & year.is_between(1970, 2261)
          & month.is_between(1, 12) & day.is_between(1, 31) & hour.is_between(0, 23)
          & minute.is_between(0, 59) & sec.is_between(0, 60) & ms.is_between(0, 999))  # fmt: skip
    days = pl.format("{}-{}-{}", year, month, day).str.to_date("%Y-%m-%d", strict=False)
    t = (days.cast(pl.Int64) * DAY_NS + hour * 3600 * NS + minute * MINUTE_NS + sec * NS
         + ms * 1_000_000)
    return pl.when(ok.fill_null(False)).then(t)


# -- refinement by the report's own second -----------------------------------------------


def refine_by_utc_second(
    time_ns: np.ndarray, utc_second: np.ndarray, refinable: np.ndarray, gap_s: float | None
) -> tuple[np.ndarray, np.ndarray]:
    """The time of each position report at the second it states (its ``utc_second``,
    ITU-R M.1371-5 Annex 2 §3.3.7.2 "time stamp": the UTC second when the report was
    generated), where that second agrees with an interpolated reception time.

    .. math:: t^* = t_{min} + s + k \\cdot 60\\,\\mathrm{s}, \\quad k = \\arg\\min_k
              |t^* - t|, \\qquad \\text{kept when } |t^* - t| \\le G + L

    with ``t`` the interpolated time, ``G`` the interpolation bracket (``gap_s``: the
    interval between the lines with a time of their own around it, None = 0) and ``L``
    :data:`REPORT_LATENCY_MAX_S`; only where ``G + L < 30 s`` (one candidate per minute
    can be told apart). ``refinable``: rows whose time was interpolated; ``utc_second``
    may hold -1 (absent). Returns the times and which rows were refined."""
    t = np.asarray(time_ns, np.int64)
    s = np.asarray(utc_second, np.int64)
    tol_s = (gap_s or 0.0) + REPORT_LATENCY_MAX_S
    ok = np.asarray(refinable, bool) & (s >= 0) & (s <= 59)
    if tol_s >= 30.0 or not ok.any():
        return t.copy(), np.zeros(t.shape, bool)
    minute = np.floor_divide(t, MINUTE_NS) * MINUTE_NS
    cand = minute + s * NS
    d = cand - t
    cand = cand - MINUTE_NS * (d > MINUTE_NS // 2) + MINUTE_NS * (d < -(MINUTE_NS // 2))
    ok &= np.abs(cand - t) <= round(tol_s * NS)
    return np.where(ok, cand, t), ok
