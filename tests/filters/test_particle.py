"""Bootstrap particle filter kernels (distributed maritime observation paper, eq. 3-7),
checked against the equations recomputed inline and against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from pipeline.filters import particle as pf
from pipeline.frames import wrap_angle


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


# --- weights -----------------------------------------------------------------------


def test_log_normalise_weights_and_ess_match_the_definitions():
    logw = np.log(np.array([[1.0, 2.0, 3.0, 4.0], [5.0, 5.0, 5.0, 5.0]])) - 700.0
    lw, total = pf.log_normalise(logw)
    w = np.array([[1, 2, 3, 4], [5, 5, 5, 5]], float)
    np.testing.assert_allclose(np.exp(lw), w / w.sum(axis=1, keepdims=True), rtol=1e-12)
    np.testing.assert_allclose(total, np.log(w.sum(axis=1)) - 700.0, rtol=1e-12)
    q = w / w.sum(axis=1, keepdims=True)
    np.testing.assert_allclose(pf.effective_sample_size(logw), 1.0 / np.sum(q * q, axis=1))
    assert pf.effective_sample_size(logw)[1] == pytest.approx(4.0)


def test_a_row_with_every_weight_zero_is_degenerate_not_nan():
    logw = np.array([[-np.inf, -np.inf], [0.0, -np.inf]])
    w = pf.normalised_weights(logw)
    np.testing.assert_array_equal(w, [[0.0, 0.0], [1.0, 0.0]])
    np.testing.assert_array_equal(pf.effective_sample_size(logw), [0.0, 1.0])
    assert np.isneginf(pf.logsumexp(logw)[0])


def test_constraint_gives_weight_zero_outside():
    """Eq. 4, 7: u_k uniform inside the admissible area, zero outside."""
    logw = np.zeros((1, 4))
    inside = np.array([[True, False, True, False]])
    np.testing.assert_array_equal(
        pf.normalised_weights(pf.apply_constraint(logw, inside)), [[0.5, 0.0, 0.5, 0.0]]
    )


def test_gaussian_log_likelihood_matches_scipy():
    rng = _rng(1)
    R = np.array([[[4.0, 1.0], [1.0, 2.0]], [[100.0, -30.0], [-30.0, 25.0]]])
    r = rng.normal(size=(2, 50, 2)) * 5
    got = pf.gaussian_log_likelihood(r, R)
    for g in range(2):
        want = stats.multivariate_normal(mean=[0, 0], cov=R[g]).logpdf(r[g])
        np.testing.assert_allclose(got[g], want, rtol=1e-10)
    R3 = np.array([[[9.0, 2.0, -1.0], [2.0, 4.0, 0.5], [-1.0, 0.5, 1.0]]])
    r3 = rng.normal(size=(1, 40, 3)) * 3
    want3 = stats.multivariate_normal(mean=[0, 0, 0], cov=R3[0]).logpdf(r3[0])
    np.testing.assert_allclose(pf.gaussian_log_likelihood(r3, R3)[0], want3, rtol=1e-10)


# --- resampling ----------------------------------------------------------------------


def _systematic_scalar(w: np.ndarray, u: float, n: int) -> np.ndarray:
    """Textbook systematic resampling of one row (the reference for the batch version)."""
    cum = np.cumsum(w / w.sum())
    cum[-1] = 1.0
    out, i = [], 0
    for j in range(n):
        pos = (u + j) / n
        while cum[i] <= pos:
            i += 1
        out.append(i)
    return np.array(out)


def test_systematic_resample_batch_equals_the_scalar_reference():
    rng = _rng(2)
    logw = np.log(rng.random((5, 40)) ** 3)
    logw[2, :30] = -np.inf  # mass on the last ten only
    idx = pf.systematic_resample(logw, _rng(3))
    u = _rng(3).random((5, 1))[:, 0]  # the same offsets the batch version drew
    for g in range(5):
        want = _systematic_scalar(np.exp(logw[g]), u[g], 40)
        np.testing.assert_array_equal(idx[g], want)


def test_systematic_counts_are_floor_or_ceil_of_n_times_weight():
    rng = _rng(4)
    w = rng.random((20, 100))
    idx = pf.systematic_resample(np.log(w), rng)
    q = w / w.sum(axis=1, keepdims=True)
    counts = np.stack([np.bincount(row, minlength=100) for row in idx])
    assert np.all(counts >= np.floor(100 * q) - 1e-9)
    assert np.all(counts <= np.ceil(100 * q) + 1e-9)


def test_resample_only_rows_below_the_ess_threshold():
    logw = np.stack([np.zeros(10), np.r_[0.0, np.full(9, -50.0)]])
    x = np.arange(20, dtype=float).reshape(2, 10, 1)
    out, lw, done = pf.resample(x, logw, _rng(5), ess_fraction=0.5)
    np.testing.assert_array_equal(done, [False, True])
    np.testing.assert_array_equal(out[0], x[0])
    np.testing.assert_array_equal(out[1, :, 0], np.full(10, 10.0))
    np.testing.assert_allclose(lw[1], -np.log(10))


def test_weighted_posterior_equals_the_kalman_update_in_the_linear_gaussian_case():
    """Prior N(m, P), y = x + v, v ~ N(0, R): the bootstrap posterior (eq. 4-7) must
    reproduce the Kalman posterior mean and variance, before and after resampling."""
    rng = _rng(6)
    m, P, R, y = 10.0, 4.0, 1.0, 12.5
    x = rng.normal(m, np.sqrt(P), size=(1, 50_000, 1))
    logw = pf.gaussian_log_likelihood(y - x, np.array([[[R]]]))
    K = P / (P + R)
    mean_kf, var_kf = m + K * (y - m), (1 - K) * P
    mean, cov = pf.weighted_mean_cov(x, logw)
    assert mean[0, 0] == pytest.approx(mean_kf, abs=0.02)
    assert cov[0, 0, 0] == pytest.approx(var_kf, rel=0.04)
    xr, _, _ = pf.resample(x, logw, rng, ess_fraction=1.0)
    assert xr.mean() == pytest.approx(mean_kf, abs=0.02)
    assert xr.var() == pytest.approx(var_kf, rel=0.04)


# --- one step, constraint, degeneracy -------------------------------------------------


def _shift(d: float):
    def prop(p, rows, rng):
        return p + d + 0.5 * rng.standard_normal(p.shape)

    return prop


def test_bootstrap_step_keeps_only_admissible_particles():
    """Half plane x > 0 admissible; a cloud centred on the boundary loses half its mass
    and every surviving particle is inside."""
    x = np.zeros((3, 4000, 1))
    res = pf.bootstrap_step(
        x,
        np.zeros((3, 4000)),
        _rng(7),
        propagate=_shift(0.0),
        admissible=lambda p, rows: p[..., 0] > 0,
        ess_fraction=1.0,
    )
    assert np.all(res.particles[..., 0] > 0)
    np.testing.assert_allclose(res.admissible_mass, 0.5, atol=0.03)
    assert not res.infeasible.any() and res.resampled.all()


def test_admissible_mass_is_exactly_one_when_no_particle_is_outside():
    """Was: the sum of the weights inside, 1 - 1e-16 for weights whose float sum rounds
    below 1 (numpy 2.4's sums: the gaps forecast of a ship in open water then reported
    its constraint "active"). Ten equal weights sum to 1 - 2.2e-16 with numpy 2.4 (the
    old code fails here)."""
    logw = np.zeros((2, 10))
    res = pf.bootstrap_step(
        np.zeros((2, 10, 1)),
        logw,
        _rng(9),
        propagate=_shift(0.0),
        admissible=lambda p, rows: np.ones(p.shape[:2], bool),
    )
    assert (res.admissible_mass == 1.0).all()


def test_infeasible_filter_keeps_its_prediction_and_says_so():
    x = np.zeros((2, 100, 1))
    res = pf.bootstrap_step(
        x,
        np.zeros((2, 100)),
        _rng(8),
        propagate=_shift(0.0),
        admissible=lambda p, rows: (p[..., 0] > 0) & (rows[:, None] == 0),
        replenish_with=(_shift(0.0),),
        max_rounds=2,
        min_ess=1.0,
    )
    np.testing.assert_array_equal(res.infeasible, [False, True])
    assert np.all(np.isfinite(res.logw[1]))
    assert res.rounds[1] == 2


def test_replenishment_from_the_prior_samples_the_truncated_prior():
    """Admissible only x > 2 (2.3 % of a standard normal prior): 200 particles leave
    ~4 survivors; with extra prior draws the pooled, resampled cloud follows the
    truncated normal (mean phi(2) / (1 - Phi(2)))."""
    N = 200
    x0 = np.zeros((1, N, 1))

    def prop(p, rows, rng):
        return rng.standard_normal(p.shape)

    res = pf.bootstrap_step(
        x0,
        np.zeros((1, N)),
        _rng(9),
        propagate=prop,
        admissible=lambda p, rows: p[..., 0] > 2.0,
        replenish_with=(prop,),
        max_rounds=40,
        min_ess=100.0,
    )
    want = stats.truncnorm(2.0, np.inf).mean()
    assert res.rounds[0] > 5
    assert np.all(res.particles[..., 0] > 2.0)
    assert res.particles[0, :, 0].mean() == pytest.approx(want, abs=0.06)
    assert len(np.unique(res.particles[0, :, 0])) > 60


def test_redraw_moves_outside_particles_inside_and_leaves_the_others():
    rng = _rng(10)
    prev = np.zeros((2, 500, 1))
    x = rng.normal(size=(2, 500, 1))
    inside = x[..., 0] > -1.0
    out, ok = pf.redraw_outside(
        prev,
        x,
        inside,
        rng,
        redraw=(_shift(0.0),) * 20,
        admissible=lambda p, rows: p[..., 0] > -1.0,
    )
    assert ok.all() and np.all(out[..., 0] > -1.0)
    np.testing.assert_array_equal(out[inside], x[inside])


# --- motion model and regularisation ---------------------------------------------------


def test_noise_free_propagation_is_straight_and_uniform():
    p = np.array([[[0.0, 0.0, 5.0, np.pi / 2], [100.0, 0.0, 2.0, 0.0]]])
    quiet = pf.MotionNoise(0.0, 0.0)
    out = pf.propagate_speed_course(p, 10.0, quiet, _rng(11))
    np.testing.assert_allclose(out[0, 0, :2], [50.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(out[0, 1, :2], [100.0, 20.0], atol=1e-9)
    same = pf.propagate_speed_course(p, np.array([0.0]), pf.MotionNoise(1.0, 1.0), _rng(12))
    np.testing.assert_allclose(same[..., :3], p[..., :3])


def test_course_random_walk_and_turn_rate_have_the_stated_statistics():
    N = 50_000
    p = np.zeros((1, N, 4))
    p[..., pf.SPEED] = 5.0
    p[..., pf.COURSE] = 1.0
    sc, dt = 0.01, 30.0
    out = pf.propagate_speed_course(p, dt, pf.MotionNoise(sc, 0.0), _rng(13))
    dc = out[0, :, pf.COURSE] - 1.0
    assert dc.std() == pytest.approx(sc * np.sqrt(dt), rel=0.02)
    lam, sj = 1.0 / 600.0, 0.8
    out = pf.propagate_speed_course(
        p, dt, pf.MotionNoise(0.0, 0.0, turn_rate_per_s=lam, turn_sigma_rad=sj), _rng(14)
    )
    jump = wrap_angle(out[0, :, pf.COURSE] - 1.0)
    turned = np.abs(jump) > 1e-12
    assert turned.mean() == pytest.approx(1 - np.exp(-lam * dt), rel=0.1)
    assert jump[turned].std() == pytest.approx(sj, rel=0.1)


def test_regularisation_keeps_the_mean_and_adds_h2_of_the_covariance():
    rng = _rng(15)
    N, d = 5000, 2
    x = rng.multivariate_normal([3.0, -1.0], [[4.0, 1.0], [1.0, 1.0]], size=(1, N))
    y = pf.regularise(x, rng, columns=(0, 1))
    h2 = (4.0 / (N * (d + 2))) ** (2.0 / (d + 4))
    np.testing.assert_allclose(y.mean(axis=1), x.mean(axis=1), atol=0.05)
    np.testing.assert_allclose(np.cov((y - x)[0].T), h2 * np.cov(x[0].T), rtol=0.1, atol=0.01 * h2)
