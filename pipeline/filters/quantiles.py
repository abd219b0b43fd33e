"""Quantiles of the chi-square and normal distributions: the gates and thresholds.

The same ``scipy.special`` calls ``scipy.stats`` makes for ``chi2.ppf`` and ``norm.ppf``
(its ``_ppf`` methods; the location 0 and scale 1 it then applies change no bit), without
importing ``scipy.stats``: ~0.5 s of the ~2.3 s a batch worker spent importing on this
machine, paid by every batch worker and every command that runs a stage
(tests/filters/test_quantiles.py holds them equal to ``scipy.stats`` to the bit).
"""

from __future__ import annotations

import numpy as np
from scipy import special


def chi2_ppf(p: float | np.ndarray, dof: float | np.ndarray) -> float | np.ndarray:
    """x with P{ξ <= x} = p for ξ ~ χ²(dof), p in (0, 1): 2 P^-1(dof / 2, p), P the
    regularized lower incomplete gamma function."""
    return 2 * special.gammaincinv(np.asarray(dof) / 2, p)


def normal_ppf(p: float | np.ndarray) -> float | np.ndarray:
    """x with P{ξ <= x} = p for ξ ~ N(0, 1), p in (0, 1)."""
    return special.ndtri(p)
