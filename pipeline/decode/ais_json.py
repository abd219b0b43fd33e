"""``surveil.AisReport`` JSON (AIS CSV imports) -> ``ais_reports``, ``ais_static`` + rejects.

The channel carries one decoded AIS table row per message (``schemas/ais_report.schema.json``)
in the source's units with its not-available codes. Payloads are parsed in bulk
(``polars.read_ndjson`` with the declared schema) and converted on whole columns, the
same way :mod:`pipeline.decode.ais` converts pyais output (ITU-R M.1371-5 §3.3, Table 46
for the codes):

- SOG knots -> m/s; 102.3 kn -> null (other speeds above the limit are rejected). COG
  deg -> rad; ≥ 360 or < 0 -> null. Heading deg -> rad; 511 (or > 359) -> null. IMO 0,
  ship type 0 -> null.
- ``msg_type``: the source's message id when it has a message-type column, else 0 (a
  table row does not say which message it came from). A static-only message (5, 24)
  without a position gives its ``ais_static`` row and no reject; a message id that is
  neither a position report (1, 2, 3, 18, 19, 27) nor static data goes to
  ``ais_other_messages``.
- Static data (name, call sign, IMO, ship type, destination) -> one ``ais_static`` row
  per message that has any of them.
- Base stations, AtoN and SAR aircraft are not vessels: one ``ais_other_messages`` row
  each under the message id they transmit (4, 21, 9), as the NMEA AIS decoder writes
  them; so is a row whose message id is neither a position report nor static data.
- ``ais_class`` of a vessel row: :func:`vessel_class` (the message id first: 18, 19, 24
  are class B whatever the source's class column says).

Rejects: ``undecodable`` (payload not JSON of this schema, MMSI or time missing),
``no_position`` (lat 91 / lon 181, or a missing coordinate), ``out_of_range`` (|lat| >
90, |lon| > 180, SOG above the limit). ``raw`` is the CSV line.
"""

from __future__ import annotations

import io
import json
import math
from collections import Counter
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa

from pipeline.decode.registry import make_rejects
from pipeline.messages import message_layout
from pipeline.tables import conform, empty
from pipeline.units import KNOT_MPS

DEG = math.pi / 180.0
MAX_SPEED_MPS = 40.0
NOT_VESSEL_MSG_ID = {"base station": 4, "aton": 21, "sar airborne": 9, "sar aircraft": 9,
                     "search and rescue aircraft": 9}
"""A source's station kind (DMA ``Type of mobile``) that is not a vessel -> the message id
such a station sends (base station report 4, AtoN report 21, SAR aircraft report 9)."""
POSITION_MSG_IDS = frozenset({1, 2, 3, 18, 19, 27})
STATIC_MSG_IDS = frozenset({5, 24})
KEPT_MSG_IDS = POSITION_MSG_IDS | STATIC_MSG_IDS
CLASS_B_MSG_IDS = frozenset({18, 19, 24})
CLASS_A_MSG_IDS = frozenset({1, 2, 3, 5, 27})
OTHER_CLASS = {4: "base_station", 11: "base_station", 21: "aton", 9: "sar_aircraft"}

SCHEMA = message_layout("ais_report.schema.json").polars_schema()
"""The fields of ``schemas/ais_report.schema.json`` (the source's units and codes)."""


def parse_payloads(payloads: list[bytes]) -> tuple[pl.DataFrame, list[int]]:
    """``(rows, bad)``: the parsed payloads (in order, a bad one as an all-null row) and
    the indexes of payloads that are not JSON objects."""
    try:
        df = pl.read_ndjson(io.BytesIO(b"\n".join(payloads)), schema=SCHEMA)
        if df.height == len(payloads):
            return df, []
    except Exception:  # one bad payload fails the bulk parse: fall back below
        pass
    rows: list[dict[str, Any]] = []
    bad: list[int] = []
    for i, p in enumerate(payloads):  # per message only after a bulk parse failed
        try:
            doc = json.loads(p)
            if not isinstance(doc, dict):
                raise ValueError("not an object")
            rows.append({k: doc.get(k) for k in SCHEMA})
        except Exception:
            rows.append(dict.fromkeys(SCHEMA))
            bad.append(i)
    return pl.DataFrame(rows, schema=SCHEMA, strict=False), bad


def _sog_na() -> pl.Expr:
    """SOG 102.3 kn: "not available" (ITU-R M.1371)."""
    return (pl.col("sog_kn") - 102.3).abs() < 1e-6


