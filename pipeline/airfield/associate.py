"""Which sensor tracks are one target: track-to-track association by gated votes.

Every channel runs its own tracker (SMR and MLAT track numbers in CAT010 I010/161, the
VASN's own track ids), and MLAT tracks carry the target's 24-bit address. A *sensor
track* is a run of one sensor's track number without a gap longer than the track
timeout. Two sensor tracks of different channels vote for each other at every epoch
where both report and their positions (common frame) are within ``association_gate_m``;
a pair is admissible when it has at least ``min_association_votes`` votes and the votes
are at least half of the epochs both report (so a brief crossing of two targets does
not count). Each sensor track keeps its best admissible partner per other channel (most
votes), MLAT tracks with one address are one target, and the connected components of
these links are the targets. Vectorised with polars joins on the epoch; the components
come from ``scipy.sparse.csgraph``.

A target's ``track_id`` is its MLAT address as 6 hex digits when it has one (stable
across batch units and days), else ``<sensor_id>-<track number>`` of its first sensor
track.
"""

from __future__ import annotations

import itertools

import numpy as np
import polars as pl
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


def sensor_tracks(obs: pl.DataFrame, timeout_epochs: int) -> pl.DataFrame:
    """Add ``node`` (int): the sensor track of each row (sensor_id, track_number, run
    without a gap > ``timeout_epochs``)."""
    df = obs.sort(["sensor_id", "track_number", "epoch"])
    brk = (
        (pl.col("sensor_id") != pl.col("sensor_id").shift(1))
        | (pl.col("track_number") != pl.col("track_number").shift(1))
        | ((pl.col("epoch") - pl.col("epoch").shift(1)) > timeout_epochs)
    ).fill_null(True)
    return df.with_columns((brk.cum_sum() - 1).cast(pl.Int64).alias("node"))


def _pair_votes(df: pl.DataFrame, a: str, b: str, gate_m: float) -> pl.DataFrame:
    """Votes of sensor-a tracks for sensor-b tracks: at each epoch a report votes for the
    nearest report of the other sensor within the gate, and that report for its nearest
    (so two targets parked side by side do not vote for each other); ``common`` counts
    the epochs where both tracks report."""
    cols = ["epoch", "node", "xc_m", "yc_m"]
    left = df.filter(pl.col("sensor_id") == a).select(cols)
    right = df.filter(pl.col("sensor_id") == b).select(cols)
    j = left.join(right, on="epoch", suffix="_b").with_columns(
        ((pl.col("xc_m") - pl.col("xc_m_b")) ** 2 + (pl.col("yc_m") - pl.col("yc_m_b")) ** 2)
        .alias("d2"))
    nearest = (
        (pl.col("d2") == pl.col("d2").min().over(["epoch", "node"]))
        & (pl.col("d2") == pl.col("d2").min().over(["epoch", "node_b"]))
        & (pl.col("d2") < gate_m * gate_m)
    )
    return j.with_columns(nearest.alias("near")).group_by(["node", "node_b"]).agg(
        pl.col("near").sum().alias("votes"), pl.len().alias("common"))


def _best(votes: pl.DataFrame, key: str) -> pl.DataFrame:
    """For each value of ``key``, its partner row with the most votes."""
    return (
        votes.sort(["votes", "node", "node_b"], descending=[True, False, False])
        .group_by(key, maintain_order=True)
        .first()
    )


def associate(
    obs: pl.DataFrame, *, gate_m: float, min_votes: int, timeout_epochs: int
) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Label every report with its target.

    ``obs``: rows with epoch (int), sensor_id, sensor_kind, track_number, xc_m, yc_m,
    target_address, callsign. Returns (obs with ``node`` and ``track_id``, targets:
    one row per track_id with callsign and target_address (null without MLAT))."""
    df = sensor_tracks(obs, timeout_epochs)
    n_nodes = int(df["node"].max()) + 1 if df.height else 0
    edges = []
    for a, b in itertools.combinations(sorted(df["sensor_id"].unique().to_list()), 2):
        v = _pair_votes(df, a, b, gate_m).filter(
            (pl.col("votes") >= min_votes) & (2 * pl.col("votes") >= pl.col("common"))
        )
        if v.height:
            edges += [
                _best(v, "node").select("node", "node_b"),
                _best(v, "node_b").select("node", "node_b"),
            ]
    addr = (
        df.filter(pl.col("target_address").is_not_null())
        .group_by("node")
        .agg(pl.col("target_address").mode().first())
    )
    same = (
        addr.join(addr, on="target_address", suffix="_b")
        .filter(pl.col("node") < pl.col("node_b"))
        .select("node", "node_b")
    )
    edges.append(same)
    e = pl.concat(edges) if edges else pl.DataFrame({"node": [], "node_b": []})
    graph = coo_matrix(
        (np.ones(e.height), (e["node"].to_numpy(), e["node_b"].to_numpy())),
        shape=(n_nodes, n_nodes),
    )
    _, comp = connected_components(graph, directed=False)
    df = df.with_columns(pl.Series("component", comp[df["node"].to_numpy()], pl.Int64))
    first = (
        df.sort("epoch")
        .group_by("component", maintain_order=True)
        .agg(pl.col("sensor_id").first(), pl.col("track_number").first())
    )
    ident = (
        df.filter(pl.col("target_address").is_not_null())
        .group_by("component")
        .agg(
            pl.col("target_address").mode().first(), pl.col("callsign").drop_nulls().mode().first()
        )
    )
    targets = first.join(ident, on="component", how="left").with_columns(
        pl.when(pl.col("target_address").is_not_null())
        # one formatting call per target (tens), not per report
        .then(pl.col("target_address").map_elements(lambda a: f"{a:06X}", pl.String))
        .otherwise(pl.col("sensor_id") + "-" + pl.col("track_number").cast(pl.String))
        .alias("track_id")
    )
    labelled = df.join(targets.select("component", "track_id"), on="component")
    return labelled.drop("component"), targets.select(
        "track_id", "callsign", "target_address"
    ).sort("track_id")
