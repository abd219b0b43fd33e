"""AIS identification of fused system tracks: gated AIS-to-track matches and an MMSI vote.

Per synchronised epoch (the same test as track-to-track association, two-radar
identification paper eq. 7-16 with AIS as the second "radar"):

1. AIS picture: for each MMSI its latest report with ais_time <= epoch and
   epoch - ais_time <= max_report_age_s, extrapolated to the epoch with its SOG/COG
   (multi-radar paper eq. 9). Its covariance is kept simple:

   .. math:: P_{AIS} = \\sigma_p^2 I + (\\sigma_{SOG} \\Delta t)^2\\, u u^T,
             \\qquad u = (\\sin COG, \\cos COG)

   (GNSS position sigma_position_m, plus the along-track effect of the SOG error; COG
   error and AIS latency are ignored). A report without SOG or COG is not extrapolated.
2. gate: d^2 = D^T (P_fused + P_AIS)^-1 D < chi2.ppf(gate_probability, 2);
3. one-to-one per epoch: least summed d^2 (``linear_sum_assignment``, gate as the cost
   of leaving a track unmatched).

Identity of a fused point (track s, time t): the MMSI with the most matches on track s
within [t - identity_window_s, t + identity_window_s]; ties go to the smaller summed
d^2 (then the smaller MMSI); null when the track has no match in the window.
"""

from __future__ import annotations

import numpy as np
import polars as pl

from pipeline.config import AisConfig, RegionConfig
from pipeline.frames import geodetic_to_enu
from pipeline.geometry import position_covariance
from pipeline.maritime.associate import assign, assign_grouped, gate_threshold
from pipeline.maritime.sync import expand_ranges, extrapolate_position
from pipeline.spatial import pairs_within
from pipeline.units import NS

IDENTIFICATION_COLUMNS = ("time_ns", "system_track_id", "mmsi", "ais_time_ns", "mahalanobis_d2")


def ais_at_epochs(
    ais_reports: pl.DataFrame, epochs_ns: np.ndarray, *, cfg: AisConfig, region: RegionConfig
) -> pl.DataFrame:
    """Each MMSI's latest AIS report (not in the future, at most max_report_age_s old)
    extrapolated to each epoch.

    Consumes ais_reports: time_ns, mmsi, lat_deg, lon_deg, sog_mps, cog_rad.
    Produces: time_ns (epoch), mmsi, ais_time_ns, x_enu_m, y_enu_m (m), P_xx, P_yy,
    P_xy (m^2), sorted by (time_ns, mmsi).
    """
    epochs = np.unique(np.asarray(epochs_ns, np.int64))
    ais = (
        ais_reports.select("time_ns", "mmsi", "lat_deg", "lon_deg", "sog_mps", "cog_rad")
        .sort("mmsi", "time_ns")
        .unique(["mmsi", "time_ns"], keep="last", maintain_order=True)
        .with_columns(pl.col("time_ns").shift(-1).over("mmsi").alias("next_ns"))
    )
    t = ais["time_ns"].to_numpy()
    nxt = ais["next_ns"].fill_null(np.iinfo(np.int64).max).to_numpy()
    lo = np.searchsorted(epochs, t, side="left")
    hi = np.minimum(
        np.searchsorted(epochs, t + round(cfg.max_report_age_s * NS), side="right"),
        np.searchsorted(epochs, nxt, side="left"),
    )
    x0, y0 = geodetic_to_enu(
        ais["lat_deg"].to_numpy(),
        ais["lon_deg"].to_numpy(),
        region.origin_lat_deg,
        region.origin_lon_deg,
    )
    row, idx = expand_ranges(lo, hi)
    pick = ais[row]
    epoch = epochs[idx]
    moving = pick["sog_mps"].is_not_null() & pick["cog_rad"].is_not_null()
    sog = pick["sog_mps"].fill_null(0.0).to_numpy() * moving.to_numpy()
    cog = pick["cog_rad"].fill_null(0.0).to_numpy()
    dt = (epoch - pick["time_ns"].to_numpy()) / NS
    x, y = extrapolate_position(np.atleast_1d(x0)[row], np.atleast_1d(y0)[row], sog, cog, dt)
    along = (cfg.sigma_sog_mps * dt) ** 2 * moving.to_numpy()
    s, c = np.sin(cog), np.cos(cog)
    var_p = cfg.sigma_position_m**2
    return pl.DataFrame(
        {
            "time_ns": epoch,
            "mmsi": pick["mmsi"],
            "ais_time_ns": pick["time_ns"],
            "x_enu_m": x,
            "y_enu_m": y,
            "P_xx": var_p + along * s * s,
            "P_yy": var_p + along * c * c,
            "P_xy": along * s * c,
        },
        schema_overrides={"time_ns": pl.Int64, "mmsi": pl.Int64, "ais_time_ns": pl.Int64},
    ).sort("time_ns", "mmsi")


