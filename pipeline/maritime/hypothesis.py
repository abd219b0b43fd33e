"""Target identification by the least summed Mahalanobis distance (two-radar
identification paper, eq. 7-24), and its n radars x m targets generalisation.

The paper (Baryshev & Mazurenko): two radars report l = 2 targets; report j of radar i
is lambda_ij = (X_ij, P_i) (eq. 1-3). A hypothesis H_k assigns every report of every
radar to a target p; with independent Gaussian errors its probability is (eq. 8, 10, 11)

.. math:: P(H_k) \\propto \\exp(-\\Sigma_k / 2), \\qquad
          \\Sigma_k = \\sum_{(i, j) \\to p \\text{ under } H_k}
          \\Delta X_{ij/p}^T P_i^{-1} \\Delta X_{ij/p}, \\quad
          \\Delta X_{ij/p} = X_{ij} - X_p

(eq. 9, 12-15), the normalising constants being equal for all hypotheses; the most
likely hypothesis has the least Sigma_k (eq. 16). Case A: both radars report two targets,
hypotheses H1..H4 (eq. 12-15); cases B / C: radar 2 / radar 1 reports one target,
eq. 17-20 / 21-24. Every hypothesis of the paper is one injective map of each radar's
reports onto the targets, and the paper's list is the product of those maps in the
order given by :func:`paper_hypotheses` (eq. 18 prints Delta X_222 where the report
lambda_22 does not exist in case B; by the symmetry of eq. 17-20 the term is
Delta X_112, report 11 to target 2, which is what we use).

X_p, the target's vector (eq. 4), is either given (e.g. a system track's prediction) or,
when unknown, its maximum-likelihood value under the hypothesis: the eq. 6 mean of the
reports assigned to p with weights P_i^-1. Then, for two reports a and b assigned to one
target, :math:`\\Delta_a^T P_a^{-1} \\Delta_a + \\Delta_b^T P_b^{-1} \\Delta_b =
(X_a - X_b)^T (P_a + P_b)^{-1} (X_a - X_b)`, so Sigma_k is the sum of the pairwise
distances of the pairs the hypothesis forms (H1 and H2 are the same pairing with the
target labels swapped and have equal sums, likewise H3 and H4).

Generalisation (:func:`associate_pictures`): n radars, any numbers of reports. Radars
are taken in order; radar k's reports are assigned to the targets formed by radars < k
(their P^-1-weighted means) by the least sum of pairwise distances, which is a linear
assignment problem; leaving a report unassigned costs the gate chi2.ppf(p, d), which
yields cases B and C (and any m x n) without enumerating hypotheses. The state is the
position (d = 2) or, where the radars report it, position and velocity (d = 4, velocity
covariance from the speed and course sigmas).

Arrays: ``X`` (..., m, d) report vectors, ``P`` (..., m, d, d) their covariances; a
leading batch axis (Monte Carlo trials, epochs) is carried through every function.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.maritime.associate import assign, gate_threshold


@dataclass(frozen=True)
class Hypothesis:
    """One hypothesis: ``targets[i][j]`` is the target index of report j of radar i."""

    name: str
    targets: tuple[tuple[int, ...], ...]


def paper_hypotheses(m1: int, m2: int, n_targets: int = 2) -> list[Hypothesis]:
    """The hypotheses of the paper for radar 1 reporting ``m1`` and radar 2 ``m2``
    targets, in the paper's order (case A: H1..H4 of eq. 12-15; case B (m2 = 1):
    eq. 17-20; case C (m1 = 1): eq. 21-24). Other (m1, m2, n_targets): every product of
    injective maps, radar 1's map varying slowest.
    """
    ident, swap = (0, 1), (1, 0)
    table = {
        (2, 2, 2): ("A", [(ident, ident), (swap, swap), (ident, swap), (swap, ident)]),
        (2, 1, 2): ("B", [(ident, (0,)), (swap, (1,)), (ident, (1,)), (swap, (0,))]),
        (1, 2, 2): ("C", [((0,), ident), ((1,), swap), ((0,), swap), ((1,), ident)]),
    }
    if (m1, m2, n_targets) in table:
        case, maps = table[(m1, m2, n_targets)]
        suffix = "" if case == "A" else case
        return [Hypothesis(f"H{k + 1}{suffix}", m) for k, m in enumerate(maps)]
    maps1 = list(itertools.permutations(range(n_targets), m1))
    maps2 = list(itertools.permutations(range(n_targets), m2))
    return [
        Hypothesis(f"H{k + 1}", (a, b)) for k, (a, b) in enumerate(itertools.product(maps1, maps2))
    ]


def mahalanobis_sq(delta: np.ndarray, P: np.ndarray) -> np.ndarray:
    """delta^T P^-1 delta over the last axis: delta (..., d), P (..., d, d) -> (...)."""
    return np.einsum("...i,...i->...", delta, np.linalg.solve(P, delta[..., None])[..., 0])


def _target_vectors(
    X: Sequence[np.ndarray], P: Sequence[np.ndarray], hyp: Hypothesis, n_targets: int
) -> np.ndarray:
    """Maximum-likelihood X_p under ``hyp``: the P^-1-weighted mean of the reports
    assigned to each target (eq. 6 with weights from the error matrices). (..., l, d);
    NaN for a target no report is assigned to (it adds nothing to Sigma_k)."""
    batch, d = X[0].shape[:-2], X[0].shape[-1]
    info = np.zeros((*batch, n_targets, d, d))
    vec = np.zeros((*batch, n_targets, d))
    for Xi, Pi, tgt in zip(X, P, hyp.targets, strict=True):
        Ii = np.linalg.inv(Pi)
        for j, p in enumerate(tgt):
            info[..., p, :, :] += Ii[..., j, :, :]
            vec[..., p, :] += np.einsum("...ij,...j->...i", Ii[..., j, :, :], Xi[..., j, :])
    used = np.abs(np.linalg.det(info)) > 0
    safe = np.where(used[..., None, None], info, np.eye(d))
    return np.where(used[..., None], np.linalg.solve(safe, vec[..., None])[..., 0], np.nan)


def hypothesis_sums(
    X: Sequence[np.ndarray],
    P: Sequence[np.ndarray],
    hypotheses: Sequence[Hypothesis],
    X_p: np.ndarray | None = None,
) -> np.ndarray:
    """Sigma_k of every hypothesis (eq. 12-15, 17-24): (..., n_hypotheses).

    ``X[i]`` (..., m_i, d) and ``P[i]`` (..., m_i, d, d): radar i's reports and their
    error matrices; ``X_p`` (..., l, d): the targets' vectors, or None for their
    maximum-likelihood values under each hypothesis (see the module docstring).
    """
    n_targets = max(max(t, default=-1) for h in hypotheses for t in h.targets) + 1
    if X_p is not None:
        n_targets = max(n_targets, X_p.shape[-2])
    sums = []
    for hyp in hypotheses:
        Xp = _target_vectors(X, P, hyp, n_targets) if X_p is None else X_p
        s = 0.0
        for Xi, Pi, tgt in zip(X, P, hyp.targets, strict=True):
            delta = Xi - Xp[..., list(tgt), :]
            s = s + mahalanobis_sq(delta, Pi).sum(axis=-1)
        sums.append(s)
    return np.stack(np.broadcast_arrays(*sums), axis=-1)


def most_likely(
    X: Sequence[np.ndarray],
    P: Sequence[np.ndarray],
    X_p: np.ndarray | None = None,
    n_targets: int = 2,
) -> tuple[np.ndarray, list[Hypothesis]]:
    """Eq. 16 for two radars: index of the hypothesis with the least Sigma_k (...,), and
    the hypotheses (:func:`paper_hypotheses`, case A, B or C from the report counts).
    Ties (equal sums) go to the first hypothesis in the paper's order."""
    hyps = paper_hypotheses(X[0].shape[-2], X[1].shape[-2], n_targets)
    return np.argmin(hypothesis_sums(X, P, hyps, X_p), axis=-1), hyps


