"""pipeline.nav.deadreckoning: the emergency-mode solution, outages and the DR bound."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline import frames
from pipeline.nav import deadreckoning as dr

ST = dr.DrSettings(step_s=1.0, window_s=120.0, position_sigma_m=3.2, log_sigma_mps=0.5,
                   gnss_velocity_sigma_mps=0.053, gnss_velocity_tau_s=15.0,
                   current_walk_mps_per_sqrt_s=2e-4, n_sigma=3.0)
LAT0, LON0 = 46.3, 30.7


def test_trailing_mean_matches_a_plain_loop():
    rng = np.random.default_rng(0)
    v = rng.normal(size=50)
    use = rng.random(50) > 0.3
    v[3] = np.nan
    mean, count = dr.trailing_mean(v, use, 7)
    for k in range(50):
        sel = [v[j] for j in range(max(0, k - 6), k + 1) if use[j] and np.isfinite(v[j])]
        assert count[k] == len(sel)
        assert (np.isnan(mean[k]) if not sel else mean[k] == pytest.approx(np.mean(sel)))


def test_outage_runs():
    emergency = np.array([1, 1, 0, 0, 1, 1, 1, 0, 0, 1, 1], bool)  # acquisition first
    valid = ~emergency
    msgs = np.array([1, 1, 1, 1, 0, 1, 0, 1, 1, 0, 0], bool)
    out = dr.outages(emergency, valid, msgs)
    assert [(o.start, o.end, o.open, o.no_fix) for o in out] == [
        (3, 7, False, True), (8, 10, True, False)]


def _straight_run(rng: np.random.Generator, T: int = 400, outage=(200, 320), heading_deg=60.0,
                  speed=8.0, current=(0.25, -0.2), log_bias=0.3):
    """Constant heading and speed through water, a constant current, GNSS with
    Gauss-Markov errors, a biased noisy log; fix quality 0 inside ``outage``."""
    K = np.radians(heading_deg)
    u = np.array([np.sin(K), np.cos(K)])
    v_true = speed * u + np.array(current)
    t = np.arange(T, dtype=float)
    pos = t[:, None] * v_true
    a = np.exp(-1.0 / ST.gnss_velocity_tau_s)
    ve = np.zeros((T, 2))
    for k in range(1, T):  # a short Gauss-Markov series
        ve[k] = a * ve[k - 1] + rng.normal(0, ST.gnss_velocity_sigma_mps * np.sqrt(1 - a * a), 2)
    pe = rng.normal(0, ST.position_sigma_m, (T, 2))
    lat, lon = frames.enu_to_geodetic(pos[:, 0] + pe[:, 0], pos[:, 1] + pe[:, 1], LAT0, LON0)
    valid = np.ones(T, bool)
    valid[outage[0] + 1:outage[1]] = False
    v = np.where(valid[:, None], v_true + ve, np.nan)
    return dict(
        lat_deg=np.where(valid, lat, np.nan), lon_deg=np.where(valid, lon, np.nan),
        vel_east=v[:, 0], vel_north=v[:, 1], accepted=valid, emergency=~valid,
        heading_rad=np.full(T, K), sigma_heading_rad=np.full(T, np.radians(0.05)),
        log_speed=speed + log_bias + rng.normal(0, ST.log_sigma_mps, T)), pos, outage


def test_dead_reckoning_follows_the_fix_and_stays_inside_its_bound():
    kw, pos, (a, b) = _straight_run(np.random.default_rng(4))
    sol = dr.dead_reckon(**kw, st=ST)
    e0, n0 = frames.geodetic_to_enu(kw["lat_deg"][0], kw["lon_deg"][0], LAT0, LON0)
    truth = pos - np.array([e0, n0]).ravel()  # the solution's origin is the first fix
    # at accepted fixes the solution IS the fix
    fe, fn = frames.geodetic_to_enu(kw["lat_deg"][:a], kw["lon_deg"][:a], sol.origin_lat_deg,
                                    sol.origin_lon_deg)
    assert np.allclose(sol.east_m[:a], fe) and np.allclose(sol.north_m[:a], fn)
    assert (~sol.from_gnss[a + 1:b]).all()
    # the frozen correction d_a = mean(v . u - V_log) removes log bias and current
    u = np.array([np.sin(kw["heading_rad"][0]), np.cos(kw["heading_rad"][0])])
    c_along = np.array([0.25, -0.2]) @ u
    assert sol.corr_along_mps[a] == pytest.approx(c_along - 0.3, abs=0.15)
    err = np.hypot(sol.east_m[b - 1] - truth[b - 1, 0], sol.north_m[b - 1] - truth[b - 1, 1])
    bound = ST.n_sigma * sol.sigma_position_m[b - 1]
    assert err < bound
    assert sol.sigma_position_m[a + 10] < sol.sigma_position_m[b - 1]  # it grows


def test_dr_bound_is_calibrated_over_seeded_runs():
    """100 seeded straight runs with a 119-s outage: the 3-sigma bound holds in >= 95 %
    of them and the 1-sigma radius in about the Rayleigh share (39-75 %)."""
    rng = np.random.default_rng(2024)
    ratios = []
    for _ in range(100):  # Monte Carlo runs
        kw, pos, (_, b) = _straight_run(rng)
        sol = dr.dead_reckon(**kw, st=ST)
        e0, n0 = frames.geodetic_to_enu(kw["lat_deg"][0], kw["lon_deg"][0], LAT0, LON0)
        d = np.array([sol.east_m[b - 1], sol.north_m[b - 1]]) - (pos[b - 1] - [e0, n0])
        ratios.append(np.hypot(*d) / sol.sigma_position_m[b - 1])
    ratios = np.array(ratios)
    assert (ratios < ST.n_sigma).mean() >= 0.95
    assert 0.39 <= (ratios < 1.0).mean() <= 0.9


def test_sigmas_follow_the_formula():
    tau = np.array([0.0, 30.0, 120.0])
    sa, ss = dr.dr_sigmas(ST, tau, np.full(3, 9.0), np.full(3, 1e-3), np.full(3, 0.01),
                          np.full(3, 0.002))
    walk = ST.current_walk_mps_per_sqrt_s**2 * tau**3 / 3
    assert np.allclose(sa**2, ST.position_sigma_m**2 + 0.25 * tau + 0.01 * tau**2 + walk)
    assert np.allclose(ss**2, ST.position_sigma_m**2 + 0.002 * tau**2 + (9e-3 * tau) ** 2 + walk)
