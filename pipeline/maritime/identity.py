"""AIS identification of fused system tracks: gated AIS-to-track matches, then a
sequential test that confirms (and withdraws) each track's MMSI.

Per synchronised epoch (the same test as track-to-track association, two-radar
identification paper eq. 7-16 with AIS as the second "radar"):

1. AIS picture: for each MMSI its latest report with ais_time <= epoch and
   epoch - ais_time <= max_report_age_s, extrapolated to the epoch with its SOG/COG
   (multi-radar paper eq. 9). Its covariance is kept simple:

   .. math:: P_{AIS} = \\sigma_p^2 I + (\\sigma_{SOG} \\Delta t)^2\\, u u^T,
             \\qquad u = (\\sin COG, \\cos COG)

   (GNSS position sigma_position_m, plus the along-track effect of the SOG error; COG
   error and AIS latency are ignored). A report without SOG or COG is not extrapolated.
2. gate: d^2 = D^T S^-1 D < gamma = chi2.ppf(gate_probability, 2), S = P_fused + P_AIS
   (the exponent of two-radar paper eq. 10);
3. one-to-one per epoch: least summed d^2 (``linear_sum_assignment``, gate as the cost
   of leaving a track unmatched; two-radar paper eq. 16).

**Confirmed identity** (:func:`confirmed_identity`). Every (track s, MMSI m) pair that
matched at least once is a hypothesis H1 "AIS target m is ship s" against H0 "m is
another ship, or none": Wald's (1945) sequential probability ratio test
(:mod:`pipeline.filters.sequential`) on the epochs where both exist, with per-epoch
log-likelihood ratio

.. math::
    l = \\begin{cases}
      \\min\\bigl(\\ln\\frac{P_M}{P_S} + \\ln\\frac{\\gamma}{2} - \\frac{d^2}{2},\\;
                 \\frac{q_{alt} - q}{2}\\bigr) & \\text{m assigned to s (d}^2\\text{)}\\\\
      \\ln\\frac{1 - P_M}{1 - P_S} & \\text{m reported, not assigned to s}\\\\
      0 & \\text{no AIS picture of m at the epoch}
    \\end{cases}

- P_M = ``match_probability``: the chance a ship's own AIS is assigned to its track at
  an epoch; P_S = ``stray_match_probability``: the chance another ship's AIS is;
- a match under H1 is Gaussian, N(D; 0, S) (two-radar paper eq. 10, the density whose
  exponent is the association's d^2);
  under H0 a stray AIS point is uniform over the gate, whose area is
  pi gamma sqrt(det S): the density ratio is (gamma / 2) exp(-d^2 / 2) (the
  log-likelihood track score of Sittler 1964, as in Blackman & Popoli 1999, with the
  gate as the clutter volume);
- H0 is composite: m may instead be another track s' in its gate. The generalised
  likelihood ratio takes the likelier alternative, so l is at most
  (q_alt - q) / 2 with q = d^2 + ln det S of the pair and q_alt the smallest q of m
  with any other track at the epoch: two tracks a few metres apart, both in m's gate,
  give almost no evidence for either.

The sum is held within Wald's boundaries B = ln(beta / (1 - alpha)),
A = ln((1 - beta) / alpha), with the budget alpha =
``false_identification_probability`` (the chance a pair that is not one ship is ever
confirmed from a fresh start, by Ville's inequality on the likelihood ratio under H0)
and beta = ``missed_identification_probability``. The track takes m when the sum
reaches A and keeps it until the sum falls to B: it drops a confirmed MMSI on the same
test (evidence e^(A-B) against it). A track with several confirmed MMSIs at an epoch
shows the one with the largest sum (then the smaller MMSI).

**Fixed lag** (``identity_lag_s``, :func:`~pipeline.filters.sequential.fixed_lag_decision`).
The batch is offline: a point takes the decision the test reaches next on its pair when
that decision comes at most ``identity_lag_s`` later. A confirmed track is named from
the start of the evidence that confirmed it (the epochs since its sum last touched B),
not from the confirmation on, and a withdrawn MMSI is taken off from the start of the
evidence against it (since the sum last touched A: an association swap's first misses),
never further back than the lag. The test, its budget alpha and its decisions are the
causal ones; only the epochs a decision covers move. ``identity_lag_s = 0`` is the
causal test (a track named from the epoch of its confirmation, what a live picture
shows). The lag is at most ``identity_window_s``, the units' look-ahead: a unit sees every
decision that reaches back into its own epochs, and results do not depend on the cuts.
"""

