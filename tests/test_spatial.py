"""Grid pair join against a dense distance matrix."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.spatial import pairs_within


def _dense(ga, xa, ya, reach, gb, xb, yb):
    d2 = (xa[:, None] - xb[None, :]) ** 2 + (ya[:, None] - yb[None, :]) ** 2
    ok = (ga[:, None] == gb[None, :]) & (d2 <= np.broadcast_to(reach, xa.shape)[:, None] ** 2)
    ok &= np.isfinite(d2)
    i, j = np.nonzero(ok)
    return i, j, d2[i, j]


@pytest.mark.parametrize("seed", range(6))
def test_same_pairs_as_dense(seed: int) -> None:
    rng = np.random.default_rng(seed)
    na, nb = 300, 400
    ga, gb = rng.integers(0, 5, na), rng.integers(0, 5, nb)
    xa, ya = rng.uniform(-5e3, 5e3, na), rng.uniform(-3e3, 3e3, na)
    xb, yb = rng.uniform(-5e3, 5e3, nb), rng.uniform(-3e3, 3e3, nb)
    reach = rng.choice([50.0, 400.0, 900.0, 3000.0, 2e4, np.inf], na)
    xb[:3] = np.nan  # no position: no pair
    got = pairs_within(ga, xa, ya, reach, gb, xb, yb, cell_m=500.0)
    want = _dense(ga, xa, ya, reach, gb, xb, yb)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)


def test_empty_sides() -> None:
    e = np.empty(0)
    i, j, d2 = pairs_within(e.astype(int), e, e, 1.0, np.array([0]), np.array([0.0]),
                            np.array([0.0]), 10.0)
    assert i.size == j.size == d2.size == 0
    i, j, _ = pairs_within(np.array([0]), np.array([0.0]), np.array([0.0]), 1.0,
                           e.astype(int), e, e, 10.0)
    assert i.size == 0
