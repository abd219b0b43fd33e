"""Cross-track deviation error along the fairway, per leg, per radar and fused
(multi-radar paper, eq. 1-6 and figures 1-2).

For every fused point on a leg (system_tracks.leg_id) and every radar point of the same
system track and epoch, against the reference of track_errors (truth, else AIS):

- cross-track deviation L_s of the estimate and of the reference from the leg's axis,
  eq. 1 in the sign convention of pipeline/geometry.py (+ to starboard of the leg's
  direction): L = (p - S) . n; the error is L_est - L_ref;
- its sigma sigma_s = sqrt(n^T P n) from the point's own covariance (eq. 2-4 in
  covariance form; for one radar sigma_s^2 = sigma_r^2 sin^2 theta + (r sigma_b)^2
  cos^2 theta, eq. 4-6, plus the synchronisation inflation of eq. 12);
- per radar, the observation geometry of figure 1: range r from the site to the
  estimate and the aspect theta, the angle between the line of sight and the leg axis
  folded into [0, 90] deg (0: the radar looks along the fairway, the unfavourable
  aspect of eq. 5; 90: across it, eq. 6);
- the RMS of the error over a sliding window of ``window_s`` (60 s in the paper,
  "averaging in time on a sliding interval of ~60 s"), trailing (t - window, t], per
  (system track, source).

The sliding window does not cross the seams between batch work units (each unit is
computed on its own); a window that starts a unit holds fewer samples (samples_60s).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import polars as pl

from pipeline.config import FairwayLeg, RadarSite, RegionConfig
from pipeline.frames import geodetic_to_enu
from pipeline.geometry import leg_endpoints, position_covariance
from pipeline.units import NS

CROSS_TRACK_COLUMNS = (
    "time_ns",
    "system_track_id",
    "source",
    "leg_id",
    "sector",
    "reference",
    "reference_id",
    "n_sources",
    "along_track_m",
    "cross_track_m",
    "reference_cross_track_m",
    "cross_track_error_m",
    "sigma_cross_track_m",
    "rms_error_60s_m",
    "samples_60s",
    "aspect_deg",
    "range_m",
)


def leg_frames(legs: Sequence[FairwayLeg], region: RegionConfig) -> pl.DataFrame:
    """One row per leg: leg_id, start (sx, sy), unit direction (ux, uy) and starboard
    normal (nx, ny) = (uy, -ux) in regional ENU."""
    start, end = leg_endpoints(legs, region)
    d = end - start
    u = d / np.hypot(d[:, 0], d[:, 1])[:, None]
    return pl.DataFrame(
        {
            "leg_id": [g.leg_id for g in legs],
            "sx": start[:, 0],
            "sy": start[:, 1],
            "ux": u[:, 0],
            "uy": u[:, 1],
            "nx": u[:, 1],
            "ny": -u[:, 0],
        }
    )


def _points(system_tracks: pl.DataFrame, associations: pl.DataFrame) -> pl.DataFrame:
    """Fused and radar points with their covariance (P_xx, P_yy, P_xy, m^2), source and
    the fused point's leg/sector/n_sources."""
    key = ["time_ns", "system_track_id"]
    fused = system_tracks.filter(pl.col("leg_id").is_not_null())
    fP = position_covariance(fused)
    f = fused.select(
        *key,
        pl.lit("fused").alias("source"),
        "x_enu_m",
        "y_enu_m",
        pl.Series("P_xx", fP[0]),
        pl.Series("P_yy", fP[1]),
        pl.Series("P_xy", fP[2]),
        pl.col("n_sources").cast(pl.Int16),
    )
    rP = position_covariance(associations)
    r = associations.select(
        *key,
        pl.col("site_id").alias("source"),
        "x_enu_m",
        "y_enu_m",
        pl.Series("P_xx", rP[0]),
        pl.Series("P_yy", rP[1]),
        pl.Series("P_xy", rP[2]),
        pl.lit(1, pl.Int16).alias("n_sources"),
    )
    ctx = fused.select(*key, "leg_id", "sector")
    return pl.concat([f, r.join(ctx.select(key), on=key, how="semi")]).join(ctx, on=key)


