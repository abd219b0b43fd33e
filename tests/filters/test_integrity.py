"""Channel integrity (airfield paper eq. 21-23) and the exclusion/readmission rule."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from pipeline.filters.integrity import chi2_thresholds, eta, nis, step_exclusion


@pytest.mark.parametrize("q", [0.001, 0.01, 0.05])
@pytest.mark.parametrize("dof", [1, 2, 4])
def test_thresholds_hold_one_minus_q_with_equal_tails(q, dof):
    d1, d2 = chi2_thresholds(q, dof)
    assert stats.chi2.cdf(d1, dof) == pytest.approx(q / 2)
    assert stats.chi2.sf(d2, dof) == pytest.approx(q / 2)
    assert stats.chi2.cdf(d2, dof) - stats.chi2.cdf(d1, dof) == pytest.approx(1 - q)


def test_bad_q_is_rejected():
    with pytest.raises(ValueError):
        chi2_thresholds(0.0, 2)


def test_nis_closed_form_agrees_with_a_solve():
    rng = np.random.default_rng(2)
    A = rng.normal(size=(500, 2, 2))
    S = A @ np.transpose(A, (0, 2, 1)) + 0.1 * np.eye(2)
    r = rng.normal(size=(500, 2))
    ref = np.array([ri @ np.linalg.solve(Si, ri) for ri, Si in zip(r, S, strict=True)])
    np.testing.assert_allclose(nis(r, S), ref, rtol=1e-10)
    r3 = rng.normal(size=(5, 3))
    S3 = np.repeat(np.eye(3)[None] * 2.0, 5, axis=0)
    np.testing.assert_allclose(nis(r3, S3), (r3**2).sum(axis=1) / 2.0)


def test_eta_is_one_outside_the_open_interval():
    np.testing.assert_array_equal(eta(np.array([0.0, 0.5, 1.0, 2.0, 3.0]), 0.5, 2.0),
                                  [1, 1, 0, 1, 1])


def test_consistent_innovations_are_flagged_at_rate_q():
    """Gaussian innovations with their own covariance: the flagged share is q."""
    rng = np.random.default_rng(8)
    n, q = 200_000, 0.01
    L = np.array([[2.0, 0.0], [0.7, 1.1]])
    r = rng.standard_normal((n, 2)) @ L.T
    S = np.repeat((L @ L.T)[None], n, axis=0)
    d1, d2 = chi2_thresholds(q, 2)
    share = eta(nis(r, S), d1, d2).mean()
    assert 0.9 * q < share < 1.1 * q


def run_rule(flags, below, readmit=3):
    """Drive step_exclusion for one target over a sequence of checks."""
    ex, run = np.zeros(1, bool), np.zeros(1, int)
    states = []
    for f, b in zip(flags, below, strict=True):
        ex, run = step_exclusion(ex, run, np.array([f]), np.array([b]), np.array([True]),
                                 readmit)
        states.append(bool(ex[0]))
    return states


def test_a_flag_excludes_and_a_run_of_passes_readmits():
    flags = [0, 1, 0, 0, 0, 0]
    assert run_rule(flags, [True] * 6) == [False, True, True, True, False, False]


def test_an_upper_tail_check_resets_the_run():
    flags = [1, 0, 0, 1, 0, 0, 0]
    below = [False, True, True, False, True, True, True]
    assert run_rule(flags, below) == [True, True, True, True, True, True, False]


def test_a_lower_tail_flag_counts_as_a_pass_while_excluded():
    # xi <= d1 gives eta = 1 but xi < d2: while excluded it does not hold the channel out
    flags = [1, 1, 1, 1]
    below = [False, True, True, True]
    assert run_rule(flags, below) == [True, True, True, False]


def test_unchecked_targets_keep_their_state():
    ex, run = step_exclusion(np.array([True, False]), np.array([2, 0]), np.array([False, True]),
                             np.array([True, False]), np.array([False, False]), 3)
    np.testing.assert_array_equal(ex, [True, False])
    np.testing.assert_array_equal(run, [2, 0])
