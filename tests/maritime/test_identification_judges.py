"""Identification judged by the nearest ship and by the ship a track follows
(pipeline.experiments.identification), on literal frames."""

from __future__ import annotations

import polars as pl
import pytest

from pipeline.experiments.identification import (
    first_identification_delay,
    identification_shares,
    judged_points,
    pair_outcomes,
)

T = [1_000_000_000 * k for k in range(4)]


@pytest.fixture
def points() -> pl.DataFrame:
    """Track 1 follows vessel 1 (MMSI 100; local tracks R1/11, R2/21) and is named from
    its second epoch; at its third its nearest ship is vessel 2 (no AIS) sailing beside.
    Track 2 follows vessel 2 and carries 100 at its second epoch."""
    tracks = pl.DataFrame({
        "time_ns": T + T, "system_track_id": [1] * 4 + [2] * 4, "sector": "s",
        "mmsi": [None, 100, 100, 100, None, 100, None, None]})
    errors = pl.DataFrame({
        "time_ns": T + T, "system_track_id": [1] * 4 + [2] * 4, "source": "fused",
        "reference": "truth", "reference_mmsi": [100, 100, None, 100] + [None] * 4},
        schema_overrides={"reference_mmsi": pl.Int64})
    assoc = pl.DataFrame({
        "time_ns": T + T + T, "site_id": ["R1"] * 4 + ["R2"] * 4 + ["R1"] * 4,
        "local_track_id": [11] * 4 + [21] * 4 + [12] * 4,
        "system_track_id": [1] * 8 + [2] * 4, "used": True})
    links = pl.DataFrame({"site_id": ["R1", "R2", "R1"], "track_id": [11, 21, 12],
                          "vessel_id": [1, 1, 2]})
    vessels = pl.DataFrame({"vessel_id": [1, 2], "mmsi": [100, None]},
                           schema_overrides={"mmsi": pl.Int64})
    out = {"system_tracks": tracks, "track_errors": errors, "associations": assoc}
    return judged_points(out, links, vessels)


def test_the_judges_differ_on_the_close_pair(points):
    p = points.sort("system_track_id", "time_ns")
    assert p["nearest_verdict"].to_list() == [
        "none", "correct", "wrong", "correct", "correct", "wrong", "correct", "correct"]
    assert p["followed_verdict"].to_list() == [
        "none", "correct", "correct", "correct", "correct", "wrong", "correct", "correct"]
    near = identification_shares(points, ["sector"], "nearest")
    assert near.filter(~pl.col("ais_aboard"))["wrong_share"].item() == pytest.approx(2 / 5)
    followed = identification_shares(points, ["sector"], "followed")
    assert followed.filter(~pl.col("ais_aboard"))["wrong_share"].item() == pytest.approx(1 / 4)
    assert followed.filter(pl.col("ais_aboard"))["none_share"].item() == pytest.approx(1 / 4)


def test_delay_and_pair_outcomes(points):
    delay = first_identification_delay(points, ["sector"])
    assert delay.rows(named=True) == [{"sector": "s", "tracks": 1, "never_named": 0,
                                        "median_s": 1.0, "p90_s": 1.0, "max_s": 1.0}]
    matches = pl.DataFrame({"system_track_id": [1, 1, 2], "mmsi": [100, 100, 100]})
    got = pair_outcomes(points, matches)
    assert got.select("same_ship", "confirmed", "pairs").rows() == [
        (False, True, 1), (True, True, 1)]
