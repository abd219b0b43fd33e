"""Radar registration bias: range bias, range gain, azimuth (north-alignment) bias and
time offset of each radar site, estimated from the AIS reports of cooperative ships, and
applied to the radar reports before alignment.

Model (per site; "reported - true"). A report stamped t_rep of a ship whose true sweep
time was t = t_rep - dt, at true range r and azimuth az (site frame, true north):

.. math:: r_{rep} = (1 + g)\\, r(t) + b_r + e_r, \\qquad
          az_{rep} + \\alpha = az(t) + b_{az} + e_{az}

with alpha the configured north alignment (``radar_sites.north_alignment_deg``) and
e_r, e_az the report's noise (sigma_range_m, sigma_azimuth_rad). The reference is the
ship's AIS track interpolated to t_rep (cubic Hermite with the reports' SOG/COG, see
:func:`interpolate_ais`; GNSS sigma ``[ais] sigma_position_m``). Since
p(t) = p(t_rep - dt) ~ p_ref(t_rep) - v dt, the residuals are linear in
theta = (b_r, b_az, dt, g) (to first order: g dt is dropped):

.. math:: r_{rep} - r_{ref} = b_r + g\\, r_{ref} - (u_r \\cdot v)\\, dt, \\qquad
          az_{rep} + \\alpha - az_{ref} = b_{az} - \\frac{u_{az} \\cdot v}{r}\\, dt

u_r = (sin az, cos az) along the line of sight, u_az = (cos az, -sin az) the direction
of increasing azimuth, v the ship's velocity (AIS SOG/COG). Weighted least squares
(weights 1/(sigma_radar^2 + sigma_AIS^2), the AIS sigma taken across the line of sight
as sigma_AIS / r for azimuth), with outlier rejection: reports whose normalised range or
azimuth residual exceeds ``outlier_sigma`` are dropped and the fit repeated until the
set is stable. The range gain (a range clock's scale error: 0.001 = 1 m per km) is
told from the bias by ships at different ranges; a prior g ~ N(0, ``prior_range_gain``^2)
(a pseudo-observation) holds it where every matched ship is at one range, and the bias
there is the fit's as without it. Covariance (A^T W A)^-1, scaled by the reduced
chi-square when it is above 1, and by (1 + rho) / (1 - rho) for the lag-1 correlation
rho of consecutive residuals of one track (a smoothing site tracker, or coasted
reports, make consecutive errors alike; independent errors give rho ~ 0 and no
change). The intervals are normal (large samples), at ``confidence``. The time offset
is observable because ships move toward, away from and across the line of sight; ships
at rest constrain only b_r and b_az.

Which AIS ship a local track follows: a sample of each track's reports is compared
with every MMSI's interpolated AIS position (Mahalanobis distance with the radar
sigmas widened by the prior bias allowance ``prior_range_bias_m``, ``prior_range_gain``
times the range, ``prior_azimuth_bias_deg``); the track takes the MMSI nearest to at least
``min_track_share`` of its sampled reports, inside the gate.

Correction (``[radar_bias] apply = true``, in pipeline/maritime/align.py before alignment):
(range_m - b_r) / (1 + g), azimuth_rad - b_az, course_rad - b_az (the tracker's courses
are read in the same biased azimuth reference), time_ns - dt.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import polars as pl

from pipeline.config import Config, RadarSite
from pipeline.filters.quantiles import normal_ppf
from pipeline.frames import TWO_PI, enu_to_polar, geodetic_to_enu, wrap_angle
from pipeline.maritime.associate import gate_threshold
from pipeline.maritime.config import RadarBiasConfig, SiteBias, radar_bias_config
from pipeline.units import NS


def correct_registration(
    radar_tracks: pl.DataFrame, biases: Mapping[str, SiteBias]
) -> pl.DataFrame:
    """Remove each site's bias from its raw reports (module docstring); sites without an
    entry pass unchanged."""
    if not biases or radar_tracks.height == 0:
        return radar_tracks
    sites = list(biases)
    site = pl.col("site_id")

    def per_site(attr: str) -> pl.Expr:
        return site.replace_strict(
            sites, [getattr(biases[s], attr) for s in sites], default=0.0, return_dtype=pl.Float64
        )

    b_az = per_site("azimuth_bias_rad")
    return radar_tracks.with_columns(
        (pl.col("range_m") - per_site("range_bias_m")) / (1.0 + per_site("range_gain")),
        (pl.col("azimuth_rad") - b_az) % TWO_PI,
        (pl.col("course_rad") - b_az) % TWO_PI,
        pl.col("time_ns") - (per_site("time_offset_s") * NS).round().cast(pl.Int64),
    )


# --- AIS reference ------------------------------------------------------------------------


def ais_in_site_frame(ais_reports: pl.DataFrame, site: RadarSite) -> pl.DataFrame:
    """AIS positions in the site's ENU frame (m) with velocity (m/s): ais_time_ns, mmsi,
    ax, ay, avx, avy (velocity null without SOG/COG)."""
    x, y = geodetic_to_enu(
        ais_reports["lat_deg"].to_numpy(),
        ais_reports["lon_deg"].to_numpy(),
        site.lat_deg,
        site.lon_deg,
    )
    return (
        ais_reports.select(
            pl.col("time_ns").alias("ais_time_ns"),
            "mmsi",
            pl.Series("ax", np.atleast_1d(x)),
            pl.Series("ay", np.atleast_1d(y)),
            (pl.col("sog_mps") * pl.col("cog_rad").sin()).alias("avx"),
            (pl.col("sog_mps") * pl.col("cog_rad").cos()).alias("avy"),
        )
        .sort("mmsi", "ais_time_ns")
        .unique(["mmsi", "ais_time_ns"], keep="last", maintain_order=True)
        .sort("ais_time_ns")
    )


def interpolate_ais(queries: pl.DataFrame, ais: pl.DataFrame, max_gap_s: float) -> pl.DataFrame:
    """Each query (time_ns, mmsi, ...) with the MMSI's AIS track interpolated to time_ns
    between the bracketing reports (at most ``max_gap_s`` apart): ref_x, ref_y (site
    frame, m), ref_vx, ref_vy (m/s); queries without a bracketing pair are dropped.

    Cubic Hermite interpolation with the reports' SOG/COG velocities at both ends (the
    chord velocity where SOG/COG is missing, i.e. linear): on a 600 m turn with 30 s
    between Class B reports a linear chord is ~15 m inside the arc, the Hermite curve
    ~0.5 m.
    """
    q = queries.sort("time_ns")
    prev = q.join_asof(
        ais,
        left_on="time_ns",
        right_on="ais_time_ns",
        by="mmsi",
        strategy="backward",
        check_sortedness=False,
    )
    nxt = q.select("time_ns", "mmsi").join_asof(
        ais,
        left_on="time_ns",
        right_on="ais_time_ns",
        by="mmsi",
        strategy="forward",
        check_sortedness=False,
    )
    both = pl.concat([prev, nxt.select(pl.all().name.suffix("_n"))], how="horizontal").filter(
        pl.col("ais_time_ns").is_not_null()
        & pl.col("ais_time_ns_n").is_not_null()
        & ((pl.col("ais_time_ns_n") - pl.col("ais_time_ns")) <= round(max_gap_s * NS))
    )
    h = (pl.col("ais_time_ns_n") - pl.col("ais_time_ns")) / NS
    s = pl.when(h > 0).then((pl.col("time_ns") - pl.col("ais_time_ns")) / NS / h).otherwise(0.0)
    hs = pl.when(h > 0).then(h).otherwise(1.0)
    h00, h10, h01, h11 = (
        2 * s**3 - 3 * s**2 + 1,
        s**3 - 2 * s**2 + s,
        -2 * s**3 + 3 * s**2,
        s**3 - s**2,
    )
    d00, d10, d01, d11 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, 3 * s**2 - 2 * s

    def axis(p: str, v: str) -> tuple[pl.Expr, pl.Expr]:
        p0, p1 = pl.col(p), pl.col(f"{p}_n")
        chord = (p1 - p0) / hs
        v0, v1 = pl.col(v).fill_null(chord), pl.col(f"{v}_n").fill_null(chord)
        pos = h00 * p0 + h10 * hs * v0 + h01 * p1 + h11 * hs * v1
        vel = (d00 * p0 + d10 * hs * v0 + d01 * p1 + d11 * hs * v1) / hs
        return pos, pl.when(h > 0).then(vel).otherwise(v0)

    (x, vx), (y, vy) = axis("ax", "avx"), axis("ay", "avy")
    return both.with_columns(
        x.alias("ref_x"), y.alias("ref_y"), vx.alias("ref_vx"), vy.alias("ref_vy")
    ).drop(
        [
            c
            for c in both.columns
            if c.endswith("_n") or c in ("ax", "ay", "avx", "avy", "ais_time_ns")
        ]
    )


def _d2_polar(df: pl.DataFrame, var_r: pl.Expr, var_az: pl.Expr) -> pl.Expr:
    """Squared Mahalanobis distance of (range, azimuth) residuals in ``df``."""
    return pl.col("res_r") ** 2 / var_r + pl.col("res_az") ** 2 / var_az


def _residuals(df: pl.DataFrame, alignment_rad: float) -> pl.DataFrame:
    """Range / azimuth residuals of reports against their AIS reference, plus the time
    offset's partial derivatives (module docstring)."""
    r_ref, az_ref = enu_to_polar(df["ref_x"].to_numpy(), df["ref_y"].to_numpy())
    az = df["azimuth_rad"].to_numpy() + alignment_rad
    vx, vy = df["ref_vx"].to_numpy(), df["ref_vy"].to_numpy()
    s, c = np.sin(az_ref), np.cos(az_ref)
    return df.with_columns(
        pl.Series("r_ref", r_ref),
        pl.Series("res_r", df["range_m"].to_numpy() - r_ref),
        pl.Series("res_az", wrap_angle(az - az_ref)),
        pl.Series("dr_ddt", -(s * vx + c * vy)),
        pl.Series("daz_ddt", -(c * vx - s * vy) / r_ref),
    )