def _problems(max_speed_mps: float) -> tuple[pl.Expr, pl.Expr]:
    lat, lon, sog = pl.col("lat_deg"), pl.col("lon_deg"), pl.col("sog_kn") * KNOT_MPS
    cases = [
        (pl.col("_bad"), "undecodable", pl.lit("payload is not a surveil.AisReport object")),
        (pl.col("mmsi").is_null(), "undecodable", pl.lit("no MMSI")),
        (pl.col("time_ns").is_null(), "undecodable", pl.lit("no time")),
        (pl.col("msg_type").is_in(list(STATIC_MSG_IDS)) & (lat.is_null() | lon.is_null()),
         "_static_only", pl.lit("static data only")),
        (lat.is_null() | lon.is_null(), "no_position", pl.lit("no latitude/longitude")),
        ((lat == 91.0) | (lon == 181.0), "no_position",
         pl.format("position not available (lat {}, lon {})", lat, lon)),
        (lat.abs() > 90.0, "out_of_range", pl.format("lat_deg={} outside [-90, 90]", lat)),
        (lon.abs() > 180.0, "out_of_range", pl.format("lon_deg={} outside [-180, 180]", lon)),
        (~_sog_na() & (sog > max_speed_mps), "out_of_range",
         pl.format("sog {} kn above {} m/s", pl.col("sog_kn"), pl.lit(max_speed_mps))),
    ]  # fmt: skip
    code: pl.Expr = pl.lit(None, pl.String)
    reason: pl.Expr = pl.lit(None, pl.String)
    for cond, k, why in reversed(cases):
        hit = cond.fill_null(False)
        code = pl.when(hit).then(pl.lit(k)).otherwise(code)
        reason = pl.when(hit).then(why).otherwise(reason)
    return code, reason


def vessel_class() -> pl.Expr:
    """A vessel row's class: from its message id when the source has one (18, 19, 24 are
    class B, 1-3, 5, 27 class A: ITU-R M.1371-5 Annex 8), else the source's class or
    station kind (``Class B``), else ``"A"`` (a table without either, Stone Soup's)."""
    msg = pl.col("msg_type")
    cls = pl.col("ais_class").str.to_uppercase()
    kind = pl.col("mobile_type").str.to_lowercase().str.extract(r"^\s*class\s*([ab])\s*$", 1)
    return (pl.when(msg.is_in(list(CLASS_B_MSG_IDS))).then(pl.lit("B"))
            .when(msg.is_in(list(CLASS_A_MSG_IDS))).then(pl.lit("A"))
            .when(cls.is_in(["A", "B"])).then(cls)
            .when(kind.is_not_null()).then(kind.str.to_uppercase())
            .otherwise(pl.lit("A")))  # fmt: skip


def _si_columns() -> list[pl.Expr]:
    sog, cog, hdg = pl.col("sog_kn"), pl.col("cog_deg"), pl.col("heading_deg")
    return [
        pl.when(~_sog_na()).then(sog * KNOT_MPS).alias("sog_mps"),
        pl.when((cog >= 0) & (cog < 360)).then(cog * DEG).alias("cog_rad"),
        pl.when((hdg >= 0) & (hdg <= 359)).then(hdg * DEG).alias("heading_rad"),
        vessel_class().alias("ais_class"),
        pl.col("msg_type").fill_null(0).cast(pl.Int16).alias("msg_type"),
        pl.col("time_ns").alias("time_ns"),
        pl.col("raw").alias("nmea"),
    ]


def _other_columns() -> list[pl.Expr]:
    """``ais_other_messages`` columns of a row of a station that is not a vessel, or of
    another message id (``_not_vessel``: the message id)."""
    lat, lon = pl.col("lat_deg"), pl.col("lon_deg")
    placed = lat.is_between(-90, 90) & lon.is_between(-180, 180)
    sar = pl.col("_not_vessel") == 9
    cog = pl.col("cog_deg")
    return [
        pl.col("_not_vessel").cast(pl.Int16).alias("msg_type"),
        pl.col("_not_vessel").replace_strict(OTHER_CLASS, default=None, return_dtype=pl.String)
        .alias("ais_class"),
        pl.when(placed).then(lat).alias("lat_deg"),
        pl.when(placed).then(lon).alias("lon_deg"),
        pl.when(sar & ~_sog_na()).then(pl.col("sog_kn") * KNOT_MPS).alias("sog_mps"),
        pl.when(sar & (cog >= 0) & (cog < 360)).then(cog * DEG).alias("cog_rad"),
        pl.when(pl.col("_not_vessel") == 21).then(pl.col("shipname")).alias("name"),
        pl.col("raw").alias("nmea"),
    ]


def _static_columns() -> list[pl.Expr]:
    def positive(c: str) -> pl.Expr:
        return pl.when(pl.col(c) > 0).then(pl.col(c))

    return [positive("imo").alias("imo"), positive("ship_type").alias("ship_type")]


