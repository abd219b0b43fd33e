"""The ``nav`` batch stage: raw navigation tables + window + config -> ``nav_solution``
and ``nav_outages`` (pure: tables in, tables out).

Per vessel segment (``pipeline.nav.inputs``): modes by fix validity (main / emergency
after ``gnss_timeout_s`` without a valid fix), the six-state filter of the gyro/GNSS/log
paper (``pipeline.filters.gyro_gnss_log``), then position and speed by GNSS or dead
reckoning (``pipeline.nav.deadreckoning``), outages with their dead-reckoning error,
errors against truth when the log has it, sectors. Rows are kept in [start_ns, end_ns);
the inputs may start earlier (warm-up).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import polars as pl

from pipeline import frames, tables
from pipeline.config import Config
from pipeline.filters.gyro_gnss_log import IA, IW, FilterInputs, run_filter
from pipeline.geometry import assign_sectors
from pipeline.nav import deadreckoning as dr
from pipeline.nav.config import OwnshipConfig
from pipeline.nav.inputs import NS, Segment, emergency_steps, segments
from pipeline.nav.integrity import GnssCheck, check_positions, nominal_q

SOLUTION_GATE = {1.0: "pass", 0.0: "reject"}


def dr_settings(oc: OwnshipConfig) -> dr.DrSettings:
    return dr.DrSettings(
        step_s=oc.nav.filter_step_s,
        window_s=oc.nav.dr_correction_window_s,
        position_sigma_m=oc.nav.gnss_position_sigma_m,
        log_sigma_mps=oc.current.log_sigma_mps,
        gnss_velocity_sigma_mps=oc.current.gnss_velocity_sigma_mps,
        gnss_velocity_tau_s=oc.current.gnss_velocity_tau_s,
        current_walk_mps_per_sqrt_s=oc.current.current_walk_mps_per_sqrt_s,
        n_sigma=oc.nav.dr_bound_n_sigma,
    )


def filter_inputs(seg: Segment, emergency: np.ndarray, step_s: float) -> FilterInputs:
    """One segment as the filter's (1, T) inputs; latitude forward/backward filled."""
    lat = pl.Series(seg.lat_deg).fill_nan(None).forward_fill().backward_fill()
    lat_rad = np.radians(lat.fill_null(0.0).to_numpy())

    def row(a: np.ndarray) -> np.ndarray:
        return np.asarray(a, float)[None, :]

    return FilterInputs(step_s, row(seg.accel_signal_rad), row(seg.amplifier_rad),
                        row(seg.heading_rad), row(lat_rad), row(seg.vel_east_mps),
                        row(seg.vel_north_mps), row(seg.log_speed_mps), emergency[None, :])


def gnss_accel_sigma(seg: Segment, step_s: float) -> float:
    """Robust per-axis sigma of the GNSS acceleration of a segment, m/s^2: 1.4826 x the
    median absolute deviation of the velocity changes between consecutive valid fixes
    (NaN with fewer than 20 of them)."""
    v = np.stack([seg.vel_east_mps, seg.vel_north_mps], axis=1)
    a = (v[1:] - v[:-1]) / step_s
    a = a[np.isfinite(a).all(axis=1)].ravel()
    if a.size < 40:
        return float("nan")
    return float(1.4826 * np.median(np.abs(a - np.median(a))))


def segment_model(seg: Segment, oc: OwnshipConfig) -> OwnshipConfig:
    """The config with sigma_w raised to the segment's robust GNSS acceleration sigma
    when that is clearly (x1.25) above the configured one: the paper's 0.019 m/s^2 is
    its receiver's; real logs quantise speed and course and are noisier, and eq. 3 would
    reject most of their fixes."""
    robust = gnss_accel_sigma(seg, oc.nav.filter_step_s)
    sw = oc.model.settings.gnss_accel_sigma_mps2
    if not np.isfinite(robust) or robust <= 1.25 * sw:
        return oc
    return replace(oc, model=replace(oc.model, settings=replace(
        oc.model.settings, gnss_accel_sigma_mps2=robust)), current=replace(
        oc.current, gnss_accel_sigma_mps2=robust))


