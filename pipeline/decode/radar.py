"""Radar track reports (JSON, ``surveil.RadarTrackReport``) -> ``radar_tracks`` + rejects.

All payloads of a batch are joined with ``b"\\n"`` and parsed in ONE ``polars.read_ndjson``
call with the declared types (~100-300 MB/s, ``research/mcap.md`` §3); validation is a few
vectorised expressions. Only when the bulk parse fails does the decoder fall back to one
``json.loads`` per payload to find the bad ones (reason_code ``undecodable``), then bulk
parses the rest again.

Validation (reason_code ``out_of_range``, the reason names every failed check):
missing required field; NaN/inf in any numeric field (JSON ``NaN``/``Infinity`` tokens
included); ``range_m`` < 0 or > ``validation.max_range_m``; ``azimuth_rad`` outside
[0, 2π]; ``speed_mps`` < 0 or > ``validation.max_speed_mps``; a sigma or
``scan_period_s`` ≤ 0.

Column mapping: ``track_id`` -> ``local_track_id``, ``x_m`` -> ``x_site_m``,
``y_m`` -> ``y_site_m``; every other field keeps its name (units in the names: m, rad,
m/s, s, ns). Rejected rows keep their raw payload in ``raw``.
"""

from __future__ import annotations

import io
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import polars as pl
import pyarrow as pa

from pipeline.config import ValidationConfig
from pipeline.decode.registry import make_rejects
from pipeline.tables import conform, empty

RADAR_FIELDS: dict[str, pl.DataType] = {
    "site_id": pl.String(),
    "track_id": pl.Int64(),
    "time_ns": pl.Int64(),
    "range_m": pl.Float64(),
    "azimuth_rad": pl.Float64(),
    "x_m": pl.Float64(),
    "y_m": pl.Float64(),
    "course_rad": pl.Float64(),
    "speed_mps": pl.Float64(),
    "sigma_range_m": pl.Float64(),
    "sigma_azimuth_rad": pl.Float64(),
    "sigma_course_rad": pl.Float64(),
    "sigma_speed_mps": pl.Float64(),
    "scan_period_s": pl.Float64(),
    "scan_end_azimuth_rad": pl.Float64(),
}
RADAR_RENAME = {"track_id": "local_track_id", "x_m": "x_site_m", "y_m": "y_site_m"}
_POSITIVE = (
    "sigma_range_m",
    "sigma_azimuth_rad",
    "sigma_course_rad",
    "sigma_speed_mps",
    "scan_period_s",
)


@dataclass(frozen=True)
class JsonParse:
    """Outcome of parsing JSON payloads.

    ``frame``: parsed rows with an ``_idx`` column (index into the payloads);
    ``bad_idx``/``bad_code``/``bad_reason``: payloads rejected while parsing.
    """

    frame: pl.DataFrame
    bad_idx: list[int]
    bad_code: list[str]
    bad_reason: list[str]


def _bulk(payloads: Sequence[bytes], schema: dict[str, pl.DataType]) -> pl.DataFrame | None:
    """One ndjson parse of all payloads; ``None`` when it fails or loses lines."""
    if not payloads:
        return pl.DataFrame(schema=schema)
    try:
        df = pl.read_ndjson(io.BytesIO(b"\n".join(payloads)), schema=schema)
    except Exception:  # polars raises ComputeError and friends; caller falls back
        return None
    return df if df.height == len(payloads) else None


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


def parse_json_payloads(payloads: Sequence[bytes], schema: dict[str, pl.DataType]) -> JsonParse:
    """Parse JSON-object payloads into typed columns (unknown fields are ignored; a
    missing field is null). Bulk first; per-payload fallback only when that fails."""
    df = _bulk(payloads, schema)
    if df is not None:
        idx = pl.Series("_idx", np.arange(len(payloads), dtype=np.int64))
        return JsonParse(df.with_columns(idx), [], [], [])
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
    frames = _bisect(payloads, candidates, schema, out) if candidates else []
    blank = pl.DataFrame(schema={**schema, "_idx": pl.Int64()})
    frame = pl.concat(frames) if frames else blank
    return JsonParse(frame, out.bad_idx, out.bad_code, out.bad_reason)


def missing_reasons(fields: Sequence[str]) -> list[pl.Expr]:
    """One expression per field: a reason string when the field is null, else null."""
    return [
        pl.when(pl.col(c).is_null()).then(pl.lit(f"missing required field {c!r}")) for c in fields
    ]


