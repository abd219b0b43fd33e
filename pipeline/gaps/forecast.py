"""Forecasts across data gaps: where is a ship that has not been seen for a while?

Distributed maritime observation paper (``seeds/``, rough Russian OCR), eq. 1 and 3-7.

1. **Messages** (eq. 1): every observation of a vessel becomes the paper's message
   vector C_ij = [i, j, K, phi, lambda, h, k, v, P, t]: source i (``ais`` or
   ``system_track``), object j (the MMSI), class K (AIS class A/B, or ``radar``),
   position, course, speed, flags P (new / manoeuvre / lost) and time, with the
   position covariance of eq. 2 (sigma_x^2, sigma_y^2, K_xy) and course/speed sigmas.
   AIS reports carry the configured AIS sigmas; fused system tracks that the maritime
   batch identified (``system_tracks.mmsi``) carry their own.
2. **Gaps**: a vessel unobserved for longer than ``gap_threshold_s`` between two
   messages (or from its last message to the end of the data read) is in a gap.
3. **Filter**: a bootstrap particle filter (:mod:`pipeline.filters.particle`) is run
   over the vessel's last messages before the gap (the "lead-in": likelihood eq. 6,
   weights eq. 7) and then carried across the gap with the exogenous constraint only:
   u_k uniform over the admissible area (water minus islands, config polygons), zero
   outside, so particles that reach land get weight 0, are resampled away, and, when
   nothing admissible is left, more particles are drawn from the prior (the paper's
   remedy for degenerate weights; then a wider "manoeuvre" prior).
4. **Forecasts** at configured lead times after the gap start and at the gap's end
   (when the vessel reappears): the particle mean and covariance, the 90% region (a
   highest-density region of the particle cloud, Hyndman 1996), and the probability
   of each named zone = the share of particle mass in it (the paper: "the posterior
   probability of reaching a zone is estimated as the share of sample values in it").
   When simulated truth exists, the true position at the forecast time, its error and
   whether it fell in the 90% region; at the gap end without truth, the reappearing
   message is the reference.

Every function here is pure: tables, window and config in, tables out; randomness
only from the ``rng`` argument.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import polars as pl
import shapely
from scipy.ndimage import gaussian_filter
from scipy.spatial import cKDTree

from pipeline import frames, tables
from pipeline.config import AisConfig, Config, RegionConfig
from pipeline.filters import particle as pf
from pipeline.gaps.config import GapsConfig, NamedPolygon
from pipeline.geometry import assign_sectors
from pipeline.units import NS

OUTSIDE_ZONES = "(outside zones)"
"""Key of the probability mass outside every named zone in ``zone_probabilities_json``."""


# --- geometry --------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class GapsGeometry:
    """The exogenous constraint and the named zones in the regional ENU plane (m).

    ``water``: the admissible area (union of the admissible polygons minus the
    islands), or ``None`` when the config gives no geometry (no constraint).
    ``zones``: (name, polygon) in config order; a point belongs to the first zone that
    contains it, so zone probabilities add up to at most 1.
    """

    water: shapely.Geometry | None
    zones: tuple[tuple[str, shapely.Geometry], ...] = field(default=())

    def inside(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """u_k(x) > 0: the points (any shape) lie in the admissible area."""
        if self.water is None:
            return np.ones(np.shape(x), bool)
        return shapely.contains_xy(self.water, x, y)

    def zone_index(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Index of the first zone containing each point, ``len(zones)`` when none."""
        idx = np.full(np.shape(x), len(self.zones))
        for k, (_, poly) in enumerate(self.zones):
            free = idx == len(self.zones)
            idx[free & shapely.contains_xy(poly, x, y)] = k
        return idx


def _enu_polygon(p: NamedPolygon, region: RegionConfig) -> shapely.Polygon:
    lat, lon = np.array(p.polygon_lat_lon_deg, float).T
    e, n = frames.geodetic_to_enu(lat, lon, region.origin_lat_deg, region.origin_lon_deg)
    return shapely.make_valid(shapely.Polygon(np.column_stack([e, n])))


