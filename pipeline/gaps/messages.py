"""Message vectors (distributed maritime observation paper, eq. 1-2) from AIS reports and
identified system tracks, gap detection, the forecasts to make and each gap's lead-in."""

from __future__ import annotations

import math

import numpy as np
import polars as pl

from pipeline import frames
from pipeline.config import AisConfig, RegionConfig
from pipeline.gaps.config import GapsConfig
from pipeline.units import NS

# --- messages (eq. 1) ---

OBS_SCHEMA: dict[str, pl.DataType] = {
    "time_ns": pl.Int64(),
    "mmsi": pl.Int64(),
    "source": pl.String(),
    "object_class": pl.String(),
    "lat_deg": pl.Float64(),
    "lon_deg": pl.Float64(),
    "x_enu_m": pl.Float64(),
    "y_enu_m": pl.Float64(),
    "P_xx": pl.Float64(),
    "P_yy": pl.Float64(),
    "P_xy": pl.Float64(),
    "sog_mps": pl.Float64(),
    "sigma_sog_mps": pl.Float64(),
    "cog_rad": pl.Float64(),
    "sigma_cog_rad": pl.Float64(),
}


def observations(
    ais_reports: pl.DataFrame,
    system_tracks: pl.DataFrame | None,
    *,
    ais: AisConfig,
    gaps: GapsConfig,
    region: RegionConfig,
) -> pl.DataFrame:
    """The message vectors (eq. 1) of every identified vessel, sorted by (mmsi, time).

    Columns: ``OBS_SCHEMA`` (position covariance ``P_xx, P_yy, P_xy`` in m^2, eq. 2;
    SOG/COG null when not available) plus the flags ``flag_new`` (first message, or
    first after a gap), ``flag_lost`` (last message before a gap or the data's end)
    and ``flag_manoeuvre`` (|dCOG/dt| from the previous message above
    ``manoeuvre_rate_rad_per_s``) and ``next_time_ns`` (the vessel's next message).
    """
    parts = [_ais_messages(ais_reports, ais, gaps, region)]
    if system_tracks is not None and system_tracks.height:
        parts.append(_track_messages(system_tracks))
    obs = pl.concat(parts).sort(["mmsi", "time_ns", "source"])
    return _flags(obs, gaps)


def gap_messages(
    ais_reports: pl.DataFrame,
    system_tracks: pl.DataFrame | None,
    *,
    ais: AisConfig,
    gaps: GapsConfig,
    region: RegionConfig,
    data_end_ns: int,
) -> pl.DataFrame:
    """The rows of :func:`observations` that the gaps ending by ``data_end_ns`` need:
    each gap's start message, the messages within ``lead_in_s`` before it and the message
    that ends it, with ``next_time_ns`` and the flags computed over every message.

    :func:`detect_gaps`, :func:`lead_in` and the gap-end references give the same rows on
    these as on all of them. The flags and gaps are found on four key columns first, and
    only the rows kept become message vectors: a dense region hour reads ~4 M messages
    over its lookback and horizon, of which a few per cent are near a gap.
    """
    parts = [_keys(ais_reports, 0, "cog_rad")]
    tracks = system_tracks is not None and system_tracks.height > 0
    if tracks:  # rows of the identified tracks, numbered in the whole frame
        parts.append(_keys(system_tracks, 1, "course_rad").filter(pl.col("mmsi").is_not_null()))
    keys = pl.concat(parts).sort(["mmsi", "time_ns", "src", "row"])
    keys = _flags(keys, gaps)
    thr, lead_ns = int(gaps.gap_threshold_s * NS), int(gaps.lead_in_s * NS)
    silence_end = pl.coalesce(pl.col("next_time_ns"), pl.lit(int(data_end_ns)))
    starts = (silence_end - pl.col("time_ns")) > thr
    # a gap's start is the last message at its time: the rows before it in (mmsi, time)
    # order are those lead_in's as-of join maps to it
    next_start = pl.when(starts).then(pl.col("time_ns")).backward_fill()
    next_start_mmsi = pl.when(starts).then(pl.col("mmsi")).backward_fill()
    keep = keys.filter(
        (next_start_mmsi == pl.col("mmsi"))
        & (next_start - pl.col("time_ns") <= lead_ns)  # a lead-in, the start itself
        | starts.shift(1) & (pl.col("mmsi") == pl.col("mmsi").shift(1))  # a gap's end
    ).select("src", "row", "next_time_ns", "flag_new", "flag_manoeuvre")
    rows = [keep.filter(pl.col("src") == s)["row"] for s in (0, 1)]
    full = [_ais_messages(ais_reports[rows[0]], ais, gaps, region).with_columns(
        pl.lit(0, pl.UInt8).alias("src"), rows[0])]
    if tracks:
        full.append(_track_messages(system_tracks[rows[1]]).with_columns(
            pl.lit(1, pl.UInt8).alias("src"), rows[1]))
    return (
        pl.concat(full).join(keep, on=["src", "row"])
        .sort(["mmsi", "time_ns", "src", "row"])
        .drop("src", "row")
    )


