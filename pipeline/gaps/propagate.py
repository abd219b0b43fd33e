"""The bootstrap particle filter over a batch of gaps (distributed maritime observation
paper, eq. 3-7): lead-in assimilation, propagation across the gap with the admissible
area as the exogenous constraint, the forecast at each time (mean, covariance, the
highest-density region, zone probabilities)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import polars as pl
from scipy.ndimage import gaussian_filter
from scipy.spatial import cKDTree

from pipeline import frames
from pipeline.config import RegionConfig
from pipeline.filters import particle as pf
from pipeline.gaps.config import GapsConfig
from pipeline.gaps.geometry import GapsGeometry
from pipeline.units import NS

KNN_QUERIES = 256
"""Particles whose k-th-neighbour distance gives the HPD bandwidth's median."""


@dataclass(frozen=True)
class LeadIn:
    """Lead-in messages of G gaps as (G, K) arrays; ``valid`` marks real messages, the
    last slot (K-1) is the gap-start message; ``t_s`` is relative to the gap start."""

    valid: np.ndarray
    t_s: np.ndarray
    z: np.ndarray  # (G, K, 2) east, north, m
    R: np.ndarray  # (G, K, 2, 2) m^2
    sog: np.ndarray
    sigma_sog: np.ndarray
    cog: np.ndarray
    sigma_cog: np.ndarray


def lead_in_arrays(leads: pl.DataFrame, gap_ids: np.ndarray, K: int) -> LeadIn:
    """Scatter the lead-in rows of the gaps ``gap_ids`` (sorted) into padded (G, K)
    arrays."""
    G = gap_ids.size
    sub = leads.filter(pl.col("gap_id").is_in(gap_ids.tolist()))
    gi = np.searchsorted(gap_ids, sub["gap_id"].to_numpy())
    k = sub["slot"].to_numpy()

    def scatter(col: str, fill: float = np.nan) -> np.ndarray:
        out = np.full((G, K), fill)
        out[gi, k] = sub[col].cast(pl.Float64).fill_null(np.nan).to_numpy()
        return out

    valid = np.zeros((G, K), bool)
    valid[gi, k] = True
    t_s = np.zeros((G, K))
    t_s[gi, k] = (sub["time_ns"].to_numpy() - sub["gap_start_ns"].to_numpy()) / NS
    R = np.zeros((G, K, 2, 2))
    R[..., 0, 0], R[..., 1, 1], R[..., 0, 1] = (
        scatter("P_xx", 1.0),
        scatter("P_yy", 1.0),
        scatter("P_xy", 0.0),
    )
    R[..., 1, 0] = R[..., 0, 1]
    z = np.stack([scatter("x_enu_m", 0.0), scatter("y_enu_m", 0.0)], axis=-1)
    return LeadIn(
        valid,
        t_s,
        z,
        R,
        scatter("sog_mps"),
        scatter("sigma_sog_mps"),
        scatter("cog_rad"),
        scatter("sigma_cog_rad"),
    )


def initial_particles(
    li: LeadIn, first: np.ndarray, g: GapsConfig, rng: np.random.Generator
) -> np.ndarray:
    """Particles (G, N, 4) drawn at each gap's first lead-in message: position from
    N(z, R), speed from N(SOG, sigma) folded at 0 (uniform in [0, max_speed] when SOG is
    missing), course from N(COG, sigma) (uniform when missing or too slow to tell)."""
    G, N = first.size, g.particles
    rows = np.arange(G)
    z, R = li.z[rows, first], li.R[rows, first]
    L = np.linalg.cholesky(R)
    xy = z[:, None, :] + np.einsum("gij,gnj->gni", L, rng.standard_normal((G, N, 2)))
    sog, s_sog = li.sog[rows, first], li.sigma_sog[rows, first]
    cog, s_cog = li.cog[rows, first], li.sigma_cog[rows, first]
    e = rng.standard_normal((G, N, 2))
    u = rng.random((G, N, 2))
    has_sog = np.isfinite(sog)[:, None]
    speed = np.where(
        has_sog,
        np.abs(np.nan_to_num(sog)[:, None] + np.nan_to_num(s_sog)[:, None] * e[..., 0]),
        u[..., 0] * g.max_speed_mps,
    )
    has_cog = (np.isfinite(cog) & (np.nan_to_num(sog) >= g.course_min_speed_mps))[:, None]
    course = np.where(
        has_cog,
        np.nan_to_num(cog)[:, None] + np.nan_to_num(s_cog)[:, None] * e[..., 1],
        2 * np.pi * u[..., 1],
    )
    return np.concatenate([xy, speed[..., None], np.mod(course, 2 * np.pi)[..., None]], axis=-1)


