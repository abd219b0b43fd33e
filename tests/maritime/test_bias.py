"""Radar registration bias: injection by the simulator and its exact removal, the least
squares with outlier rejection, recovery from AIS in the channel scenario, its effect on
the batch, and `surveil calibrate-radars` on a real warehouse."""

from __future__ import annotations

import math

import numpy as np
import polars as pl
import pytest
from click.testing import CliRunner
from maritime_helpers import NS, T0_NS, biased, scenario_tables, with_sections

from jobs.cli import cli
from pipeline.family import Window
from pipeline.maritime.bias import (
    SiteBias,
    correct_registration,
    estimate_biases,
    fit_bias,
    radar_bias_config,
    serial_inflation,
)
from pipeline.maritime.stage import stage
from pipeline.warehouse.delta import read_table

INJECTED = {"R1": {"range_bias_m": 20.0, "azimuth_bias_deg": 0.3, "time_offset_s": 0.5,
                   "range_gain": 0.002},
            "R2": {"range_bias_m": -15.0, "azimuth_bias_deg": -0.2, "time_offset_s": -0.3,
                   "range_gain": -0.001}}
DURATION_S = 1200.0
SEED = 7
# (estimate column, injected key, its interval's columns)
PARAMS = (("range_bias_m", "range_bias_m", "range_bias_ci_low_m", "range_bias_ci_high_m"),
          ("azimuth_bias_deg", "azimuth_bias_deg", "azimuth_bias_ci_low_deg",
           "azimuth_bias_ci_high_deg"),
          ("time_offset_s", "time_offset_s", "time_offset_ci_low_s", "time_offset_ci_high_s"),
          ("range_gain", "range_gain", "range_gain_ci_low", "range_gain_ci_high"))
CORRECTED = ("range_bias_m", "azimuth_bias_deg", "time_offset_s", "range_gain")


def z_scores(est: pl.DataFrame, truth: dict, confidence: float = 0.95) -> list[float]:
    """(estimate - injected) / its standard error, from the interval half-width."""
    z95 = 1.959963984540054
    out = []
    for r in est.iter_rows(named=True):
        for col, key, lo, hi in PARAMS:
            half = (r[hi] - r[lo]) / 2
            out.append((r[col] - truth[r["site_id"]][key]) / (half / z95))
    return out


@pytest.fixture(scope="module")
def biased_run(cfg):
    c = biased(cfg, INJECTED)
    radar, ais, truth = scenario_tables(c, duration_s=DURATION_S, seed=SEED)
    return c, radar, ais, truth


def test_config_section_parses_degrees(cfg):
    c = biased(cfg, {"R1": {"range_bias_m": 5.0, "azimuth_bias_deg": 0.5}}, apply=True,
               correction={"R2": {"time_offset_s": 0.25}})
    b = radar_bias_config(c)
    assert b.apply and b.simulate["R1"] == SiteBias(5.0, math.radians(0.5), 0.0)
    assert b.correction["R2"] == SiteBias(0.0, 0.0, 0.25)
    assert radar_bias_config(cfg).apply is False  # the shipped default applies nothing


def test_correction_removes_exactly_what_the_simulator_injects(cfg):
    """Same seed, same noise: biased reports minus the bias == unbiased reports."""
    clean, _, _ = scenario_tables(cfg, duration_s=240.0, seed=3)
    dirty, _, _ = scenario_tables(biased(cfg, INJECTED), duration_s=240.0, seed=3)
    corrected = correct_registration(dirty, radar_bias_config(biased(cfg, INJECTED)).simulate)
    key = ["site_id", "local_track_id", "log_time_ns"]
    a, b = clean.sort(key), corrected.sort(key)
    assert a.height == b.height > 100
    assert (a["time_ns"] - b["time_ns"]).abs().max() <= 1  # ns rounding
    # measured reports (coasted ones are extrapolated from a biased report: a range
    # offset changes their geometry slightly, they are not measurements)
    measured = (a["status"] != "coasting") & (b["status"] != "coasting")
    a, b = a.filter(measured), b.filter(measured)
    for col, tol in (("range_m", 1e-6), ("azimuth_rad", 1e-9), ("course_rad", 1e-9)):
        d = np.asarray(a[col] - b[col])
        if col != "range_m":
            d = (d + np.pi) % (2 * np.pi) - np.pi
        assert np.abs(d).max() < tol, col