from __future__ import annotations

import math

import numpy as np
import polars as pl

from pipeline.config import AisConfig, RegionConfig
from pipeline.filters.sequential import (
    fixed_lag_decision,
    held_cumsum,
    held_decision,
    wald_boundaries,
)
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
    lineage: pl.DataFrame | None = None,
) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Match AIS reports to fused tracks and give each fused point its confirmed identity.

    Consumes system_tracks: time_ns, system_track_id, x_enu_m, y_enu_m, sigma_x_m,
    sigma_y_m, cov_xy_m2 (or P_xx, P_yy, P_xy); ais_reports as in :func:`ais_at_epochs`;
    ``lineage``: the track each track split from
    (:func:`~pipeline.maritime.associate.split_parents`; its confirmed identities carry
    over to the split, :func:`confirmed_identity`).

    Returns ``(identifications, system_tracks)``: identifications rows (time_ns,
    system_track_id, mmsi, ais_time_ns, mahalanobis_d2), and system_tracks with an
    ``mmsi`` column (int64, null when no identity is confirmed).
    """
    epochs = system_tracks["time_ns"].unique().sort().to_numpy()
    ais = ais_at_epochs(ais_reports, epochs, cfg=cfg, region=region)
    tracks = system_tracks.sort("time_ns", "system_track_id")
    gate = gate_threshold(cfg.gate_probability)
    pairs = _gated_pairs(tracks, ais, gate)
    matches, rival = _assign(tracks, ais, pairs, gate)
    mmsi = confirmed_identity(tracks, ais, matches.with_columns(rival_llr=rival), cfg, gate,
                              lineage)
    out = tracks.drop("mmsi", strict=False).with_columns(mmsi)
    return matches, out


def _match(tracks: pl.DataFrame, ais: pl.DataFrame, gate: float) -> pl.DataFrame:
    """One-to-one gated matches per epoch, vectorised over all epochs (the same matches
    as :func:`_match_reference`, a dense matrix per epoch)."""
    return _assign(tracks, ais, _gated_pairs(tracks, ais, gate), gate)[0]


def _gated_pairs(tracks: pl.DataFrame, ais: pl.DataFrame, gate: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every (track row i, AIS row j) of one epoch with d^2 < gate: (i, j, d^2, ln det S).

    The AIS points that can pass the gate are found by a grid join (``pipeline.spatial``;
    |D|^2 <= d^2 lambda_max(P_t + P_a) bounds the distance of a gated pair), their d^2
    computed pair by pair."""
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
    det = sxx * syy - sxy * sxy
    d2 = (syy * dx * dx - 2.0 * sxy * dx * dy + sxx * dy * dy) / det
    keep = d2 < gate
    return i[keep], j[keep], d2[keep], np.log(det[keep])


def _assign(tracks: pl.DataFrame, ais: pl.DataFrame,
            pairs: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], gate: float
            ) -> tuple[pl.DataFrame, np.ndarray]:
    """The matches of every epoch from its gated pairs
    (:func:`~pipeline.maritime.associate.assign_grouped`: lone pairs at once, a
    linear_sum_assignment only where gates overlap), and per match the rival term of the
    identity test, (q_alt - q) / 2 with q = d^2 + ln det S (+inf: no other track in the
    AIS point's gate)."""
    i, j, d2, logdet = pairs
    tt = tracks["time_ns"].to_numpy()
    group = np.searchsorted(np.unique(tt), tt)
    r, c = assign_grouped(i, j, d2, np.full(tt.size, gate), group, ais.height)
    pair_d2 = _pair_lookup(i, j, d2, r, c)
    return _matches_frame(tracks, ais, r, c, pair_d2), _rival_llr(i, j, d2 + logdet, r, c)