def build_geometry(g: GapsConfig, region: RegionConfig) -> GapsGeometry:
    """Shapely geometry (prepared for ``contains_xy``) of the constraint and the zones."""
    water = None
    if g.admissible or g.islands:
        if g.admissible:
            water = shapely.union_all([_enu_polygon(p, region) for p in g.admissible])
        else:  # islands only: everything but the islands is admissible
            water = shapely.box(-1e8, -1e8, 1e8, 1e8)
        if g.islands:
            water = water.difference(
                shapely.union_all([_enu_polygon(p, region) for p in g.islands])
            )
        shapely.prepare(water)
    zones = []
    for z in g.zones:
        poly = _enu_polygon(z, region)
        shapely.prepare(poly)
        zones.append((z.name, poly))
    return GapsGeometry(water, tuple(zones))


# --- messages (eq. 1) ------------------------------------------------------------

OBS_SCHEMA: dict[str, pl.DataType] = {
    "time_ns": pl.Int64(),
    "mmsi": pl.Int64(),
    "source": pl.String(),
    "object_class": pl.String(),
    "lat_deg": pl.Float64(),
    "lon_deg": pl.Float64(),
    "x_enu_m": pl.Float64(),
    "y_enu_m": pl.Float64(),
    "P_xx": pl.Float64(),
    "P_yy": pl.Float64(),
    "P_xy": pl.Float64(),
    "sog_mps": pl.Float64(),
    "sigma_sog_mps": pl.Float64(),
    "cog_rad": pl.Float64(),
    "sigma_cog_rad": pl.Float64(),
}


def observations(
    ais_reports: pl.DataFrame,
    system_tracks: pl.DataFrame | None,
    *,
    ais: AisConfig,
    gaps: GapsConfig,
    region: RegionConfig,
) -> pl.DataFrame:
    """The message vectors (eq. 1) of every identified vessel, sorted by (mmsi, time).

    Columns: ``OBS_SCHEMA`` (position covariance ``P_xx, P_yy, P_xy`` in m^2, eq. 2;
    SOG/COG null when not available) plus the flags ``flag_new`` (first message, or
    first after a gap), ``flag_lost`` (last message before a gap or the data's end)
    and ``flag_manoeuvre`` (|dCOG/dt| from the previous message above
    ``manoeuvre_rate_rad_per_s``) and ``next_time_ns`` (the vessel's next message).
    """
    parts = [_ais_messages(ais_reports, ais, gaps, region)]
    if system_tracks is not None and system_tracks.height:
        parts.append(_track_messages(system_tracks))
    obs = pl.concat(parts).sort(["mmsi", "time_ns", "source"])
    return _flags(obs, gaps)


def _ais_messages(
    ais_reports: pl.DataFrame, ais: AisConfig, gaps: GapsConfig, region: RegionConfig
) -> pl.DataFrame:
    if ais_reports.height == 0:
        return pl.DataFrame(schema=OBS_SCHEMA)
    x, y = frames.geodetic_to_enu(
        ais_reports["lat_deg"].to_numpy(),
        ais_reports["lon_deg"].to_numpy(),
        region.origin_lat_deg,
        region.origin_lon_deg,
    )
    var = ais.sigma_position_m**2
    return ais_reports.select(
        pl.col("time_ns"),
        pl.col("mmsi"),
        pl.lit("ais").alias("source"),
        pl.col("ais_class").alias("object_class"),
        pl.col("lat_deg"),
        pl.col("lon_deg"),
        pl.Series("x_enu_m", np.atleast_1d(x)),
        pl.Series("y_enu_m", np.atleast_1d(y)),
        pl.lit(var).alias("P_xx"),
        pl.lit(var).alias("P_yy"),
        pl.lit(0.0).alias("P_xy"),
        pl.col("sog_mps"),
        pl.lit(ais.sigma_sog_mps).alias("sigma_sog_mps"),
        pl.col("cog_rad"),
        pl.lit(gaps.sigma_cog_rad).alias("sigma_cog_rad"),
    ).cast(OBS_SCHEMA)  # type: ignore[arg-type]


