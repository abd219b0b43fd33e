"""Vector AR error models (airfield paper eq. 2, 7, 8): simulation, LS / Yule-Walker fits
with white-noise bias compensation, BIC order selection, confidence intervals."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.filters.ar_errors import (
    VarModel,
    companion,
    fit_var_ls,
    fit_var_yule_walker,
    is_stable,
    lagged_rows,
    select_order,
    simulate_var,
    stationary_covariance,
)

AR2 = VarModel([[[1.30, 0.10], [-0.05, 1.20]], [[-0.45, -0.06], [0.04, -0.35]]],
               [[1.00, 0.0], [0.25, 0.90]])
AR1 = VarModel([[[0.80, 0.05], [0.0, 0.75]]], [[0.15, 0.0], [0.03, 0.18]])
Z_999 = 3.2905


def series(model: VarModel, n_steps: int, n_series: int, seed: int):
    x = simulate_var(model, n_steps, n_series, np.random.default_rng(seed))
    seg = np.repeat(np.arange(n_series), n_steps)
    step = np.tile(np.arange(n_steps), n_series)
    return x.reshape(-1, model.dim), seg, step


def test_companion_is_the_markov_form_of_eq_9():
    A, G = companion(AR2)
    assert A.shape == (4, 4) and G.shape == (4, 2)
    np.testing.assert_array_equal(A[:2, :2], AR2.B[0])
    np.testing.assert_array_equal(A[:2, 2:], AR2.B[1])
    np.testing.assert_array_equal(A[2:, :2], np.eye(2))  # e(k-1) shifts down
    np.testing.assert_array_equal(G[:2], AR2.Gamma)


def test_stationary_covariance_matches_a_long_simulation():
    x, *_ = series(AR2, 4000, 40, seed=1)
    P = stationary_covariance(AR2)[:2, :2]
    np.testing.assert_allclose(np.cov(x.T), P, rtol=0.06)


def test_an_explosive_model_has_no_stationary_covariance():
    bad = VarModel([[[1.05, 0.0], [0.0, 0.5]]], np.eye(2))
    assert not is_stable(bad)
    with pytest.raises(ValueError, match="not stable"):
        stationary_covariance(bad)


def test_lagged_rows_break_at_gaps_and_segments():
    s = np.arange(14, dtype=float).reshape(7, 2)
    seg = np.array([0, 0, 0, 0, 1, 1, 1])
    step = np.array([0, 1, 2, 4, 5, 6, 7])  # gap between steps 2 and 4
    Y, X, idx = lagged_rows(s, seg, step, 2)
    # rows need two gap-free lags in the same segment: sample 2 (steps 0,1) and 6 (5,6)
    np.testing.assert_array_equal(idx, [2, 6])
    np.testing.assert_array_equal(X[0], np.r_[s[1], s[0]])
    np.testing.assert_array_equal(Y[1], s[6])


def test_least_squares_recovers_the_coefficients_within_their_intervals():
    x, seg, step = series(AR2, 600, 20, seed=3)
    fit = fit_var_ls(x, seg, step, 2)
    z = np.abs(fit.model.B - AR2.B) / fit.se_b
    assert z.max() < Z_999, z
    lo, hi = fit.gamma_ci
    tril = np.tril_indices(2)
    assert np.all((AR2.Gamma[tril] >= lo[tril]) & (AR2.Gamma[tril] <= hi[tril]))


def test_bias_compensation_removes_the_quantisation_attenuation():
    """1 m quantisation (CAT010 LSB) biases plain LS; the compensated fit is unbiased."""
    rng = np.random.default_rng(5)
    x, seg, step = series(AR2, 800, 25, seed=5)
    off = rng.uniform(0.0, 1.0, x.shape)  # a moving target: the LSB grid slides under it
    q = np.round(x + off) - off
    plain = fit_var_ls(q, seg, step, 2)
    fixed = fit_var_ls(q, seg, step, 2, white_cov=np.eye(2) / 12.0)
    z_plain = np.abs(plain.model.B - AR2.B) / plain.se_b
    z_fixed = np.abs(fixed.model.B - AR2.B) / fixed.se_b
    assert z_plain.max() > 4.0
    assert z_fixed.max() < Z_999, z_fixed


def test_yule_walker_and_least_squares_agree():
    x, seg, step = series(AR2, 1000, 10, seed=7)
    ls = fit_var_ls(x, seg, step, 2).model
    yw = fit_var_yule_walker(x, seg, 2)
    np.testing.assert_allclose(yw.B, ls.B, atol=0.02)
    np.testing.assert_allclose(yw.Gamma, ls.Gamma, atol=0.02)


@pytest.mark.parametrize(("model", "order"), [(AR2, 2), (AR1, 1)])
def test_bic_picks_the_true_order(model, order):
    x, seg, step = series(model, 500, 20, seed=11)
    fit = select_order(x, seg, step, max_order=4)
    assert fit.model.order == order
    assert set(fit.bic_by_order) == {1, 2, 3, 4}
    assert fit.bic == min(fit.bic_by_order.values())


def test_too_few_rows_is_an_error():
    x, seg, step = series(AR2, 12, 1, seed=1)
    with pytest.raises(ValueError, match="too few rows"):
        fit_var_ls(x, seg, step, 2)