def solve_segment(seg: Segment, oc: OwnshipConfig) -> tuple[pl.DataFrame, list[dict]]:
    """``(solution rows, outage dicts)`` of one segment (all of its steps)."""
    emergency, _ = emergency_steps(seg, oc.nav.gnss_timeout_s)
    oc = segment_model(seg, oc)
    out = run_filter(filter_inputs(seg, emergency, oc.nav.filter_step_s), oc.model, oc.current)
    gnss = _gnss_check(seg, emergency, out.fix_accepted[0], oc)
    accepted = out.fix_accepted[0] & ~gnss.excluded
    has_heading = np.isfinite(seg.heading_rad)
    # no gyro signals logged (plain NMEA): alpha is not observable, the heading is the
    # gyro's own and its sigma the prior (the filter still estimates W for the gate)
    signals = bool(np.isfinite(seg.accel_signal_rad).any())
    alpha = out.x[0, :, IA] if signals else np.zeros(seg.n)
    sig_alpha = np.sqrt(out.P_diag[0, :, IA]) if signals else np.full(
        seg.n, oc.model.settings.prior_alpha_sigma_rad)
    heading = np.mod(seg.heading_rad - alpha, 2 * np.pi)
    st = dr_settings(oc)
    sol = dr.dead_reckon(
        lat_deg=seg.lat_deg, lon_deg=seg.lon_deg, vel_east=seg.vel_east_mps,
        vel_north=seg.vel_north_mps, accepted=accepted, emergency=emergency,
        heading_rad=heading, sigma_heading_rad=sig_alpha,
        log_speed=seg.log_speed_mps, st=st, current=out.current[0],
        current_cov=out.current_cov[0])
    lat, lon = _geodetic(sol)
    t_rel_s = (seg.times_ns - seg.times_ns[0]) / NS
    rows = pl.DataFrame({
        "time_ns": seg.times_ns,
        "platform_id": seg.platform_id,
        "mode": pl.Series(np.where(emergency, "emergency", "main"), dtype=pl.String),
        "heading_rad": heading,
        "sigma_heading_rad": np.where(has_heading, sig_alpha, np.nan),
        "gyro_heading_rad": seg.heading_rad,
        "gyro_error_rad": np.where(has_heading & signals, alpha, np.nan),
        "accel_mps2": out.x[0, :, IW],
        "sigma_accel_mps2": np.sqrt(out.P_diag[0, :, IW]),
        "speed_mps": np.hypot(sol.vel_east_mps, sol.vel_north_mps),
        "course_rad": np.mod(np.arctan2(sol.vel_east_mps, sol.vel_north_mps), 2 * np.pi),
        "lat_deg": lat,
        "lon_deg": lon,
        "sigma_position_m": sol.sigma_position_m,
        "position_source": pl.Series(np.where(sol.from_gnss, "gnss", "dead_reckoning"),
                                     dtype=pl.String).set(pl.Series(sol.anchor < 0), None),
        "current_east_mps": out.current[0, :, 0],
        "current_north_mps": out.current[0, :, 1],
        "log_bias_mps": out.current[0, :, 2],
        "fix_quality": seg.fix_quality,
        "gate": [SOLUTION_GATE.get(g) for g in out.gate_passed[0].tolist()],
        "w_innovation_mps2": out.w_innovation[0],
        "w_innovation_sigma_mps2": out.w_innovation_sigma[0],
        "nis": out.nis[0],
        "gnss_nis": gnss.xi,
        "gnss_eta": _gnss_eta(seg, emergency, out.gate_passed[0], gnss),
        "gnss_excluded": emergency | (seg.fix_valid & ~accepted),
        "gnss_q": nominal_q(oc.nav.gnss_q, oc.model.settings.gate_n_sigma),
        "converged": t_rel_s >= oc.nav.convergence_s,
    }, strict=False).with_columns(
        pl.col(pl.Float64).exclude("fix_quality").fill_nan(None),
        pl.col("fix_quality").fill_nan(None).cast(pl.Int16),
        pl.col("gnss_eta").replace(-1, None).cast(pl.Int16),
    )
    outs = [_outage_row(seg, sol, o, sig_alpha, st) for o in dr.outages(
        emergency, seg.fix_valid, seg.gnss_msg)]
    return rows, outs