# --- track to MMSI --------------------------------------------------------------------------


def match_tracks(
    reports: pl.DataFrame,
    ais: pl.DataFrame,
    site: RadarSite,
    sigma_ais_m: float,
    cfg: RadarBiasConfig,
    sample: int = 20,
) -> pl.DataFrame:
    """(local_track_id, mmsi) of the site's tracks that follow an AIS ship."""
    counts = reports.group_by("local_track_id").agg(pl.len().alias("_n"))
    sampled = (
        reports.join(counts.filter(pl.col("_n") >= cfg.min_reports_per_track), on="local_track_id")
        .with_columns(pl.int_range(pl.len()).over("local_track_id").alias("_i"))
        .filter(pl.col("_i") % (pl.col("_n") // sample).clip(lower_bound=1) == 0)
    )
    mmsis = ais.select("mmsi").unique()
    cand = interpolate_ais(sampled.join(mmsis, how="cross"), ais, cfg.max_ais_gap_s)
    if cand.height == 0:
        return pl.DataFrame(schema={"local_track_id": pl.Int64, "mmsi": pl.Int64})
    cand = _residuals(cand, site.north_alignment_rad)
    var_r = (pl.col("sigma_range_m") ** 2 + sigma_ais_m**2 + cfg.prior_range_bias_m**2
             + (cfg.prior_range_gain * pl.col("r_ref")) ** 2)
    var_az = (
        pl.col("sigma_azimuth_rad") ** 2
        + (sigma_ais_m / pl.col("r_ref")) ** 2
        + cfg.prior_azimuth_bias_rad**2
    )
    gate = gate_threshold(cfg.gate_probability)
    nearest = (
        cand.with_columns(_d2_polar(cand, var_r, var_az).alias("d2"))
        .filter(pl.col("d2") < gate)
        .sort("d2")
        .group_by("local_track_id", "time_ns")
        .first()
    )
    votes = (
        nearest.group_by("local_track_id", "mmsi")
        .agg(pl.len().alias("_v"))
        .join(sampled.group_by("local_track_id").agg(pl.len().alias("_s")), on="local_track_id")
    )
    return (
        votes.filter(pl.col("_v") >= cfg.min_track_share * pl.col("_s"))
        .select("local_track_id", "mmsi")
        .sort("local_track_id")
    )


# --- least squares --------------------------------------------------------------------------


@dataclass(frozen=True)
class BiasFit:
    """Estimate theta = (range bias m, azimuth bias rad, time offset s, range gain), its
    covariance, and the bookkeeping of the fit."""

    theta: np.ndarray
    cov: np.ndarray
    used: np.ndarray  # bool per report
    reduced_chi2: float
    rms_range_m: float
    rms_azimuth_rad: float


def fit_bias(
    res_r: np.ndarray,
    res_az: np.ndarray,
    dr_ddt: np.ndarray,
    daz_ddt: np.ndarray,
    sigma_r: np.ndarray,
    sigma_az: np.ndarray,
    outlier_sigma: float,
    track: np.ndarray | None = None,
    max_iter: int = 20,
    *,
    range_ref_m: np.ndarray | None = None,
    prior_range_gain: float = 0.01,
) -> BiasFit:
    """Weighted least squares of the linear model of the module docstring, with
    iterative rejection of reports whose normalised residual exceeds ``outlier_sigma``.

    Arrays (n,): residuals (m, rad), partial derivatives d res / d dt (m/s, rad/s),
    sigmas (m, rad), ``range_ref_m`` the reference ranges (the range gain's partial
    derivative; None: every report at range 0, the gain held at its prior 0);
    ``track``: the local track of each report, in time order within a track, for the
    serial-correlation factor (see :func:`serial_inflation`). The gain is solved in m
    per km (its column in km: a well-conditioned system) under the prior
    N(0, ``prior_range_gain``^2). Raises ValueError with fewer than 4 usable reports.
    """
    n = res_r.size
    r_km = np.zeros(n) if range_ref_m is None else np.asarray(range_ref_m) / 1e3
    A = np.zeros((2 * n + 1, 4))
    A[:n, 0], A[n:2 * n, 1] = 1.0, 1.0
    A[:n, 2], A[n:2 * n, 2] = dr_ddt, daz_ddt
    A[:n, 3], A[-1, 3] = r_km, 1.0  # the last row: the gain's prior, 0 +- sigma
    y = np.concatenate([res_r, res_az, [0.0]])
    sig = np.concatenate([sigma_r, sigma_az, [prior_range_gain * 1e3]])
    used = (np.isfinite(y[:n]) & np.isfinite(y[n:2 * n]) & np.isfinite(A[:n, 2])
            & np.isfinite(A[n:2 * n, 2]) & np.isfinite(r_km))
    for _ in range(max_iter):
        if used.sum() < 4:
            raise ValueError(f"only {int(used.sum())} usable reports: cannot fit the bias")
        rows = np.concatenate([used, used, [True]])
        Aw = A[rows] / sig[rows, None]
        theta, *_ = np.linalg.lstsq(Aw, y[rows] / sig[rows], rcond=None)
        z = (y - A @ theta) / sig
        keep = (np.abs(z[:n]) <= outlier_sigma) & (np.abs(z[n:2 * n]) <= outlier_sigma) & used
        if np.array_equal(keep, used):
            break
        used = keep
    rows = np.concatenate([used, used, [True]])  # the data kept and the prior
    Aw = A[rows] / sig[rows, None]
    data = rows[:-1]
    dof = max(int(data.sum()) - 4, 1)
    chi2_red = float(np.sum(z[:-1][data] ** 2) / dof)
    e = y - A @ theta
    inflation = (
        1.0
        if track is None
        else serial_inflation(z[:n][used], z[n:2 * n][used], np.asarray(track)[used])
    )
    cov = np.linalg.inv(Aw.T @ Aw) * max(1.0, chi2_red) * inflation
    to_gain = np.array([1.0, 1.0, 1.0, 1e-3])  # m per km -> dimensionless
    return BiasFit(
        theta=theta * to_gain,
        cov=cov * np.outer(to_gain, to_gain),
        used=used,
        reduced_chi2=chi2_red,
        rms_range_m=float(np.sqrt(np.mean(e[:n][used] ** 2))),
        rms_azimuth_rad=float(np.sqrt(np.mean(e[n:2 * n][used] ** 2))),
    )


def serial_inflation(z_r: np.ndarray, z_az: np.ndarray, track: np.ndarray) -> float:
    """Variance factor (1 + rho) / (1 - rho) (>= 1) for serially correlated errors: rho
    is the lag-1 correlation of the normalised residuals of consecutive reports of one
    track (pooled over tracks, range and azimuth). A smoothing tracker or coasted
    reports make consecutive errors alike, and a mean of AR(1) errors has this much more
    variance than one of independent errors."""
    same = track[1:] == track[:-1]
    if same.sum() < 10:
        return 1.0
    pairs = [(z[:-1][same], z[1:][same]) for z in (z_r, z_az)]
    rho = float(np.mean([np.corrcoef(a, b)[0, 1] for a, b in pairs]))
    rho = min(max(rho, 0.0), 0.95)
    return (1.0 + rho) / (1.0 - rho)


BIAS_COLUMNS = (
    "time_ns",
    "end_time_ns",
    "site_id",
    "reports_used",
    "reports_rejected",
    "tracks_used",
    "ships_used",
    "range_bias_m",
    "range_bias_ci_low_m",
    "range_bias_ci_high_m",
    "azimuth_bias_deg",
    "azimuth_bias_ci_low_deg",
    "azimuth_bias_ci_high_deg",
    "time_offset_s",
    "time_offset_ci_low_s",
    "time_offset_ci_high_s",
    "range_gain",
    "range_gain_ci_low",
    "range_gain_ci_high",
    "rms_range_residual_m",
    "rms_azimuth_residual_deg",
    "reduced_chi2",
)


def estimate_site_bias(
    radar_tracks: pl.DataFrame,
    ais_reports: pl.DataFrame,
    site: RadarSite,
    *,
    sigma_ais_m: float,
    cfg: RadarBiasConfig,
) -> tuple[BiasFit, pl.DataFrame] | None:
    """Fit one site's bias from its raw reports and the AIS reports; None when no track
    of the site follows an AIS ship. Returns the fit and the reports used (with their
    residuals and MMSI)."""
    reports = radar_tracks.filter(pl.col("site_id") == site.site_id)
    ais = ais_in_site_frame(ais_reports, site)
    if reports.height == 0 or ais.height == 0:
        return None
    tracks = match_tracks(reports, ais, site, sigma_ais_m, cfg)
    if tracks.height == 0:
        return None
    df = interpolate_ais(reports.join(tracks, on="local_track_id"), ais, cfg.max_ais_gap_s)
    df = _residuals(df.drop_nulls(["ref_vx", "ref_vy"]), site.north_alignment_rad).sort(
        "local_track_id", "time_ns"
    )
    sigma_r = np.sqrt(df["sigma_range_m"].to_numpy() ** 2 + sigma_ais_m**2)
    sigma_az = np.sqrt(
        df["sigma_azimuth_rad"].to_numpy() ** 2 + (sigma_ais_m / df["r_ref"].to_numpy()) ** 2
    )
    fit = fit_bias(
        df["res_r"].to_numpy(),
        df["res_az"].to_numpy(),
        df["dr_ddt"].to_numpy(),
        df["daz_ddt"].to_numpy(),
        sigma_r,
        sigma_az,
        cfg.outlier_sigma,
        track=df["local_track_id"].to_numpy(),
        range_ref_m=df["r_ref"].to_numpy(),
        prior_range_gain=cfg.prior_range_gain,
    )
    return fit, df.with_columns(pl.Series("used", fit.used))


def estimate_biases(
    radar_tracks: pl.DataFrame,
    ais_reports: pl.DataFrame,
    cfg: Config,
    *,
    start_ns: int,
    end_ns: int,
) -> pl.DataFrame:
    """``radar_bias_by_site`` rows: one per configured site with AIS-matched tracks in the
    window (raw radar reports, not corrected by ``[radar_bias.correction]``)."""
    bcfg = radar_bias_config(cfg)
    z = float(normal_ppf(0.5 + bcfg.confidence / 2))
    rows = []
    for site in cfg.radar_sites:  # a handful of sites: one least-squares problem each
        out = estimate_site_bias(
            radar_tracks, ais_reports, site, sigma_ais_m=cfg.ais.sigma_position_m, cfg=bcfg
        )
        if out is None:
            continue
        fit, used = out
        th, sd = fit.theta, np.sqrt(np.diag(fit.cov))
        deg = math.degrees
        rows.append(
            {
                "time_ns": int(start_ns),
                "end_time_ns": int(end_ns),
                "site_id": site.site_id,
                "reports_used": int(fit.used.sum()),
                "reports_rejected": int((~fit.used).sum()),
                "tracks_used": used["local_track_id"].n_unique(),
                "ships_used": used["mmsi"].n_unique(),
                "range_bias_m": th[0],
                "range_bias_ci_low_m": th[0] - z * sd[0],
                "range_bias_ci_high_m": th[0] + z * sd[0],
                "azimuth_bias_deg": deg(th[1]),
                "azimuth_bias_ci_low_deg": deg(th[1] - z * sd[1]),
                "azimuth_bias_ci_high_deg": deg(th[1] + z * sd[1]),
                "time_offset_s": th[2],
                "time_offset_ci_low_s": th[2] - z * sd[2],
                "time_offset_ci_high_s": th[2] + z * sd[2],
                "range_gain": th[3],
                "range_gain_ci_low": th[3] - z * sd[3],
                "range_gain_ci_high": th[3] + z * sd[3],
                "rms_range_residual_m": fit.rms_range_m,
                "rms_azimuth_residual_deg": deg(fit.rms_azimuth_rad),
                "reduced_chi2": fit.reduced_chi2,
            }
        )
    if not rows:
        return pl.DataFrame(
            schema={c: (pl.String if c == "site_id" else pl.Float64) for c in BIAS_COLUMNS}
        )
    return pl.DataFrame(rows).select(BIAS_COLUMNS)


def correction_toml(estimates: pl.DataFrame) -> str:
    """The ``[radar_bias.correction]`` lines for the estimates (to paste into the config)."""
    lines = ["[radar_bias.correction]"]
    for r in estimates.iter_rows(named=True):
        lines.append(
            f"{r['site_id']} = {{ range_bias_m = {r['range_bias_m']:.2f}, "
            f"azimuth_bias_deg = {r['azimuth_bias_deg']:.4f}, "
            f"time_offset_s = {r['time_offset_s']:.3f}, "
            f"range_gain = {r['range_gain']:.6f} }}"
        )
    return "\n".join(lines)