def decode_ais_json(
    payloads: list[bytes],
    log_time_ns: np.ndarray,
    *,
    source_file: str,
    topic: str,
    max_speed_mps: float = MAX_SPEED_MPS,
    time_source: str = "csv",
) -> tuple[dict[str, pa.Table], dict[int, int]]:
    """``({"ais_reports", "ais_static", "ais_other_messages", "rejects"}, not_stored)`` of
    a batch of ``surveil.AisReport`` payloads (see module docstring); ``log_time_ns``
    int64 ns; ``time_source``: the rows' ``time_source`` (the channel's
    ``log_time_source``, ``csv:<column>``)."""
    df, bad = parse_payloads(payloads)
    n = df.height
    mask = np.zeros(n, dtype=bool)
    mask[bad] = True
    df = df.with_row_index("_i").with_columns(
        _bad=pl.Series(mask),
        log_time_ns=pl.Series(np.asarray(log_time_ns, dtype=np.int64)),
        source_file=pl.lit(source_file),
        topic=pl.lit(topic),
        time_source=pl.lit(time_source),
        _kind=pl.col("mobile_type").str.to_lowercase().str.strip_chars(),
    )
    not_vessel = pl.col("_kind").replace_strict(
        NOT_VESSEL_MSG_ID, default=None, return_dtype=pl.Int64
    )
    msg = pl.col("msg_type")
    other_msg = msg.is_not_null() & (msg > 0) & ~msg.is_in(list(KEPT_MSG_IDS))
    df = df.with_columns(
        _not_vessel=pl.when(other_msg).then(msg).otherwise(not_vessel).fill_null(-1)
    )
    other = df.filter((pl.col("_not_vessel") >= 0) & ~pl.col("_bad")
                      & pl.col("mmsi").is_not_null() & pl.col("time_ns").is_not_null())
    other = other.with_columns(_other_columns())
    not_stored: dict[int, int] = {}
    code, reason = _problems(max_speed_mps)
    df = df.filter((pl.col("_not_vessel") < 0) | pl.col("_bad")).with_columns(
        code=code, reason=reason
    )
    ok = df.filter(pl.col("code").is_null()).with_columns(_si_columns())
    static = (
        df.filter(
            pl.col("code").is_null()
            | pl.col("code").is_in(["no_position", "_static_only"])
            & pl.col("mmsi").is_not_null()
            & pl.col("time_ns").is_not_null()
        )
        .with_columns(_si_columns())
        .with_columns(_static_columns())
    )
    has_static = pl.any_horizontal(
        [
            pl.col(c).is_not_null()
            for c in ("imo", "callsign", "shipname", "ship_type", "destination")
        ]
    )
    static = static.filter(has_static)
    rej = df.filter(pl.col("code").is_not_null() & (pl.col("code") != "_static_only"))
    tables = {
        "ais_reports": conform("ais_reports", ok.to_arrow()) if ok.height else empty("ais_reports"),
        "ais_static": conform("ais_static", static.to_arrow())
        if static.height
        else empty("ais_static"),
        "ais_other_messages": conform("ais_other_messages", other.to_arrow())
        if other.height else empty("ais_other_messages"),
        "rejects": _rejects(rej, payloads, source_file, topic),
    }
    return tables, not_stored


def _rejects(rej: pl.DataFrame, payloads: list[bytes], source_file: str, topic: str) -> pa.Table:
    """Rejects rows; ``raw`` is the CSV line, or the payload when it did not parse."""
    if not rej.height:
        return empty("rejects")
    raw = [
        r.encode() if r is not None else bytes(payloads[i])  # per reject row
        for r, i in zip(rej["raw"].to_list(), rej["_i"].to_list(), strict=True)
    ]
    return make_rejects(
        rej["log_time_ns"].to_numpy(),
        source_file=source_file,
        topic=topic,
        reason_code=rej["code"].to_list(),
        reason=rej["reason"].to_list(),
        raw=raw,
    )


class AisJsonChannelDecoder:
    """Stateful per-channel adapter for :mod:`pipeline.decode.registry`: decodes each
    batch as it comes (rows are independent) and counts ``not_stored``."""

    def __init__(self, source_file: str, topic: str, time_source: str = "csv"):
        self.source_file = source_file
        self.topic = topic
        self.time_source = time_source
        self.not_stored: Counter = Counter()

    @classmethod
    def for_channel(cls, batch: Any, source_file: str) -> AisJsonChannelDecoder:
        meta = getattr(batch, "metadata", None) or {}
        return cls(source_file, batch.topic, meta.get("log_time_source") or "csv")

    def feed(self, batch: Any) -> dict[str, pa.Table]:
        tables, not_stored = decode_ais_json(
            list(batch.payloads),
            batch.log_time_ns,
            source_file=self.source_file,
            topic=self.topic,
            time_source=self.time_source,
        )
        self.not_stored.update({f"ais_type_{k}": v for k, v in not_stored.items()})
        return {k: v for k, v in tables.items() if v.num_rows}

    def finish(self) -> dict[str, pa.Table]:
        return {}
