"""Position and speed of the solution: GNSS in the main mode, dead reckoning with the
log and the last GNSS-derived correction in the emergency mode (gyro/GNSS/log paper),
and the outages with their dead-reckoning error and its bound.

**Log correction** (paper, Fig. 1, summator 1: dV = dV_gnss - dV_log - V_T, "the last
value kept in the emergency mode"). A log measures along the heading only, so we keep
the correction as two components in the ship's frame (u = (sin K, cos K) ahead,
u_s = (cos K, -sin K) to starboard), averaged over the accepted fixes of the last
``window_s`` (the log's 0.5 m/s noise makes one sample useless):

.. math:: d_a = \\overline{v_g \\cdot u - V_{log}}, \\qquad d_s = \\overline{v_g \\cdot u_s}

d_a is the paper's correction (GNSS minus log error and the current along the heading);
d_s the drift across it (current, and any heading error), which the paper's scalar lacks.
In the emergency mode both are frozen at their last value and

.. math:: v_{DR} = (V_{log} + d_a)\\, u(\\hat K) + d_s\\, u_s(\\hat K)

(without a log: the last accepted speed along the heading). The position is integrated
from the last accepted fix. A fix the gate rejects also gets the predicted position.

The window mean goes stale in a turn (the current turns in the ship's frame). The
filter's current/log-bias estimator (``pipeline.filters.current_log``: c, b in the earth
frame, well observed once the ship has turned) gives the same two terms,
d_a = c . u - b and d_s = c . u_s, rotating with the heading during the outage; each
component uses the estimator when its variance at the last fix is the smaller, the
window mean's variance counting (sigma_c sin(heading change in the window))^2 for its
staleness.

**Bound** of the dead-reckoning error tau seconds after the last fix (independent
Gaussian terms; along and across the heading):

.. math::
    \\sigma_a^2 = \\sigma_0^2 + \\sigma_{log}^2\\,\\Delta t\\,\\tau + \\sigma_{d_a}^2 \\tau^2
      + q_c^2 \\tau^3 / 3

    \\sigma_s^2 = \\sigma_0^2 + \\sigma_{d_s}^2 \\tau^2 + (V \\sigma_K \\tau)^2
      + q_c^2 \\tau^3 / 3

sigma_0 the GNSS position sigma at the last fix; sigma_log dt tau the log's white noise
integrated (a random walk); sigma_{d_a} = sqrt(sigma_log^2 + sigma_v'^2 / N) and
sigma_{d_s} = sigma_v' / sqrt(N) the errors of the frozen corrections (N fixes in the
window, sigma_v' the GNSS velocity sigma with its correlation time counted:
sigma_v^2 min(1, 2 tau_v / (N dt)) N); sigma_K the heading sigma; q_c the current's
random walk. sigma_position = sqrt(sigma_a^2 + sigma_s^2) and the bound is
n_sigma * sigma_position (for a 2-D Gaussian, P(|e| <= 3 sqrt(tr)) >= 98.9 %).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl

from pipeline import frames


@dataclass(frozen=True)
class DrSettings:
    step_s: float
    window_s: float
    position_sigma_m: float
    log_sigma_mps: float
    gnss_velocity_sigma_mps: float
    gnss_velocity_tau_s: float
    current_walk_mps_per_sqrt_s: float
    n_sigma: float
    current_prior_sigma_mps: float = 0.5


@dataclass(frozen=True)
class DrResult:
    """Per step (T,): solution ENU (m, around ``origin``), velocity, sigma, source."""

    origin_lat_deg: float
    origin_lon_deg: float
    east_m: np.ndarray
    north_m: np.ndarray
    vel_east_mps: np.ndarray
    vel_north_mps: np.ndarray
    sigma_position_m: np.ndarray
    from_gnss: np.ndarray  # bool: the position is the step's accepted fix
    anchor: np.ndarray  # index of the last accepted fix (-1: none yet)
    corr_along_mps: np.ndarray  # frozen d_a used at each step (NaN: no estimate)
    corr_cross_mps: np.ndarray  # frozen d_s
    var_corr_along: np.ndarray  # their variances, (m/s)^2
    var_corr_cross: np.ndarray


def trailing_mean(values: np.ndarray, use: np.ndarray,
                  window: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``values`` over the used samples of the last ``window`` steps (including
    this one) and their count, by cumulative sums."""
    ok = use & np.isfinite(values)
    s = np.concatenate([[0.0], np.cumsum(np.where(ok, values, 0.0))])
    c = np.concatenate([[0], np.cumsum(ok)])
    k = np.arange(values.size) + 1
    lo = np.maximum(k - window, 0)
    count = c[k] - c[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, (s[k] - s[lo]) / np.maximum(count, 1), np.nan), count


