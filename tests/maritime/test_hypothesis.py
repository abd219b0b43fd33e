"""The two-radar identification paper's hypothesis test (eq. 7-24) and its n x m
generalisation, checked against the paper's sums recomputed inline."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.maritime.hypothesis import (
    associate_pictures,
    hypothesis_sums,
    mahalanobis_sq,
    most_likely,
    paper_hypotheses,
    state_vectors,
    velocity_covariance,
)


def _q(d: np.ndarray, P: np.ndarray) -> float:
    return float(d @ np.linalg.inv(P) @ d)


@pytest.fixture()
def case_a():
    rng = np.random.default_rng(5)
    X1 = rng.normal(0.0, 40.0, (2, 2))
    X2 = rng.normal(0.0, 40.0, (2, 2))
    P1 = np.array([[400.0, 50.0], [50.0, 900.0]])
    P2 = np.array([[1600.0, -100.0], [-100.0, 225.0]])
    Xp = np.array([[3.0, -4.0], [60.0, 10.0]])
    return X1, X2, P1, P2, Xp


def test_case_a_sums_are_eq_12_to_15(case_a):
    X1, X2, P1, P2, Xp = case_a
    hyps = paper_hypotheses(2, 2)
    assert [h.name for h in hyps] == ["H1", "H2", "H3", "H4"]
    sums = hypothesis_sums([X1, X2], [np.stack([P1, P1]), np.stack([P2, P2])], hyps, Xp)

    def t(i, j, p):  # Delta X_{ij/p}^T P_i^-1 Delta X_{ij/p} (eq. 9-10), 1-based indices
        X, P = (X1, P1) if i == 1 else (X2, P2)
        return _q(X[j - 1] - Xp[p - 1], P)

    expect = [
        t(1, 1, 1) + t(2, 1, 1) + t(1, 2, 2) + t(2, 2, 2),  # eq. 12
        t(1, 2, 1) + t(2, 2, 1) + t(1, 1, 2) + t(2, 1, 2),  # eq. 13
        t(1, 1, 1) + t(2, 2, 1) + t(1, 2, 2) + t(2, 1, 2),  # eq. 14
        t(1, 2, 1) + t(2, 1, 1) + t(1, 1, 2) + t(2, 2, 2),  # eq. 15
    ]
    assert sums == pytest.approx(expect, rel=1e-12)


def test_cases_b_and_c_sums_are_eq_17_to_24(case_a):
    X1, X2, P1, P2, Xp = case_a

    def t(i, j, p):
        X, P = (X1, P1) if i == 1 else (X2, P2)
        return _q(X[j - 1] - Xp[p - 1], P)

    # case B: radar 2 reports one target (lambda_21)
    hb = paper_hypotheses(2, 1)
    assert [h.name for h in hb] == ["H1B", "H2B", "H3B", "H4B"]
    sums_b = hypothesis_sums([X1, X2[:1]], [np.stack([P1, P1]), P2[None]], hb, Xp)
    expect_b = [
        t(1, 1, 1) + t(2, 1, 1) + t(1, 2, 2),  # eq. 17
        t(1, 2, 1) + t(2, 1, 2) + t(1, 1, 2),  # eq. 18 (Delta X_222 read as Delta X_112)
        t(1, 1, 1) + t(1, 2, 2) + t(2, 1, 2),  # eq. 19
        t(1, 2, 1) + t(2, 1, 1) + t(1, 1, 2),  # eq. 20
    ]
    assert sums_b == pytest.approx(expect_b, rel=1e-12)
    # case C: radar 1 reports one target (lambda_11)
    hc = paper_hypotheses(1, 2)
    sums_c = hypothesis_sums([X1[:1], X2], [P1[None], np.stack([P2, P2])], hc, Xp)
    expect_c = [
        t(1, 1, 1) + t(2, 1, 1) + t(2, 2, 2),  # eq. 21
        t(2, 2, 1) + t(1, 1, 2) + t(2, 1, 2),  # eq. 22
        t(1, 1, 1) + t(2, 2, 1) + t(2, 1, 2),  # eq. 23
        t(2, 1, 1) + t(1, 1, 2) + t(2, 2, 2),  # eq. 24
    ]
    assert sums_c == pytest.approx(expect_c, rel=1e-12)


def test_unknown_targets_reduce_to_pairwise_distances(case_a):
    """X_p at its maximum-likelihood value: Sigma_k is the sum of the pairs' distances
    with P_1 + P_2, and H1 = H2, H3 = H4."""
    X1, X2, P1, P2, _ = case_a
    sums = hypothesis_sums([X1, X2], [np.stack([P1, P1]), np.stack([P2, P2])],
                        paper_hypotheses(2, 2))
    same = _q(X1[0] - X2[0], P1 + P2) + _q(X1[1] - X2[1], P1 + P2)
    cross = _q(X1[0] - X2[1], P1 + P2) + _q(X1[1] - X2[0], P1 + P2)
    assert sums == pytest.approx([same, same, cross, cross], rel=1e-10)


def test_most_likely_is_eq_16_and_batches_over_trials():
    rng = np.random.default_rng(11)
    n = 500
    truth = np.array([[0.0, 0.0], [300.0, 0.0]])
    X1 = truth + rng.normal(0, 10.0, (n, 2, 2))
    X2 = truth + rng.normal(0, 10.0, (n, 2, 2))
    P = np.broadcast_to(100.0 * np.eye(2), (n, 2, 2, 2))
    k, hyps = most_likely([X1, X2], [P, P], X_p=np.broadcast_to(truth, (n, 2, 2)))
    assert {hyps[i].name for i in k} == {"H1"}  # 30 sigma apart: always right
    k2, _ = most_likely([X1, X2[:, ::-1]], [P, P], X_p=np.broadcast_to(truth, (n, 2, 2)))
    assert {hyps[i].name for i in k2} == {"H3"}  # radar 2's reports swapped


def test_associate_pictures_n_radars_with_gate_and_missing_reports():
    truth = np.array([[0.0, 0.0], [500.0, 0.0], [0.0, 800.0]])
    rng = np.random.default_rng(3)
    P = 100.0 * np.eye(2)
    X = [truth + rng.normal(0, 5, (3, 2)), truth[[2, 0]] + rng.normal(0, 5, (2, 2)),
         np.vstack([truth[[1]] + rng.normal(0, 5, (1, 2)), [[5000.0, 5000.0]]])]
    labels = associate_pictures(X, [np.broadcast_to(P, (x.shape[0], 2, 2)) for x in X])
    assert labels[0].tolist() == [0, 1, 2]
    assert labels[1].tolist() == [2, 0]
    assert labels[2].tolist() == [1, 3]  # the far report is a target of its own


def test_associate_pictures_agrees_with_the_hypothesis_test():
    """Two paths agree: LSA on pairwise distances == argmin over H1..H4 (ungated)."""
    rng = np.random.default_rng(8)
    n, sigma = 300, 30.0
    truth = np.array([[0.0, 0.0], [40.0, 0.0]])
    X1 = truth + rng.normal(0, sigma, (n, 2, 2))
    X2 = truth + rng.normal(0, sigma, (n, 2, 2))
    P = np.broadcast_to(sigma**2 * np.eye(2), (n, 2, 2, 2))
    k, hyps = most_likely([X1, X2], [P, P])
    hyp_pairs = [hyps[i].targets[0] == hyps[i].targets[1] for i in k]
    lsa_pairs = []
    for t in range(n):
        lab = associate_pictures([X1[t], X2[t]], [P[t], P[t]], gate_probability=1 - 1e-12)
        lsa_pairs.append(lab[1].tolist() == [0, 1])
    assert 0.5 < np.mean(lsa_pairs) < 1.0  # a hard case: both outcomes occur
    assert hyp_pairs == lsa_pairs


def test_velocity_separates_crossing_targets():
    """Two ships at nearly the same place on courses 90 deg apart: position alone is a
    coin toss, position + velocity (d = 4) is not."""
    rng = np.random.default_rng(4)
    pos = np.array([[0.0, 0.0], [10.0, 0.0]])
    V, C = np.array([5.0, 5.0]), np.array([0.0, np.pi / 2])
    right_pos = right_vel = 0
    for _ in range(200):
        picks = []
        for _r in range(2):
            z = pos + rng.normal(0, 30.0, (2, 2))
            picks.append(state_vectors(z[:, 0], z[:, 1], np.full(2, 900.0), np.full(2, 900.0),
                                       np.zeros(2), V + rng.normal(0, 0.25, 2),
                                       C + rng.normal(0, 0.035, 2), np.full(2, 0.25),
                                       np.full(2, 0.035)))
        lab4 = associate_pictures([p[0] for p in picks], [p[1] for p in picks])
        lab2 = associate_pictures([p[0][:, :2] for p in picks], [p[1][:, :2, :2] for p in picks])
        right_vel += lab4[1].tolist() == [0, 1]
        right_pos += lab2[1].tolist() == [0, 1]
    assert right_vel >= 198  # a correct pair may fall outside the 0.999 gate
    assert right_pos < 160


def test_velocity_covariance_matches_the_jacobian_numerically():
    V, C, sv, sc = 6.0, 0.7, 0.2, 0.05
    cov = velocity_covariance(np.array([V]), np.array([C]), np.array([sv]), np.array([sc]))[0]
    h = 1e-6
    f = lambda v, c: np.array([v * np.sin(c), v * np.cos(c)])  # noqa: E731
    J = np.column_stack([(f(V + h, C) - f(V - h, C)) / (2 * h),
                         (f(V, C + h) - f(V, C - h)) / (2 * h)])
    assert cov == pytest.approx(J @ np.diag([sv**2, sc**2]) @ J.T, rel=1e-6, abs=1e-9)


def test_mahalanobis_sq_broadcasts():
    d = np.array([[1.0, 2.0], [3.0, -1.0]])
    P = np.array([[[2.0, 0.5], [0.5, 1.0]]] * 2)
    assert mahalanobis_sq(d, P) == pytest.approx([_q(d[0], P[0]), _q(d[1], P[1])])