def _gnss_check(seg: Segment, emergency: np.ndarray, gate_ok: np.ndarray,
                oc: OwnshipConfig) -> GnssCheck:
    """The GNSS position test of :mod:`pipeline.nav.integrity` on one segment."""
    ok = seg.fix_valid & np.isfinite(seg.lat_deg) & np.isfinite(seg.lon_deg)
    if not ok.any():
        n = seg.n
        return GnssCheck(np.full(n, np.nan), np.full(n, -1, np.int8), np.zeros(n, bool))
    k0 = int(np.flatnonzero(ok)[0])
    e, n_ = frames.geodetic_to_enu(np.where(ok, seg.lat_deg, seg.lat_deg[k0]),
                                   np.where(ok, seg.lon_deg, seg.lon_deg[k0]),
                                   float(seg.lat_deg[k0]), float(seg.lon_deg[k0]))
    nav = oc.nav
    return check_positions(
        np.atleast_1d(e), np.atleast_1d(n_), seg.vel_east_mps, seg.vel_north_mps, ok,
        gate_ok, emergency, step_s=nav.filter_step_s, q=nav.gnss_q,
        readmit_run=nav.gnss_readmit_run, sigma_p_m=nav.gnss_position_sigma_m,
        tau_p_s=nav.gnss_position_tau_s, sigma_v_mps=oc.current.gnss_velocity_sigma_mps,
        tau_v_s=oc.current.gnss_velocity_tau_s, exclusion=nav.gnss_exclusion)


def _gnss_eta(seg: Segment, emergency: np.ndarray, gate: np.ndarray, g: GnssCheck
              ) -> np.ndarray:
    """Eq. 23 per step for the GNSS channel: 1 when the filter's gate rejected the fix,
    the position test flagged it, or no fix came (emergency mode: an outage); 0 for a
    fix that passed both; -1 no decision (no fix outside an outage, a fix not tested)."""
    rejected = gate == 0.0
    passed = (gate == 1.0) & (g.eta == 0)
    out = np.where(rejected | (g.eta == 1) | emergency, 1, np.where(passed, 0, -1))
    return out.astype(np.int16)


def _silence_between(prev: Segment, seg: Segment) -> dict:
    """A gap longer than max_gap_s between two segments (the filter restarts): an outage
    of kind silence, from the last valid fix before to the first after; no DR."""
    a = np.flatnonzero(prev.fix_valid)
    b = np.flatnonzero(seg.fix_valid)
    start = int(prev.times_ns[a[-1]] if a.size else prev.times_ns[-1])
    end = int(seg.times_ns[b[0]] if b.size else seg.times_ns[0])
    k = a[-1] if a.size else 0
    return {
        "start_ns": start, "platform_id": seg.platform_id, "end_ns": end,
        "duration_s": (end - start) / NS, "open": False, "kind": "silence",
        "dr_distance_m": None, "dr_error_m": None, "dr_error_reference": None,
        "dr_bound_m": None, "_end_lat_deg": None, "_end_lon_deg": None,
        "_start_lat_deg": float(prev.lat_deg[k]), "_start_lon_deg": float(prev.lon_deg[k]),
    }


def _geodetic(sol: dr.DrResult) -> tuple[np.ndarray, np.ndarray]:
    if not np.isfinite(sol.origin_lat_deg):
        nan = np.full(sol.east_m.size, np.nan)
        return nan, nan
    return frames.enu_to_geodetic(np.nan_to_num(sol.east_m), np.nan_to_num(sol.north_m),
                                  sol.origin_lat_deg, sol.origin_lon_deg)


