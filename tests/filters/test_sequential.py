"""Wald's SPRT held between its boundaries: the scan equals the recursion."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.filters.sequential import (
    held_cumsum,
    held_cumsum_reference,
    held_decision,
    wald_boundaries,
)


def test_wald_boundaries():
    lo, hi = wald_boundaries(0.001, 0.01)
    assert hi == pytest.approx(math.log(0.99 / 0.001))
    assert lo == pytest.approx(math.log(0.01 / 0.999))
    with pytest.raises(ValueError):
        wald_boundaries(0.6, 0.5)


@pytest.mark.parametrize("seed", range(4))
def test_scan_equals_recursion_over_segments(seed: int):
    rng = np.random.default_rng(seed)
    n = 5000
    llr = rng.normal(0.3, 3.0, n) * (rng.random(n) < 0.9)
    start = rng.random(n) < 0.02
    start[0] = True
    lo, hi = wald_boundaries(0.001, 0.01)
    got = held_cumsum(llr, start, lo, hi)
    want = held_cumsum_reference(llr, start, lo, hi)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    assert (got == hi).any() and (got == lo).any()  # both boundaries held


def test_decision_is_the_boundary_touched_last():
    lo, hi = -2.0, 3.0
    llr = np.array([2.0, 2.0, -1.0, -1.0, -1.0, -1.0, -1.0, 1.0, 9.0, 0.0])
    start = np.zeros(llr.size, bool)
    start[[0, 9]] = True
    s = held_cumsum(llr, start, lo, hi)
    np.testing.assert_allclose(s, [2, 3, 2, 1, 0, -1, -2, -1, 3, 0])
    assert held_decision(s, start, lo, hi).tolist() == [
        False, True, True, True, True, True, False, False, True, False]
