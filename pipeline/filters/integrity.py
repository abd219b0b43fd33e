"""Channel integrity monitoring and reconfiguration (airfield paper eq. 21–23).

Per channel i and target, the quadratic form of the innovation

.. math:: \\xi_i = r_i^T (H_i P H_i^T + R_i)^{-1} r_i \\qquad \\text{(eq. 21)}

is χ²-distributed with dim(r_i) degrees of freedom in normal operation. With the
q-percent thresholds d1, d2 such that P{d1 < ξ < d2} = 1 − q (eq. 22), we take the
two equal tails, d1 = χ²_m(q/2) and d2 = χ²_m(1 − q/2), and

.. math:: \\eta_i = 0 \\text{ if } \\xi_i \\in (d_1, d_2), \\; 1 \\text{ otherwise}
          \\qquad \\text{(eq. 23)}

A channel with η = 1 is excluded from the fusion for that target and readmitted after
``readmit_run`` consecutive passing checks (our reconfiguration rule; the paper states
only that an anomalous channel's data are excluded). All functions are vectorised over
targets; the state of the rule is plain arrays, returned, never mutated.
"""

from __future__ import annotations

import numpy as np

from pipeline.filters.quantiles import chi2_ppf


def chi2_thresholds(q: float, dof: int) -> tuple[float, float]:
    """(d1, d2) with P{d1 < ξ < d2} = 1 − q for ξ ~ χ²(dof), equal tails (eq. 22)."""
    if not 0.0 < q < 1.0:
        raise ValueError("q must be in (0, 1)")
    return float(chi2_ppf(q / 2.0, dof)), float(chi2_ppf(1.0 - q / 2.0, dof))


def nis(r: np.ndarray, S: np.ndarray) -> np.ndarray:
    """ξ = rᵀ S⁻¹ r (eq. 21) for r (n, m) and S (n, m, m) -> (n,)."""
    if r.shape[-1] == 2:  # closed form for the 2-D position innovations
        a, b, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
        x, y = r[:, 0], r[:, 1]
        return (d * x * x - 2.0 * b * x * y + a * y * y) / (a * d - b * b)
    sol = np.linalg.solve(S, r[..., None])[..., 0]
    return np.einsum("nm,nm->n", r, sol)


def eta(xi: np.ndarray, d1: float, d2: float) -> np.ndarray:
    """η (eq. 23): 1 when ξ is outside (d1, d2), else 0; int8 (n,)."""
    xi = np.asarray(xi, float)
    return ((xi <= d1) | (xi >= d2)).astype(np.int8)


def step_exclusion(
    excluded: np.ndarray,
    pass_run: np.ndarray,
    flagged: np.ndarray,
    below_d2: np.ndarray,
    checked: np.ndarray,
    readmit_run: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Advance the exclusion rule by one epoch for every target of one channel.

    An included channel with η = 1 (``flagged``) is excluded and its run reset. An
    excluded channel counts a check with ξ < d2 (``below_d2``) as a pass and is readmitted
    once ``readmit_run`` passes follow one another (the readmitting check's measurement
    is used); a check with ξ ≥ d2 resets the run. Only the upper tail can hold a channel
    out: while excluded its own error states are not updated, so its S carries their
    unconditioned variance and ξ is biased low — a small ξ then says nothing about a
    fault (with the two-sided test, lower-tail flags kept the only healthy channel out
    during a double fault, measured; see docs/airfield.md). Unchecked entries keep
    their state. Returns the new (excluded, pass_run)."""
    exclude = checked & flagged & ~excluded
    passing = checked & excluded & below_d2
    failing = checked & excluded & ~below_d2
    run = np.where(passing, pass_run + 1, np.where(failing | exclude, 0, pass_run))
    readmit = passing & (run >= readmit_run)
    new_excluded = (excluded | exclude) & ~readmit
    return new_excluded, np.where(new_excluded, run, 0)