def cross_track_by_leg(
    system_tracks: pl.DataFrame,
    associations: pl.DataFrame,
    track_errors: pl.DataFrame,
    *,
    legs: Sequence[FairwayLeg],
    region: RegionConfig,
    sites: Sequence[RadarSite],
    window_s: float = 60.0,
) -> pl.DataFrame:
    """Rows of the ``cross_track_by_leg`` table (columns CROSS_TRACK_COLUMNS).

    Consumes system_tracks (time_ns, system_track_id, x_enu_m, y_enu_m, sigma_x_m,
    sigma_y_m, cov_xy_m2, n_sources, leg_id, sector), associations (time_ns,
    system_track_id, site_id, x_enu_m, y_enu_m, P_xx/P_yy/P_xy or the sigma form) and
    track_errors (time_ns, system_track_id, source, reference, reference_id,
    error_east_m, error_north_m), each sorted by its key. Sorted by (time_ns,
    system_track_id, source).

    Built on positions: points and error rows meet on one integer key (time rank,
    track id, source rank) instead of string joins; the trailing RMS is polars'
    ``rolling_mean_by`` over a narrow frame (integer group key); the same rows and values
    as :func:`cross_track_by_leg_reference`.
    """
    if not legs or system_tracks.height == 0 or track_errors.height == 0:
        return _empty()
    on_leg = system_tracks.filter(pl.col("leg_id").is_not_null())
    if on_leg.height == 0:
        return _empty()
    ft, fs = on_leg["time_ns"].to_numpy(), on_leg["system_track_id"].to_numpy()
    at, as_ = associations["time_ns"].to_numpy(), associations["system_track_id"].to_numpy()
    et, es = track_errors["time_ns"].to_numpy(), track_errors["system_track_id"].to_numpy()
    times = np.unique(np.concatenate([ft, at, et]))
    # track ids by rank in the keys (ids are birth times: too far apart to combine)
    track_ids = np.unique(np.concatenate([fs, as_, es]))
    span = track_ids.size
    fr, ar, er = (np.searchsorted(track_ids, v) for v in (fs, as_, es))
    names = sorted({"fused", *associations["site_id"].unique().to_list(),
                    *track_errors["source"].unique().to_list()})
    n_src = len(names)

    def key(t: np.ndarray, sid: np.ndarray, src: np.ndarray) -> np.ndarray:
        return (np.searchsorted(times, t) * span + sid) * n_src + src

    def rank(col: pl.Series) -> np.ndarray:
        return col.replace_strict(names, list(range(n_src)), return_dtype=pl.Int64).to_numpy()

    # radar points of the fused points on a leg
    f_key2 = np.searchsorted(times, ft) * span + fr
    a_key2 = np.searchsorted(times, at) * span + ar
    pos = np.searchsorted(f_key2, a_key2)
    has = (pos < f_key2.size) & (f_key2[np.minimum(pos, f_key2.size - 1)] == a_key2)
    ai = np.flatnonzero(has)
    a_f = pos[ai]  # fused row of each radar point
    fP = position_covariance(on_leg)
    rP = position_covariance(associations)
    fused_src = names.index("fused")
    n_f = on_leg.height
    src = np.r_[np.full(n_f, fused_src), rank(associations["site_id"])[ai]]
    f_of = np.r_[np.arange(n_f), a_f]  # each point's fused row
    t = ft[f_of]
    sid, sid_rank = fs[f_of], fr[f_of]
    pk = key(t, sid_rank, src)
    ek = key(et, er, rank(track_errors["source"]))
    e_order = np.argsort(ek, kind="stable")
    ek_sorted = ek[e_order]
    epos = np.searchsorted(ek_sorted, pk)
    match = (epos < ek.size) & (ek_sorted[np.minimum(epos, ek.size - 1)] == pk)
    pts = np.flatnonzero(match)
    e_row = e_order[epos[pts]]
    is_f = pts < n_f
    r_row = ai[pts[~is_f] - n_f]
    f_row = f_of[pts]

    def both(fcol: np.ndarray, rcol: np.ndarray) -> np.ndarray:
        out = np.empty(pts.size, np.result_type(fcol, rcol))
        out[is_f] = fcol[pts[is_f]]
        out[~is_f] = rcol[r_row]
        return out

    x = both(on_leg["x_enu_m"].to_numpy(), associations["x_enu_m"].to_numpy())
    y = both(on_leg["y_enu_m"].to_numpy(), associations["y_enu_m"].to_numpy())
    P_xx, P_yy, P_xy = (both(fp, rp) for fp, rp in zip(fP, rP, strict=True))
    frames = leg_frames(legs, region)
    leg_idx = on_leg["leg_id"].replace_strict(frames["leg_id"].to_list(),
                                              list(range(frames.height)),
                                              return_dtype=pl.Int64).to_numpy()[f_row]
    sx, sy, ux, uy, nx, ny = (frames[c].to_numpy()[leg_idx]
                              for c in ("sx", "sy", "ux", "uy", "nx", "ny"))
    ex = track_errors["error_east_m"].to_numpy()[e_row]
    ey = track_errors["error_north_m"].to_numpy()[e_row]
    rx, ry = x - ex, y - ey
    cross = (x - sx) * nx + (y - sy) * ny
    ref_cross = (rx - sx) * nx + (ry - sy) * ny
    along = (rx - sx) * ux + (ry - sy) * uy
    sigma = np.sqrt(nx * nx * P_xx + 2.0 * nx * ny * P_xy + ny * ny * P_yy)
    err = cross - ref_cross
    # observation geometry of each radar point (null for fused points)
    site_x, site_y = _site_positions(sites, region, names)
    px_s, py_s = site_x[src[pts]], site_y[src[pts]]
    lx, ly = x - px_s, y - py_s
    rng = np.sqrt(lx * lx + ly * ly)
    cos_aspect = np.clip(np.abs((lx * ux + ly * uy) / rng), 0.0, 1.0)
    # trailing RMS per (track, source): rows sorted by (track, source, time) for polars
    srcp = src[pts]
    grp = sid_rank[pts] * n_src + srcp
    o = np.lexsort((t[pts], grp))
    win = f"{round(window_s * NS)}i"
    narrow = pl.DataFrame({"g": grp[o], "time_ns": t[pts][o], "e": err[o],
                           "c": cos_aspect[o]}).with_columns(
        (pl.col("e") ** 2).rolling_mean_by("time_ns", window_size=win).over("g").sqrt()
        .alias("rms"),
        pl.col("e").is_not_null().cast(pl.Int32).rolling_sum_by("time_ns", window_size=win)
        .over("g").alias("n"),
        pl.col("c").arccos().degrees().alias("aspect"),
    )
    back = np.empty(o.size, np.int64)
    back[o] = np.arange(o.size)
    rms = narrow["rms"].gather(back)
    samples = narrow["n"].gather(back)
    aspect = narrow["aspect"].gather(back)
    final = np.lexsort((srcp, sid[pts], t[pts]))
    radar = ~is_f
    out = pl.DataFrame({
        "time_ns": t[pts],
        "system_track_id": sid[pts],
        "source": pl.Series(names, dtype=pl.String).gather(srcp),
        "leg_id": on_leg["leg_id"].gather(f_row),
        "sector": on_leg["sector"].gather(f_row),
        "reference": track_errors["reference"].gather(e_row),
        "reference_id": track_errors["reference_id"].gather(e_row),
        "n_sources": np.where(is_f, on_leg["n_sources"].to_numpy()[f_row], 1).astype(np.int16),
        "along_track_m": along,
        "cross_track_m": cross,
        "reference_cross_track_m": ref_cross,
        "cross_track_error_m": err,
        "sigma_cross_track_m": sigma,
        "rms_error_60s_m": rms,
        "samples_60s": samples,
        "aspect_deg": aspect.set(pl.Series(~radar), None),
        "range_m": pl.Series(rng).set(pl.Series(~radar), None),
    }, schema_overrides={"time_ns": pl.Int64, "system_track_id": pl.Int64})
    return out[final].select(CROSS_TRACK_COLUMNS)


