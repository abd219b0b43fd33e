"""Wald's sequential probability ratio test, held between its boundaries (a kernel).

Wald (1945), "Sequential tests of statistical hypotheses", Ann. Math. Statist. 16(2),
117-186: sum the log-likelihood ratios l_k = ln f(z_k | H1) / f(z_k | H0) of the
observations and stop at the first n where

.. math:: S_n = \\sum_{k \\le n} l_k \\ge A = \\ln\\frac{1-\\beta}{\\alpha}
          \\;(\\text{accept } H_1) \\quad\\text{or}\\quad
          S_n \\le B = \\ln\\frac{\\beta}{1-\\alpha} \\;(\\text{accept } H_0)

(Wald's approximations of the boundaries), which keep the probability of
accepting H1 when H0 is true at most about alpha, and of accepting H0 when H1 is true at
most about beta.

For monitoring a hypothesis that can change (a track that is, then stops being, one
ship) the test does not stop: the sum is held within [B, A],

.. math:: S_n = \\min(\\max(S_{n-1} + l_n, B), A), \\qquad S_0 = 0,

and the decision is the boundary it touched last (none touched yet: H0). A decision is
then reversed only by evidence of a whole test against it (a likelihood ratio of
e^{A-B}), the repeated-SPRT form of Page's (1954) CUSUM. The clamp map
x -> clip(x + a, lo, hi) composes into a map of the same form, so the held sums of many
independent sequences (segments) are a parallel prefix scan: log2(longest segment)
numpy passes over all rows, no loop over rows or segments.
"""

from __future__ import annotations

import math

import numpy as np

BOUNDARY_TOLERANCE = 1e-9
"""A held sum within this of a boundary touches it (the scan sums in another order)."""


def wald_boundaries(alpha: float, beta: float) -> tuple[float, float]:
    """(B, A) = (ln(beta / (1 - alpha)), ln((1 - beta) / alpha)) (Wald 1945).

    alpha: probability of accepting H1 under H0; beta: of accepting H0 under H1."""
    if not (0.0 < alpha < 1.0 and 0.0 < beta < 1.0 and alpha + beta < 1.0):
        raise ValueError("alpha and beta must be in (0, 1) with alpha + beta < 1")
    return math.log(beta / (1.0 - alpha)), math.log((1.0 - beta) / alpha)


def held_cumsum(increments: np.ndarray, segment_start: np.ndarray, lo: float, hi: float
                ) -> np.ndarray:
    """S_i = clip(S_{i-1} + l_i, lo, hi) with S = 0 before each segment.

    increments: (n,) l_i, rows of a segment consecutive and in order; segment_start:
    (n,) bool, True at each segment's first row (row 0 must be one). lo <= 0 <= hi.
    Returns (n,) S_i. Vectorised: each row holds the map (a, b, c): x -> clip(x + a, b,
    c) of the rows up to 2^k back in its segment; one pass composes it with the map of
    the 2^k rows before (later o earlier: a = a_e + a_l, b = clip(b_e + a_l, b_l, c_l),
    c = clip(c_e + a_l, b_l, c_l)) until it covers the whole segment before the row.
    """
    llr = np.asarray(increments, dtype=float)
    n = llr.size
    if n == 0:
        return np.empty(0)
    start = np.asarray(segment_start, dtype=bool)
    if not start[0] or not lo <= 0.0 <= hi:
        raise ValueError("row 0 must start a segment and lo <= 0 <= hi")
    rows = np.arange(n)
    pos = rows - np.maximum.accumulate(np.where(start, rows, 0))  # row's place in segment
    a, b, c = llr.copy(), np.full(n, float(lo)), np.full(n, float(hi))
    k = 1
    while k <= pos.max():
        late = np.flatnonzero(pos >= k)
        early = late - k
        al, bl, cl = a[late], b[late], c[late]
        b[late] = np.clip(b[early] + al, bl, cl)
        c[late] = np.clip(c[early] + al, bl, cl)
        a[late] = a[early] + al
        k *= 2
    return np.clip(a, b, c)


def held_decision(s: np.ndarray, segment_start: np.ndarray, lo: float, hi: float
                  ) -> np.ndarray:
    """Per row, True when the held sum ``s`` (:func:`held_cumsum`) last touched ``hi``
    rather than ``lo`` within its segment (False before either is touched)."""
    s = np.asarray(s, dtype=float)
    if s.size == 0:
        return np.empty(0, dtype=bool)
    start = np.asarray(segment_start, dtype=bool)
    up, down = _touches(s, lo, hi)
    rows = np.arange(s.size)
    last = np.maximum.accumulate(np.where(up | down | start, rows, 0))
    return up[last]


def _touches(s: np.ndarray, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """(rows at ``hi``, rows at ``lo``) of the held sum, within the boundary tolerance."""
    return s >= hi - BOUNDARY_TOLERANCE, s <= lo + BOUNDARY_TOLERANCE


def fixed_lag_decision(s: np.ndarray, segment_start: np.ndarray, lo: float, hi: float,
                       time_ns: np.ndarray, lag_ns: int) -> np.ndarray:
    """:func:`held_decision` smoothed with a fixed lag: per row, the decision the test
    reaches NEXT in its segment (the next row whose held sum touches ``hi`` or ``lo``,
    this row included) when that row is at most ``lag_ns`` later, else the row's own
    (causal) decision. An offline test thus names a pair from the start of the evidence
    that confirmed it (the rows since the sum last touched ``lo``) and withdraws it from
    the start of the evidence that rejected it (since it last touched ``hi``), never
    more than ``lag_ns`` before the decision. ``time_ns``: non-decreasing within each
    segment. ``lag_ns = 0`` is :func:`held_decision`."""
    causal = held_decision(s, segment_start, lo, hi)
    if causal.size == 0 or lag_ns <= 0:
        return causal
    s = np.asarray(s, dtype=float)
    t = np.asarray(time_ns, dtype=np.int64)
    up, down = _touches(s, lo, hi)
    touch = up | down
    rows = np.arange(s.size)
    segment = np.cumsum(np.asarray(segment_start, dtype=bool))
    nxt = np.minimum.accumulate(np.where(touch, rows, s.size)[::-1])[::-1]
    j = np.minimum(nxt, s.size - 1)
    ahead = (nxt < s.size) & (segment[j] == segment) & (t[j] - t <= lag_ns)
    return np.where(ahead, up[j], causal)


def held_cumsum_reference(increments: np.ndarray, segment_start: np.ndarray, lo: float,
                          hi: float) -> np.ndarray:
    """:func:`held_cumsum` as the plain recursion, one row after another (tests)."""
    out = np.empty(len(increments))
    s = 0.0
    for i, (x, first) in enumerate(zip(increments, segment_start, strict=True)):
        s = min(max((0.0 if first else s) + float(x), lo), hi)
        out[i] = s
    return out