def _measurement_loglik(
    li: LeadIn, k: int, rows_all: np.ndarray, g: GapsConfig
) -> pf.LogLikelihood:
    """log p(y_k | x) of lead-in slot k (eq. 6): position N(z, R), plus SOG and COG
    (wrapped residual) when reported; COG only above ``course_min_speed_mps``."""

    def loglik(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
        r = rows_all[rows]
        out = pf.gaussian_log_likelihood(li.z[r, k][:, None, :] - x[..., :2], li.R[r, k])
        sog, s_sog = li.sog[r, k][:, None], li.sigma_sog[r, k][:, None]
        has = np.isfinite(sog) & np.isfinite(s_sog)
        out += np.where(
            has,
            -0.5 * ((np.nan_to_num(sog) - x[..., pf.SPEED]) / np.where(has, s_sog, 1.0)) ** 2,
            0.0,
        )
        cog, s_cog = li.cog[r, k][:, None], li.sigma_cog[r, k][:, None]
        has = (
            np.isfinite(cog)
            & np.isfinite(s_cog)
            & (np.nan_to_num(sog, nan=0.0) >= g.course_min_speed_mps)
        )
        dc = frames.wrap_angle(np.nan_to_num(cog) - x[..., pf.COURSE])
        out += np.where(has, -0.5 * (dc / np.where(has, s_cog, 1.0)) ** 2, 0.0)
        return out

    return loglik


def _jitter(x: np.ndarray, rows: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Regularisation kernel (Musso et al. 2001) on position and speed, and on course
    unwrapped around each filter's circular mean."""
    c = x[..., pf.COURSE]
    mean_c = np.arctan2(np.sin(c).mean(axis=1), np.cos(c).mean(axis=1))[:, None]
    y = x.copy()
    y[..., pf.COURSE] = frames.wrap_angle(c - mean_c)
    y = pf.regularise(y, rng, columns=(pf.X, pf.Y, pf.SPEED, pf.COURSE), scale=0.5)
    y[..., pf.SPEED] = np.abs(y[..., pf.SPEED])
    y[..., pf.COURSE] = np.mod(y[..., pf.COURSE] + mean_c, 2 * np.pi)
    return y


@dataclass
class _Track:
    """Per-gap bookkeeping while its filter runs (G,) arrays."""

    log_path_admissible: np.ndarray
    rounds: np.ndarray
    infeasible: np.ndarray


def run_lead_in(
    li: LeadIn, g: GapsConfig, geometry: GapsGeometry | None, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Filter each gap's lead-in messages (predict, eq. 6-7 update, resample); return the
    particles and log-weights at the gap start, (G, N, 4) and (G, N)."""
    G, K = li.valid.shape
    first = np.argmax(li.valid, axis=1)
    x = initial_particles(li, first, g, rng)
    logw = np.full((G, g.particles), -np.log(g.particles))
    t_cur = li.t_s[np.arange(G), first]
    for k in range(1, K):
        rows = np.flatnonzero(li.valid[:, k] & (k > first))
        if rows.size == 0:
            continue
        dt = li.t_s[rows, k] - t_cur[rows]
        res = _step(
            x[rows], logw[rows], dt, g, geometry, rng, loglik=_measurement_loglik(li, k, rows, g)
        )
        x[rows], logw[rows] = res.particles, res.logw
        t_cur[rows] = li.t_s[rows, k]
    return x, logw


def _step(
    x: np.ndarray,
    logw: np.ndarray,
    dt: np.ndarray | float,
    g: GapsConfig,
    geometry: GapsGeometry | None,
    rng: np.random.Generator,
    *,
    loglik: pf.LogLikelihood | None = None,
    exempt: np.ndarray | None = None,
) -> pf.StepResult:
    """One bootstrap step of the filters ``x`` (g, N, 4) over ``dt`` s (scalar or (g,)).
    ``exempt`` (g,) marks filters whose constraint was given up (found infeasible)."""
    dt_rows = np.broadcast_to(np.asarray(dt, float), (x.shape[0],))
    noise = g.noise
    wide = replace(
        noise,
        course_rad_per_sqrt_s=noise.course_rad_per_sqrt_s * g.manoeuvre_noise_factor,
        speed_mps_per_sqrt_s=noise.speed_mps_per_sqrt_s * g.manoeuvre_noise_factor,
    )

    def propagate(p: np.ndarray, rows: np.ndarray, r: np.random.Generator) -> np.ndarray:
        return pf.propagate_speed_course(p, dt_rows[rows], noise, r)

    def manoeuvre(p: np.ndarray, rows: np.ndarray, r: np.random.Generator) -> np.ndarray:
        return pf.propagate_speed_course(p, dt_rows[rows], wide, r)

    free = np.zeros(x.shape[0], bool) if exempt is None else exempt
    admissible = None
    if g.constrain and geometry is not None and geometry.water is not None:

        def admissible(p: np.ndarray, rows: np.ndarray) -> np.ndarray:
            return geometry.inside(p[..., pf.X], p[..., pf.Y]) | free[rows][:, None]

    redraw: tuple[pf.Propagate, ...] = ()
    if g.constraint_mode == "redraw":
        redraw = _redraw_sequence(dt_rows, noise, g)
    return pf.bootstrap_step(
        x,
        logw,
        rng,
        propagate=propagate,
        loglik=loglik,
        admissible=admissible,
        replenish_with=(propagate, manoeuvre),
        max_rounds=g.replenish_rounds,
        min_ess=max(g.min_ess_fraction * g.particles, 1.0),
        ess_fraction=g.ess_fraction,
        jitter=_jitter,
        regularise_below=g.regularise_below,
        redraw=redraw,
    )


def _redraw_sequence(
    dt_rows: np.ndarray, noise: pf.MotionNoise, g: GapsConfig
) -> tuple[pf.Propagate, ...]:
    """Transitions tried, in turn, for a particle predicted onto land: twice as
    predicted, then a forced turn ("manoeuvre") of growing size, sigma = 90 deg * k / K,
    k = 1..K (K = redraw_tries - 2): a ship that meets the coast turns along it."""

    def make(n: pf.MotionNoise) -> pf.Propagate:
        def prop(p: np.ndarray, rows: np.ndarray, r: np.random.Generator) -> np.ndarray:
            return pf.propagate_speed_course(p, dt_rows[rows], n, r)

        return prop

    K = max(g.redraw_tries - 2, 0)
    turns = [
        replace(noise, turn_rate_per_s=1e6, turn_sigma_rad=0.5 * np.pi * k / K)
        for k in range(1, K + 1)
    ]
    return (make(noise),) * min(g.redraw_tries, 2) + tuple(make(n) for n in turns)


@dataclass(frozen=True)
class Reference:
    """Reference positions (G_rows,) for the planned rows: ENU, NaN when unknown."""

    x: np.ndarray
    y: np.ndarray


def propagate_gaps(
    x: np.ndarray,
    logw: np.ndarray,
    schedule: Sequence[tuple[float, np.ndarray, np.ndarray]],
    g: GapsConfig,
    geometry: GapsGeometry | None,
    region: RegionConfig,
    ref: Reference,
    rng: np.random.Generator,
) -> dict[str, np.ndarray]:
    """Carry the gap-start particles across the gaps with the constraint only, recording
    the forecast statistics at the scheduled lead times.

    ``schedule``: (lead_s, local gap rows (r,), plan rows (r,)) in increasing lead; the
    filters step every ``step_s`` and at each scheduled lead. Returns column arrays
    indexed by plan row (see :func:`_record`).
    """
    G = x.shape[0]
    last_lead = np.zeros(G)
    for lead, rows, _ in schedule:
        last_lead[rows] = np.maximum(last_lead[rows], lead)
    leads = sorted(
        {round(s, 3) for s, _, _ in schedule}
        | set(np.arange(g.step_s, last_lead.max() + 1e-9, g.step_s).round(3))
    )
    by_lead = {round(s, 3): (rows, plan) for s, rows, plan in schedule}
    track = _Track(np.zeros(G), np.zeros(G, np.int64), np.zeros(G, bool))
    ess = np.full(G, float(g.particles))
    xw, lww = x.copy(), logw.copy()  # weighted sample before resampling, for the records
    out: dict[str, list[np.ndarray]] = {}
    t = 0.0
    for lead in leads:
        active = np.flatnonzero(last_lead >= lead - 1e-9)
        res = _step(
            x[active], logw[active], lead - t, g, geometry, rng, exempt=track.infeasible[active]
        )
        x[active], logw[active] = res.particles, res.logw
        xw[active], lww[active] = res.weighted, res.weighted_logw
        ess[active] = res.ess
        with np.errstate(divide="ignore"):
            track.log_path_admissible[active] += np.log(res.admissible_mass)
        track.rounds[active] += res.rounds
        track.infeasible[active] |= res.infeasible
        t = lead
        if lead in by_lead:
            rows, plan = by_lead[lead]
            rec = _record(
                xw[rows], lww[rows], ess[rows], track, rows, plan, g, geometry, region, ref
            )
            for k, v in rec.items():
                out.setdefault(k, []).append(v)
    return {k: np.concatenate(v) for k, v in out.items()}


def _record(
    x: np.ndarray,
    logw: np.ndarray,
    ess: np.ndarray,
    track: _Track,
    rows: np.ndarray,
    plan: np.ndarray,
    g: GapsConfig,
    geometry: GapsGeometry | None,
    region: RegionConfig,
    ref: Reference,
) -> dict[str, np.ndarray]:
    """Forecast statistics of the filters ``rows`` (their particles ``x``, ``logw``)."""
    mean, cov = pf.weighted_mean_cov(x[..., :2], logw)
    w = pf.normalised_weights(logw)
    vx = np.einsum("gn,gn->g", w, x[..., pf.SPEED] * np.sin(x[..., pf.COURSE]))
    vy = np.einsum("gn,gn->g", w, x[..., pf.SPEED] * np.cos(x[..., pf.COURSE]))
    rx, ry = ref.x[plan], ref.y[plan]
    spread = np.einsum(
        "gn,gn->g", w, np.hypot(x[..., pf.X] - rx[:, None], x[..., pf.Y] - ry[:, None])
    )
    area, inside = np.zeros(rows.size), np.zeros(rows.size, bool)
    for i in range(rows.size):  # one highest-density region per forecast row
        area[i], inside[i] = hpd_region(
            x[i, :, :2], w[i], g.region_probability, np.array([[rx[i], ry[i]]])
        )
    zones = _zone_probabilities(x, w, geometry)
    lat, lon = frames.enu_to_geodetic(
        mean[:, 0], mean[:, 1], region.origin_lat_deg, region.origin_lon_deg
    )
    return {
        "plan_row": plan,
        "x_enu_m": mean[:, 0],
        "y_enu_m": mean[:, 1],
        "lat_deg": np.atleast_1d(lat),
        "lon_deg": np.atleast_1d(lon),
        "sigma_x_m": np.sqrt(cov[:, 0, 0]),
        "sigma_y_m": np.sqrt(cov[:, 1, 1]),
        "cov_xy_m2": cov[:, 0, 1],
        "speed_mps": np.hypot(vx, vy),
        "course_rad": np.mod(np.arctan2(vx, vy), 2 * np.pi),
        "region_area_m2": area,
        "true_in_region90": inside,
        "expected_error_m": spread,
        "effective_sample_size": ess,
        "constraint_mass_removed": np.clip(-np.expm1(track.log_path_admissible[rows]), 0.0, 1.0),
        "prior_draw_rounds": track.rounds[rows].copy(),
        "constraint_infeasible": track.infeasible[rows].copy(),
        "zone_p": zones,
    }


def _zone_probabilities(x: np.ndarray, w: np.ndarray, geometry: GapsGeometry | None) -> np.ndarray:
    """(r, Z + 1) particle mass per zone (first containing zone) and outside all zones."""
    nz = 0 if geometry is None else len(geometry.zones)
    if nz == 0:
        return np.ones((x.shape[0], 1))
    idx = geometry.zone_index(x[..., pf.X], x[..., pf.Y])  # (r, N)
    return np.stack([np.sum(np.where(idx == k, w, 0.0), axis=1) for k in range(nz + 1)], axis=1)


def hpd_region(
    xy: np.ndarray, w: np.ndarray, probability: float, refs: np.ndarray
) -> tuple[float, np.ndarray]:
    """Highest-density region of a weighted particle cloud (Hyndman 1996, "Computing
    and graphing highest density regions"): f is a Gaussian kernel density estimate
    binned on a grid; the region is {f >= f_a}, f_a the weighted (1 - probability)
    quantile of f at the particles, so it holds ``probability`` of the particle mass.

    Bandwidth: isotropic, from the median distance r_k to the k-th nearest particle
    (k = 10): h = r_k n^(1/3) / (2 sqrt(k)), n the effective sample size. For one
    Gaussian blob this is Silverman's h = sigma n^(-1/6) (a median point of a 2-D
    Gaussian has density 1 / (4 pi sigma^2), so r_k = 2 sigma sqrt(k / n)); unlike
    Silverman's rule it does not over-smooth a cloud split into several modes
    (the constraint often splits one), because it measures the spread locally.

    Returns (area of the region, m^2; whether each of ``refs`` (k, 2) lies in it).
    NaN references are outside.
    """
    keep = w > 0
    xy, w = xy[keep], w[keep] / w[keep].sum()
    n_eff = 1.0 / np.sum(w * w)
    h = _knn_bandwidth(xy, n_eff)
    lo, hi = xy.min(axis=0) - 3 * h, xy.max(axis=0) + 3 * h
    n_cells = np.clip(np.ceil((hi - lo) / (0.5 * h)), 16, 512).astype(int)
    cell = (hi - lo) / n_cells
    hist, _, _ = np.histogram2d(
        xy[:, 0], xy[:, 1], bins=n_cells, range=list(zip(lo, hi, strict=True)), weights=w
    )
    dens = gaussian_filter(hist, sigma=h / cell, mode="constant", truncate=3.0)
    ij = np.clip(((xy - lo) / cell).astype(int), 0, n_cells - 1)
    f = dens[ij[:, 0], ij[:, 1]]
    order = np.argsort(f)
    cum = np.cumsum(w[order])
    level = f[order][min(np.searchsorted(cum, 1.0 - probability, side="right"), f.size - 1)]
    area = float(np.count_nonzero(dens >= level) * cell[0] * cell[1])
    rij = np.floor((refs - lo) / cell)
    ok = np.all(np.isfinite(rij), axis=1) & np.all((rij >= 0) & (rij < n_cells), axis=1)
    rij = np.where(ok[:, None], rij, 0).astype(int)
    return area, ok & (dens[rij[:, 0], rij[:, 1]] >= level)


def _knn_bandwidth(xy: np.ndarray, n_eff: float, k: int = 10,
                   max_queries: int = KNN_QUERIES) -> float:
    """Kernel bandwidth (m) from the median k-th-nearest-neighbour distance (see
    :func:`hpd_region`); at least 1 m. The distinct particles (a resampled cloud repeats
    them) are the neighbours; the median is taken over at most ``max_queries`` of them,
    evenly spaced in (x, y) order (a median's standard error over 256 points is ~8 % of
    the spread of r_k, well inside what the kernel estimate tolerates; querying all 2,000
    was most of the forecast's time)."""
    pts = np.unique(xy[:, 0] + 1j * xy[:, 1])  # distinct (x, y), sorted: complex sorts x, y
    if pts.size <= k:
        return max(float(np.sqrt(np.mean(np.var(xy, axis=0)))), 1.0)
    pts = np.column_stack([pts.real, pts.imag])
    queries = pts[:: -(-pts.shape[0] // max_queries)]
    r_k = np.median(cKDTree(pts).query(queries, k=k + 1)[0][:, k])
    return max(float(r_k * n_eff ** (1.0 / 3.0) / (2.0 * np.sqrt(k))), 1.0)