def _ffill_index(mask: np.ndarray) -> np.ndarray:
    idx = np.where(mask, np.arange(mask.size), -1)
    return np.maximum.accumulate(idx) if mask.size else idx


def dead_reckon(
    *, lat_deg: np.ndarray, lon_deg: np.ndarray, vel_east: np.ndarray, vel_north: np.ndarray,
    accepted: np.ndarray, emergency: np.ndarray, heading_rad: np.ndarray,
    sigma_heading_rad: np.ndarray, log_speed: np.ndarray, st: DrSettings,
    current: np.ndarray | None = None, current_cov: np.ndarray | None = None,
) -> DrResult:
    """The solution of one segment (see the module docstring); vectorised.

    current, current_cov: (T, 3), (T, 3, 3) the filter's [c_E, c_N, b] estimate."""
    n = accepted.size
    anchor = _ffill_index(accepted)
    first = int(np.flatnonzero(accepted)[0]) if accepted.any() else -1
    lat0 = float(lat_deg[first]) if first >= 0 else np.nan
    lon0 = float(lon_deg[first]) if first >= 0 else np.nan
    e, nn = frames.geodetic_to_enu(np.nan_to_num(lat_deg, nan=lat0),
                                   np.nan_to_num(lon_deg, nan=lon0), lat0, lon0) \
        if first >= 0 else (np.full(n, np.nan), np.full(n, np.nan))
    has_h = np.isfinite(heading_rad)
    K = np.nan_to_num(heading_rad)
    u = np.stack([np.sin(K), np.cos(K)], axis=1)
    us = np.stack([np.cos(K), -np.sin(K)], axis=1)
    v = np.stack([vel_east, vel_north], axis=1)
    window = max(1, round(st.window_s / st.step_s))
    along = np.einsum("ni,ni->n", v, u) - log_speed
    cross = np.einsum("ni,ni->n", v, us)
    d_a, n_a = trailing_mean(along, accepted & has_h, window)
    d_s, n_s = trailing_mean(cross, accepted & has_h, window)
    a = np.maximum(anchor, 0)
    var_da, var_ds = _window_variances(st, n_a[a], n_s[a])
    # a turn inside the window makes its mean stale: the current turned in the ship's
    # frame by the heading change; count (prior current sigma x sin(change))^2
    stale = (st.current_prior_sigma_mps * np.sin(np.minimum(
        _heading_range(heading_rad, window)[a], np.pi / 2))) ** 2
    var_da, var_ds = var_da + stale, var_ds + stale
    corr_a, corr_s = d_a[a], d_s[a]
    if current is not None and current_cov is not None:
        ea, es, var_ea, var_es = _estimator_terms(current[a], current_cov[a], u, us)
        use_a = var_ea < var_da
        use_s = var_es < var_ds
        corr_a = np.where(use_a, ea, corr_a)
        corr_s = np.where(use_s, es, corr_s)
        var_da = np.where(use_a, var_ea, var_da)
        var_ds = np.where(use_s, var_es, var_ds)
    # velocity: the accepted fix's; else the frozen correction applied to log + heading
    v_hold = v[a]
    speed_hold = np.einsum("ni,ni->n", v_hold, u[a])
    speed = np.where(np.isfinite(log_speed) & np.isfinite(corr_a), log_speed + corr_a,
                     speed_hold)
    v_dr = speed[:, None] * u + np.nan_to_num(corr_s)[:, None] * us
    v_dr = np.where((has_h & emergency)[:, None], v_dr, v_hold)
    v_sol = np.where(accepted[:, None], v, v_dr)
    v_sol = np.where((anchor >= 0)[:, None], v_sol, np.nan)
    # position: the fix, else the last fix + the integrated velocity since it
    step = np.nan_to_num(v_sol) * st.step_s
    cs = np.vstack([[0.0, 0.0], np.cumsum(step, axis=0)])[1:]
    pos_fix = np.stack([e, nn], axis=1)
    pos = np.where(accepted[:, None], pos_fix, pos_fix[a] + cs - cs[a])
    pos = np.where((anchor >= 0)[:, None], pos, np.nan)
    tau = (np.arange(n) - anchor) * st.step_s
    sa, ss = dr_sigmas(st, tau, np.hypot(v_hold[:, 0], v_hold[:, 1]), sigma_heading_rad,
                       var_da, var_ds)
    sigma = np.where(accepted, np.sqrt(2.0) * st.position_sigma_m, np.hypot(sa, ss))
    sigma = np.where(anchor >= 0, sigma, np.nan)
    return DrResult(lat0, lon0, pos[:, 0], pos[:, 1], v_sol[:, 0], v_sol[:, 1], sigma,
                    accepted.copy(), anchor, corr_a, corr_s, var_da, var_ds)


