"""Score fused tracks and channel reports against a reference (simulated truth, or in
real use reference vehicles with DGNSS logged on the truth channel).

Each fused track is matched to the reference target that is nearest to it at the most
epochs (within ``association_gate_m``); its rows then get the horizontal error of the
fused position and of every channel's report against that target at the same epoch,
whether the track's identity (callsign) is the target's, and whether the target was
cooperative at that moment (transponder on: the ED-87 probability of identification is
defined over cooperative targets).
"""

from __future__ import annotations

import polars as pl

from pipeline.airfield.config import AirfieldConfig
from pipeline.frames import geodetic_to_enu


def reference_frame(truth: pl.DataFrame, cfg: AirfieldConfig) -> pl.DataFrame:
    """Truth rows with ``tx_m, ty_m`` in the common frame (from lat/lon)."""
    e, n = geodetic_to_enu(
        truth["lat_deg"].to_numpy(),
        truth["lon_deg"].to_numpy(),
        cfg.reference_lat_deg,
        cfg.reference_lon_deg,
    )
    return truth.select(
        "time_ns",
        "target_id",
        pl.col("callsign").alias("truth_callsign"),
        "transponder_on",
        pl.Series("tx_m", e),
        pl.Series("ty_m", n),
    )


def match_tracks(tracks: pl.DataFrame, ref: pl.DataFrame, gate_m: float) -> pl.DataFrame:
    """track_id -> truth target_id (majority of nearest-within-gate over epochs)."""
    j = (
        tracks.select("time_ns", "track_id", "x_m", "y_m")
        .join(ref, on="time_ns")
        .with_columns(
            ((pl.col("x_m") - pl.col("tx_m")) ** 2 + (pl.col("y_m") - pl.col("ty_m")) ** 2).alias(
                "d2"
            )
        )
    )
    nearest = (
        j.filter(pl.col("d2") < gate_m * gate_m)
        .sort("d2")
        .group_by(["time_ns", "track_id"])
        .first()
    )
    return nearest.group_by("track_id").agg(
        pl.col("target_id").mode().sort().first().alias("truth_target_id")
    )


def score(
    tracks: pl.DataFrame, health: pl.DataFrame, truth: pl.DataFrame | None, cfg: AirfieldConfig
) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Add truth_target_id, error_m, identity_correct, cooperative to ``tracks`` and
    error_m to ``health`` (channel reports). Nulls when there is no reference."""
    if truth is None or truth.height == 0 or tracks.height == 0:
        return (
            tracks.with_columns(
                pl.lit(None, pl.Int64).alias("truth_target_id"),
                pl.lit(None, pl.Float64).alias("error_m"),
                pl.lit(None, pl.Boolean).alias("identity_correct"),
                pl.lit(None, pl.Boolean).alias("cooperative"),
            ),
            health.with_columns(pl.lit(None, pl.Float64).alias("error_m")),
        )
    ref = reference_frame(truth, cfg)
    match = match_tracks(tracks, ref, cfg.filter.association_gate_m)
    tr = tracks.join(match, on="track_id", how="left").join(
        ref.rename({"target_id": "truth_target_id"}), on=["time_ns", "truth_target_id"], how="left"
    )
    tr = tr.with_columns(
        ((pl.col("x_m") - pl.col("tx_m")) ** 2 + (pl.col("y_m") - pl.col("ty_m")) ** 2)
        .sqrt()
        .alias("error_m"),
        pl.when(pl.col("truth_callsign").is_not_null())
        .then(pl.col("callsign").fill_null("") == pl.col("truth_callsign"))
        .alias("identity_correct"),
        pl.col("transponder_on").alias("cooperative"),
    ).drop("tx_m", "ty_m", "truth_callsign", "transponder_on")
    h = health.join(
        tr.select("time_ns", "track_id", "truth_target_id"), on=["time_ns", "track_id"], how="left"
    ).join(
        ref.select("time_ns", pl.col("target_id").alias("truth_target_id"), "tx_m", "ty_m"),
        on=["time_ns", "truth_target_id"],
        how="left",
    )
    h = h.with_columns(
        (
            (pl.col("report_x_m") - pl.col("tx_m")) ** 2
            + (pl.col("report_y_m") - pl.col("ty_m")) ** 2
        )
        .sqrt()
        .alias("error_m")
    ).drop("tx_m", "ty_m", "truth_target_id")
    return tr, h