def _track_messages(tracks: pl.DataFrame) -> pl.DataFrame:
    return (
        tracks.filter(pl.col("mmsi").is_not_null())
        .select(
            pl.col("time_ns"),
            pl.col("mmsi"),
            pl.lit("system_track").alias("source"),
            pl.lit("radar").alias("object_class"),
            pl.col("lat_deg"),
            pl.col("lon_deg"),
            pl.col("x_enu_m"),
            pl.col("y_enu_m"),
            (pl.col("sigma_x_m") ** 2).alias("P_xx"),
            (pl.col("sigma_y_m") ** 2).alias("P_yy"),
            pl.col("cov_xy_m2").alias("P_xy"),
            pl.col("speed_mps").alias("sog_mps"),
            pl.col("sigma_speed_mps").alias("sigma_sog_mps"),
            pl.col("course_rad").alias("cog_rad"),
            pl.col("sigma_course_rad").alias("sigma_cog_rad"),
        )
        .cast(OBS_SCHEMA)
    )  # type: ignore[arg-type]


def _flags(obs: pl.DataFrame, gaps: GapsConfig) -> pl.DataFrame:
    thr = int(gaps.gap_threshold_s * NS)
    by = "mmsi"
    prev_t = pl.col("time_ns").shift(1).over(by)
    dt_prev_s = (pl.col("time_ns") - prev_t) / NS
    dcog = (pl.col("cog_rad") - pl.col("cog_rad").shift(1).over(by) + math.pi) % (
        2 * math.pi
    ) - math.pi
    return obs.with_columns(
        pl.col("time_ns").shift(-1).over(by).alias("next_time_ns"),
        (prev_t.is_null() | ((pl.col("time_ns") - prev_t) > thr)).alias("flag_new"),
        pl.when(dt_prev_s > 0)
        .then(dcog.abs() / dt_prev_s > gaps.manoeuvre_rate_rad_per_s)
        .otherwise(False)
        .fill_null(False)
        .alias("flag_manoeuvre"),
    )


# --- gaps ------------------------------------------------------------------------


def detect_gaps(obs: pl.DataFrame, *, threshold_s: float, data_end_ns: int) -> pl.DataFrame:
    """One row per gap: a vessel's message followed by more than ``threshold_s`` of
    silence (until its next message, or until ``data_end_ns`` when there is none).

    Columns: mmsi, gap_start_ns (time of the last message), gap_end_ns (the next
    message, null when open), gap_open, source/object_class of the last message,
    manoeuvre_at_gap_start (its manoeuvre flag). Sorted by (mmsi, gap_start_ns).
    """
    thr = int(threshold_s * NS)
    silence_end = pl.coalesce(pl.col("next_time_ns"), pl.lit(int(data_end_ns)))
    return (
        obs.filter((silence_end - pl.col("time_ns")) > thr)
        .select(
            pl.col("mmsi"),
            pl.col("time_ns").alias("gap_start_ns"),
            pl.col("next_time_ns").alias("gap_end_ns"),
            pl.col("next_time_ns").is_null().alias("gap_open"),
            pl.col("source").alias("last_source"),
            pl.col("object_class"),
            pl.col("flag_manoeuvre").alias("manoeuvre_at_gap_start"),
        )
        .sort(["mmsi", "gap_start_ns"])
    )


def mark_lost(obs: pl.DataFrame, gaps: pl.DataFrame) -> pl.DataFrame:
    """Add ``flag_lost`` to the messages: true on the last message before each gap."""
    lost = gaps.select(
        pl.col("mmsi"), pl.col("gap_start_ns").alias("time_ns"), pl.lit(True).alias("flag_lost")
    ).unique(["mmsi", "time_ns"])
    return obs.join(lost, on=["mmsi", "time_ns"], how="left").with_columns(
        pl.col("flag_lost").fill_null(False)
    )