def identify(
    system_tracks: pl.DataFrame,
    ais_reports: pl.DataFrame,
    *,
    cfg: AisConfig,
    region: RegionConfig,
) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Match AIS reports to fused tracks and vote each fused point's identity.

    Consumes system_tracks: time_ns, system_track_id, x_enu_m, y_enu_m, sigma_x_m,
    sigma_y_m, cov_xy_m2 (or P_xx, P_yy, P_xy); ais_reports as in :func:`ais_at_epochs`.

    Returns ``(identifications, system_tracks)``: identifications rows (time_ns,
    system_track_id, mmsi, ais_time_ns, mahalanobis_d2), and system_tracks with an
    ``mmsi`` column (int64, null when no identity).
    """
    epochs = system_tracks["time_ns"].unique().sort().to_numpy()
    ais = ais_at_epochs(ais_reports, epochs, cfg=cfg, region=region)
    tracks = system_tracks.sort("time_ns", "system_track_id")
    matches = _match(tracks, ais, gate_threshold(cfg.gate_probability))
    mmsi = vote_identity_rows(
        tracks["time_ns"].to_numpy(),
        tracks["system_track_id"].to_numpy(),
        matches,
        cfg.identity_window_s,
        cfg.min_identity_matches,
    )
    out = tracks.drop("mmsi", strict=False).with_columns(mmsi)
    return matches, out


def _match(tracks: pl.DataFrame, ais: pl.DataFrame, gate: float) -> pl.DataFrame:
    """One-to-one gated matches per epoch, vectorised over all epochs: the AIS points
    that can pass the gate are found by a grid join (``pipeline.spatial``; |D|^2 <=
    d^2 lambda_max(P_t + P_a) bounds the distance of a gated pair), their d^2 computed
    pair by pair, then :func:`~pipeline.maritime.associate.assign_grouped` makes the
    assignment of every epoch (lone pairs at once, a linear_sum_assignment only where
    gates overlap). Same matches as :func:`_match_reference` (dense matrix per epoch)."""
    tt, at = tracks["time_ns"].to_numpy(), ais["time_ns"].to_numpy()
    epochs = np.intersect1d(tt, at)
    tP, aP = position_covariance(tracks), position_covariance(ais)
    ti, ai = _in_epochs(tt, epochs), _in_epochs(at, epochs)
    tx, ty = tracks["x_enu_m"].to_numpy(), tracks["y_enu_m"].to_numpy()
    ax, ay = ais["x_enu_m"].to_numpy(), ais["y_enu_m"].to_numpy()
    r_t, r_a = _gate_radius(tP, gate), _gate_radius(aP, gate)
    r_a_max = float(r_a[ai].max()) if ai.size else 0.0
    i, j, _ = pairs_within(
        np.searchsorted(epochs, tt[ti]), tx[ti], ty[ti], r_t[ti] + r_a_max,
        np.searchsorted(epochs, at[ai]), ax[ai], ay[ai], cell_m=1000.0,
    )
    i, j = ti[i], ai[j]
    dx = tx[i] - ax[j]
    dy = ty[i] - ay[j]
    sxx, syy, sxy = (tP[k][i] + aP[k][j] for k in range(3))
    d2 = (syy * dx * dx - 2.0 * sxy * dx * dy + sxx * dy * dy) / (sxx * syy - sxy * sxy)
    keep = d2 < gate
    i, j, d2 = i[keep], j[keep], d2[keep]
    group = np.searchsorted(epochs, tt)
    r, c = assign_grouped(i, j, d2, np.full(tt.size, gate), group, at.size)
    pair_d2 = _pair_lookup(i, j, d2, r, c)
    return _matches_frame(tracks, ais, r, c, pair_d2)


def _in_epochs(t: np.ndarray, epochs: np.ndarray) -> np.ndarray:
    """Indices of the rows whose time is one of ``epochs`` (sorted)."""
    pos = np.searchsorted(epochs, t)
    return np.flatnonzero((pos < epochs.size) & (epochs[np.minimum(pos, epochs.size - 1)] == t))


def _gate_radius(P: tuple[np.ndarray, ...], gate: float) -> np.ndarray:
    """sqrt(gate * lambda_max(P)) per row (slightly widened); inf where P is not positive
    definite (such a row is compared with every point of its epoch)."""
    a, c, b = (np.asarray(x, float) for x in P)
    h = 0.5 * (a - c)
    lam = 0.5 * (a + c) + np.sqrt(h * h + b * b)
    ok = (a > 0) & (c > 0) & (a * c - b * b > 0) & np.isfinite(lam)
    return np.where(ok, np.sqrt(gate * np.where(ok, lam, 0.0)) * (1 + 1e-9) + 1e-6, np.inf)


def _pair_lookup(i: np.ndarray, j: np.ndarray, v: np.ndarray, r: np.ndarray, c: np.ndarray
                 ) -> np.ndarray:
    """v of the pairs (r, c), looked up among the pairs (i, j) (sorted by (i, j))."""
    order = np.lexsort((j, i))
    i, j, v = i[order], j[order], v[order]
    key = i.astype(np.int64) * (int(j.max()) + 1 if j.size else 1) + j
    q = r.astype(np.int64) * (int(j.max()) + 1 if j.size else 1) + c
    return v[np.searchsorted(key, q)]


def _matches_frame(tracks: pl.DataFrame, ais: pl.DataFrame, ti: np.ndarray, ai: np.ndarray,
                   d2: np.ndarray) -> pl.DataFrame:
    return pl.DataFrame(
        {
            "time_ns": tracks["time_ns"].to_numpy()[ti],
            "system_track_id": tracks["system_track_id"].to_numpy()[ti],
            "mmsi": ais["mmsi"].to_numpy()[ai],
            "ais_time_ns": ais["ais_time_ns"].to_numpy()[ai],
            "mahalanobis_d2": d2,
        },
        schema={
            "time_ns": pl.Int64,
            "system_track_id": pl.Int64,
            "mmsi": pl.Int64,
            "ais_time_ns": pl.Int64,
            "mahalanobis_d2": pl.Float64,
        },
    )


def _match_reference(tracks: pl.DataFrame, ais: pl.DataFrame, gate: float) -> pl.DataFrame:
    """One-to-one gated matches per epoch, one dense (n_tracks, n_mmsi) d^2 matrix and one
    :func:`~pipeline.maritime.associate.assign` per epoch (the reference of
    :func:`_match`; quadratic in the number of ships)."""
    tt, at = tracks["time_ns"].to_numpy(), ais["time_ns"].to_numpy()
    tx, ty = tracks["x_enu_m"].to_numpy(), tracks["y_enu_m"].to_numpy()
    ax, ay = ais["x_enu_m"].to_numpy(), ais["y_enu_m"].to_numpy()
    tP, aP = position_covariance(tracks), position_covariance(ais)
    epochs = np.intersect1d(tt, at)
    t_lo, t_hi = np.searchsorted(tt, epochs, "left"), np.searchsorted(tt, epochs, "right")
    a_lo, a_hi = np.searchsorted(at, epochs, "left"), np.searchsorted(at, epochs, "right")
    ti_all, ai_all, d2_all = [], [], []
    for i0, i1, j0, j1 in zip(t_lo, t_hi, a_lo, a_hi, strict=True):
        dx = tx[i0:i1, None] - ax[None, j0:j1]
        dy = ty[i0:i1, None] - ay[None, j0:j1]
        sxx, syy, sxy = (tP[k][i0:i1, None] + aP[k][None, j0:j1] for k in range(3))
        d2 = (syy * dx * dx - 2.0 * sxy * dx * dy + sxx * dy * dy) / (sxx * syy - sxy * sxy)
        d2 = np.where(d2 < gate, d2, np.inf)
        if not np.isfinite(d2).any():
            continue
        r, c = assign(d2, gate)
        ti_all.append(i0 + r)
        ai_all.append(j0 + c)
        d2_all.append(d2[r, c])
    ti = np.concatenate(ti_all) if ti_all else np.empty(0, int)
    ai = np.concatenate(ai_all) if ai_all else np.empty(0, int)
    return _matches_frame(tracks, ais, ti, ai,
                          np.concatenate(d2_all) if d2_all else np.empty(0))


def vote_identity_rows(
    t: np.ndarray, sid: np.ndarray, matches: pl.DataFrame, window_s: float,
    min_matches: int = 3,
) -> pl.Series:
    """:func:`vote_identity` for points (t, sid) sorted by (t, sid), as an ``mmsi``
    Series aligned with the points (null: no identity); the same votes, on arrays.

    Counts and d^2 sums of each (track, MMSI) run of matches are read at t + W and just
    before t - W by ``searchsorted`` on one integer key (run rank, time offset) instead of
    two ``join_asof``; each run's d^2 is summed in order, as polars' ``cum_sum``."""
    n = t.size
    out = pl.Series("mmsi", np.zeros(n, np.int64)).set(pl.Series(np.ones(n, bool)), None)
    if n == 0 or matches.height == 0:
        return out
    w = round(window_s * NS)
    mt = matches["time_ns"].to_numpy()
    ms = matches["system_track_id"].to_numpy()
    mm = matches["mmsi"].to_numpy()
    md2 = matches["mahalanobis_d2"].to_numpy()
    base = int(min(mt.min(), t.min())) - w - 2
    span = int(max(mt.max(), t.max())) + w + 2 - base
    bits = span.bit_length()
    # runs of (track, MMSI) in time order; per run: counts and d^2 sums in order
    o = np.lexsort((mt, mm, ms))
    rs, rm, rt, rd2 = ms[o], mm[o], mt[o], md2[o]
    new = np.r_[True, (rs[1:] != rs[:-1]) | (rm[1:] != rm[:-1])]
    starts = np.flatnonzero(new)
    if starts.size >= 1 << (62 - bits):  # pragma: no cover - keys would overflow
        return _vote_via_frames(t, sid, matches, window_s, min_matches)
    run = np.cumsum(new) - 1
    size = np.diff(np.r_[starts, rs.size])
    cum = np.empty(rs.size)
    cum[starts] = rd2[starts]
    for k in range(1, int(size.max())):
        idx = starts[size > k] + k
        cum[idx] = cum[idx - 1] + rd2[idx]
    run_key = (run << bits) + (rt - base)
    # queries: each point x each MMSI matched on its track
    run_sid = rs[starts]
    lo = np.searchsorted(run_sid, sid, "left")
    hi = np.searchsorted(run_sid, sid, "right")
    p, r = expand_ranges(lo, hi)
    if p.size == 0:
        return out
    tp = t[p]

    def upto(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(matches of run r with time <= q, their d^2 sum)."""
        k = np.searchsorted(run_key, (r << bits) + (q - base), "right")
        cnt = k - starts[r]
        d2 = np.where(cnt > 0, cum[np.maximum(k - 1, 0)], 0.0)
        return cnt, d2

    n_hi, d_hi = upto(tp + w)
    n_lo, d_lo = upto(tp - w - 1)
    count = n_hi - n_lo
    d2sum = d_hi - d_lo
    # each MMSI's matches on any track within the window
    om = np.lexsort((mt, mm))
    mm_sorted, mt_sorted = mm[om], mt[om]
    m_new = np.r_[True, mm_sorted[1:] != mm_sorted[:-1]]
    m_rank = np.cumsum(m_new) - 1
    m_key = (m_rank << bits) + (mt_sorted - base)
    mmsi_of_run = rm[starts][r]
    qr = np.searchsorted(mm_sorted[m_new], mmsi_of_run)
    total = (np.searchsorted(m_key, (qr << bits) + (tp + w - base), "right")
             - np.searchsorted(m_key, (qr << bits) + (tp - w - 1 - base), "right"))
    ok = (count >= min_matches) & (2 * count > total) & (count > 0)
    p, count, d2sum, mmsi_c = p[ok], count[ok], d2sum[ok], mmsi_of_run[ok]
    best = np.lexsort((mmsi_c, d2sum, -count, p))
    first = best[np.r_[True, p[best][1:] != p[best][:-1]]] if best.size else best
    values = np.zeros(n, np.int64)
    has = np.zeros(n, bool)
    values[p[first]] = mmsi_c[first]
    has[p[first]] = True
    return pl.Series("mmsi", values).set(pl.Series(~has), None)