def _outage_row(seg: Segment, sol: dr.DrResult, o: dr.Outage, sig_alpha: np.ndarray,
                st: dr.DrSettings) -> dict:
    """One nav_outages row (the truth-based error is filled in later, if any)."""
    steps = slice(o.start + 1, o.end + 1)
    dist = float(np.nansum(np.hypot(sol.vel_east_mps[steps], sol.vel_north_mps[steps]))
                 * st.step_s)
    tau = (seg.times_ns[o.end] - seg.times_ns[o.start]) / NS
    end_pos = dr.dr_end_position(sol, o, st)
    a = o.start
    sa, ss = dr.dr_sigmas(st, np.array([tau]), np.array([np.hypot(
        sol.vel_east_mps[a], sol.vel_north_mps[a])]), sig_alpha[[a]],
        sol.var_corr_along[[o.end]], sol.var_corr_cross[[o.end]])
    fix_err = None
    if not o.open and sol.from_gnss[o.end]:
        fix_err = float(np.hypot(*(end_pos - [sol.east_m[o.end], sol.north_m[o.end]])))
    lat, lon = frames.enu_to_geodetic(end_pos[0], end_pos[1], sol.origin_lat_deg,
                                      sol.origin_lon_deg)
    slat, slon = frames.enu_to_geodetic(sol.east_m[a], sol.north_m[a], sol.origin_lat_deg,
                                        sol.origin_lon_deg)
    return {
        "start_ns": int(seg.times_ns[o.start]),
        "platform_id": seg.platform_id,
        "end_ns": int(seg.times_ns[o.end]),
        "duration_s": float(tau),
        "open": o.open,
        "kind": "no_fix" if o.no_fix else "silence",
        "dr_distance_m": dist,
        "dr_error_m": fix_err,
        "dr_error_reference": None if fix_err is None else "gnss",
        "dr_bound_m": float(st.n_sigma * np.hypot(sa[0], ss[0])),
        "_end_lat_deg": float(lat),
        "_end_lon_deg": float(lon),
        "_start_lat_deg": float(slat),
        "_start_lon_deg": float(slon),
    }


def nav_window(
    gnss: pl.DataFrame, heading: pl.DataFrame, speed_log: pl.DataFrame, gyro: pl.DataFrame,
    truth: pl.DataFrame | None, *, start_ns: int, end_ns: int, cfg: Config, oc: OwnshipConfig,
) -> dict[str, pl.DataFrame]:
    """``{"nav_solution", "nav_outages"}`` for [start_ns, end_ns) from the raw tables
    (which may start before the window: the filter warms up on them)."""
    segs = segments(gnss, heading, speed_log, gyro, step_s=oc.nav.filter_step_s,
                    max_gap_s=oc.nav.max_gap_s)
    sols, outs = [], []
    for i, seg in enumerate(segs):  # one filter run per vessel segment
        rows, o = solve_segment(seg, oc)
        sols.append(rows)
        outs += o
        if i and segs[i - 1].platform_id == seg.platform_id:
            outs.append(_silence_between(segs[i - 1], seg))
    solution = pl.concat(sols, how="diagonal_relaxed") if sols else _empty("nav_solution")
    outage = pl.DataFrame(outs) if outs else _empty("nav_outages")
    if solution.height:
        solution = solution.filter(pl.col("time_ns").is_between(start_ns, end_ns, closed="left"))
        solution = _with_truth_errors(solution, truth)
        solution = _with_sector(solution, cfg, "lat_deg", "lon_deg")
    if outage.height:
        outage = outage.filter(pl.col("start_ns").is_between(start_ns, end_ns, closed="left"))
        outage = _outage_truth(outage, truth)
        outage = _with_sector(outage, cfg, "_start_lat_deg", "_start_lon_deg")
    return {"nav_solution": solution, "nav_outages": outage}