def _keys(frame: pl.DataFrame, src: int, cog: str) -> pl.DataFrame:
    """(time_ns, mmsi, src, row, cog_rad): what the flags and the gaps are found on."""
    return frame.select(
        pl.col("time_ns").cast(pl.Int64),
        pl.col("mmsi").cast(pl.Int64),
        pl.lit(src, pl.UInt8).alias("src"),
        pl.int_range(pl.len(), dtype=pl.UInt32).alias("row"),
        pl.col(cog).cast(pl.Float64).alias("cog_rad"),
    )


def _ais_messages(
    ais_reports: pl.DataFrame, ais: AisConfig, gaps: GapsConfig, region: RegionConfig
) -> pl.DataFrame:
    if ais_reports.height == 0:
        return pl.DataFrame(schema=OBS_SCHEMA)
    x, y = frames.geodetic_to_enu(
        ais_reports["lat_deg"].to_numpy(),
        ais_reports["lon_deg"].to_numpy(),
        region.origin_lat_deg,
        region.origin_lon_deg,
    )
    var = ais.sigma_position_m**2
    return ais_reports.select(
        pl.col("time_ns"),
        pl.col("mmsi"),
        pl.lit("ais").alias("source"),
        pl.col("ais_class").alias("object_class"),
        pl.col("lat_deg"),
        pl.col("lon_deg"),
        pl.Series("x_enu_m", np.atleast_1d(x)),
        pl.Series("y_enu_m", np.atleast_1d(y)),
        pl.lit(var).alias("P_xx"),
        pl.lit(var).alias("P_yy"),
        pl.lit(0.0).alias("P_xy"),
        pl.col("sog_mps"),
        pl.lit(ais.sigma_sog_mps).alias("sigma_sog_mps"),
        pl.col("cog_rad"),
        pl.lit(gaps.sigma_cog_rad).alias("sigma_cog_rad"),
    ).cast(OBS_SCHEMA)  # type: ignore[arg-type]


def _track_messages(tracks: pl.DataFrame) -> pl.DataFrame:
    return (
        tracks.filter(pl.col("mmsi").is_not_null())
        .select(
            pl.col("time_ns"),
            pl.col("mmsi"),
            pl.lit("system_track").alias("source"),
            pl.lit("radar").alias("object_class"),
            pl.col("lat_deg"),
            pl.col("lon_deg"),
            pl.col("x_enu_m"),
            pl.col("y_enu_m"),
            (pl.col("sigma_x_m") ** 2).alias("P_xx"),
            (pl.col("sigma_y_m") ** 2).alias("P_yy"),
            pl.col("cov_xy_m2").alias("P_xy"),
            pl.col("speed_mps").alias("sog_mps"),
            pl.col("sigma_speed_mps").alias("sigma_sog_mps"),
            pl.col("course_rad").alias("cog_rad"),
            pl.col("sigma_course_rad").alias("sigma_cog_rad"),
        )
        .cast(OBS_SCHEMA)
    )  # type: ignore[arg-type]


def _flags(obs: pl.DataFrame, gaps: GapsConfig) -> pl.DataFrame:
    """``obs`` sorted by (mmsi, time): a row's neighbours are the vessel's previous and
    next messages when their MMSI is the same (shifts, not per-vessel windows: ~4 M rows
    in a dense unit)."""
    thr = int(gaps.gap_threshold_s * NS)
    same_prev = pl.col("mmsi") == pl.col("mmsi").shift(1)
    prev_t = pl.when(same_prev).then(pl.col("time_ns").shift(1))
    dt_prev_s = (pl.col("time_ns") - prev_t) / NS
    dcog = (pl.col("cog_rad") - pl.col("cog_rad").shift(1) + math.pi) % (2 * math.pi) - math.pi
    return obs.with_columns(
        pl.when(pl.col("mmsi") == pl.col("mmsi").shift(-1))
        .then(pl.col("time_ns").shift(-1))
        .alias("next_time_ns"),
        (prev_t.is_null() | ((pl.col("time_ns") - prev_t) > thr)).alias("flag_new"),
        pl.when(dt_prev_s > 0)
        .then(dcog.abs() / dt_prev_s > gaps.manoeuvre_rate_rad_per_s)
        .otherwise(False)
        .fill_null(False)
        .alias("flag_manoeuvre"),
    )


# --- gaps ------------------------------------------------------------------------