def _rival_llr(i: np.ndarray, j: np.ndarray, q: np.ndarray, r: np.ndarray, c: np.ndarray
               ) -> np.ndarray:
    """(q of AIS row c with its best other track - q of the match (r, c)) / 2 per match."""
    if r.size == 0:
        return np.empty(0)
    order = np.lexsort((q, j))  # per AIS row, its gated tracks from the likeliest
    i, j, q = i[order], j[order], q[order]
    first = np.searchsorted(j, c, "left")
    n_gated = np.searchsorted(j, c, "right") - first
    best_is_match = i[first] == r
    second = np.where(n_gated > 1, first + 1, first)
    q_best, q_second = q[first], q[second]
    q_match = np.where(best_is_match, q_best, _pair_lookup(i, j, q, r, c))
    q_alt = np.where(best_is_match, np.where(n_gated > 1, q_second, np.inf), q_best)
    return 0.5 * (q_alt - q_match)


def _in_epochs(t: np.ndarray, epochs: np.ndarray) -> np.ndarray:
    """Indices of the rows whose time is one of ``epochs`` (sorted)."""
    if epochs.size == 0:  # no epoch at all (radar without AIS in the window)
        return np.empty(0, dtype=np.int64)
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


def identity_evidence(tracks: pl.DataFrame, ais: pl.DataFrame, matches: pl.DataFrame,
                      cfg: AisConfig, gate: float, extra: pl.DataFrame | None = None
                      ) -> pl.DataFrame:
    """The per-epoch log-likelihood ratio ``llr`` of every candidate pair (module
    docstring): one row per point of a track and MMSI that matched it at least once (or
    is in ``extra``: system_track_id, mmsi), sorted by (system_track_id, mmsi, time_ns).

    Consumes tracks: time_ns, system_track_id; ais (the AIS picture, :func:`ais_at_epochs`):
    time_ns, mmsi; matches: time_ns, system_track_id, mmsi, mahalanobis_d2, rival_llr."""
    key = ["time_ns", "system_track_id", "mmsi"]
    match_llr = (math.log(cfg.match_probability / cfg.stray_match_probability)
                 + math.log(gate / 2.0))
    miss_llr = math.log((1.0 - cfg.match_probability) / (1.0 - cfg.stray_match_probability))
    candidates = matches.select("system_track_id", "mmsi")
    if extra is not None:
        candidates = pl.concat([candidates, extra.select(candidates.columns)])
    candidates = candidates.unique()
    reported = ais.select("time_ns", "mmsi").unique().with_columns(reported=pl.lit(True))
    matched = matches.select(*key, llr_match=pl.min_horizontal(
        match_llr - 0.5 * pl.col("mahalanobis_d2"), pl.col("rival_llr")))
    return (
        tracks.select("time_ns", "system_track_id")
        .join(candidates, on="system_track_id")
        .join(reported, on=["time_ns", "mmsi"], how="left")
        .join(matched, on=key, how="left")
        .select(*key, llr=pl.when(pl.col("llr_match").is_not_null()).then("llr_match")
                .when(pl.col("reported")).then(pl.lit(miss_llr))
                .otherwise(pl.lit(0.0)))
        .sort("system_track_id", "mmsi", "time_ns")
    )