def test_least_squares_recovers_theta_and_rejects_outliers():
    rng = np.random.default_rng(5)
    n = 4000
    theta = np.array([12.0, math.radians(-0.4), 0.8, 0.003])  # gain 3 m per km
    r = rng.uniform(2000, 20000, n)
    dr = rng.uniform(-8, 8, n)  # -(u_r . v), m/s
    daz = rng.uniform(-8, 8, n) / r
    sr, saz = np.full(n, 15.0), np.full(n, math.radians(0.45))
    res_r = theta[0] + theta[3] * r + dr * theta[2] + rng.normal(0, 15.0, n)
    res_az = theta[1] + daz * theta[2] + rng.normal(0, saz)
    bad = rng.choice(n, 40, replace=False)
    res_r[bad] += 400.0  # mismatched reports
    prior = 0.01
    fit = fit_bias(res_r, res_az, dr, daz, sr, saz, outlier_sigma=3.5,
                   track=np.repeat(np.arange(n // 20), 20), range_ref_m=r,
                   prior_range_gain=prior)
    assert not fit.used[bad].any() and fit.used.sum() > 0.99 * (n - 40)
    z = (fit.theta - theta) / np.sqrt(np.diag(fit.cov))
    assert np.all(np.abs(z) < 4), z
    # the interval is as wide as theory says (independent errors: no inflation), the
    # gain's prior a row of its own
    u = np.r_[fit.used, fit.used]
    A = np.column_stack([np.r_[np.ones(n), np.zeros(n)], np.r_[np.zeros(n), np.ones(n)],
                         np.r_[dr, daz], np.r_[r, np.zeros(n)]])[u]
    w = 1 / np.r_[sr, saz][u] ** 2
    info = A.T @ (A * w[:, None])
    info[3, 3] += 1 / prior**2
    expect = np.sqrt(np.diag(np.linalg.inv(info)))
    assert np.sqrt(np.diag(fit.cov)) == pytest.approx(expect, rel=0.1)


def test_the_gain_prior_holds_where_every_ship_is_at_one_range():
    """Ships all at 10 km: bias and gain cannot be told apart; the gain stays at its
    prior 0 +- 1 %, the bias takes the range error, and the fit's intervals say so."""
    rng = np.random.default_rng(9)
    n = 2000
    r = np.full(n, 10_000.0)
    dr, daz = rng.uniform(-8, 8, n), rng.uniform(-8, 8, n) / r
    sr, saz = np.full(n, 15.0), np.full(n, math.radians(0.45))
    res_r = 25.0 + rng.normal(0, 15.0, n)
    res_az = rng.normal(0, saz)
    fit = fit_bias(res_r, res_az, dr, daz, sr, saz, outlier_sigma=3.5, range_ref_m=r,
                   prior_range_gain=0.01)
    assert abs(fit.theta[3]) < 1e-3 and fit.theta[0] == pytest.approx(25.0, abs=2.0)
    sd = np.sqrt(np.diag(fit.cov))
    assert sd[3] == pytest.approx(0.01, rel=0.01) and sd[0] > 50.0
    # bias + gain x range, the range error at 10 km, is as precise as with one parameter
    d = np.array([1.0, 0.0, 0.0, 10_000.0])
    assert math.sqrt(d @ fit.cov @ d) < 1.0


def test_serial_inflation_is_one_for_white_noise_and_grows_with_correlation():
    rng = np.random.default_rng(2)
    track = np.repeat(np.arange(200), 50)
    white = rng.normal(size=track.size)
    assert serial_inflation(white, rng.normal(size=track.size), track) < 1.1
    ar = np.empty(track.size)
    ar[0] = 0.0
    e = rng.normal(size=track.size)
    for i in range(1, track.size):  # AR(1), rho = 0.6 (a reference series, not a hot path)
        ar[i] = 0.6 * ar[i - 1] + e[i]
    assert serial_inflation(ar, ar, track) == pytest.approx(1.6 / 0.4, rel=0.15)


def test_biases_recovered_from_ais_in_the_channel_scenario(biased_run):
    c, radar, ais, _ = biased_run
    est = estimate_biases(radar, ais, c, start_ns=T0_NS, end_ns=T0_NS + int(DURATION_S * NS))
    assert sorted(est["site_id"]) == ["R1", "R2"]
    assert (est["tracks_used"] >= 20).all() and (est["ships_used"] >= 15).all()
    # within their stated precision (the 95 % coverage is checked in the slow test)
    z = z_scores(est, INJECTED)
    assert np.all(np.abs(z) < 4), z
    # and precise: 20 minutes of traffic pin the biases down to (the range bias 1.2 m
    # wide with no gain estimated, ~1.8 m beside a gain 0.25 m per km wide)
    assert ((est["range_bias_ci_high_m"] - est["range_bias_ci_low_m"]) < 2.5).all()
    assert ((est["range_gain_ci_high"] - est["range_gain_ci_low"]) < 5e-4).all()
    assert ((est["azimuth_bias_ci_high_deg"] - est["azimuth_bias_ci_low_deg"]) < 0.04).all()
    assert ((est["time_offset_ci_high_s"] - est["time_offset_ci_low_s"]) < 0.25).all()


def test_applying_the_estimate_in_batch_restores_accuracy(biased_run):
    """The batch with [radar_bias] apply = true and the estimated corrections: fused
    errors shrink and the NEES comes back to ~2 (it is ~5 with uncorrected biases). The
    online registration (issue 38) off in both runs: it corrects a standing bias too;
    and the exclusion: uncorrected, both radars fail the integrity test all the time
    (20 m + 2 m per km against -15 m - 1 m per km) and nothing would be fused."""
    c, radar, ais, truth = biased_run
    c = with_sections(c, registration={**c.section("registration"), "enabled": False},
                      channel_integrity={**c.section("channel_integrity"), "exclusion": False})
    start, end = T0_NS + 300 * NS, T0_NS + 900 * NS
    est = estimate_biases(radar, ais, c, start_ns=T0_NS, end_ns=T0_NS + int(DURATION_S * NS))
    correction = {r["site_id"]: {k: r[k] for k in CORRECTED}
                  for r in est.iter_rows(named=True)}
    inputs = {"radar_tracks": radar, "ais_reports": ais, "truth": truth}

    def fused(config) -> pl.DataFrame:
        e = stage(inputs, Window(start, end), config)["track_errors"]
        return e.filter((pl.col("source") == "fused") & (pl.col("reference") == "truth"))

    raw = fused(c)
    fixed = fused(biased(c, INJECTED, apply=True, correction=correction))
    rms = {k: float(np.sqrt((f["error_m"] ** 2).mean())) for k, f in (("raw", raw),
                                                                      ("fixed", fixed))}
    assert rms["fixed"] < 0.8 * rms["raw"], rms
    assert raw["nees"].mean() > 3.0
    assert 1.6 < fixed["nees"].mean() < 2.4


def test_calibrate_radars_on_the_end_to_end_warehouse(e2e):
    """No bias injected there: the estimates are zero within their precision; the table
    is written and the config lines printed."""
    runner = CliRunner()
    args = ["--warehouse", str(e2e.warehouse), "calibrate-radars",
            "--from", str(e2e.start_ns), "--to", str(e2e.end_ns)]
    res = runner.invoke(cli, args)
    assert res.exit_code == 0, res.output
    assert "[radar_bias.correction]" in res.output and "R1 = {" in res.output
    est = pl.from_arrow(read_table(e2e.warehouse, "radar_bias_by_site"))
    assert sorted(est["site_id"]) == ["R1", "R2"]
    zero = {s: {k: 0.0 for _, k, _, _ in PARAMS} for s in ("R1", "R2")}
    assert np.all(np.abs(z_scores(est, zero)) < 4)
    empty = runner.invoke(cli, ["--warehouse", str(e2e.warehouse), "calibrate-radars",
                                "--from", "0", "--to", "1000"])
    assert empty.exit_code != 0 and "no radar" in str(empty.exception)


@pytest.mark.slow
def test_interval_coverage_over_seeds(cfg):
    """95 % intervals cover the injected biases ~95 % of the time (10 seeds x 2 sites x
    4 parameters, 20 minutes each). Run with -m slow -s to print the figures."""
    c = biased(cfg, INJECTED)
    z = []
    for seed in range(1, 11):
        radar, ais, _ = scenario_tables(c, duration_s=DURATION_S, seed=seed)
        est = estimate_biases(radar, ais, c, start_ns=T0_NS,
                              end_ns=T0_NS + int(DURATION_S * NS))
        z += z_scores(est, INJECTED)
    z = np.array(z)
    cover = float(np.mean(np.abs(z) <= 1.959963984540054))
    each = np.mean(np.abs(z.reshape(-1, len(PARAMS))) <= 1.959963984540054, axis=0)
    print(f"\ncoverage of the 95 % intervals: {cover:.3f} over {z.size} ("
          + ", ".join(f"{p[0]} {c:.2f}" for p, c in zip(PARAMS, each, strict=True))
          + f"); z mean {z.mean():.3f}, sd {z.std():.3f}")
    assert cover >= 0.85 and abs(z.mean()) < 0.5 and 0.7 < z.std() < 1.3
