"""SIAP measures of the fused picture against simulated truth, per sector.

Definitions follow the SIAP Systems Engineering Task Force measures (Votruba et al.,
"Single Integrated Air Picture (SIAP) Metrics Implementation", 2001) as implemented by
Stone Soup's ``SIAPMetrics`` / ``IDSIAPMetrics`` (stonesoup/metricgenerator/
tracktotruthmetrics.py), with sums over the synchronised epochs t (uniform, so sums
of epochs are time):

=============================  ==============================  ============
completeness C                 sum JT / sum J                  target 1
ambiguity A                    sum NA / sum JT                 target 1
spuriousness S                 sum (N - NA) / sum N            target 0
position accuracy PA           sum |p_track - p_truth| / sum NA (m)
velocity accuracy VA           sum |v_track - v_truth| / sum NA (m/s)
rate of track number change R  changes / sum TT (per hour here; Stone Soup per s)
longest track segment LS       sum_j TL_j / sum_j T_j
ID completeness / correctness  sum (JT - JU) / sum JT, sum JC / sum JT, sum JA / sum JT
/ ambiguity                    (over truths carrying AIS; ID = MMSI)
=============================  ==============================  ============

J(t) truths present, JT(t) truths with at least one associated track, N(t) system
tracks, NA(t) associated tracks; JU / JC / JI: truths whose tracks all carry no MMSI /
the truth's MMSI / another MMSI, JA = JT - JU - JC - JI (mixed).

Track-to-truth association (per epoch): a system track is associated with the truth
nearest to it in Mahalanobis distance with the track's own position covariance, if
d^2 < chi2.ppf(gate_probability, 2) and the distance is <= max_distance_m; a track
keeps the truth it had at its previous epoch while that truth still passes the gate
(hysteresis, like Stone Soup's TrackToTruth, which holds an association until it
fails). Several tracks may hold one truth (ambiguity). Each tracked truth has a
*primary* track: the one it had before while still associated, else the nearest.

Continuity:

- a *track number change* is a change of a truth's primary track id (between its
  consecutive tracked epochs, across gaps too); Stone Soup counts NU_j - 1, the number
  of association intervals needed to cover the truth minus one, which also counts an
  association that breaks and resumes with the SAME track. We count only real changes
  of track number (a short loss that keeps the id is continuity, not a change);
- a *swap* is a pair of changes that exchange two tracks between two truths (truth a:
  p -> q and truth b: q -> p within ``swap_window_s``): two close ships whose tracks
  crossed over;
- TT_j = tracked epochs x epoch period; T_j = present epochs x epoch period (Stone
  Soup uses last - first timestamp, one period less); TL_j = longest span (first to
  last epoch, inclusive) during which the truth's primary track keeps one id, x
  period: untracked epochs inside the span do not break it when the same id resumes
  (Stone Soup's association also survives short misses, ``consec_misses_end``).

Per sector: truth quantities (J, JT, NA, PA, VA, TT, T, TL, changes, swaps, ID) go to
the sector of the truth at that epoch, track quantities (N, N - NA) to the sector of the
track. Rows keep the sums, so that windows and sectors aggregate exactly (the report
divides sums); the measures of one row are also given. Continuity is measured inside
one batch work unit (a change exactly at a unit seam is not seen).

Truth velocity is the truth's speed and true course (the meridian convergence between
the vessel and the region origin, < 0.1 deg here, is neglected).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import pairwise

import numpy as np
import polars as pl

from pipeline.config import RegionConfig, Sector
from pipeline.frames import enu_to_geodetic
from pipeline.geometry import assign_sectors, position_covariance
from pipeline.maritime.associate import gate_threshold
from pipeline.maritime.config import SiapConfig
from pipeline.maritime.reference import Reference
from pipeline.maritime.score import TruthPairing, truth_at_epochs
from pipeline.spatial import pairs_within
from pipeline.units import NS

SUM_COLUMNS = (
    "truths",
    "truth_epochs",
    "tracked_truth_epochs",
    "track_epochs",
    "associated_track_epochs",
    "spurious_track_epochs",
    "sum_position_error_m",
    "sum_velocity_error_mps",
    "track_number_changes",
    "track_swaps",
    "tracked_time_s",
    "truth_time_s",
    "longest_segment_s",
    "id_truth_epochs",
    "id_unknown_epochs",
    "id_correct_epochs",
    "id_incorrect_epochs",
    "id_ambiguous_epochs",
)
MEASURE_COLUMNS = (
    "completeness",
    "ambiguity",
    "spuriousness",
    "position_accuracy_m",
    "velocity_accuracy_mps",
    "track_number_changes_per_h",
    "longest_segment",
    "id_completeness",
    "id_correctness",
    "id_ambiguity",
)
SIAP_COLUMNS = (
    "time_ns",
    "end_time_ns",
    "sector",
    "reference",
    "epoch_period_s",
    *SUM_COLUMNS,
    *MEASURE_COLUMNS,
)


# --- inputs ------------------------------------------------------------------------------


def truth_states(truth: pl.DataFrame, epochs_ns: np.ndarray, region: RegionConfig) -> pl.DataFrame:
    """Truth at each epoch inside each vessel's sampled span: time_ns, vessel_id, mmsi,
    ref_x_m, ref_y_m (interpolated, regional ENU) and ref_vx_mps, ref_vy_mps (speed
    and course of the nearest earlier truth sample)."""
    return _with_velocity(truth_at_epochs(truth, epochs_ns, region).sort("time_ns"), truth)


def _with_velocity(at: pl.DataFrame, truth: pl.DataFrame) -> pl.DataFrame:
    """Truth states ``at`` (sorted by time) with ref_vx_mps, ref_vy_mps from the speed
    and course of each vessel's nearest earlier truth sample."""
    vel = truth.select(
        "time_ns",
        pl.col("vessel_id").cast(pl.Int64),
        (pl.col("speed_mps") * pl.col("course_rad").sin()).alias("ref_vx_mps"),
        (pl.col("speed_mps") * pl.col("course_rad").cos()).alias("ref_vy_mps"),
    ).sort("time_ns")
    return at.join_asof(
        vel, on="time_ns", by="vessel_id", strategy="backward", check_sortedness=False
    )