def _site_positions(sites: Sequence[RadarSite], region: RegionConfig, names: list[str]
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Regional ENU position of each source name's radar site (NaN: fused, unknown)."""
    x = np.full(len(names), np.nan)
    y = np.full(len(names), np.nan)
    if sites:
        e, n = geodetic_to_enu(np.array([s.lat_deg for s in sites]),
                               np.array([s.lon_deg for s in sites]),
                               region.origin_lat_deg, region.origin_lon_deg)
        for s, ee, nn in zip(sites, np.atleast_1d(e), np.atleast_1d(n), strict=True):
            if s.site_id in names:
                x[names.index(s.site_id)] = ee
                y[names.index(s.site_id)] = nn
    return x, y


def cross_track_by_leg_reference(
    system_tracks: pl.DataFrame,
    associations: pl.DataFrame,
    track_errors: pl.DataFrame,
    *,
    legs: Sequence[FairwayLeg],
    region: RegionConfig,
    sites: Sequence[RadarSite],
    window_s: float = 60.0,
) -> pl.DataFrame:
    """Rows of the ``cross_track_by_leg`` table (columns CROSS_TRACK_COLUMNS).

    Consumes system_tracks (time_ns, system_track_id, x_enu_m, y_enu_m, sigma_x_m,
    sigma_y_m, cov_xy_m2, n_sources, leg_id, sector), associations (time_ns,
    system_track_id, site_id, x_enu_m, y_enu_m, P_xx/P_yy/P_xy or the sigma form) and
    track_errors (time_ns, system_track_id, source, reference, reference_id,
    error_east_m, error_north_m). Sorted by (time_ns, system_track_id, source). The
    polars reference of :func:`cross_track_by_leg`.
    """
    if not legs or system_tracks.height == 0 or track_errors.height == 0:
        return _empty()
    key = ["time_ns", "system_track_id", "source"]
    pts = (
        _points(system_tracks, associations)
        .join(
            track_errors.select(*key, "reference", "reference_id", "error_east_m", "error_north_m"),
            on=key,
            how="inner",
        )
        .join(leg_frames(legs, region), on="leg_id", how="inner")
    )
    if pts.height == 0:
        return _empty()
    x, y = pl.col("x_enu_m"), pl.col("y_enu_m")
    rx, ry = x - pl.col("error_east_m"), y - pl.col("error_north_m")
    nx, ny = pl.col("nx"), pl.col("ny")
    pts = pts.with_columns(
        ((x - pl.col("sx")) * nx + (y - pl.col("sy")) * ny).alias("cross_track_m"),
        ((rx - pl.col("sx")) * nx + (ry - pl.col("sy")) * ny).alias("reference_cross_track_m"),
        ((rx - pl.col("sx")) * pl.col("ux") + (ry - pl.col("sy")) * pl.col("uy")).alias(
            "along_track_m"
        ),
        (nx * nx * pl.col("P_xx") + 2.0 * nx * ny * pl.col("P_xy") + ny * ny * pl.col("P_yy"))
        .sqrt()
        .alias("sigma_cross_track_m"),
    ).with_columns(
        (pl.col("cross_track_m") - pl.col("reference_cross_track_m")).alias("cross_track_error_m"),
    )
    pts = _with_geometry(pts, sites, region)
    win = f"{round(window_s * NS)}i"
    g = ["system_track_id", "source"]
    out = pts.sort(*g, "time_ns").with_columns(
        (pl.col("cross_track_error_m") ** 2)
        .rolling_mean_by("time_ns", window_size=win)
        .over(g)
        .sqrt()
        .alias("rms_error_60s_m"),
        pl.col("cross_track_error_m")
        .is_not_null()
        .cast(pl.Int32)
        .rolling_sum_by("time_ns", window_size=win)
        .over(g)
        .alias("samples_60s"),
    )
    return out.select(CROSS_TRACK_COLUMNS).sort(key)


def _with_geometry(
    pts: pl.DataFrame, sites: Sequence[RadarSite], region: RegionConfig
) -> pl.DataFrame:
    """range_m and aspect_deg of each radar point (null for fused points)."""
    e, n = geodetic_to_enu(
        np.array([s.lat_deg for s in sites]),
        np.array([s.lon_deg for s in sites]),
        region.origin_lat_deg,
        region.origin_lon_deg,
    )
    site_xy = pl.DataFrame(
        {
            "source": [s.site_id for s in sites],
            "site_x": np.atleast_1d(e),
            "site_y": np.atleast_1d(n),
        }
    )
    pts = pts.join(site_xy, on="source", how="left")
    lx, ly = pl.col("x_enu_m") - pl.col("site_x"), pl.col("y_enu_m") - pl.col("site_y")
    rng = (lx * lx + ly * ly).sqrt()
    cos_aspect = ((lx * pl.col("ux") + ly * pl.col("uy")) / rng).abs().clip(0.0, 1.0)
    return pts.with_columns(
        rng.alias("range_m"),
        cos_aspect.arccos().degrees().alias("aspect_deg"),
    )


def _empty() -> pl.DataFrame:
    schema = {c: pl.Float64 for c in CROSS_TRACK_COLUMNS}
    schema.update(
        {
            "time_ns": pl.Int64,
            "system_track_id": pl.Int64,
            "source": pl.String,
            "leg_id": pl.String,
            "sector": pl.String,
            "reference": pl.String,
            "reference_id": pl.Int64,
            "n_sources": pl.Int16,
            "samples_60s": pl.Int32,
        }
    )
    return pl.DataFrame(schema=schema)