def _vote_via_frames(t: np.ndarray, sid: np.ndarray, matches: pl.DataFrame, window_s: float,
                     min_matches: int) -> pl.Series:
    points = pl.DataFrame({"time_ns": t, "system_track_id": sid})
    voted = vote_identity(points, matches, window_s, min_matches)
    return points.join(voted, on=["time_ns", "system_track_id"], how="left")["mmsi"]


def vote_identity(
    points: pl.DataFrame, matches: pl.DataFrame, window_s: float, min_matches: int = 3
) -> pl.DataFrame:
    """Identity of each (time_ns, system_track_id) point: most matches within +-window_s
    on the same track, ties -> smaller summed d^2, then smaller MMSI.

    Mutual support: an MMSI is a candidate only when this track holds the majority of
    that MMSI's matches in the window (it is the MMSI's main track) and at least
    ``min_matches`` of them; otherwise a ship without AIS sailing in the lane
    of an AIS ship inherits its MMSI from one stray gated match.

    Vectorised: cumulative match counts / d^2 per (track, MMSI) are read at t + W and
    just before t - W with two ``join_asof`` calls. Returns time_ns, system_track_id,
    mmsi for the points that have an identity.
    """
    w = round(window_s * NS)
    key = ["system_track_id", "mmsi"]
    cum = (
        matches.sort(*key, "time_ns")
        .with_columns(
            pl.int_range(1, pl.len() + 1).over(key).alias("n"),
            pl.col("mahalanobis_d2").cum_sum().over(key).alias("d2"),
        )
        .select(*key, "time_ns", "n", "d2")
        .sort("time_ns")
    )
    queries = points.join(matches.select(key).unique(), on="system_track_id", how="inner")

    def cum_at(t: pl.Expr) -> pl.DataFrame:
        q = queries.with_columns(t.alias("_t")).sort("_t")
        return q.join_asof(
            cum.rename({"time_ns": "_t"}),
            on="_t",
            by=key,
            strategy="backward",
            check_sortedness=False,
        ).select("time_ns", *key, pl.col("n").fill_null(0), pl.col("d2").fill_null(0.0))

    hi = cum_at(pl.col("time_ns") + w)
    lo = cum_at(pl.col("time_ns") - w - 1)
    counts = hi.join(lo, on=["time_ns", *key], suffix="_lo").select(
        "time_ns",
        *key,
        (pl.col("n") - pl.col("n_lo")).alias("count"),
        (pl.col("d2") - pl.col("d2_lo")).alias("d2sum"),
    )
    totals = _mmsi_totals(counts.select("time_ns", "mmsi").unique(), matches, w)
    counts = counts.join(totals, on=["time_ns", "mmsi"], how="left").filter(
        (pl.col("count") >= min_matches) & (2 * pl.col("count") > pl.col("total"))
    )
    return (
        counts.filter(pl.col("count") > 0)
        .sort(
            ["time_ns", "system_track_id", "count", "d2sum", "mmsi"],
            descending=[False, False, True, False, False],
        )
        .unique(["time_ns", "system_track_id"], keep="first", maintain_order=True)
        .select("time_ns", "system_track_id", "mmsi")
    )


def _mmsi_totals(queries: pl.DataFrame, matches: pl.DataFrame, w: int) -> pl.DataFrame:
    """Matches of each MMSI to any track within +-w ns of each queried (time_ns, mmsi)."""
    cum = (
        matches.sort("mmsi", "time_ns")
        .with_columns(pl.int_range(1, pl.len() + 1).over("mmsi").alias("n"))
        .select("mmsi", "time_ns", "n")
        .sort("time_ns")
    )

    def at(t: pl.Expr) -> pl.DataFrame:
        q = queries.with_columns(t.alias("_t")).sort("_t")
        return q.join_asof(
            cum.rename({"time_ns": "_t"}),
            on="_t",
            by="mmsi",
            strategy="backward",
            check_sortedness=False,
        ).select("time_ns", "mmsi", pl.col("n").fill_null(0))

    hi, lo = at(pl.col("time_ns") + w), at(pl.col("time_ns") - w - 1)
    return hi.join(lo, on=["time_ns", "mmsi"], suffix="_lo").select(
        "time_ns", "mmsi", (pl.col("n") - pl.col("n_lo")).alias("total")
    )