def _heading_range(heading_rad: np.ndarray, window: int) -> np.ndarray:
    """Max - min of the (unwrapped) heading over the last ``window`` steps, rad."""
    h = pl.Series(np.unwrap(np.nan_to_num(heading_rad)))
    return (h.rolling_max(window, min_samples=1) - h.rolling_min(window, min_samples=1)
            ).to_numpy()


def _window_variances(st: DrSettings, n_along: np.ndarray,
                      n_cross: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Variances of the window means d_a, d_s (N fixes; GNSS error correlated over tau_v)."""
    nn_a, nn_s = np.maximum(n_along, 1), np.maximum(n_cross, 1)
    v_eff2_a = st.gnss_velocity_sigma_mps**2 * np.minimum(
        1.0, 2.0 * st.gnss_velocity_tau_s / (nn_a * st.step_s)) * nn_a
    v_eff2_s = st.gnss_velocity_sigma_mps**2 * np.minimum(
        1.0, 2.0 * st.gnss_velocity_tau_s / (nn_s * st.step_s)) * nn_s
    var_a = (st.log_sigma_mps**2 + v_eff2_a) / nn_a
    var_s = v_eff2_s / nn_s
    return np.where(n_along > 0, var_a, np.inf), np.where(n_cross > 0, var_s, np.inf)


def _estimator_terms(cur: np.ndarray, cov: np.ndarray, u: np.ndarray,
                     us: np.ndarray) -> tuple[np.ndarray, ...]:
    """d_a = c . u - b, d_s = c . u_s from the estimator (T,) and their variances."""
    ha = np.concatenate([u, -np.ones((u.shape[0], 1))], axis=1)
    hs = np.concatenate([us, np.zeros((u.shape[0], 1))], axis=1)
    ea = np.einsum("ni,ni->n", ha, cur)
    es = np.einsum("ni,ni->n", hs, cur)
    var_a = np.einsum("ni,nij,nj->n", ha, cov, ha)
    var_s = np.einsum("ni,nij,nj->n", hs, cov, hs)
    bad = ~np.isfinite(var_a) | ~np.isfinite(ea)
    return ea, es, np.where(bad, np.inf, var_a), np.where(bad | ~np.isfinite(es), np.inf,
                                                          var_s)


def dr_sigmas(st: DrSettings, tau_s: np.ndarray, speed_mps: np.ndarray,
              sigma_heading_rad: np.ndarray, var_da: np.ndarray,
              var_ds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sigma_a, sigma_s) of the module docstring, m; var_da, var_ds the variances of
    the frozen corrections, (m/s)^2."""
    sig_da2 = np.where(np.isfinite(var_da), var_da, st.log_sigma_mps**2)
    sig_ds2 = np.where(np.isfinite(var_ds), var_ds, st.log_sigma_mps**2)
    walk = st.current_walk_mps_per_sqrt_s**2 * tau_s**3 / 3.0
    p0 = st.position_sigma_m**2
    var_a = p0 + st.log_sigma_mps**2 * st.step_s * tau_s + sig_da2 * tau_s**2 + walk
    var_s = p0 + sig_ds2 * tau_s**2 + (speed_mps * np.nan_to_num(sigma_heading_rad)
                                       * tau_s) ** 2 + walk
    return np.sqrt(var_a), np.sqrt(var_s)


@dataclass(frozen=True)
class Outage:
    """One emergency-mode span: step indices of the last fix before and the first after
    (``end`` = last step when still open)."""

    start: int
    end: int
    open: bool
    no_fix: bool  # GNSS messages without a valid fix (else silence)


def outages(emergency: np.ndarray, valid_fix: np.ndarray, gnss_msg: np.ndarray) -> list[Outage]:
    """Runs of emergency steps after a first valid fix (acquisition at the start of the
    data is not an outage)."""
    e = emergency.astype(np.int8)
    edges = np.diff(np.concatenate([[0], e, [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)  # [start, stop)
    last_fix = _ffill_index(valid_fix)
    out = []
    for s, t in zip(starts.tolist(), stops.tolist(), strict=True):  # one per outage
        a = int(last_fix[s])
        if a < 0:
            continue
        end_open = t >= emergency.size
        end = emergency.size - 1 if end_open else t
        out.append(Outage(a, end, end_open, bool(gnss_msg[a + 1:end + 1].any())))
    return out


def dr_end_position(dr: DrResult, o: Outage, st: DrSettings) -> np.ndarray:
    """Dead-reckoned (east, north) at the outage's end step: the previous DR position
    plus one step of the DR velocity (the end step itself may hold the new fix)."""
    k = o.end
    if o.open or not dr.from_gnss[k]:
        return np.array([dr.east_m[k], dr.north_m[k]])
    v = np.array([dr.vel_east_mps[k - 1], dr.vel_north_mps[k - 1]])
    return np.array([dr.east_m[k - 1], dr.north_m[k - 1]]) + v * st.step_s
