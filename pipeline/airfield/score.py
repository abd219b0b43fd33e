"""Score fused tracks and channel reports against a reference: simulated truth (or in
real use reference vehicles with DGNSS logged on the truth channel), else the
reconstructed reference, the smoother of the fused filter (issue 37,
:mod:`pipeline.airfield.reference`).

Each fused track is matched to the reference target that is nearest to it at the most
epochs (within ``association_gate_m``); its rows then get the horizontal error of the
fused position and of every channel's report against that target at the same epoch,
whether the track's identity (callsign) is the target's, and whether the target was
cooperative at that moment (transponder on: the ED-87 probability of identification is
defined over cooperative targets).

Against the reconstructed reference the reference of a track is its own smoothed
trajectory (same target, same epoch); ``reference_correction_m2`` is the signed term
that makes the mean squared error against it an estimate of the true one (+ trace of
the reference covariance for the fused point and the reports the smoother used, − for
a report it did not use; 0 against truth). A report it did not use is not scored where
the reference's own 95 % error exceeds ``MAX_REFERENCE_P95_M``. Identity cannot be
judged without truth: ``identity_correct`` stays null, ``cooperative`` is "the track
has an MLAT address".
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


_REF_COLUMNS = ("reference", "reference_p95_m", "reference_correction_m2")
MAX_REFERENCE_P95_M = 5.0
"""A report the smoother did not use (excluded by the integrity check) is scored against
the reference only when the reference's own 95 % error is within this: not against the
smoothed track while the filter coasts (a target lost in a take-off roll is coasted at
its last velocity for the track timeout while its excluded reports go on). Typical
reference: 1.4 m on stands, 2.4 m moving. Points the smoother used are always scored:
the correction holds for any reference error."""


def _no_reference(tracks: pl.DataFrame, health: pl.DataFrame
                  ) -> tuple[pl.DataFrame, pl.DataFrame]:
    none = (pl.lit(None, pl.String).alias("reference"),
            pl.lit(None, pl.Float64).alias("reference_p95_m"),
            pl.lit(None, pl.Float64).alias("reference_correction_m2"))
    return (
        tracks.with_columns(
            pl.lit(None, pl.Int64).alias("truth_target_id"),
            pl.lit(None, pl.Float64).alias("error_m"),
            pl.lit(None, pl.Boolean).alias("identity_correct"),
            pl.lit(None, pl.Boolean).alias("cooperative"),
            *none,
        ),
        health.with_columns(pl.lit(None, pl.Float64).alias("error_m"), *none),
    )


def score_reconstructed(tracks: pl.DataFrame, health: pl.DataFrame, ref: pl.DataFrame
                        ) -> tuple[pl.DataFrame, pl.DataFrame]:
    """The columns of :func:`score` against the smoothed reference ``ref``
    (:func:`pipeline.airfield.reference.smooth`; module docstring)."""
    r = ref.select("time_ns", "track_id", pl.col("x_m").alias("rx"), pl.col("y_m").alias("ry"),
                   (pl.col("sigma_x_m") ** 2 + pl.col("sigma_y_m") ** 2).alias("_var"),
                   pl.col("p95_m").alias("reference_p95_m"))
    key = ["time_ns", "track_id"]
    tr = tracks.join(r, on=key, how="left").with_columns(
        pl.lit(None, pl.Int64).alias("truth_target_id"),
        ((pl.col("x_m") - pl.col("rx")) ** 2 + (pl.col("y_m") - pl.col("ry")) ** 2).sqrt()
        .alias("error_m"),
        pl.lit(None, pl.Boolean).alias("identity_correct"),
        pl.col("target_address").is_not_null().alias("cooperative")
        if "target_address" in tracks.columns else pl.lit(None, pl.Boolean).alias("cooperative"),
        pl.when(pl.col("rx").is_not_null()).then(pl.lit("reconstructed")).alias("reference"),
        pl.col("_var").alias("reference_correction_m2"),
    ).drop("rx", "ry", "_var")
    # a report the smoother did not use is judged by an independent reference: not by a
    # poor one (the smoothed track while the filter coasts)
    poor = ~pl.col("used") & (pl.col("reference_p95_m") > MAX_REFERENCE_P95_M)
    h = health.join(r, on=key, how="left").with_columns(
        pl.when(poor).then(None).otherwise(pl.col("rx")).alias("rx")).with_columns(
        ((pl.col("report_x_m") - pl.col("rx")) ** 2 + (pl.col("report_y_m") - pl.col("ry")) ** 2)
        .sqrt().alias("error_m"),
        pl.when(pl.col("rx").is_not_null()).then(pl.lit("reconstructed")).alias("reference"),
        pl.when(pl.col("used")).then(pl.col("_var")).otherwise(-pl.col("_var"))
        .alias("reference_correction_m2"),
    ).drop("rx", "ry", "_var")
    return tr, h


def score(
    tracks: pl.DataFrame, health: pl.DataFrame, truth: pl.DataFrame | None, cfg: AirfieldConfig,
    reference: pl.DataFrame | None = None,
) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Add truth_target_id, error_m, identity_correct, cooperative and the reference
    columns (reference, reference_p95_m, reference_correction_m2) to ``tracks`` and
    error_m with the reference columns to ``health`` (channel reports): against truth,
    else against the reconstructed ``reference``; nulls when there is neither."""
    if tracks.height and (truth is None or truth.height == 0) and reference is not None \
            and reference.height:
        return score_reconstructed(tracks, health, reference)
    if truth is None or truth.height == 0 or tracks.height == 0:
        return _no_reference(tracks, health)
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
        pl.when(pl.col("tx_m").is_not_null()).then(pl.lit("truth")).alias("reference"),
        pl.lit(0.0).alias("reference_p95_m"),
        pl.lit(0.0).alias("reference_correction_m2"),
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
        .alias("error_m"),
        pl.when(pl.col("tx_m").is_not_null()).then(pl.lit("truth")).alias("reference"),
        pl.lit(0.0).alias("reference_p95_m"),
        pl.lit(0.0).alias("reference_correction_m2"),
    ).drop("tx_m", "ty_m", "truth_target_id")
    return tr, h