def confirmed_identity(tracks: pl.DataFrame, ais: pl.DataFrame, matches: pl.DataFrame,
                       cfg: AisConfig, gate: float, lineage: pl.DataFrame | None = None
                       ) -> pl.Series:
    """The confirmed MMSI of each point of ``tracks`` (sorted by time_ns,
    system_track_id), as an ``mmsi`` Series aligned with it (null: none confirmed).

    Each pair's test is :func:`~pipeline.filters.sequential.held_cumsum` over its rows of
    :func:`identity_evidence`; all pairs in one scan (segments), no loop over tracks.

    **A split keeps the name.** A track that split from a named one (``lineage``:
    system_track_id, parent_track_id, split_ns) starts its test of each MMSI its parent
    had confirmed at the split where the parent's test stood: confirmed, with the
    parent's sum. Its radar tracks carried that evidence; a track born of them a few
    seconds ago (a faulty radar's reports leaving the gate, the other radar's track
    losing the id) is otherwise unnamed until it gathers the evidence anew, often longer
    than it lives. The same test withdraws an inherited MMSI the evidence turns against
    (with the fixed lag, from the child's first point on)."""
    lo, hi = wald_boundaries(cfg.false_identification_probability,
                             cfg.missed_identification_probability)
    lag_ns = round(cfg.identity_lag_s * NS)
    ev = identity_evidence(tracks, ais, matches, cfg, gate)
    inherited = _inherited(ev, lineage, lo, hi)
    if inherited.height:
        pair = ["system_track_id", "mmsi"]
        # the inherited pairs the child never matched: their evidence is misses and 0s
        unmatched = inherited.select(pair).unique().join(ev.select(pair).unique(), on=pair,
                                                         how="anti")
        ev = pl.concat([
            inherited,
            *(e.with_columns(rank=pl.lit(2, pl.Int8)) for e in (
                ev, identity_evidence(tracks, ais, matches.clear(), cfg, gate,
                                      extra=unmatched))),
        ]).sort("system_track_id", "mmsi", "time_ns", "rank")
    s, confirmed = _sequential_test(ev, lo, hi, lag_ns)
    real = ev["rank"].to_numpy() == 2 if inherited.height else np.ones(ev.height, bool)
    # several confirmed MMSIs on a track: the largest sum (rounded: the scan's sums
    # differ in the last bits with the rows before them), then the smaller MMSI
    best = (
        ev.select("time_ns", "system_track_id", "mmsi")
        .with_columns(score=np.round(s, 6))
        .filter(pl.Series(confirmed & real))
        .sort("score", "mmsi", descending=[True, False])
        .unique(["time_ns", "system_track_id"], keep="first")
    )
    return tracks.select("time_ns", "system_track_id").join(
        best.select("time_ns", "system_track_id", "mmsi"),
        on=["time_ns", "system_track_id"], how="left", maintain_order="left")["mmsi"]


def _segment_starts(ev: pl.DataFrame) -> np.ndarray:
    """True at the first row of each (system_track_id, mmsi) pair of ``ev`` (sorted)."""
    if not ev.height:
        return np.empty(0, bool)
    sid, mmsi = ev["system_track_id"].to_numpy(), ev["mmsi"].to_numpy()
    return np.r_[True, (sid[1:] != sid[:-1]) | (mmsi[1:] != mmsi[:-1])]


def _sequential_test(ev: pl.DataFrame, lo: float, hi: float, lag_ns: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(held sum, fixed-lag decision) of every row of ``ev``, pair by pair."""
    start = _segment_starts(ev)
    s = held_cumsum(ev["llr"].to_numpy(), start, lo, hi)
    return s, fixed_lag_decision(s, start, lo, hi, ev["time_ns"].to_numpy(), lag_ns)


def _inherited(ev: pl.DataFrame, lineage: pl.DataFrame | None, lo: float, hi: float
               ) -> pl.DataFrame:
    """Rows that start a split track's test of each MMSI its parent had confirmed at the
    split (causal decision), at the parent's last point before it: one row of llr ``hi``
    (the test confirmed) and one that brings the sum to the parent's (``rank`` 0 and 1;
    columns of :func:`identity_evidence`)."""
    cols = {"time_ns": pl.Int64, "system_track_id": pl.Int64, "mmsi": pl.Int64,
            "llr": pl.Float64, "rank": pl.Int8}
    if lineage is None or not lineage.height or not ev.height:
        return pl.DataFrame(schema=cols)
    start = _segment_starts(ev)
    s = held_cumsum(ev["llr"].to_numpy(), start, lo, hi)
    state = ev.select("time_ns", "system_track_id", "mmsi").with_columns(
        s=s, up=held_decision(s, start, lo, hi))
    at_split = (
        state.join(lineage.rename({"system_track_id": "child",
                                   "parent_track_id": "system_track_id"}),
                   on="system_track_id")
        .filter(pl.col("time_ns") < pl.col("split_ns"))
        .group_by("child", "mmsi", maintain_order=True).last()
        .filter("up")
    )
    first = at_split.select("time_ns", pl.col("child").alias("system_track_id"), "mmsi",
                            pl.lit(hi).alias("llr"), pl.lit(0, pl.Int8).alias("rank"))
    second = first.with_columns(at_split["s"].alias("llr") - hi, pl.lit(1, pl.Int8).alias("rank"))
    return pl.concat([first, second]).select(
        pl.col(c).cast(t) for c, t in cols.items())
