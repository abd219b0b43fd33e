"""pipeline.filters.gyro_gnss_log: the paper's six-state filter (eq. 1-3)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from pipeline.filters.gyro_gnss_log import (
    G_MPS2,
    IA,
    IW,
    FilterInputs,
    NavFilterModel,
    run_filter,
    step_model,
)
from pipeline.simulate.ownship import (
    OwnshipScenarioConfig,
    _gyro_and_roll,
    simulate_ownship,
)

LAT = np.radians([46.3])


def test_roll_row_tends_to_the_continuous_acceleration():
    """For dt -> 0 the y1 roll coefficients are z sin K / g (-(nu^2+mu^2), -2 mu)."""
    m = NavFilterModel()
    K = np.radians([70.0])
    sm = step_model(LAT, K, 1e-3, m)
    z, r = m.gyro.mount_height_m, m.roll
    expected = z * math.sin(K[0]) / G_MPS2 * np.array([-r.omega0_sq, -2 * r.irregularity_per_s])
    assert np.allclose(sm.H[0, 0, 3:5], expected, rtol=1e-2)
    assert sm.H[0, 0, 1] == 1.0 and sm.H[0, 0, IW] == pytest.approx(math.cos(K[0]) / G_MPS2)
    assert sm.u_gain[0] == pytest.approx(-math.sin(K[0]) / G_MPS2)


def test_heading_derivative_of_the_step_agrees_with_central_differences():
    """dF/dK (W column) and dGamma/dK of the step, exact by Van Loan, against central
    differences of the discretised model (the roll columns are left out on purpose, and
    W and a_s never reach the roll states, so these columns are complete)."""
    m = NavFilterModel()
    K = np.radians([0.0, 30.0, 135.0, 250.0])
    lat = np.full(K.size, LAT[0])
    sm = step_model(lat, K, 1.0, m)
    eps = 1e-6
    hi, lo = step_model(lat, K + eps, 1.0, m), step_model(lat, K - eps, 1.0, m)
    assert np.allclose(sm.F_dheading[:, :, IW], (hi.F - lo.F)[:, :, IW] / (2 * eps),
                       rtol=1e-6, atol=1e-12)
    assert np.allclose(sm.Gamma_dheading, (hi.Gamma - lo.Gamma) / (2 * eps),
                       rtol=1e-6, atol=1e-12)
    assert np.abs(sm.Gamma_dheading).max() > 1e-3  # not trivially zero


def test_discrete_model_matches_the_simulated_gyro_and_roll():
    """Q, the correlated-noise cross-covariance M (eq. 2, D W) and R11 of one 1-s step
    against 6000 s of the simulator's exact fine-step gyro + roll (seeded)."""
    c = OwnshipScenarioConfig()
    m = NavFilterModel()
    rng = np.random.default_rng(2)
    K = math.radians(90.0)
    h, per, T = 0.1, 10, 6000
    kin = {"K": np.full(T * per, K), "W": np.zeros(T * per), "a_s": np.zeros(T * per)}
    st = _gyro_and_roll(rng, kin, h, float(LAT[0]), c.gyro, c.roll, 0.0)
    a_n = c.gyro.mount_height_m * np.diff(st[:, 4]) / h * math.sin(K)
    y1 = (0.5 * (st[:-1, 1] + st[1:, 1]) + a_n / G_MPS2).reshape(T, per).mean(axis=1)
    k = np.arange(1, T + 1) * per
    x = np.column_stack([st[k, :5], np.zeros(T)])
    sm = step_model(LAT, np.array([K]), 1.0, m)
    w = x[1:] - x[:-1] @ sm.F[0].T
    r1 = (y1 - x @ sm.H[0, 0])[1:]
    roll = [3, 4]
    assert np.allclose(np.var(w[:, roll], axis=0), np.diag(sm.Q[0])[roll], rtol=0.1)
    assert np.var(w[:, 2]) == pytest.approx(sm.Q[0, 2, 2], rel=0.1)
    emp_m = np.array([np.cov(w[:, i], r1)[0, 1] for i in (2, 3, 4)])
    assert np.allclose(emp_m, sm.M[0, [2, 3, 4], 0], rtol=0.15)
    r11 = sm.R[0, 0, 0] - m.settings.accelerometer_sigma_rad**2
    assert np.var(r1) == pytest.approx(r11, rel=0.1)