def plan_forecasts(
    gaps: pl.DataFrame, g: GapsConfig, *, start_ns: int, end_ns: int
) -> pl.DataFrame:
    """The forecasts to make in [start_ns, end_ns): one row per (gap, forecast time).

    Lead times: each configured offset (strictly inside a closed gap, any offset for an
    open one) and, when ``forecast_at_gap_end``, the reappearance time of a gap not
    longer than ``max_horizon_s``. Columns: gap_id (row of ``gaps``), mmsi,
    gap_start_ns, forecast_time_ns, lead_ns, forecast_kind (offset | gap_end).
    """
    gaps = gaps.with_row_index("gap_id")
    offsets_ns = pl.Series("lead_ns", [int(o * NS) for o in g.forecast_offsets_s], pl.Int64)
    by_offset = (
        gaps.join(pl.DataFrame(offsets_ns), how="cross")
        .filter(
            pl.col("gap_open") | (pl.col("lead_ns") < pl.col("gap_end_ns") - pl.col("gap_start_ns"))
        )
        .with_columns(pl.lit("offset").alias("forecast_kind"))
    )
    parts = [by_offset]
    if g.forecast_at_gap_end:
        ends = (
            gaps.filter(~pl.col("gap_open"))
            .with_columns(
                (pl.col("gap_end_ns") - pl.col("gap_start_ns")).alias("lead_ns"),
                pl.lit("gap_end").alias("forecast_kind"),
            )
            .filter(pl.col("lead_ns") <= int(g.max_horizon_s * NS))
        )
        parts.append(ends)
    cols = ["gap_id", "mmsi", "gap_start_ns", "lead_ns", "forecast_kind"]
    return (
        pl.concat([p.select(cols) for p in parts])
        .with_columns((pl.col("gap_start_ns") + pl.col("lead_ns")).alias("forecast_time_ns"))
        .filter(pl.col("forecast_time_ns").is_between(start_ns, end_ns, closed="left"))
        .sort(["gap_id", "lead_ns"])
    )