def detect_gaps(obs: pl.DataFrame, *, threshold_s: float, data_end_ns: int) -> pl.DataFrame:
    """One row per gap: a vessel's message followed by more than ``threshold_s`` of
    silence (until its next message, or until ``data_end_ns`` when there is none).

    Columns: mmsi, gap_start_ns (time of the last message), gap_end_ns (the next
    message, null when open), gap_open, source/object_class of the last message,
    manoeuvre_at_gap_start (its manoeuvre flag). Sorted by (mmsi, gap_start_ns).
    """
    thr = int(threshold_s * NS)
    silence_end = pl.coalesce(pl.col("next_time_ns"), pl.lit(int(data_end_ns)))
    return (
        obs.filter((silence_end - pl.col("time_ns")) > thr)
        .select(
            pl.col("mmsi"),
            pl.col("time_ns").alias("gap_start_ns"),
            pl.col("next_time_ns").alias("gap_end_ns"),
            pl.col("next_time_ns").is_null().alias("gap_open"),
            pl.col("source").alias("last_source"),
            pl.col("object_class"),
            pl.col("flag_manoeuvre").alias("manoeuvre_at_gap_start"),
        )
        .sort(["mmsi", "gap_start_ns"])
    )


def mark_lost(obs: pl.DataFrame, gaps: pl.DataFrame) -> pl.DataFrame:
    """Add ``flag_lost`` to the messages: true on the last message before each gap."""
    lost = gaps.select(
        pl.col("mmsi"), pl.col("gap_start_ns").alias("time_ns"), pl.lit(True).alias("flag_lost")
    ).unique(["mmsi", "time_ns"])
    return obs.join(lost, on=["mmsi", "time_ns"], how="left").with_columns(
        pl.col("flag_lost").fill_null(False)
    )


def plan_forecasts(
    gaps: pl.DataFrame, g: GapsConfig, *, start_ns: int, end_ns: int
) -> pl.DataFrame:
    """The forecasts to make in [start_ns, end_ns): one row per (gap, forecast time).

    Lead times: each configured offset (strictly inside a closed gap, any offset for an
    open one) and, when ``forecast_at_gap_end``, the reappearance time of a gap not
    longer than ``max_horizon_s``. Columns: gap_id (row of ``gaps``), mmsi,
    gap_start_ns, forecast_time_ns, lead_ns, forecast_kind (offset | gap_end).
    """
    gaps = gaps.with_row_index("gap_id")
    offsets_ns = pl.Series("lead_ns", [int(o * NS) for o in g.forecast_offsets_s], pl.Int64)
    by_offset = (
        gaps.join(pl.DataFrame(offsets_ns), how="cross")
        .filter(
            pl.col("gap_open") | (pl.col("lead_ns") < pl.col("gap_end_ns") - pl.col("gap_start_ns"))
        )
        .with_columns(pl.lit("offset").alias("forecast_kind"))
    )
    parts = [by_offset]
    if g.forecast_at_gap_end:
        ends = (
            gaps.filter(~pl.col("gap_open"))
            .with_columns(
                (pl.col("gap_end_ns") - pl.col("gap_start_ns")).alias("lead_ns"),
                pl.lit("gap_end").alias("forecast_kind"),
            )
            .filter(pl.col("lead_ns") <= int(g.max_horizon_s * NS))
        )
        parts.append(ends)
    cols = ["gap_id", "mmsi", "gap_start_ns", "lead_ns", "forecast_kind"]
    return (
        pl.concat([p.select(cols) for p in parts])
        .with_columns((pl.col("gap_start_ns") + pl.col("lead_ns")).alias("forecast_time_ns"))
        .filter(pl.col("forecast_time_ns").is_between(start_ns, end_ns, closed="left"))
        .sort(["gap_id", "lead_ns"])
    )


def lead_in(obs: pl.DataFrame, gaps: pl.DataFrame, g: GapsConfig) -> pl.DataFrame:
    """Each gap's last messages before it: those within ``lead_in_s`` of the gap start,
    thinned to at most ``max_lead_in_obs`` (the last one of each lead_in_s / K slice),
    with ``slot`` = K-1 for the gap-start message, K-2 for the one before, ..."""
    K = g.max_lead_in_obs
    slice_ns = max(int(g.lead_in_s * NS / K), 1)
    starts = (
        gaps.with_row_index("gap_id").select("gap_id", "mmsi", "gap_start_ns").sort("gap_start_ns")
    )
    return (
        obs.sort("time_ns")
        .join_asof(
            starts,
            left_on="time_ns",
            right_on="gap_start_ns",
            by="mmsi",
            strategy="forward",
            check_sortedness=False,
        )
        .filter(
            pl.col("gap_id").is_not_null()
            & (pl.col("gap_start_ns") - pl.col("time_ns") <= int(g.lead_in_s * NS))
        )
        .with_columns(((pl.col("gap_start_ns") - pl.col("time_ns")) // slice_ns).alias("_slice"))
        .sort(["gap_id", "time_ns"])
        .group_by(["gap_id", "_slice"], maintain_order=True)
        .last()
        .with_columns(
            (K - pl.col("_slice").rank("ordinal").over("gap_id").cast(pl.Int64)).alias("slot")
        )
        .filter(pl.col("slot") >= 0)
        .drop("_slice")
    )


