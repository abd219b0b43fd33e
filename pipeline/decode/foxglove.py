"""GNSS fixes -> ``nav_gnss``: the shared mapping of ``foxglove.LocationFix`` (JSON,
protobuf, ROS 2) and ``sensor_msgs/NavSatFix``, and the JSON ``foxglove.LocationFix``
channel decoder.

``foxglove.LocationFix`` (docs.foxglove.dev, schema ``LocationFix``): ``timestamp``,
``frame_id``, ``latitude``/``longitude`` (deg), ``altitude`` (m), ``position_covariance``
(float64[9], m², ENU tangent plane, row-major), ``position_covariance_type`` (0 UNKNOWN,
1 APPROXIMATED, 2 DIAGONAL_KNOWN, 3 KNOWN). The optional ``heading``/``velocity`` fields
of newer schema versions are not mapped. JSON encodes ``timestamp`` as
``{"sec": s, "nsec": ns}`` (``nanosec`` accepted too).

Mapping to ``nav_gnss`` (:func:`fix_table`):

- ``time_ns`` = the message's own timestamp (LocationFix ``timestamp``, NavSatFix
  ``header.stamp``) when it is non-zero, else the MCAP log time;
- ``platform_id`` = channel metadata ``platform_id``, else the topic;
- ``sentence`` = ``LocationFix`` | ``NavSatFix``; ``talker`` null;
- ``lat_deg``/``lon_deg``/``altitude_m``: NaN -> null (no fix). NOTE: these sources give
  the height above the WGS-84 ellipsoid (REP-145; foxglove does not say), stored as is in
  ``altitude_m`` (which NMEA GGA fills with height above mean sea level): no geoid model
  is applied;
- ``sigma_lon_m`` = sqrt(cov[0]) (east), ``sigma_lat_m`` = sqrt(cov[4]) (north) when the
  covariance type is not UNKNOWN (0) and the variances are finite and ≥ 0;
- ``fix_quality``/``fix_valid``: NavSatFix only (see :mod:`pipeline.decode.ros2`); null
  for LocationFix, which carries no fix status.

Rejects: ``out_of_range`` (|latitude| > 90° or |longitude| > 180°), ``undecodable``
(payload that does not parse), with the raw payload.
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa

from pipeline.decode.registry import make_rejects
from pipeline.io.mcap_read import ChannelBatch
from pipeline.tables import conform, empty
from pipeline.units import NS


@dataclass
class FixColumns:
    """Decoded fixes of one batch, one entry per message (NaN / -1 where absent): numpy
    arrays from the vectorised decoders, or lists filled by :meth:`add`.

    ``index``: the message's position in its batch; ``stamp_ns``: own timestamp (0 when
    absent); ``cov``: (n, 9) ENU covariance, m²; ``cov_type``: covariance type (0
    unknown); ``fix_quality``: GGA-style quality (-1 = unknown); ``fix_valid``: 1/0, -1
    unknown.
    """

    stamp_ns: Any = field(default_factory=list)
    lat: Any = field(default_factory=list)
    lon: Any = field(default_factory=list)
    alt: Any = field(default_factory=list)
    cov: Any = field(default_factory=list)
    cov_type: Any = field(default_factory=list)
    fix_quality: Any = field(default_factory=list)
    fix_valid: Any = field(default_factory=list)
    index: Any = field(default_factory=list)

    def add(
        self, i: int, stamp_ns: int, lat: float, lon: float, alt: float,
        cov: Sequence[float], cov_type: int, fix_quality: int = -1, fix_valid: int = -1,
    ) -> None:  # fmt: skip
        """One message ``i`` of the batch (its index, for log time and raw bytes)."""
        self.index.append(i)
        self.stamp_ns.append(int(stamp_ns))
        self.lat.append(float(lat))
        self.lon.append(float(lon))
        self.alt.append(float(alt))
        cov = list(cov)
        self.cov.append(cov if len(cov) == 9 else [np.nan] * 9)
        self.cov_type.append(int(cov_type))
        self.fix_quality.append(int(fix_quality))
        self.fix_valid.append(int(fix_valid))


@dataclass(frozen=True)
class FixContext:
    source_file: str
    topic: str
    platform_id: str
    sentence: str


def platform_of(batch: ChannelBatch) -> str:
    """Channel metadata ``platform_id``, else the topic (schemas/tables.d/nav.toml)."""
    return batch.metadata.get("platform_id") or batch.topic


def _nan_to_null(x: np.ndarray) -> pa.Array:
    return pa.array(x, pa.float64(), mask=~np.isfinite(x))


def _sigma(var: np.ndarray, ok: np.ndarray) -> pa.Array:
    good = ok & np.isfinite(var) & (var >= 0)
    return pa.array(np.sqrt(np.where(good, var, 0.0)), pa.float64(), mask=~good)


def fix_table(
    fixes: FixColumns,
    log_time_ns: np.ndarray,
    payloads: Sequence[bytes],
    ctx: FixContext,
) -> tuple[pa.Table, pa.Table]:
    """``(nav_gnss rows, rejects rows)`` of decoded fixes (vectorised over the batch).

    ``log_time_ns``/``payloads``: the whole batch, indexed by ``fixes.index``.
    """
    if not len(fixes.index):
        return empty("nav_gnss"), empty("rejects")
    idx = np.asarray(fixes.index, dtype=np.int64)
    log_t = np.asarray(log_time_ns, dtype=np.int64)[idx]
    lat, lon = np.asarray(fixes.lat), np.asarray(fixes.lon)
    bad = (np.abs(lat) > 90) | (np.abs(lon) > 180)
    rejects = make_rejects(
        log_t[bad], source_file=ctx.source_file, topic=ctx.topic, reason_code="out_of_range",
        reason=[f"{ctx.sentence}: latitude {a} / longitude {b} deg out of range"
                for a, b in zip(lat[bad], lon[bad], strict=True)],
        raw=[payloads[i] for i in idx[bad]],
    )  # fmt: skip
    keep = ~bad
    stamp = np.asarray(fixes.stamp_ns, dtype=np.int64)
    cov = np.asarray(fixes.cov, dtype=np.float64).reshape(-1, 9)
    known = np.asarray(fixes.cov_type) > 0
    quality = np.asarray(fixes.fix_quality, dtype=np.int64)
    valid = np.asarray(fixes.fix_valid, dtype=np.int64)
    n = int(keep.sum())
    table = pa.table({
        "time_ns": np.where(stamp > 0, stamp, log_t)[keep],
        "platform_id": [ctx.platform_id] * n,
        "sentence": [ctx.sentence] * n,
        "lat_deg": _nan_to_null(lat[keep]),
        "lon_deg": _nan_to_null(lon[keep]),
        "altitude_m": _nan_to_null(np.asarray(fixes.alt)[keep]),
        "fix_quality": pa.array(quality[keep], pa.int16(), mask=quality[keep] < 0),
        "fix_valid": pa.array(valid[keep] == 1, pa.bool_(), mask=valid[keep] < 0),
        "sigma_lon_m": _sigma(cov[keep, 0], known[keep]),
        "sigma_lat_m": _sigma(cov[keep, 4], known[keep]),
        "source_file": [ctx.source_file] * n,
        "topic": [ctx.topic] * n,
        "log_time_ns": log_t[keep],
    })  # fmt: skip
    return conform("nav_gnss", table), rejects


# -- JSON ------------------------------------------------------------------------------

_JSON_SCHEMA: dict[str, pl.DataType] = {
    "timestamp": pl.Struct({"sec": pl.Int64, "nsec": pl.Int64, "nanosec": pl.Int64}),
    "latitude": pl.Float64(),
    "longitude": pl.Float64(),
    "altitude": pl.Float64(),
    "position_covariance": pl.List(pl.Float64),
    "position_covariance_type": pl.Int64(),
}


def _bulk_json(payloads: Sequence[bytes]) -> pl.DataFrame | None:
    """One ndjson parse of every payload, ``None`` when it fails or loses lines."""
    try:
        df = pl.read_ndjson(io.BytesIO(b"\n".join(payloads)), schema=_JSON_SCHEMA)
    except Exception:  # polars raises several error types; the caller falls back
        return None
    return df if df.height == len(payloads) else None


def _json_problem(payload: bytes) -> str | None:
    """Why one payload is not a LocationFix JSON object, else ``None``."""
    try:
        obj = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        return f"invalid JSON: {exc}"
    if not isinstance(obj, dict):
        return f"JSON {type(obj).__name__} where a LocationFix object was expected"
    if _bulk_json([payload]) is None:
        return "fields of the wrong type for foxglove.LocationFix"
    return None


def _cov9(col: pl.Series) -> np.ndarray:
    """(n, 9) covariance from a list column; rows without exactly 9 values -> NaN."""
    out = np.full((len(col), 9), np.nan)
    ok = (col.list.len() == 9).fill_null(False).to_numpy()
    if ok.any():
        out[ok] = col.filter(pl.Series(ok)).explode().fill_null(np.nan).to_numpy().reshape(-1, 9)
    return out


def decode_location_fix_json(
    payloads: Sequence[bytes],
    log_time_ns: np.ndarray,
    ctx: FixContext,
) -> tuple[pa.Table, pa.Table]:
    """JSON ``foxglove.LocationFix`` payloads -> ``(nav_gnss, rejects)``.

    All payloads are parsed in ONE ``polars.read_ndjson`` call; only when that fails is
    each payload checked on its own to find the bad ones (``undecodable``)."""
    good = list(range(len(payloads)))
    df = _bulk_json(payloads)
    bad_rows: list[tuple[int, str]] = []
    if df is None:
        # per message only on the failure path, to name the payloads that do not parse
        bad_rows = [(i, why) for i, p in enumerate(payloads) if (why := _json_problem(p))]
        bad = {i for i, _ in bad_rows}
        good = [i for i in good if i not in bad]
        df = _bulk_json([payloads[i] for i in good])
        if df is None:  # cannot happen: each remaining payload parsed on its own
            raise RuntimeError("LocationFix JSON payloads parse alone but not together")
    ts = pl.col("timestamp").struct
    nsec = pl.coalesce(ts.field("nsec"), ts.field("nanosec"), pl.lit(0))
    stamps = df.select((ts.field("sec").fill_null(0) * NS + nsec).alias("t"))["t"]
    fixes = FixColumns(
        index=np.asarray(good, dtype=np.int64),
        stamp_ns=stamps.to_numpy(),
        lat=df["latitude"].fill_null(np.nan).to_numpy(),
        lon=df["longitude"].fill_null(np.nan).to_numpy(),
        alt=df["altitude"].fill_null(np.nan).to_numpy(),
        cov=_cov9(df["position_covariance"]),
        cov_type=df["position_covariance_type"].fill_null(0).to_numpy(),
        fix_quality=np.full(len(good), -1),
        fix_valid=np.full(len(good), -1),
    )
    table, rejects = fix_table(fixes, log_time_ns, payloads, ctx)
    if bad_rows:
        log_t = np.asarray(log_time_ns, dtype=np.int64)
        more = make_rejects(
            [log_t[i] for i, _ in bad_rows], source_file=ctx.source_file, topic=ctx.topic,
            reason_code="undecodable", reason=[f"{ctx.sentence}: {w}" for _, w in bad_rows],
            raw=[payloads[i] for i, _ in bad_rows],
        )  # fmt: skip
        rejects = pa.concat_tables([rejects, more])
    return table, rejects


@dataclass
class FoxgloveJsonChannelDecoder:
    """Channel decoder (registry protocol) for JSON ``foxglove.LocationFix``."""

    ctx: FixContext

    @classmethod
    def for_channel(cls, batch: ChannelBatch, source_file: str) -> FoxgloveJsonChannelDecoder:
        return cls(FixContext(source_file, batch.topic, platform_of(batch), "LocationFix"))

    def feed(self, batch: ChannelBatch) -> Mapping[str, pa.Table]:
        table, rejects = decode_location_fix_json(batch.payloads, batch.log_time_ns, self.ctx)
        return {"nav_gnss": table, "rejects": rejects}

    def finish(self) -> Mapping[str, pa.Table]:
        return {}
