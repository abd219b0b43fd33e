"""Identification against the simulator's truth, two ways (issue 38, item 3).

A fused point's ship is judged

- **nearest**: the truth vessel nearest to the fused point at the epoch (``track_errors``
  reference, what ``sql/identification_by_sector.sql`` judges by); two ships closer
  than the track's error make it flip between them from epoch to epoch;
- **followed**: the vessel the point's radar member tracks follow (the simulator's
  ``radar_track_truth``; the majority of the members, the smaller vessel id on a tie):
  the ship an operator would say the track is.

A point is *correct* when it carries that ship's MMSI (a ship without AIS: no MMSI),
*wrong* when it carries another, *none* when a ship with AIS carries none. Shares of
points are shares of track time (fused points come at uniform epochs).
"""

from __future__ import annotations

import polars as pl

from pipeline.units import NS


def followed_vessel(associations: pl.DataFrame, radar_track_truth: pl.DataFrame
                    ) -> pl.DataFrame:
    """(time_ns, system_track_id, followed_vessel_id) of every fused point with a member
    whose local track follows a vessel."""
    links = radar_track_truth.select(pl.col("site_id"), pl.col("track_id").alias(
        "local_track_id"), pl.col("vessel_id").cast(pl.Int64))
    return (
        associations.filter(pl.col("used")) if "used" in associations.columns
        else associations
    ).select("time_ns", "site_id", "local_track_id", "system_track_id").join(
        links, on=["site_id", "local_track_id"]).group_by(
        "time_ns", "system_track_id", "vessel_id").len().sort(
        "len", "vessel_id", descending=[True, False]).unique(
        ["time_ns", "system_track_id"], keep="first").select(
        "time_ns", "system_track_id", pl.col("vessel_id").alias("followed_vessel_id"))


def judged_points(out: dict[str, pl.DataFrame], radar_track_truth: pl.DataFrame,
                  vessels: pl.DataFrame) -> pl.DataFrame:
    """Fused points of the maritime stage's ``out`` scored against truth, with the
    verdict of each judge (``nearest_verdict``, ``followed_verdict``) and the AIS
    carriage of each judged ship (``nearest_ais``, ``followed_ais``)."""
    mmsi_of = vessels.select(pl.col("vessel_id").cast(pl.Int64), pl.col("mmsi").cast(pl.Int64))
    errors = out["track_errors"].filter((pl.col("source") == "fused")
                                        & (pl.col("reference") == "truth"))
    points = out["system_tracks"].select(
        "time_ns", "system_track_id", pl.col("sector").fill_null("(outside sectors)"), "mmsi"
    ).join(errors.select("time_ns", "system_track_id", pl.col("reference_mmsi").alias(
        "nearest_mmsi")), on=["time_ns", "system_track_id"])
    followed = followed_vessel(out["associations"], radar_track_truth).join(
        mmsi_of.rename({"vessel_id": "followed_vessel_id", "mmsi": "followed_mmsi"}),
        on="followed_vessel_id", how="left")
    points = points.join(followed, on=["time_ns", "system_track_id"], how="left")
    return points.with_columns(
        nearest_ais=pl.col("nearest_mmsi").is_not_null(),
        nearest_verdict=_verdict("nearest_mmsi"),
        followed_ais=pl.col("followed_mmsi").is_not_null(),
        followed_verdict=pl.when(pl.col("followed_vessel_id").is_null()).then(None)
        .otherwise(_verdict("followed_mmsi")),
    )


def _verdict(truth_mmsi: str) -> pl.Expr:
    t, m = pl.col(truth_mmsi), pl.col("mmsi")
    return (pl.when(t.is_null()).then(pl.when(m.is_null()).then(pl.lit("correct"))
                                      .otherwise(pl.lit("wrong")))
            .when(m.is_null()).then(pl.lit("none"))
            .when(m == t).then(pl.lit("correct")).otherwise(pl.lit("wrong")))


def identification_shares(points: pl.DataFrame, by: list[str], judge: str) -> pl.DataFrame:
    """Per ``by`` and AIS carriage of the judged ship (``judge``: nearest | followed):
    samples, correct / wrong / none shares."""
    v = pl.col(f"{judge}_verdict")
    return points.filter(v.is_not_null()).group_by(*by, pl.col(f"{judge}_ais").alias(
        "ais_aboard")).agg(
        pl.len().alias("samples"), (v == "correct").mean().alias("correct_share"),
        (v == "wrong").mean().alias("wrong_share"), (v == "none").mean().alias("none_share"),
    ).sort(*by, "ais_aboard")


def first_identification_delay(points: pl.DataFrame, by: list[str]) -> pl.DataFrame:
    """Time to the first identification, per ``by`` (the sector of a track's first
    point): for every system track following a ship with AIS (judge: followed), the
    time from its first point following that ship to its first point carrying that
    ship's MMSI (tracks never named: counted apart). Median, p90 and max in s."""
    p = points.filter(pl.col("followed_ais")).sort("time_ns")
    per = p.group_by("system_track_id", "followed_mmsi").agg(
        pl.col(by).first(), pl.col("time_ns").first().alias("t0"),
        pl.col("time_ns").filter(pl.col("mmsi") == pl.col("followed_mmsi")).first().alias("t1"))
    per = per.with_columns(((pl.col("t1") - pl.col("t0")) / NS).alias("delay_s"))
    return per.group_by(by).agg(
        pl.len().alias("tracks"), pl.col("delay_s").is_null().sum().alias("never_named"),
        pl.col("delay_s").median().alias("median_s"),
        pl.col("delay_s").quantile(0.9, "nearest").alias("p90_s"),
        pl.col("delay_s").max().alias("max_s"),
    ).sort(by)


def pair_outcomes(points: pl.DataFrame, identifications: pl.DataFrame) -> pl.DataFrame:
    """The sequential test's outcomes per candidate pair (a system track and an MMSI that
    matched it at least once): ``same_ship`` when the MMSI is that of the ship the track
    follows in most of its points, ``confirmed`` when the track ever carried it. Counts
    per (same_ship, confirmed): the empirical rates to set beside the test's alpha
    (a pair of two ships confirmed) and beta (a ship's own pair never confirmed)."""
    followed = points.filter(pl.col("followed_mmsi").is_not_null()).group_by(
        "system_track_id", "followed_mmsi").len().sort("len", descending=True).unique(
        "system_track_id", keep="first").select("system_track_id", "followed_mmsi")
    carried = points.filter(pl.col("mmsi").is_not_null()).select(
        "system_track_id", "mmsi").unique().with_columns(confirmed=pl.lit(True))
    pairs = identifications.group_by("system_track_id", "mmsi").agg(
        pl.len().alias("matches"))
    return pairs.join(followed, on="system_track_id", how="left").join(
        carried, on=["system_track_id", "mmsi"], how="left").with_columns(
        same_ship=(pl.col("mmsi") == pl.col("followed_mmsi")).fill_null(False),
        confirmed=pl.col("confirmed").fill_null(False)).group_by(
        "same_ship", "confirmed").agg(pl.len().alias("pairs"),
                                      pl.col("matches").sum()).sort("same_ship", "confirmed")
