"""Accuracy scoring of fused and per-radar synchronised points against a reference.

For every fused point (source ``fused``) and every radar's synchronised point of the
same system track and epoch (source = site_id):

- reference ``truth`` when the log has simulated truth: truth interpolated linearly to
  the epoch per vessel (and prolonged up to ``truth_extrapolation_s`` past a vessel's
  last sample, see :func:`truth_at_epochs`); the reference vessel is the truth vessel
  nearest to the FUSED point at that epoch (within ``max_reference_distance_m``;
  farther points are false tracks and are not scored here), and the same vessel is the
  reference for that system track's radar points at that epoch. reference_id = vessel_id,
  reference_mmsi = the vessel's MMSI (null: no AIS aboard);
- otherwise reference ``reconstructed`` (issue 37, :mod:`pipeline.maritime.reference`):
  each AIS vessel's smoothed trajectory with its own covariance. Each radar's local
  track takes a vessel when within the gate most of the time both exist
  (:func:`pipeline.maritime.reference.match_points`): a radar's tracker follows one
  ship, a system track may stray from one ship to another. A fused point takes the
  vessel of its radar members (:func:`pipeline.maritime.reference.match_by_members`),
  so a ship without AIS passing one with AIS, or a system track straying onto it, is
  not scored against it; the radar points take the fused point's reference.
  reference_id = reference_mmsi = MMSI; ``reference_p95_m`` is the reference's own 95 %
  horizontal error at the point, ``reference_var_m2`` the trace of its covariance;
- (without truth and without a reconstructed reference, the older ``ais`` reference:
  the identified MMSI's latest AIS report extrapolated to the epoch; kept for callers
  that pass none.)

Error decomposition (every reference): along and across the reference's course
(``along_track_error_m`` > 0: ahead of it; ``across_track_error_m`` > 0: to its
starboard; null below ``MIN_DECOMPOSITION_SPEED_MPS``), and for a radar's point its
range error and azimuth error (clockwise) seen from its site. A clock that runs late by
dt puts a radar's points dt x speed behind: latency = -along / speed (the report
``latency_by_sensor``).

error = estimate - reference (east, north, m); error_m = its norm; NEES =
e^T P^-1 e with the point's own position covariance (m^2), chi-square with 2 degrees
of freedom (mean 2) when the reported covariance is calibrated; the reference's own
error is not included (negligible for truth; for AIS, NEES measures consistency only).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import polars as pl
from scipy.spatial import cKDTree

from pipeline.config import AisConfig, RadarSite, RegionConfig, Sector
from pipeline.filters.quantiles import chi2_ppf
from pipeline.frames import geodetic_to_enu
from pipeline.geometry import assign_sectors, position_covariance
from pipeline.maritime.config import ReferenceConfig
from pipeline.maritime.identity import ais_at_epochs
from pipeline.maritime.reference import Reference, match_by_members, match_points
from pipeline.maritime.sync import NS, expand_ranges
from pipeline.spatial import pairs_within

MIN_DECOMPOSITION_SPEED_MPS = 0.5
"""Below this reference speed the course is noise: no along/across-track error."""

ERROR_COLUMNS = (
    "time_ns",
    "system_track_id",
    "source",
    "sector",
    "reference",
    "reference_id",
    "reference_mmsi",
    "error_east_m",
    "error_north_m",
    "error_m",
    "nees",
    "reference_p95_m",
    "reference_var_m2",
    "reference_speed_mps",
    "along_track_error_m",
    "across_track_error_m",
    "reference_range_m",
    "range_error_m",
    "azimuth_error_rad",
)
_DECOMPOSITION = ERROR_COLUMNS[-8:]
_ERROR_SCHEMA = {
    "time_ns": pl.Int64,
    "system_track_id": pl.Int64,
    "source": pl.String,
    "sector": pl.String,
    "reference": pl.String,
    "reference_id": pl.Int64,
    "reference_mmsi": pl.Int64,
    "error_east_m": pl.Float64,
    "error_north_m": pl.Float64,
    "error_m": pl.Float64,
    "nees": pl.Float64,
    **{c: pl.Float64 for c in _DECOMPOSITION},
}


@dataclass(frozen=True)
class TruthPairing:
    """A unit's track points paired with the simulated truth once, for the scoring here
    and the SIAP measures (:func:`pipeline.maritime.siap.siap_by_sector`): the truth at
    the unit's epochs (:func:`truth_at_epochs`, prolonged by ``extrapolate_s``, with
    ``sampled`` false on the prolonged rows; ordered by (time, vessel)), the track points
    (time_ns, system_track_id, x_enu_m, y_enu_m: the system tracks at those epochs, in
    their order) and every (point ``i``, truth row ``j``) of one epoch within ``near_m``
    (a grid join, :func:`pipeline.spatial.pairs_within`; ``dist_m``; sorted by (i, j));
    ``epochs_ns``: the epochs, sorted.
    The scoring takes each point's nearest truth from these pairs (a point with none
    looks farther), SIAP its gated candidates."""

    truths: pl.DataFrame
    points: pl.DataFrame
    i: np.ndarray
    j: np.ndarray
    dist_m: np.ndarray
    near_m: float
    extrapolate_s: float
    epochs_ns: np.ndarray

    def nearest(self, t: np.ndarray, track: np.ndarray, x: np.ndarray, y: np.ndarray,
                max_dist_m: float) -> np.ndarray | None:
        """Row of ``truths`` nearest to each point (t, track: one of ``points``; x, y)
        within ``max_dist_m`` (ties: smaller vessel id), -1: none, as
        :func:`nearest_truth` finds it; None when a point is not among ``points``."""
        p = _row_of_any(self.points["time_ns"].to_numpy(),
                        self.points["system_track_id"].to_numpy(), t, track)
        if (p < 0).any():
            return None
        vessel = self.truths["vessel_id"].to_numpy()
        best = _nearest_of_pairs(self.i, self.j, self.dist_m, vessel, self.points.height,
                                 max_dist_m)[p]
        rest = np.flatnonzero(best < 0)
        if rest.size and self.near_m < max_dist_m:  # nothing within near_m: look farther
            tt, epochs = self.truths["time_ns"].to_numpy(), self.epochs_ns
            rx, ry = self.truths["ref_x_m"].to_numpy(), self.truths["ref_y_m"].to_numpy()
            reach = max_dist_m * (1 + 1e-9) + 1e-6
            i, j, d2 = pairs_within(np.searchsorted(epochs, t[rest]), x[rest], y[rest], reach,
                                    np.searchsorted(epochs, tt), rx, ry, cell_m=reach)
            best[rest] = _nearest_of_pairs(i, j, np.sqrt(d2), vessel, rest.size, max_dist_m)
        return best


def pair_with_truth(system_tracks: pl.DataFrame, truth: pl.DataFrame, epochs_ns: np.ndarray,
                    region: RegionConfig, *, near_m: float, extrapolate_s: float = 10.0
                    ) -> TruthPairing:
    """The :class:`TruthPairing` of the system tracks at ``epochs_ns`` with ``truth``."""
    epochs = np.unique(np.asarray(epochs_ns, np.int64))
    at = truth_at_epochs(truth, epochs, region, extrapolate_s=extrapolate_s, velocity=True,
                         sampled=True)
    at = at[np.argsort(at["time_ns"].to_numpy(), kind="stable")]
    points = system_tracks.filter(pl.col("time_ns").is_in(epochs)).select(
        "time_ns", "system_track_id", "x_enu_m", "y_enu_m")
    tt = points["time_ns"].to_numpy()
    reach = near_m * (1 + 1e-9) + 1e-6
    i, j, d2 = pairs_within(np.searchsorted(epochs, tt), points["x_enu_m"].to_numpy(),
                            points["y_enu_m"].to_numpy(), reach,
                            np.searchsorted(epochs, at["time_ns"].to_numpy()),
                            at["ref_x_m"].to_numpy(), at["ref_y_m"].to_numpy(), cell_m=reach)
    return TruthPairing(at, points, i, j, np.sqrt(d2), near_m, extrapolate_s, epochs)


def _nearest_of_pairs(i: np.ndarray, j: np.ndarray, dist: np.ndarray, vessel: np.ndarray,
                      n: int, max_dist_m: float) -> np.ndarray:
    """For each of n points, the ``j`` of its pair (``i``, sorted) nearest within
    ``max_dist_m`` (ties: smaller ``vessel[j]``, one row per vessel and epoch), -1: none."""
    out = np.full(n, -1, np.int64)
    ok = dist <= max_dist_m
    i, j, dist = i[ok], j[ok], dist[ok]
    if i.size == 0:
        return out
    start = np.flatnonzero(np.r_[True, i[1:] != i[:-1]])
    count = np.diff(np.r_[start, i.size])
    nearest = dist == np.repeat(np.minimum.reduceat(dist, start), count)
    v = np.where(nearest, vessel[j], np.iinfo(np.int64).max)
    first = nearest & (v == np.repeat(np.minimum.reduceat(v, start), count))
    out[i[first]] = j[first]
    return out


def _row_of_any(t: np.ndarray, s: np.ndarray, qt: np.ndarray, qs: np.ndarray) -> np.ndarray:
    """:func:`_row_of` for rows (t, s) in any order."""
    ordered = t.size < 2 or bool(np.all((t[1:] > t[:-1]) | ((t[1:] == t[:-1]) & (s[1:] > s[:-1]))))
    if ordered:
        return _row_of(t, s, qt, qs)
    order = np.lexsort((s, t))
    row = _row_of(t[order], s[order], qt, qs)
    return np.where(row >= 0, order[np.maximum(row, 0)], -1)


def score_tracks(
    system_tracks: pl.DataFrame,
    associations: pl.DataFrame,
    *,
    truth: pl.DataFrame | None,
    ais_reports: pl.DataFrame,
    region: RegionConfig,
    sectors: Sequence[Sector],
    max_reference_distance_m: float = 2000.0,
    max_ais_age_s: float = 30.0,
    truth_extrapolation_s: float = 10.0,
    reference: Reference | None = None,
    reference_cfg: ReferenceConfig | None = None,
    sites: Sequence[RadarSite] = (),
    pairing: TruthPairing | None = None,
) -> pl.DataFrame:
    """Errors of fused and radar points against truth (else the reconstructed
    ``reference``, else AIS), track_errors columns.

    Consumes system_tracks: time_ns, system_track_id, x_enu_m, y_enu_m, sigma_x_m,
    sigma_y_m, cov_xy_m2, optional sector, mmsi (AIS reference only); associations:
    time_ns, system_track_id, site_id, x_enu_m, y_enu_m, P_xx/P_yy/P_xy (or the sigma
    form), optional sector; truth: time_ns, vessel_id, mmsi, lat_deg, lon_deg. ``sites``:
    the radar sites (range/azimuth errors of their points). ``pairing``: the system
    tracks already paired with this truth (:func:`pair_with_truth`, shared with SIAP).
    """
    fused = _with_sector(system_tracks, sectors, region)
    radar = _with_sector(associations, sectors, region)
    if truth is not None and truth.height:
        out = _truth_errors(fused, radar, truth, region, max_reference_distance_m,
                            truth_extrapolation_s, pairing)
        return _decompose(out, sites, region)
    if reference is not None:
        rcfg = reference_cfg or ReferenceConfig()
        return _decompose(_reconstructed_errors(fused, radar, reference, rcfg), sites, region)
    fused = fused.with_columns(pl.lit("fused").alias("source"))
    radar = radar.rename({"site_id": "source"})
    ref = _ais_reference(fused, ais_reports, region, max_ais_age_s)
    key = ["time_ns", "system_track_id"]
    parts = [_errors(pts.join(ref, on=key, how="inner")) for pts in (fused, radar) if pts.height]
    if not parts:
        return pl.DataFrame(schema=_ERROR_SCHEMA)
    return pl.concat(parts).sort("time_ns", "system_track_id", "source")


def _decompose(out: pl.DataFrame, sites: Sequence[RadarSite], region: RegionConfig
               ) -> pl.DataFrame:
    """Fill the decomposition columns from the helper columns (reference position,
    velocity and covariance trace) and drop those (module docstring)."""
    if out.height == 0:  # whichever reference, nothing scored: the empty table
        return pl.DataFrame(schema=_ERROR_SCHEMA)
    if "_ref_x" not in out.columns:
        return out.select(ERROR_COLUMNS).cast(_ERROR_SCHEMA)
    ex, ey = out["error_east_m"].to_numpy(), out["error_north_m"].to_numpy()
    vx, vy = out["_ref_vx"].to_numpy(), out["_ref_vy"].to_numpy()
    speed = np.hypot(vx, vy)
    moving = speed >= MIN_DECOMPOSITION_SPEED_MPS
    ux, uy = np.where(moving, vx / np.where(moving, speed, 1.0), np.nan), \
        np.where(moving, vy / np.where(moving, speed, 1.0), np.nan)
    along, across = ex * ux + ey * uy, ex * uy - ey * ux
    names = [s.site_id for s in sites]
    sx, sy = np.full(len(names) + 1, np.nan), np.full(len(names) + 1, np.nan)
    if names:
        e, n = geodetic_to_enu(np.array([s.lat_deg for s in sites]),
                               np.array([s.lon_deg for s in sites]),
                               region.origin_lat_deg, region.origin_lon_deg)
        sx[:-1], sy[:-1] = np.atleast_1d(e), np.atleast_1d(n)
    site = out["source"].replace_strict(names, list(range(len(names))), default=len(names),
                                        return_dtype=pl.Int64).to_numpy()
    rx = out["_ref_x"].to_numpy() - sx[site]
    ry = out["_ref_y"].to_numpy() - sy[site]
    rng = np.hypot(rx, ry)
    rng_err = (ex * rx + ey * ry) / rng
    az_err = (ex * ry - ey * rx) / rng**2  # along d/d(azimuth) = (ry, -rx) / range
    p95 = out["reference_p95_m"] if "reference_p95_m" in out.columns else None
    return out.with_columns(
        (p95 if p95 is not None else pl.lit(0.0)).alias("reference_p95_m"),
        pl.col("_ref_var").alias("reference_var_m2"),
        pl.Series("reference_speed_mps", speed),
        pl.Series("along_track_error_m", along).fill_nan(None),
        pl.Series("across_track_error_m", across).fill_nan(None),
        pl.Series("reference_range_m", rng).fill_nan(None),
        pl.Series("range_error_m", rng_err).fill_nan(None),
        pl.Series("azimuth_error_rad", az_err).fill_nan(None),
    ).select(ERROR_COLUMNS).cast(_ERROR_SCHEMA)


def _reconstructed_errors(fused: pl.DataFrame, radar: pl.DataFrame, ref: Reference,
                          rcfg: ReferenceConfig) -> pl.DataFrame:
    """track_errors rows against the reconstructed reference (module docstring): every
    fused point matched to a reference vessel (:func:`match_points`), the radar points of
    its (epoch, system track) scored against the same one."""
    if fused.height == 0 or ref.rows == 0:
        return pl.DataFrame(schema=_ERROR_SCHEMA)
    fused = fused.sort("time_ns", "system_track_id")
    ft = fused["time_ns"].to_numpy()
    fs = fused["system_track_id"].to_numpy()
    at = ref.at_epochs(np.unique(ft))
    rt = radar["time_ns"].to_numpy()
    rs = radar["system_track_id"].to_numpy()
    f_of_r = _row_of(ft, fs, rt, rs)
    # each radar's local track takes a target, the fused point its members' target
    r_xx, r_yy, r_xy = position_covariance(radar)
    track_key = (radar["site_id"].rank("dense").cast(pl.Int64) * 10**12
                 + radar["local_track_id"]).to_numpy()
    owner = match_points(
        rt, radar["x_enu_m"].to_numpy(), radar["y_enu_m"].to_numpy(), track_key, r_xx, r_yy,
        r_xy, at, max_distance_m=rcfg.max_distance_m,
        gate_d2=float(chi2_ppf(rcfg.match_gate_probability, 2)), min_share=rcfg.min_match_share)
    ref_row = match_by_members(f_of_r, owner, fused.height, ft, fused["x_enu_m"].to_numpy(),
                               fused["y_enu_m"].to_numpy(), at)
    cols = {k: at[k].to_numpy() for k in ("x", "y", "vx", "vy", "var_x", "var_y", "p95_m")}
    ref = {"x": cols["x"], "y": cols["y"], "vx": cols["vx"], "vy": cols["vy"],
           "p95": cols["p95_m"], "var": cols["var_x"] + cols["var_y"]}
    return _scored_points(fused, radar, f_of_r, ref_row, ref, at["mmsi"], at["mmsi"],
                          "reconstructed")


def _scored_points(fused: pl.DataFrame, radar: pl.DataFrame, f_of_r: np.ndarray,
                   ref_row: np.ndarray, ref: dict[str, np.ndarray], ref_id: pl.Series,
                   ref_mmsi: pl.Series, kind: str) -> pl.DataFrame:
    """The rows of every fused point with a reference (``ref_row``: its row of the
    reference arrays ``ref``: x, y, vx, vy and optionally p95, var; -1: none) and of the
    radar points of its (epoch, system track) (``f_of_r``: a radar row's fused row)
    against the same one, in (time_ns, system_track_id, source) order: the fused rows
    are sorted by (time, track), so a fused row and a source's rank as a string order
    all of them at once; every column is gathered in that order once."""
    names = sorted({"fused", *radar["site_id"].unique().to_list()})
    parts, rows, f_sel, rank = [], [], [], []
    for pts, f_rows in ((fused, np.arange(fused.height)), (radar, f_of_r)):
        if pts.height == 0:
            continue
        # (radar rows without a fused row have no reference: as the join of the AIS path)
        sel = np.flatnonzero(np.where(f_rows >= 0, ref_row[np.maximum(f_rows, 0)], -1) >= 0)
        parts.append(pts)
        rows.append(sel)
        f_sel.append(f_rows[sel])
        rank.append(np.full(sel.size, names.index("fused")) if pts is fused else
                    pts["site_id"].gather(sel).replace_strict(
                        names, list(range(len(names))), return_dtype=pl.Int64).to_numpy())
    f_all, rank_all = np.concatenate(f_sel), np.concatenate(rank)
    if f_all.size == 0:
        return pl.DataFrame(schema=_ERROR_SCHEMA)
    order = np.argsort(f_all * len(names) + rank_all, kind="stable")

    def ordered(per_part: list[np.ndarray]) -> np.ndarray:
        return np.concatenate([v[sel] for v, sel in zip(per_part, rows, strict=True)])[order]

    def column(name: str) -> np.ndarray:
        return ordered([p[name].to_numpy() for p in parts])

    covariances = [position_covariance(p) for p in parts]
    P_xx, P_yy, P_xy = (ordered([c[n] for c in covariances]) for n in range(3))
    k = ref_row[f_all[order]]
    ex = column("x_enu_m") - ref["x"][k]
    ey = column("y_enu_m") - ref["y"][k]
    nees = (P_yy * ex * ex - 2.0 * P_xy * ex * ey + P_xx * ey * ey) / (P_xx * P_yy - P_xy**2)
    out = pl.DataFrame({
        "time_ns": column("time_ns"),
        "system_track_id": column("system_track_id"),
        "source": pl.Series(names).gather(rank_all[order]),
        "sector": pl.concat([p["sector"].gather(sel) for p, sel in zip(parts, rows, strict=True)]
                            ).gather(order),
        "reference": pl.Series([kind]).new_from_index(0, order.size),
        "reference_id": ref_id.gather(k),
        "reference_mmsi": ref_mmsi.gather(k),
        "error_east_m": ex, "error_north_m": ey, "error_m": np.hypot(ex, ey), "nees": nees,
    })
    extra = {"reference_p95_m": ref["p95"][k]} if "p95" in ref else {}
    return out.with_columns(
        *(pl.Series(n, v) for n, v in extra.items()),
        pl.Series("_ref_x", ref["x"][k]), pl.Series("_ref_y", ref["y"][k]),
        pl.Series("_ref_vx", ref["vx"][k]), pl.Series("_ref_vy", ref["vy"][k]),
        pl.Series("_ref_var", ref["var"][k]) if "var" in ref else pl.lit(0.0).alias("_ref_var"),
    )


def _truth_errors(
    fused: pl.DataFrame,
    radar: pl.DataFrame,
    truth: pl.DataFrame,
    region: RegionConfig,
    max_dist_m: float,
    extrapolate_s: float,
    pairing: TruthPairing | None = None,
) -> pl.DataFrame:
    """track_errors rows against truth, built positionally: the nearest truth vessel of
    each fused point (:func:`nearest_truth`, or the ``pairing``'s) is also the reference
    of the radar points of
    its (epoch, system track), found by ``searchsorted`` on the fused keys (associations
    and system tracks are both sorted by (time_ns, system_track_id)); the rows come out
    in (time_ns, system_track_id, source) order without a join."""
    if fused.height == 0:
        return pl.DataFrame(schema=_ERROR_SCHEMA)
    fused = fused.sort("time_ns", "system_track_id")
    ft = fused["time_ns"].to_numpy()
    fs = fused["system_track_id"].to_numpy()
    fx, fy = fused["x_enu_m"].to_numpy(), fused["y_enu_m"].to_numpy()
    if pairing is not None and pairing.extrapolate_s != extrapolate_s:
        raise ValueError("score_tracks: the pairing prolongs the truth by another time")
    ref_row = None if pairing is None else pairing.nearest(ft, fs, fx, fy, max_dist_m)
    if ref_row is None:
        at = truth_at_epochs(truth, np.unique(ft), region, extrapolate_s=extrapolate_s,
                             velocity=True)
        ref_row = nearest_truth(ft, fx, fy, at, max_dist_m)
    else:
        at = pairing.truths
    ref = {"x": at["ref_x_m"].to_numpy(), "y": at["ref_y_m"].to_numpy(),
           "vx": at["ref_vx_mps"].to_numpy(), "vy": at["ref_vy_mps"].to_numpy()}
    # radar rows -> their fused row
    f_of_r = _row_of(ft, fs, radar["time_ns"].to_numpy(), radar["system_track_id"].to_numpy())
    return _scored_points(fused, radar, f_of_r, ref_row, ref, at["vessel_id"], at["mmsi"],
                          "truth")


def _row_of(t: np.ndarray, s: np.ndarray, qt: np.ndarray, qs: np.ndarray) -> np.ndarray:
    """Index of each (qt, qs) among the rows (t, s) sorted by (t, s), -1 where absent (a
    radar row of a track none of whose rows was fused at that epoch: its radars were all
    excluded): one searchsorted on a combined key (time rank, track id rank: ids are
    birth times, too far apart to combine as they are)."""
    if qt.size == 0:
        return np.empty(0, np.int64)
    times = np.unique(t)
    ids, rank = np.unique(np.concatenate([s, qs]), return_inverse=True)
    key = np.searchsorted(times, t) * ids.size + rank[: s.size]
    qkey = np.searchsorted(times, qt) * ids.size + rank[s.size:]
    row = np.searchsorted(key, qkey)
    found = row < key.size
    found[found] = key[row[found]] == qkey[found]
    found &= np.isin(qt, times)  # (a time after the last fused one ranks as the last + 1)
    return np.where(found, row, -1)


def nearest_truth(t: np.ndarray, x: np.ndarray, y: np.ndarray, at: pl.DataFrame,
                  max_dist_m: float) -> np.ndarray:
    """Row of ``at`` (truth at the epochs, :func:`truth_at_epochs`) nearest to each point
    (t, x, y) at the same time within ``max_dist_m`` (ties: smaller vessel id); -1: none.

    One k-d tree query for all points: epochs are stacked apart on a third axis (epoch
    rank x 1e9 m), so a neighbour within ``max_dist_m`` is always of the same epoch. The
    two nearest are asked for, and the distances recomputed as the reference computes
    them, so that an exact tie goes to the smaller vessel id as there."""
    out = np.full(t.size, -1, np.int64)
    tt = at["time_ns"].to_numpy()
    if t.size == 0 or tt.size == 0:
        return out
    epochs = np.unique(np.concatenate([t, tt]))
    rx, ry = at["ref_x_m"].to_numpy(), at["ref_y_m"].to_numpy()
    ok_b = np.isfinite(rx) & np.isfinite(ry)
    jb = np.flatnonzero(ok_b)
    ok_a = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
    if jb.size == 0 or ok_a.size == 0:
        return out
    tree = cKDTree(np.column_stack([rx[jb], ry[jb], np.searchsorted(epochs, tt[jb]) * 1e9]))
    q = np.column_stack([x[ok_a], y[ok_a], np.searchsorted(epochs, t[ok_a]) * 1e9])
    k = min(2, jb.size)
    _, idx = tree.query(q, k=k, distance_upper_bound=max_dist_m * (1 + 1e-9) + 1e-6)
    idx = idx.reshape(ok_a.size, k)
    vessel = at["vessel_id"].to_numpy()
    best = np.full(ok_a.size, -1, np.int64)
    best_d = np.full(ok_a.size, np.inf)
    for c in range(k):
        found = idx[:, c] < jb.size
        j = np.where(found, jb[np.minimum(idx[:, c], jb.size - 1)], -1)
        d = np.where(found, np.sqrt((x[ok_a] - rx[j]) ** 2 + (y[ok_a] - ry[j]) ** 2), np.inf)
        better = found & ((d < best_d) | ((d == best_d) & (best >= 0)
                                         & (vessel[j] < vessel[np.maximum(best, 0)])))
        best = np.where(better, j, best)
        best_d = np.where(better, d, best_d)
    keep = (best >= 0) & (best_d <= max_dist_m)
    out[ok_a[keep]] = best[keep]
    return out


def _with_sector(df: pl.DataFrame, sectors: Sequence[Sector], region: RegionConfig) -> pl.DataFrame:
    return df if "sector" in df.columns else assign_sectors(df, sectors, region)


def truth_at_epochs(
    truth: pl.DataFrame,
    epochs_ns: np.ndarray,
    region: RegionConfig,
    *,
    extrapolate_s: float = 0.0,
    velocity: bool = False,
    sampled: bool = False,
) -> pl.DataFrame:
    """Truth interpolated linearly to each epoch inside each vessel's sampled span, and
    extrapolated linearly (velocity of its last two samples) up to ``extrapolate_s``
    past its last sample: a radar report made just before a vessel left the scene is
    synchronised up to two scans later, when the simulator no longer logs its truth.

    Returns time_ns (epoch), vessel_id, mmsi, ref_x_m, ref_y_m (regional ENU, m), and
    with ``velocity`` ref_vx_mps, ref_vy_mps: that of the segment interpolated (0 for a
    vessel with one sample); with ``sampled`` a column of that name, false on the rows
    past a vessel's last sample.
    """
    epochs = np.unique(np.asarray(epochs_ns, np.int64))
    tr = (
        truth.select("time_ns", "vessel_id", "mmsi", "lat_deg", "lon_deg")
        .sort("vessel_id", "time_ns")
        .unique(["vessel_id", "time_ns"], keep="last", maintain_order=True)
    )
    x, y = geodetic_to_enu(
        tr["lat_deg"].to_numpy(),
        tr["lon_deg"].to_numpy(),
        region.origin_lat_deg,
        region.origin_lon_deg,
    )
    t = tr["time_ns"].to_numpy()
    vessel = tr["vessel_id"].to_numpy()
    last = np.r_[vessel[1:] != vessel[:-1], True]
    single = last & np.r_[True, vessel[1:] != vessel[:-1]]
    idx_all = np.arange(t.size)
    nxt = np.where(last, idx_all, idx_all + 1)
    # the segment of a last sample is its previous one, prolonged past its end
    seg0 = np.where(last & ~single, idx_all - 1, idx_all)
    seg1 = np.where(last, idx_all, nxt)
    lo = np.searchsorted(epochs, t, "left")
    end = np.where(last, t + np.where(single, 0, round(extrapolate_s * NS)), t[nxt])
    hi = np.where(last, np.searchsorted(epochs, end, "right"), np.searchsorted(epochs, end, "left"))
    row, idx = expand_ranges(lo, hi)
    e, a, b = epochs[idx], seg0[row], seg1[row]
    dt = np.where(b == a, 1, t[b] - t[a])
    f = (e - t[a]) / dt
    cols = {
        "time_ns": e,
        "vessel_id": vessel[row],
        "mmsi": tr["mmsi"].gather(row),
        "ref_x_m": x[a] + f * (x[b] - x[a]),
        "ref_y_m": y[a] + f * (y[b] - y[a]),
    }
    if velocity:
        cols["ref_vx_mps"] = (x[b] - x[a]) / dt * NS
        cols["ref_vy_mps"] = (y[b] - y[a]) / dt * NS
    if sampled:
        cols["sampled"] = ~last[row] | (e == t[row])
    return pl.DataFrame(
        cols, schema_overrides={"time_ns": pl.Int64, "vessel_id": pl.Int64, "mmsi": pl.Int64})


def _truth_reference_reference(
    fused: pl.DataFrame,
    truth: pl.DataFrame,
    region: RegionConfig,
    max_dist_m: float,
    extrapolate_s: float,
) -> pl.DataFrame:
    """Nearest truth vessel to each fused point (grid-cell join in polars: the 3x3 cells of
    size max_dist_m around the point hold every vessel within max_dist_m): the
    reference of :func:`nearest_truth` (tests)."""
    at = truth_at_epochs(
        truth, fused["time_ns"].unique().to_numpy(), region, extrapolate_s=extrapolate_s
    )
    cell = pl.lit(max_dist_m)
    at = at.with_columns(
        (pl.col("ref_x_m") / cell).floor().cast(pl.Int64).alias("cx"),
        (pl.col("ref_y_m") / cell).floor().cast(pl.Int64).alias("cy"),
    )
    shifts = pl.DataFrame({"sx": np.repeat([-1, 0, 1], 3), "sy": np.tile([-1, 0, 1], 3)})
    at = at.join(shifts, how="cross").with_columns(
        pl.col("cx") + pl.col("sx"), pl.col("cy") + pl.col("sy")
    )
    pts = fused.select(
        "time_ns",
        "system_track_id",
        "x_enu_m",
        "y_enu_m",
        (pl.col("x_enu_m") / cell).floor().cast(pl.Int64).alias("cx"),
        (pl.col("y_enu_m") / cell).floor().cast(pl.Int64).alias("cy"),
    )
    dist = (
        (pl.col("x_enu_m") - pl.col("ref_x_m")) ** 2 + (pl.col("y_enu_m") - pl.col("ref_y_m")) ** 2
    ).sqrt()
    return (
        pts.join(at, on=["time_ns", "cx", "cy"], how="inner")
        .with_columns(dist.alias("_d"))
        .filter(pl.col("_d") <= max_dist_m)
        .sort("time_ns", "system_track_id", "_d", "vessel_id")
        .unique(["time_ns", "system_track_id"], keep="first", maintain_order=True)
        .select(
            "time_ns",
            "system_track_id",
            "ref_x_m",
            "ref_y_m",
            pl.lit("truth").alias("reference"),
            pl.col("vessel_id").alias("reference_id"),
            pl.col("mmsi").alias("reference_mmsi"),
        )
    )


def _ais_reference(
    fused: pl.DataFrame, ais_reports: pl.DataFrame, region: RegionConfig, max_age_s: float
) -> pl.DataFrame:
    """The identified MMSI's AIS report extrapolated to the epoch (skipped: no identity)."""
    ident = fused.filter(pl.col("mmsi").is_not_null()) if "mmsi" in fused.columns else None
    if ident is None or ident.height == 0 or ais_reports.height == 0:
        return pl.DataFrame(
            schema={
                "time_ns": pl.Int64,
                "system_track_id": pl.Int64,
                "ref_x_m": pl.Float64,
                "ref_y_m": pl.Float64,
                "reference": pl.String,
                "reference_id": pl.Int64,
                "reference_mmsi": pl.Int64,
            }
        )
    cfg = AisConfig(max_report_age_s=max_age_s)
    ais = ais_at_epochs(ais_reports, ident["time_ns"].unique().to_numpy(), cfg=cfg, region=region)
    return (
        ident.select("time_ns", "system_track_id", "mmsi")
        .join(
            ais.select(
                "time_ns",
                "mmsi",
                pl.col("x_enu_m").alias("ref_x_m"),
                pl.col("y_enu_m").alias("ref_y_m"),
            ),
            on=["time_ns", "mmsi"],
            how="inner",
        )
        .select(
            "time_ns",
            "system_track_id",
            "ref_x_m",
            "ref_y_m",
            pl.lit("ais").alias("reference"),
            pl.col("mmsi").alias("reference_id"),
            pl.col("mmsi").alias("reference_mmsi"),
        )
    )


def _errors(pts: pl.DataFrame) -> pl.DataFrame:
    """error = estimate - reference; NEES = e^T P^-1 e with the point's own covariance."""
    ex = pts["x_enu_m"].to_numpy() - pts["ref_x_m"].to_numpy()
    ey = pts["y_enu_m"].to_numpy() - pts["ref_y_m"].to_numpy()
    P_xx, P_yy, P_xy = position_covariance(pts)
    nees = (P_yy * ex * ex - 2.0 * P_xy * ex * ey + P_xx * ey * ey) / (P_xx * P_yy - P_xy**2)
    return (
        pts.with_columns(
            pl.Series("error_east_m", ex),
            pl.Series("error_north_m", ey),
            pl.Series("error_m", np.hypot(ex, ey)),
            pl.Series("nees", nees),
            *(pl.lit(None, pl.Float64).alias(c) for c in _DECOMPOSITION),
        )
        .select(ERROR_COLUMNS)
        .cast(_ERROR_SCHEMA)
    )