def nonfinite_reasons(fields: Sequence[str]) -> list[pl.Expr]:
    return [
        pl.when(~pl.col(c).is_finite()).then(pl.lit(f"non-finite value in {c!r}")) for c in fields
    ]


def outside(col: str, lo: float | None, hi: float | None, *, lo_open: bool = False) -> pl.Expr:
    """Reason when ``col`` is outside [lo, hi] (``(lo, hi]`` with ``lo_open``)."""
    c = pl.col(col)
    cond = pl.lit(False)
    if lo is not None:
        cond = cond | ((c <= lo) if lo_open else (c < lo))
    if hi is not None:
        cond = cond | (c > hi)
    lo_txt = "-inf" if lo is None else f"{lo:g}"
    hi_txt = "inf" if hi is None else f"{hi:g}"
    bracket = "(" if lo_open else "["
    msg = pl.format(f"{col}={{}} outside {bracket}{lo_txt}, {hi_txt}]", c)
    return pl.when(c.is_finite() & cond).then(msg)


def split_valid(frame: pl.DataFrame, reasons: list[pl.Expr]) -> tuple[pl.DataFrame, pl.DataFrame]:
    """(valid rows, rejected rows with a ``_reason`` column joining every failed check)."""
    if not reasons:
        return frame, frame.clear().with_columns(pl.lit("").alias("_reason"))
    tagged = frame.with_columns(
        pl.concat_str(reasons, separator="; ", ignore_nulls=True).alias("_reason")
    )
    tagged = tagged.with_columns(
        pl.when(pl.col("_reason") == "").then(None).otherwise(pl.col("_reason")).alias("_reason")
    )
    bad = tagged.filter(pl.col("_reason").is_not_null())
    good = tagged.filter(pl.col("_reason").is_null()).drop("_reason")
    return good, bad


def rejects_for(
    parsed: JsonParse,
    bad_rows: pl.DataFrame,
    payloads: Sequence[bytes],
    log_time_ns: np.ndarray,
    *,
    source_file: str,
    topic: str,
) -> pa.Table:
    """Rejects rows for the parse failures and the rows that failed validation."""
    if not parsed.bad_idx and bad_rows.height == 0:
        return empty("rejects")
    idx = list(parsed.bad_idx) + bad_rows["_idx"].to_list()
    codes = list(parsed.bad_code) + ["out_of_range"] * bad_rows.height
    reasons = list(parsed.bad_reason) + bad_rows["_reason"].to_list()
    return make_rejects(
        np.asarray(log_time_ns, dtype=np.int64)[np.asarray(idx, dtype=np.int64)],
        source_file=source_file,
        topic=topic,
        reason_code=codes,
        reason=reasons,
        raw=[payloads[i] for i in idx],
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


def radar_reasons(validation: ValidationConfig) -> list[pl.Expr]:
    """Validation checks of a radar report (see module docstring)."""
    numeric = [c for c, t in RADAR_FIELDS.items() if t == pl.Float64()]
    return [
        *missing_reasons(list(RADAR_FIELDS)),
        *nonfinite_reasons(numeric),
        outside("range_m", 0.0, validation.max_range_m),
        outside("azimuth_rad", 0.0, 2 * math.pi),
        outside("speed_mps", 0.0, validation.max_speed_mps),
        *(outside(c, 0.0, None, lo_open=True) for c in _POSITIVE),
    ]


def decode_radar_reports(
    payloads: list[bytes],
    log_time_ns: np.ndarray,
    *,
    source_file: str,
    topic: str,
    validation: ValidationConfig,
) -> tuple[pa.Table, pa.Table]:
    """``(radar_tracks rows, rejects rows)`` of a batch of radar report payloads.

    ``log_time_ns``: int64 MCAP log times of the payloads, ns. Output rows carry the
    provenance columns and are conformed to the canonical schemas.
    """
    parsed = parse_json_payloads(payloads, RADAR_FIELDS)
    good, bad = split_valid(parsed.frame, radar_reasons(validation))
    rows = with_provenance(good, log_time_ns, source_file=source_file, topic=topic)
    rows = rows.rename(RADAR_RENAME)
    rejects = rejects_for(parsed, bad, payloads, log_time_ns, source_file=source_file, topic=topic)
    return conform("radar_tracks", rows.to_arrow()), rejects