def _paired(pairing: TruthPairing, truth: pl.DataFrame, tracks: pl.DataFrame,
            epochs_ns: np.ndarray, cfg: SiapConfig
            ) -> tuple[pl.DataFrame, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """:func:`truth_states` and the (track row, truth row, distance) pairs within
    max_distance_m from the shared ``pairing``: its sampled truth rows (none prolonged
    past a vessel's last sample), the truth rows renumbered to those kept."""
    if pairing.points.height != tracks.height or pairing.near_m < cfg.max_distance_m:
        raise ValueError("siap_by_sector: the pairing is of other tracks or a shorter reach")
    at = pairing.truths
    kept = (at["sampled"] & at["time_ns"].is_in(np.asarray(epochs_ns, np.int64))).to_numpy()
    row = np.cumsum(kept) - 1
    ok = kept[pairing.j]
    truths = _with_velocity(
        at.filter(pl.Series(kept)).drop("ref_vx_mps", "ref_vy_mps", "sampled"), truth)
    return truths, (pairing.i[ok], row[pairing.j[ok]], pairing.dist_m[ok])


def reference_as_truth(reference: Reference, epochs_ns: np.ndarray, region: RegionConfig
                       ) -> pl.DataFrame:
    """A reconstructed reference sampled at the epochs in the truth table's columns
    (time_ns, vessel_id = the target id, mmsi, lat_deg, lon_deg, course_rad, speed_mps),
    so that the SIAP measures run on real data."""
    at = reference.at_epochs(epochs_ns)
    lat, lon = enu_to_geodetic(at["x"].to_numpy(), at["y"].to_numpy(), region.origin_lat_deg,
                               region.origin_lon_deg)
    vx, vy = at["vx"].to_numpy(), at["vy"].to_numpy()
    return pl.DataFrame({
        "time_ns": at["time_ns"], "vessel_id": at["target"],
        "mmsi": at["mmsi"].set(at["mmsi"] < 0, None), "lat_deg": np.atleast_1d(lat),
        "lon_deg": np.atleast_1d(lon), "course_rad": np.arctan2(vx, vy) % (2.0 * np.pi),
        "speed_mps": np.hypot(vx, vy),
    }).unique(["vessel_id", "time_ns"], keep="first").sort("time_ns", "vessel_id")


def _tracks(system_tracks: pl.DataFrame) -> pl.DataFrame:
    P_xx, P_yy, P_xy = position_covariance(system_tracks)
    cols = ["time_ns", "system_track_id", "x_enu_m", "y_enu_m"]
    return system_tracks.select(
        *cols,
        pl.Series("P_xx", P_xx),
        pl.Series("P_yy", P_yy),
        pl.Series("P_xy", P_xy),
        (pl.col("speed_mps") * pl.col("course_rad").sin()).alias("vx_mps"),
        (pl.col("speed_mps") * pl.col("course_rad").cos()).alias("vy_mps"),
        pl.col("mmsi") if "mmsi" in system_tracks.columns else pl.lit(None, pl.Int64).alias("mmsi"),
        pl.col("sector")
        if "sector" in system_tracks.columns
        else pl.lit(None, pl.String).alias("sector"),
    )


# --- association ---------------------------------------------------------------------------


def candidate_pairs(tracks: pl.DataFrame, truths: pl.DataFrame, cfg: SiapConfig) -> pl.DataFrame:
    """Track-truth pairs of the same epoch within the gate: time_ns, system_track_id,
    vessel_id, d2 (Mahalanobis, track covariance), dist_m, and the rows of the track and
    of the truth (``_i``, ``_j``: positions in ``tracks`` and ``truths``, which the sums
    use instead of joins). A grid join (``pipeline.spatial``) of the points within
    max_distance_m; the same pairs, values and order as :func:`candidate_pairs_reference`."""
    cell = cfg.max_distance_m
    tt, rt = tracks["time_ns"].to_numpy(), truths["time_ns"].to_numpy()
    epochs = np.unique(tt)
    ok = np.isin(rt, epochs)
    jr = np.flatnonzero(ok)
    tx, ty = tracks["x_enu_m"].to_numpy(), tracks["y_enu_m"].to_numpy()
    rx, ry = truths["ref_x_m"].to_numpy(), truths["ref_y_m"].to_numpy()
    reach = cell * (1 + 1e-9) + 1e-6
    i, j, d2 = pairs_within(np.searchsorted(epochs, tt), tx, ty, reach,
                            np.searchsorted(epochs, rt[jr]), rx[jr], ry[jr], cell_m=reach)
    return gated_pairs(tracks, truths, i, jr[j], np.sqrt(d2), cfg)


def gated_pairs(tracks: pl.DataFrame, truths: pl.DataFrame, i: np.ndarray, j: np.ndarray,
                dist: np.ndarray, cfg: SiapConfig) -> pl.DataFrame:
    """:func:`candidate_pairs` from the pairs (``i``: row of ``tracks``, ``j``: row of
    ``truths``, of one epoch, sorted by (i, j)) within a reach of at least
    max_distance_m, ``dist``: their distances: those within max_distance_m and the gate."""
    gate = gate_threshold(cfg.gate_probability)
    tx, ty = tracks["x_enu_m"].to_numpy(), tracks["y_enu_m"].to_numpy()
    rx, ry = truths["ref_x_m"].to_numpy(), truths["ref_y_m"].to_numpy()
    pxx, pyy, pxy = (tracks[c].to_numpy()[i] for c in ("P_xx", "P_yy", "P_xy"))
    dx, dy = tx[i] - rx[j], ty[i] - ry[j]
    det = pxx * pyy - pxy**2
    d2 = (pyy * dx * dx - 2.0 * pxy * dx * dy + pxx * dy * dy) / det
    keep = (d2 < gate) & (dist <= cfg.max_distance_m)
    i, j, d2, dist = i[keep], j[keep], d2[keep], dist[keep]
    vessel = truths["vessel_id"].to_numpy()[j]
    order = np.lexsort((vessel, i))  # tracks sorted by (time, track): (time, track, vessel)
    i, j = i[order], j[order]
    return pl.DataFrame({
        "time_ns": tracks["time_ns"].to_numpy()[i],
        "system_track_id": tracks["system_track_id"].to_numpy()[i],
        "vessel_id": vessel[order],
        "d2": d2[order],
        "dist_m": dist[order],
        "_i": i,
        "_j": j,
    }, schema_overrides={"time_ns": pl.Int64, "system_track_id": pl.Int64,
                         "vessel_id": pl.Int64})


def candidate_pairs_reference(
    tracks: pl.DataFrame, truths: pl.DataFrame, cfg: SiapConfig
) -> pl.DataFrame:
    """:func:`candidate_pairs` as a polars grid-cell join (the 3 x 3 cells of size
    max_distance_m around a track hold every truth within that distance): the reference
    (without the ``_i``/``_j`` positions)."""
    cell = cfg.max_distance_m
    gate = gate_threshold(cfg.gate_probability)
    shifts = pl.DataFrame({"sx": np.repeat([-1, 0, 1], 3), "sy": np.tile([-1, 0, 1], 3)})
    tr = (
        truths.select(
            "time_ns",
            "vessel_id",
            "ref_x_m",
            "ref_y_m",
            (pl.col("ref_x_m") / cell).floor().cast(pl.Int64).alias("cx"),
            (pl.col("ref_y_m") / cell).floor().cast(pl.Int64).alias("cy"),
        )
        .join(shifts, how="cross")
        .with_columns(pl.col("cx") + pl.col("sx"), pl.col("cy") + pl.col("sy"))
    )
    tk = tracks.select(
        "time_ns",
        "system_track_id",
        "x_enu_m",
        "y_enu_m",
        "P_xx",
        "P_yy",
        "P_xy",
        (pl.col("x_enu_m") / cell).floor().cast(pl.Int64).alias("cx"),
        (pl.col("y_enu_m") / cell).floor().cast(pl.Int64).alias("cy"),
    )
    dx, dy = pl.col("x_enu_m") - pl.col("ref_x_m"), pl.col("y_enu_m") - pl.col("ref_y_m")
    det = pl.col("P_xx") * pl.col("P_yy") - pl.col("P_xy") ** 2
    d2 = (
        pl.col("P_yy") * dx * dx - 2.0 * pl.col("P_xy") * dx * dy + pl.col("P_xx") * dy * dy
    ) / det
    return (
        tk.join(tr, on=["time_ns", "cx", "cy"], how="inner")
        .with_columns(d2.alias("d2"), (dx * dx + dy * dy).sqrt().alias("dist_m"))
        .filter((pl.col("d2") < gate) & (pl.col("dist_m") <= cell))
        .select("time_ns", "system_track_id", "vessel_id", "d2", "dist_m")
        .sort("time_ns", "system_track_id", "vessel_id")
    )


def associate_to_truth(pairs: pl.DataFrame) -> pl.DataFrame:
    """Choose each track's truth and each truth's primary track, epoch by epoch (the
    hysteresis makes each epoch depend on the previous one, hence the loop over epochs;
    inside an epoch everything is array work).

    Returns the associated pairs (time_ns, system_track_id, vessel_id, d2, dist_m) with
    ``primary`` (bool): the truth's primary track at that epoch.
    """
    if pairs.height == 0:
        return pairs.with_columns(pl.lit(False).alias("primary"))
    track_ids, track = np.unique(pairs["system_track_id"].to_numpy(), return_inverse=True)
    truth_ids, truth = np.unique(pairs["vessel_id"].to_numpy(), return_inverse=True)
    t, d2 = pairs["time_ns"].to_numpy(), pairs["d2"].to_numpy()
    prev_truth = np.full(track_ids.size, -1)
    prev_primary = np.full(truth_ids.size, -1)
    chosen = np.zeros(t.size, bool)
    primary = np.zeros(t.size, bool)
    bounds = np.flatnonzero(np.r_[True, t[1:] != t[:-1], True])
    for a, b in pairwise(bounds):
        tr, tu, dd = track[a:b], truth[a:b], d2[a:b]
        keep = prev_truth[tr] == tu
        order = np.lexsort((dd, ~keep, tr))
        first = order[np.r_[True, tr[order][1:] != tr[order][:-1]]]
        chosen[a + first] = True
        prev_truth[tr[first]] = tu[first]
        ctr, ctu, cd = tr[first], tu[first], dd[first]
        keep_p = prev_primary[ctu] == ctr
        order2 = np.lexsort((cd, ~keep_p, ctu))
        prim = order2[np.r_[True, ctu[order2][1:] != ctu[order2][:-1]]]
        primary[a + first[prim]] = True
        prev_primary[ctu[prim]] = ctr[prim]
    return pairs.with_columns(pl.Series("primary", primary)).filter(pl.Series(chosen))


# --- continuity ----------------------------------------------------------------------------


def track_changes(primary: pl.DataFrame) -> pl.DataFrame:
    """Changes of each truth's primary track between its consecutive tracked epochs:
    time_ns, vessel_id, from_track, to_track."""
    return (
        primary.sort("vessel_id", "time_ns")
        .with_columns(pl.col("system_track_id").shift(1).over("vessel_id").alias("from_track"))
        .filter(
            pl.col("from_track").is_not_null() & (pl.col("from_track") != pl.col("system_track_id"))
        )
        .select("time_ns", "vessel_id", "from_track", pl.col("system_track_id").alias("to_track"))
    )


def track_swaps(changes: pl.DataFrame, swap_window_s: float) -> pl.DataFrame:
    """Pairs of changes exchanging two tracks between two truths within the window
    (truth a: p -> q, truth b: q -> p): time_ns (of a's change), vessel_a, vessel_b."""
    other = changes.select(
        pl.col("time_ns").alias("t_b"),
        pl.col("vessel_id").alias("vessel_b"),
        pl.col("from_track").alias("to_track"),
        pl.col("to_track").alias("from_track"),
    )
    return (
        changes.join(other, on=["from_track", "to_track"], how="inner")
        .filter(
            (pl.col("vessel_id") < pl.col("vessel_b"))
            & ((pl.col("time_ns") - pl.col("t_b")).abs() <= round(swap_window_s * NS))
        )
        .unique(["vessel_id", "vessel_b", "from_track", "to_track"], keep="first")
        .select("time_ns", pl.col("vessel_id").alias("vessel_a"), "vessel_b")
    )


# --- the table ----------------------------------------------------------------------------


def siap_by_sector(
    system_tracks: pl.DataFrame,
    truth: pl.DataFrame | None,
    *,
    epochs_ns: np.ndarray,
    epoch_period_s: float,
    region: RegionConfig,
    sectors: Sequence[Sector],
    cfg: SiapConfig,
    start_ns: int,
    end_ns: int,
    reference: Reference | None = None,
    pairing: TruthPairing | None = None,
) -> pl.DataFrame:
    """Rows of the ``siap_by_sector`` table for the epochs of the window [start_ns,
    end_ns) (empty without truth and without a reconstructed ``reference``): one row per
    sector (null: outside every sector), sums and measures. Without truth the
    reconstructed reference's vessels (those carrying AIS, issue 37) stand in for the
    truths, column ``reference`` says which. ``epochs_ns`` may reach beyond the window
    (a work unit's lead-in and look-ahead): the track-to-truth hysteresis runs over all
    of them, so it enters the window as it would in one pass, and the track changes and
    swaps seen there count where they happen; every sum is of the window's epochs.
    ``pairing``: these system tracks already paired with this truth at ``epochs_ns``
    (:func:`pipeline.maritime.score.pair_with_truth`, shared with the scoring)."""
    kind = "truth"
    if (truth is None or truth.height == 0) and reference is not None and len(epochs_ns):
        truth, kind = reference_as_truth(reference, epochs_ns, region), reference.kind
    if truth is None or truth.height == 0 or len(epochs_ns) == 0:
        return empty_siap()
    tracks = _tracks(system_tracks.filter(pl.col("time_ns").is_in(list(epochs_ns))))
    if kind == "truth" and pairing is not None:
        truths, pairs = _paired(pairing, truth, tracks, epochs_ns, cfg)
    else:
        truths = truth_states(truth, epochs_ns, region)
        pairs = None
    truths = assign_sectors(
        truths.rename({"ref_x_m": "x_enu_m", "ref_y_m": "y_enu_m"}), sectors, region,
    ).rename({"x_enu_m": "ref_x_m", "y_enu_m": "ref_y_m"})
    assoc = associate_to_truth(candidate_pairs(tracks, truths, cfg) if pairs is None
                               else gated_pairs(tracks, truths, *pairs, cfg))
    primary = assoc.filter(pl.col("primary")).select("time_ns", "vessel_id", "system_track_id")
    tracks, truths, assoc = _in_window(tracks, truths, assoc, start_ns, end_ns)
    if truths.height == 0:
        return empty_siap()
    sums = siap_sums(tracks, truths, assoc, epoch_period_s, cfg.swap_window_s,
                     primary=primary, window=(start_ns, end_ns))
    return (
        sums.with_columns(
            pl.lit(int(start_ns), pl.Int64).alias("time_ns"),
            pl.lit(int(end_ns), pl.Int64).alias("end_time_ns"),
            pl.lit(float(epoch_period_s)).alias("epoch_period_s"),
            pl.lit(kind).alias("reference"),
        )
        .pipe(with_measures)
        .select(SIAP_COLUMNS)
        .sort("sector", nulls_last=True)
    )


def _in_window(tracks: pl.DataFrame, truths: pl.DataFrame, assoc: pl.DataFrame,
               start_ns: int, end_ns: int) -> tuple[pl.DataFrame, pl.DataFrame, pl.DataFrame]:
    """The rows of [start_ns, end_ns), the association's row positions (``_i``, ``_j``)
    renumbered to the rows kept."""
    def keep(df: pl.DataFrame) -> np.ndarray:
        t = df["time_ns"].to_numpy()
        return (t >= start_ns) & (t < end_ns)

    ki, kj, ka = keep(tracks), keep(truths), keep(assoc)
    if ki.all() and kj.all() and ka.all():
        return tracks, truths, assoc
    assoc = assoc.filter(pl.Series(ka))
    if "_i" in assoc.columns and "_j" in assoc.columns:
        new_i, new_j = np.cumsum(ki) - 1, np.cumsum(kj) - 1
        assoc = assoc.with_columns(
            pl.Series("_i", new_i[assoc["_i"].to_numpy()]).cast(assoc["_i"].dtype),
            pl.Series("_j", new_j[assoc["_j"].to_numpy()]).cast(assoc["_j"].dtype),
        )
    return tracks.filter(pl.Series(ki)), truths.filter(pl.Series(kj)), assoc


def siap_sums(
    tracks: pl.DataFrame,
    truths: pl.DataFrame,
    assoc: pl.DataFrame,
    epoch_period_s: float,
    swap_window_s: float,
    *,
    primary: pl.DataFrame | None = None,
    window: tuple[int, int] | None = None,
) -> pl.DataFrame:
    """Per-sector sums (SUM_COLUMNS) from tracks (time_ns, system_track_id, vx_mps,
    vy_mps, mmsi, sector, x/y), truths (time_ns, vessel_id, mmsi, ref_x_m, ref_y_m,
    ref_vx_mps, ref_vy_mps, sector) and the association (associate_to_truth).
    ``primary``: the truths' primary tracks (time_ns, vessel_id, system_track_id) also
    around the window, whose track changes and swaps are those inside ``window``
    (default: the association's, everything counted)."""
    key = ["time_ns", "vessel_id"]
    positional = "_i" in assoc.columns and "_j" in assoc.columns
    if positional:  # rows of tracks and truths known: gathers instead of joins
        i, j = assoc["_i"].to_numpy(), assoc["_j"].to_numpy()
        a = assoc.with_columns(
            truths["sector"].gather(j),
            truths["mmsi"].gather(j).alias("truth_mmsi"),
            truths["ref_vx_mps"].gather(j),
            truths["ref_vy_mps"].gather(j),
            tracks["vx_mps"].gather(i),
            tracks["vy_mps"].gather(i),
            tracks["mmsi"].gather(i),
        )
    else:
        a = assoc.join(
            truths.select(
                *key, "sector", pl.col("mmsi").alias("truth_mmsi"), "ref_vx_mps", "ref_vy_mps"
            ),
            on=key,
            how="left",
        ).join(
            tracks.select("time_ns", "system_track_id", "vx_mps", "vy_mps", "mmsi"),
            on=["time_ns", "system_track_id"],
            how="left",
        )
    a = a.with_columns(
        (
            (pl.col("vx_mps") - pl.col("ref_vx_mps")) ** 2
            + (pl.col("vy_mps") - pl.col("ref_vy_mps")) ** 2
        )
        .sqrt()
        .alias("vel_err"),
    )
    if positional:
        tt = truths.with_columns(_per_truth_columns(a, j, truths.height))
    else:
        per_truth = a.group_by(key).agg(
            pl.len().alias("n_tracks"),
            pl.col("mmsi").is_null().sum().alias("n_null"),
            (pl.col("mmsi") == pl.col("truth_mmsi")).sum().alias("n_correct"),
            (pl.col("mmsi").is_not_null() & (pl.col("mmsi") != pl.col("truth_mmsi")))
            .sum()
            .alias("n_wrong"),
            pl.col("system_track_id").filter(pl.col("primary")).first().alias("primary_track"),
        )
        tt = truths.join(per_truth, on=key, how="left").with_columns(
            pl.col("n_tracks").fill_null(0))
    parts = [
        _truth_sums(tt, epoch_period_s),
        _error_sums(a),
        _track_sums(tracks, assoc),
        _continuity_sums(tt, a.filter(pl.col("primary")) if primary is None else primary,
                         epoch_period_s, swap_window_s, window),
    ]
    out = parts[0]
    for p in parts[1:]:
        out = out.join(p, on="sector", how="full", coalesce=True, nulls_equal=True)
    return out.with_columns([pl.col(c).fill_null(0) for c in SUM_COLUMNS if c in out.columns])


def _error_sums(a: pl.DataFrame) -> pl.DataFrame:
    """Per sector the associated track-epochs and their position and velocity error
    sums, each added in row order (a polars group_by adds a float column in an order
    that follows its threads: the last digits of a sum changed from run to run)."""
    sectors = a.select("sector").unique(maintain_order=True)
    code = a.select("sector").join(sectors.with_row_index("_g"), on="sector", how="left",
                                   nulls_equal=True, maintain_order="left")["_g"].to_numpy()
    n = sectors.height
    def total(col: str) -> np.ndarray:
        return np.bincount(code, weights=a[col].fill_null(0.0).to_numpy(), minlength=n)
    return sectors.with_columns(
        pl.Series("associated_track_epochs", np.bincount(code, minlength=n), pl.UInt32),
        pl.Series("sum_position_error_m", total("dist_m")),
        pl.Series("sum_velocity_error_mps", total("vel_err")),
    )


def _per_truth_columns(a: pl.DataFrame, j: np.ndarray, n: int) -> list[pl.Series]:
    """n_tracks, n_null, n_correct, n_wrong, primary_track of each truth row (bincounts
    over the associated pairs' truth rows ``j``: the per-truth aggregation without a
    group_by and a join)."""
    mmsi = a["mmsi"]
    truth_mmsi = a["truth_mmsi"]
    has = mmsi.is_not_null().to_numpy()
    same = (mmsi == truth_mmsi).fill_null(False).to_numpy()
    primary = a["primary"].to_numpy()
    prim_track = np.zeros(n, np.int64)
    prim_has = np.zeros(n, bool)
    prim_track[j[primary]] = a["system_track_id"].to_numpy()[primary]
    prim_has[j[primary]] = True

    def count(w: np.ndarray | None = None) -> np.ndarray:
        return np.bincount(j, weights=w, minlength=n).astype(np.uint32)

    return [
        pl.Series("n_tracks", count()),
        pl.Series("n_null", count((~has).astype(float))),
        pl.Series("n_correct", count(same.astype(float))),
        pl.Series("n_wrong", count((has & ~same).astype(float))),
        pl.Series("primary_track", prim_track).set(pl.Series(~prim_has), None),
    ]


def _truth_sums(tt: pl.DataFrame, period_s: float) -> pl.DataFrame:
    tracked = pl.col("n_tracks") > 0
    ais = pl.col("mmsi").is_not_null() & tracked
    n = pl.col("n_tracks")
    return (
        tt.group_by("sector")
        .agg(
            pl.col("vessel_id").n_unique().alias("truths"),
            pl.len().alias("truth_epochs"),
            tracked.sum().alias("tracked_truth_epochs"),
            (tracked.sum() * period_s).alias("tracked_time_s"),
            (pl.len() * period_s).alias("truth_time_s"),
            ais.sum().alias("id_truth_epochs"),
            (ais & (pl.col("n_null") == n)).sum().alias("id_unknown_epochs"),
            (ais & (pl.col("n_correct") == n)).sum().alias("id_correct_epochs"),
            (ais & (pl.col("n_wrong") == n)).sum().alias("id_incorrect_epochs"),
        )
        .with_columns(
            (
                pl.col("id_truth_epochs")
                - pl.col("id_unknown_epochs")
                - pl.col("id_correct_epochs")
                - pl.col("id_incorrect_epochs")
            ).alias("id_ambiguous_epochs"),
        )
    )


def _track_sums(tracks: pl.DataFrame, assoc: pl.DataFrame) -> pl.DataFrame:
    if "_i" in assoc.columns:
        associated = np.zeros(tracks.height, bool)
        associated[assoc["_i"].to_numpy()] = True
        return tracks.select("sector").with_columns(pl.Series("_a", associated)).group_by(
            "sector").agg(pl.len().alias("track_epochs"),
                          (~pl.col("_a")).sum().alias("spurious_track_epochs"))
    flagged = tracks.select("time_ns", "system_track_id", "sector").join(
        assoc.select("time_ns", "system_track_id", pl.lit(True).alias("_a")),
        on=["time_ns", "system_track_id"],
        how="left",
    )
    return flagged.group_by("sector").agg(
        pl.len().alias("track_epochs"),
        pl.col("_a").is_null().sum().alias("spurious_track_epochs"),
    )


def _continuity_sums(
    tt: pl.DataFrame, primary: pl.DataFrame, period_s: float, swap_window_s: float,
    window: tuple[int, int] | None = None,
) -> pl.DataFrame:
    """Track number changes, swaps and the longest segments, per truth sector (changes
    and swaps at times inside ``window``, when given)."""
    changes = track_changes(primary.select("time_ns", "vessel_id", "system_track_id"))
    swaps = track_swaps(changes, swap_window_s)
    if window is not None:
        inside = pl.col("time_ns").is_between(*window, closed="left")
        changes, swaps = changes.filter(inside), swaps.filter(inside)
    sector_of = tt.select("time_ns", "vessel_id", "sector")
    ch = changes.join(sector_of, on=["time_ns", "vessel_id"], how="left")
    sw = swaps.join(
        sector_of.rename({"vessel_id": "vessel_a"}), on=["time_ns", "vessel_a"], how="left"
    )
    # runs of one primary track, within one sector: a run breaks when the truth's
    # primary track id changes (or it changes sector), not when the truth is untracked
    # for a while and the same track id resumes (continuity kept across short losses)
    sec = pl.col("sector").fill_null("")
    prim = pl.col("primary_track")
    runs = (
        tt.filter(prim.is_not_null())
        .sort("vessel_id", "time_ns")
        .with_columns(
            ((prim != prim.shift(1)) | (sec != sec.shift(1)) | (pl.col("vessel_id").diff() != 0))
            .fill_null(True)
            .cum_sum()
            .alias("_run"),
        )
    )
    period_ns = round(period_s * NS)
    longest = (
        runs.group_by("vessel_id", "sector", "_run")
        .agg(((pl.col("time_ns").max() - pl.col("time_ns").min()) // period_ns + 1).alias("_n"))
        .group_by("vessel_id", "sector")
        .agg(pl.col("_n").max().alias("_tl"))
        .group_by("sector")
        .agg((pl.col("_tl").sum() * period_s).alias("longest_segment_s"))
    )
    return (
        ch.group_by("sector")
        .agg(pl.len().alias("track_number_changes"))
        .join(
            sw.group_by("sector").agg(pl.len().alias("track_swaps")),
            on="sector",
            how="full",
            coalesce=True,
            nulls_equal=True,
        )
        .join(longest, on="sector", how="full", coalesce=True, nulls_equal=True)
    )


def with_measures(df: pl.DataFrame) -> pl.DataFrame:
    """The SIAP measures (MEASURE_COLUMNS) from the sums of each row (null when the
    denominator is 0)."""

    def ratio(num: pl.Expr, den: pl.Expr) -> pl.Expr:
        return pl.when(den > 0).then(num / den).otherwise(None)

    c = pl.col
    return df.with_columns(
        ratio(c("tracked_truth_epochs"), c("truth_epochs")).alias("completeness"),
        ratio(c("associated_track_epochs"), c("tracked_truth_epochs")).alias("ambiguity"),
        ratio(c("spurious_track_epochs"), c("track_epochs")).alias("spuriousness"),
        ratio(c("sum_position_error_m"), c("associated_track_epochs")).alias("position_accuracy_m"),
        ratio(c("sum_velocity_error_mps"), c("associated_track_epochs")).alias(
            "velocity_accuracy_mps"
        ),
        ratio(c("track_number_changes") * 3600.0, c("tracked_time_s")).alias(
            "track_number_changes_per_h"
        ),
        ratio(c("longest_segment_s"), c("truth_time_s")).alias("longest_segment"),
        ratio(c("id_truth_epochs") - c("id_unknown_epochs"), c("id_truth_epochs")).alias(
            "id_completeness"
        ),
        ratio(c("id_correct_epochs"), c("id_truth_epochs")).alias("id_correctness"),
        ratio(c("id_ambiguous_epochs"), c("id_truth_epochs")).alias("id_ambiguity"),
    )


def empty_siap() -> pl.DataFrame:
    schema: dict[str, pl.DataType] = {c: pl.Float64() for c in SIAP_COLUMNS}
    schema.update({"time_ns": pl.Int64(), "end_time_ns": pl.Int64(), "sector": pl.String(),
                   "reference": pl.String()})
    return pl.DataFrame(schema=schema)