def lead_in(obs: pl.DataFrame, gaps: pl.DataFrame, g: GapsConfig) -> pl.DataFrame:
    """Each gap's last messages before it: those within ``lead_in_s`` of the gap start,
    thinned to at most ``max_lead_in_obs`` (the last one of each lead_in_s / K slice),
    with ``slot`` = K-1 for the gap-start message, K-2 for the one before, ..."""
    K = g.max_lead_in_obs
    slice_ns = max(int(g.lead_in_s * NS / K), 1)
    starts = (
        gaps.with_row_index("gap_id").select("gap_id", "mmsi", "gap_start_ns").sort("gap_start_ns")
    )
    return (
        obs.sort("time_ns")
        .join_asof(
            starts,
            left_on="time_ns",
            right_on="gap_start_ns",
            by="mmsi",
            strategy="forward",
            check_sortedness=False,
        )
        .filter(
            pl.col("gap_id").is_not_null()
            & (pl.col("gap_start_ns") - pl.col("time_ns") <= int(g.lead_in_s * NS))
        )
        .with_columns(((pl.col("gap_start_ns") - pl.col("time_ns")) // slice_ns).alias("_slice"))
        .sort(["gap_id", "time_ns"])
        .group_by(["gap_id", "_slice"], maintain_order=True)
        .last()
        .with_columns(
            (K - pl.col("_slice").rank("ordinal").over("gap_id").cast(pl.Int64)).alias("slot")
        )
        .filter(pl.col("slot") >= 0)
        .drop("_slice")
    )


# --- the particle filter over a batch of gaps -------------------------------------


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


def _knn_bandwidth(xy: np.ndarray, n_eff: float, k: int = 10) -> float:
    """Kernel bandwidth (m) from the median k-th-nearest-neighbour distance (see
    :func:`hpd_region`); at least 1 m."""
    pts = np.unique(xy, axis=0)
    if pts.shape[0] <= k:
        return max(float(np.sqrt(np.mean(np.var(xy, axis=0)))), 1.0)
    r_k = np.median(cKDTree(pts).query(pts, k=k + 1)[0][:, k])
    return max(float(r_k * n_eff ** (1.0 / 3.0) / (2.0 * np.sqrt(k))), 1.0)


# --- references: truth, or the reappearing message ---------------------------------


def truth_at(plan: pl.DataFrame, truth: pl.DataFrame | None) -> pl.DataFrame:
    """Truth of each plan row's vessel (by MMSI) at its forecast time, linearly
    interpolated between the neighbouring truth samples (at most 2 s away).
    Columns: plan_row, true_lat_deg, true_lon_deg (null when no truth)."""
    q = plan.select("plan_row", "mmsi", "forecast_time_ns").sort("forecast_time_ns")
    if truth is None or truth.height == 0:
        return q.select(
            "plan_row",
            pl.lit(None, pl.Float64).alias("true_lat_deg"),
            pl.lit(None, pl.Float64).alias("true_lon_deg"),
        )
    t = (
        truth.filter(pl.col("mmsi").is_not_null())
        .select("mmsi", pl.col("time_ns").alias("t"), "lat_deg", "lon_deg")
        .sort("t")
    )
    tol = 2 * NS
    b = q.join_asof(
        t,
        left_on="forecast_time_ns",
        right_on="t",
        by="mmsi",
        strategy="backward",
        tolerance=tol,
        check_sortedness=False,
    )
    a = q.join_asof(
        t,
        left_on="forecast_time_ns",
        right_on="t",
        by="mmsi",
        strategy="forward",
        tolerance=tol,
        check_sortedness=False,
    ).select(
        "plan_row",
        pl.col("t").alias("t1"),
        pl.col("lat_deg").alias("lat1"),
        pl.col("lon_deg").alias("lon1"),
    )
    m = b.join(a, on="plan_row")
    span = (pl.col("t1") - pl.col("t")).cast(pl.Float64)
    frac = pl.when(span > 0).then((pl.col("forecast_time_ns") - pl.col("t")) / span).otherwise(0.0)
    return m.select(
        "plan_row",
        pl.coalesce(
            pl.col("lat_deg") + frac * (pl.col("lat1") - pl.col("lat_deg")), pl.col("lat1")
        ).alias("true_lat_deg"),
        pl.coalesce(
            pl.col("lon_deg") + frac * (pl.col("lon1") - pl.col("lon_deg")), pl.col("lon1")
        ).alias("true_lon_deg"),
    )


def references(plan: pl.DataFrame, obs: pl.DataFrame, truth: pl.DataFrame | None) -> pl.DataFrame:
    """Reference position of each plan row: truth when the log has it, else (at the gap
    end) the reappearing message. Columns: plan_row, reference, true_lat/lon_deg."""
    tr = truth_at(plan, truth)
    seen = obs.select(
        "mmsi",
        pl.col("time_ns").alias("forecast_time_ns"),
        pl.col("lat_deg").alias("obs_lat"),
        pl.col("lon_deg").alias("obs_lon"),
    ).unique(["mmsi", "forecast_time_ns"], keep="first")
    ends = (
        plan.filter(pl.col("forecast_kind") == "gap_end")
        .join(seen, on=["mmsi", "forecast_time_ns"], how="inner")
        .select("plan_row", "obs_lat", "obs_lon")
    )
    return (
        plan.select("plan_row")
        .join(tr, on="plan_row", how="left")
        .join(ends, on="plan_row", how="left")
        .select(
            "plan_row",
            pl.when(pl.col("true_lat_deg").is_not_null())
            .then(pl.lit("truth"))
            .when(pl.col("obs_lat").is_not_null())
            .then(pl.lit("observation"))
            .otherwise(pl.lit(None, pl.String))
            .alias("reference"),
            pl.coalesce("true_lat_deg", "obs_lat").alias("true_lat_deg"),
            pl.coalesce("true_lon_deg", "obs_lon").alias("true_lon_deg"),
        )
        .sort("plan_row")
    )


# --- the stage -----------------------------------------------------------------------


def empty_forecasts() -> pl.DataFrame:
    """No forecasts: an empty frame with the ``gap_forecasts`` columns."""
    return pl.from_arrow(tables.empty("gap_forecasts"))


def forecast_gaps(
    ais_reports: pl.DataFrame,
    system_tracks: pl.DataFrame | None,
    truth: pl.DataFrame | None,
    *,
    cfg: Config,
    gaps_cfg: GapsConfig,
    start_ns: int,
    end_ns: int,
    data_end_ns: int,
    rng: np.random.Generator,
) -> pl.DataFrame:
    """``gap_forecasts`` rows with forecast time in [start_ns, end_ns).

    Inputs: AIS position reports and fused system tracks (only those with an MMSI are
    used) from ``gaps_cfg.lookback_s`` before the window to ``data_end_ns`` (how far the
    caller read: a silence running to there is an open gap), and truth over the window
    (or None). Pure: the same inputs and rng state give the same rows.
    """
    g = gaps_cfg
    obs = observations(ais_reports, system_tracks, ais=cfg.ais, gaps=g, region=cfg.region)
    if obs.height == 0:
        return empty_forecasts()
    data_end = min(int(data_end_ns), int(obs["time_ns"].max()))
    gaps = detect_gaps(obs, threshold_s=g.gap_threshold_s, data_end_ns=data_end)
    plan = plan_forecasts(gaps, g, start_ns=start_ns, end_ns=end_ns).with_row_index("plan_row")
    if plan.height == 0:
        return empty_forecasts()
    geometry = build_geometry(g, cfg.region)
    refs = references(plan, obs, truth)
    rx, ry = frames.geodetic_to_enu(
        refs["true_lat_deg"].fill_null(np.nan).to_numpy(),
        refs["true_lon_deg"].fill_null(np.nan).to_numpy(),
        cfg.region.origin_lat_deg,
        cfg.region.origin_lon_deg,
    )
    ref = Reference(np.atleast_1d(rx), np.atleast_1d(ry))
    leads = lead_in(obs, gaps, g)
    gap_ids = np.unique(plan["gap_id"].to_numpy())
    records = [
        _run_batch(gap_ids[i : i + g.batch_gaps], plan, leads, g, geometry, cfg.region, ref, rng)
        for i in range(0, gap_ids.size, g.batch_gaps)
    ]
    stats = {k: np.concatenate([r[k] for r in records]) for k in records[0]}
    return _assemble(plan, gaps, leads, refs, ref, stats, g, geometry, cfg)


def _run_batch(
    gap_ids: np.ndarray,
    plan: pl.DataFrame,
    leads: pl.DataFrame,
    g: GapsConfig,
    geometry: GapsGeometry,
    region: RegionConfig,
    ref: Reference,
    rng: np.random.Generator,
) -> dict[str, np.ndarray]:
    """Lead-in filter and gap propagation for one batch of gaps (vectorised over them)."""
    li = lead_in_arrays(leads, gap_ids, g.max_lead_in_obs)
    x, logw = run_lead_in(li, g, geometry, rng)
    mine = plan.filter(pl.col("gap_id").is_in(gap_ids.tolist())).with_columns(
        (pl.col("lead_ns") / NS).round(3).alias("lead_s")
    )
    schedule = [
        (
            float(lead),
            np.searchsorted(gap_ids, part["gap_id"].to_numpy()),
            part["plan_row"].to_numpy(),
        )
        for (lead,), part in mine.group_by(["lead_s"], maintain_order=True)
    ]
    schedule.sort(key=lambda s: s[0])
    return propagate_gaps(x, logw, schedule, g, geometry, region, ref, rng)


def _assemble(
    plan: pl.DataFrame,
    gaps: pl.DataFrame,
    leads: pl.DataFrame,
    refs: pl.DataFrame,
    ref: Reference,
    stats: dict[str, np.ndarray],
    g: GapsConfig,
    geometry: GapsGeometry,
    cfg: Config,
) -> pl.DataFrame:
    order = np.argsort(stats["plan_row"])
    st = {k: v[order] for k, v in stats.items()}
    zone_names = [name for name, _ in geometry.zones] + [OUTSIDE_ZONES]
    zp = st.pop("zone_p")
    if not geometry.zones:
        zone_names = [OUTSIDE_ZONES]
    best = np.argmax(zp, axis=1)
    true_zone = geometry.zone_index(ref.x, ref.y)[st["plan_row"]]
    has_ref = np.isfinite(ref.x[st["plan_row"]])
    err = np.hypot(st["x_enu_m"] - ref.x[st["plan_row"]], st["y_enu_m"] - ref.y[st["plan_row"]])
    n_lead = leads.group_by("gap_id").len("lead_in_messages")
    status = _constraint_status(st, g, geometry)
    st.pop("constraint_infeasible")
    frame = pl.DataFrame(
        {
            **{k: v for k, v in st.items() if k != "true_in_region90"},
            "zone_probabilities_json": [
                json.dumps({n: round(float(p), 4) for n, p in zip(zone_names, row, strict=True)})
                for row in zp
            ],  # one JSON document per output row
            "most_likely_zone": pl.Series(
                np.array(zone_names, dtype=object)[best].tolist(), dtype=pl.String
            ),
            "most_likely_zone_probability": zp[np.arange(zp.shape[0]), best],
            "constraint_status": pl.Series(status.tolist(), dtype=pl.String),
            "true_in_region": pl.Series(
                np.where(has_ref, st["true_in_region90"], None).tolist(), dtype=pl.Boolean
            ),
            "true_zone": pl.Series(
                np.where(
                    has_ref,
                    np.array(zone_names, dtype=object)[np.minimum(true_zone, len(zone_names) - 1)],
                    None,
                ).tolist(),
                dtype=pl.String,
            ),
            "true_zone_probability": np.where(
                has_ref, zp[np.arange(zp.shape[0]), np.minimum(true_zone, zp.shape[1] - 1)], np.nan
            ),
            "error_m": np.where(has_ref, err, np.nan),
            "expected_error_m": np.where(has_ref, st["expected_error_m"], np.nan),
        },
        strict=False,
    )
    out = (
        plan.join(frame, left_on="plan_row", right_on="plan_row", how="inner")
        .join(gaps.with_row_index("gap_id"), on=["gap_id", "mmsi", "gap_start_ns"], how="left")
        .join(n_lead, on="gap_id", how="left")
        .join(refs, on="plan_row", how="left")
        .with_columns(
            (pl.col("lead_ns") / NS).alias("lead_s"),
            pl.lit(g.particles).alias("n_particles"),
            pl.lit(g.region_probability).alias("region_probability"),
            (pl.col("region_area_m2") / math.pi).sqrt().alias("region_radius_m"),
            (pl.col("constraint_mass_removed") > 0).alias("constraint_active"),
            pl.col("error_m").fill_nan(None),
            pl.col("true_zone_probability").fill_nan(None),
            pl.col("expected_error_m").fill_nan(None),
        )
    )
    tx, ty = frames.geodetic_to_enu(
        out["true_lat_deg"].fill_null(np.nan).to_numpy(),
        out["true_lon_deg"].fill_null(np.nan).to_numpy(),
        cfg.region.origin_lat_deg,
        cfg.region.origin_lon_deg,
    )
    out = out.with_columns(
        pl.Series("true_x_enu_m", np.atleast_1d(tx)).fill_nan(None),
        pl.Series("true_y_enu_m", np.atleast_1d(ty)).fill_nan(None),
    )
    return assign_sectors(out, cfg.sectors, cfg.region)


def _constraint_status(
    st: dict[str, np.ndarray], g: GapsConfig, geometry: GapsGeometry
) -> np.ndarray:
    """off | inactive | active | replenished | infeasible, per row (most severe wins)."""
    if not g.constrain or geometry.water is None:
        return np.full(st["plan_row"].size, "off", dtype=object)
    return np.select(
        [
            st["constraint_infeasible"],
            st["prior_draw_rounds"] > 0,
            st["constraint_mass_removed"] > 0,
        ],
        ["infeasible", "replenished", "active"],
        default="inactive",
    ).astype(object)
