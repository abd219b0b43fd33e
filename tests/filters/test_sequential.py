"""Wald's SPRT held between its boundaries: the scan equals the recursion."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.filters.sequential import (
    BOUNDARY_TOLERANCE,
    fixed_lag_decision,
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


def _fixed_lag_reference(s, start, lo, hi, t, lag):
    """Row by row: the next row of the segment at a boundary, if within the lag."""
    causal = held_decision(s, start, lo, hi)
    seg = np.cumsum(start)
    out = causal.copy()
    for i in range(s.size):
        for j in range(i, s.size):
            if seg[j] != seg[i] or t[j] - t[i] > lag:
                break
            if s[j] >= hi - BOUNDARY_TOLERANCE or s[j] <= lo + BOUNDARY_TOLERANCE:
                out[i] = s[j] >= hi - BOUNDARY_TOLERANCE
                break
    return out


@pytest.mark.parametrize("seed", range(3))
def test_fixed_lag_decision_is_the_next_boundary_within_the_lag(seed: int):
    rng = np.random.default_rng(seed)
    n = 1500
    llr = rng.normal(0.2, 2.5, n)
    start = rng.random(n) < 0.03
    start[0] = True
    t = np.cumsum(rng.integers(1, 6, n)) * 10**9
    lo, hi = wald_boundaries(0.001, 0.01)
    s = held_cumsum(llr, start, lo, hi)
    for lag in (0, 4 * 10**9, 20 * 10**9):
        got = fixed_lag_decision(s, start, lo, hi, t, lag)
        np.testing.assert_array_equal(got, _fixed_lag_reference(s, start, lo, hi, t, lag))
    causal = held_decision(s, start, lo, hi)
    smoothed = fixed_lag_decision(s, start, lo, hi, t, 20 * 10**9)
    assert (smoothed & ~causal).any() and (causal & ~smoothed).any()  # both ways


def test_fixed_lag_names_from_the_start_of_the_evidence():
    lo, hi = -2.0, 3.0
    llr = np.array([2.0, 2.0, -1.0, -1.0, -1.0, -1.0, -1.0, 1.0, 9.0, 0.0])
    start = np.zeros(llr.size, bool)
    start[[0, 9]] = True
    s = held_cumsum(llr, start, lo, hi)
    t = np.arange(llr.size) * 10
    # causal: [F, T, T, T, T, T, F, F, T, F]; the rise at row 1 reaches back to row 0,
    # the fall at row 6 to row 2 (the first row after the last touch of hi), the rise at
    # row 8 to row 7; row 9 starts a segment that never decides
    assert fixed_lag_decision(s, start, lo, hi, t, 100).tolist() == [
        True, True, False, False, False, False, False, True, True, False]
    # a 20 lag reaches two rows back: rows 2 and 3 keep the causal name
    assert fixed_lag_decision(s, start, lo, hi, t, 20).tolist() == [
        True, True, True, True, False, False, False, True, True, False]