def _inputs(sc, n_steps: int, drop: list[int] | None = None) -> FilterInputs:
    g = sc.gnss.head(n_steps)
    q = g["fix_quality"].to_numpy()
    ve = np.array((g["sog_mps"] * g["cog_rad"].sin()).fill_null(np.nan))
    vn = np.array((g["sog_mps"] * g["cog_rad"].cos()).fill_null(np.nan))
    if drop:
        ve[drop], vn[drop] = np.nan, np.nan
    lat = np.radians(g["lat_deg"].fill_null(strategy="forward").fill_null(46.3).to_numpy())

    def row(a) -> np.ndarray:
        return np.asarray(a, float)[:n_steps][None, :]

    return FilterInputs(
        1.0, row(sc.gyro_signals["accel_signal_rad"]), row(sc.gyro_signals["amplifier_rad"]),
        row(sc.gyro_heading["heading_rad"]), row(lat), row(ve), row(vn),
        row(sc.speed_log["speed_water_mps"]), (q == 0)[None, :])


@pytest.fixture(scope="module")
def short_scenario():
    c = dataclasses.replace(OwnshipScenarioConfig(), outlier_count=3, outages_s=())
    return simulate_ownship(c, start_ns=0, duration_s=400.0, seed=5)


def test_gate_rejects_outliers_and_keeps_the_prediction(short_scenario):
    """Eq. 3: every injected outlier fails the gate, and a rejected fix leaves the
    estimate exactly where the same run without that fix goes."""
    sc = short_scenario
    m = NavFilterModel()
    outliers = np.flatnonzero(sc.gnss["is_outlier"].to_numpy())
    assert outliers.size == 3
    out = run_filter(_inputs(sc, 400), m)
    assert (out.gate_passed[0, outliers] == 0).all()
    assert not out.fix_accepted[0, outliers].any()
    without = run_filter(_inputs(sc, 400, drop=list(outliers)), m)
    assert np.allclose(out.x, without.x, rtol=0, atol=1e-12, equal_nan=True)
    # a rejected fix: W after the step equals W predicted from the previous step alone
    k = int(outliers[0])
    assert np.isfinite(out.w_innovation[0, k])
    assert abs(out.w_innovation[0, k]) > 3 * out.w_innovation_sigma[0, k]


def test_filters_vectorised_over_runs_agree_with_single_runs(short_scenario):
    """Two paths agree: two filters in one call vs one call each."""
    sc = short_scenario
    m = NavFilterModel()
    a = _inputs(sc, 120)
    b = dataclasses.replace(a, accel_signal_rad=a.accel_signal_rad + 1e-4,
                            gyro_heading_rad=a.gyro_heading_rad + 0.01)
    both = FilterInputs(1.0, *(np.concatenate([getattr(a, f.name), getattr(b, f.name)])
                               for f in dataclasses.fields(a)[1:]))
    out2 = run_filter(both, m)
    for i, single in enumerate((a, b)):
        out1 = run_filter(single, m)
        assert np.allclose(out2.x[i], out1.x[0], atol=1e-10, equal_nan=True)
        assert np.allclose(out2.P_diag[i], out1.P_diag[0], atol=1e-12, equal_nan=True)


def test_without_gyro_signals_alpha_keeps_its_prior(short_scenario):
    """No accelerometer/amplifier logged (real NMEA logs): only y3 updates; alpha is not
    observable (it moves only through the model's weak coupling with W and keeps its
    prior sigma); W is still estimated."""
    sc = short_scenario
    m = NavFilterModel()
    inp = _inputs(sc, 200)
    nan = np.full_like(inp.accel_signal_rad, np.nan)
    out = run_filter(dataclasses.replace(inp, accel_signal_rad=nan, amplifier_rad=nan), m)
    prior = m.settings.prior_alpha_sigma_rad
    assert np.abs(out.x[0, :, IA]).max() < 0.1 * prior
    assert np.sqrt(out.P_diag[0, :, IA]).min() > 0.9 * prior
    true_w = sc.truth["accel_mps2"].to_numpy()[150:200]
    assert np.abs(out.x[0, 150:200, IW] - true_w).mean() < 0.01