def _empty(name: str) -> pl.DataFrame:
    return pl.from_arrow(tables.empty(name)).drop("date")


def _wrap(a: pl.Expr) -> pl.Expr:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _truth_at(df: pl.DataFrame, truth: pl.DataFrame, time_col: str) -> pl.DataFrame:
    """Join the truth row nearest in time (within 0.5 s) per vessel."""
    t = truth.select(
        pl.col("time_ns").alias("_t"), "platform_id", pl.col("lat_deg").alias("_tlat"),
        pl.col("lon_deg").alias("_tlon"), pl.col("heading_rad").alias("_theading"),
    ).sort("_t")
    return df.sort(time_col).join_asof(t, left_on=time_col, right_on="_t", by="platform_id",
                                       strategy="nearest", tolerance=NS // 2,
                                       check_sortedness=False)  # both sorted just above


def _distance_m(lat1: pl.Series, lon1: pl.Series, lat2: pl.Series, lon2: pl.Series) -> np.ndarray:
    """Horizontal distance on the local tangent plane at point 2, m."""
    a1, o1 = lat1.fill_null(np.nan).to_numpy(), lon1.fill_null(np.nan).to_numpy()
    a2, o2 = lat2.fill_null(np.nan).to_numpy(), lon2.fill_null(np.nan).to_numpy()
    k_lat = np.radians(1.0) * 6_371_000.0
    de = (o1 - o2) * k_lat * np.cos(np.radians(a2))
    dn = (a1 - a2) * k_lat
    return np.hypot(de, dn)


def _with_truth_errors(sol: pl.DataFrame, truth: pl.DataFrame | None) -> pl.DataFrame:
    if truth is None or truth.height == 0:
        return sol
    j = _truth_at(sol, truth, "time_ns")
    err = _distance_m(j["lat_deg"], j["lon_deg"], j["_tlat"], j["_tlon"])
    return j.with_columns(
        _wrap(pl.col("heading_rad") - pl.col("_theading")).alias("heading_error_rad"),
        _wrap(pl.col("gyro_heading_rad") - pl.col("_theading")).alias("gyro_heading_error_rad"),
        pl.Series("position_error_m", err).fill_nan(None),
    ).drop("_t", "_tlat", "_tlon", "_theading")


def _outage_truth(outage: pl.DataFrame, truth: pl.DataFrame | None) -> pl.DataFrame:
    if truth is None or truth.height == 0:
        return outage
    j = _truth_at(outage.with_columns(pl.col("end_ns").alias("_te")), truth, "_te")
    err = pl.Series(_distance_m(j["_end_lat_deg"], j["_end_lon_deg"], j["_tlat"],
                                j["_tlon"])).fill_nan(None)
    known = err.is_not_null()
    return j.with_columns(
        pl.when(known).then(err).otherwise(pl.col("dr_error_m")).alias("dr_error_m"),
        pl.when(known).then(pl.lit("truth")).otherwise(pl.col("dr_error_reference"))
        .alias("dr_error_reference"),
    ).drop("_te", "_t", "_tlat", "_tlon", "_theading")


def _with_sector(df: pl.DataFrame, cfg: Config, lat_col: str, lon_col: str) -> pl.DataFrame:
    if not cfg.sectors:
        return df.with_columns(pl.lit(None, dtype=pl.String).alias("sector"))
    lat = df[lat_col].fill_null(np.nan).to_numpy()
    lon = df[lon_col].fill_null(np.nan).to_numpy()
    ok = np.isfinite(lat) & np.isfinite(lon)
    x, y = frames.geodetic_to_enu(np.where(ok, lat, cfg.region.origin_lat_deg),
                                  np.where(ok, lon, cfg.region.origin_lon_deg),
                                  cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
    tmp = assign_sectors(pl.DataFrame({"x_enu_m": x, "y_enu_m": y}), cfg.sectors, cfg.region)
    sector = tmp["sector"].to_numpy()
    return df.with_columns(pl.Series("sector", np.where(ok, sector, None), dtype=pl.String))