# --- state vectors --------------------------------------------------------------------


def velocity_covariance(
    speed_mps: np.ndarray,
    course_rad: np.ndarray,
    sigma_speed_mps: np.ndarray,
    sigma_course_rad: np.ndarray,
) -> np.ndarray:
    """Covariance of (v_east, v_north) = V (sin C, cos C) from independent speed and
    course errors, J diag(sigma_V^2, sigma_C^2) J^T: (n, 2, 2) in (m/s)^2."""
    s, c = np.sin(course_rad), np.cos(course_rad)
    V = np.asarray(speed_mps, float)
    J = np.stack([np.stack([s, V * c], -1), np.stack([c, -V * s], -1)], -2)
    D = np.zeros((*J.shape[:-2], 2, 2))
    D[..., 0, 0] = np.asarray(sigma_speed_mps, float) ** 2
    D[..., 1, 1] = np.asarray(sigma_course_rad, float) ** 2
    return J @ D @ np.swapaxes(J, -1, -2)


def state_vectors(
    x_m: np.ndarray,
    y_m: np.ndarray,
    P_xx: np.ndarray,
    P_yy: np.ndarray,
    P_xy: np.ndarray,
    speed_mps: np.ndarray | None = None,
    course_rad: np.ndarray | None = None,
    sigma_speed_mps: np.ndarray | None = None,
    sigma_course_rad: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Report vectors X (n, d) and covariances P (n, d, d): position (d = 2), or position
    and velocity (d = 4, block-diagonal: the tracker's position-velocity
    cross-covariance is not in the log) when speed and course are given."""
    pos = np.stack([x_m, y_m], -1).astype(float)
    Pp = np.stack([np.stack([P_xx, P_xy], -1), np.stack([P_xy, P_yy], -1)], -2).astype(float)
    if speed_mps is None:
        return pos, Pp
    V, C = np.asarray(speed_mps, float), np.asarray(course_rad, float)
    vel = np.stack([V * np.sin(C), V * np.cos(C)], -1)
    Pv = velocity_covariance(V, C, sigma_speed_mps, sigma_course_rad)
    P = np.zeros((*pos.shape[:-1], 4, 4))
    P[..., :2, :2], P[..., 2:, 2:] = Pp, Pv
    return np.concatenate([pos, vel], -1), P


# --- n radars x m targets ---------------------------------------------------------------


def pair_cost(
    Xa: np.ndarray, Pa: np.ndarray, Xb: np.ndarray, Pb: np.ndarray, gate: float
) -> np.ndarray:
    """(n_a, n_b) pairwise distances (X_a - X_b)^T (P_a + P_b)^-1 (X_a - X_b), +inf at
    or beyond ``gate`` (broadcast over all pairs)."""
    delta = Xa[:, None, :] - Xb[None, :, :]
    d2 = mahalanobis_sq(delta, Pa[:, None] + Pb[None, :])
    return np.where(d2 < gate, d2, np.inf)


def associate_pictures(
    X: Sequence[np.ndarray], P: Sequence[np.ndarray], gate_probability: float = 0.999
) -> list[np.ndarray]:
    """Group the reports of n radars into targets (one epoch).

    ``X[i]`` (m_i, d), ``P[i]`` (m_i, d, d). Returns, per radar, the target index of each
    report (targets numbered from 0 in order of creation). Radar k's reports are
    assigned to the targets formed so far (P^-1-weighted means of their members) by
    the least sum of distances, a report staying alone when no target is within the
    gate chi2.ppf(gate_probability, d) (its cost of non-assignment).
    """
    d = X[0].shape[-1]
    gate = gate_threshold(gate_probability, d)
    info = np.zeros((0, d, d))
    vec = np.zeros((0, d))
    labels = []
    for Xi, Pi in zip(X, P, strict=True):
        lab = np.full(Xi.shape[0], -1)
        if info.shape[0]:
            Pt = np.linalg.inv(info)
            Xt = np.einsum("nij,nj->ni", Pt, vec)
            rows, cols = assign(pair_cost(Xi, Pi, Xt, Pt, gate), gate)
            lab[rows] = cols
        new = np.flatnonzero(lab < 0)
        lab[new] = info.shape[0] + np.arange(new.size)
        info = np.concatenate([info, np.zeros((new.size, d, d))])
        vec = np.concatenate([vec, np.zeros((new.size, d))])
        Ii = np.linalg.inv(Pi)
        np.add.at(info, lab, Ii)
        np.add.at(vec, lab, np.einsum("nij,nj->ni", Ii, Xi))
        labels.append(lab)
    return labels
