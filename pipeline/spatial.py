"""Pairs of nearby points, per group (epoch), without comparing every pair.

A grid join vectorised over whole columns: the B points are sorted by (group, cell x,
cell y) on a grid of ``cell_m``; each A point looks up the cells within its reach with
``searchsorted`` (one call per cell offset for all A points at once) and keeps the pairs
within its reach. A points whose reach spans more than ``MAX_CELLS`` cells each way are
paired with every B point of their group instead. The result is exactly the set of
pairs (a, b) of the same group with |p_a - p_b| <= reach_a: the same pairs as a dense
(n_a, n_b) distance matrix per group, without building one.

Used where per-epoch dense matrices made the batch quadratic in the number of targets:
AIS-to-track gating (identity), the track-to-truth pairing that the scoring and SIAP
share (score), the channel integrity's candidates.
"""

from __future__ import annotations

import numpy as np

MAX_CELLS = 4
"""Reach beyond this many cells each way: compare with every point of the group."""
_BITS = 21  # bits per cell coordinate in the key


def expand_ranges(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For rows with index ranges [lo_i, hi_i): (row i repeated, each index in its range),
    vectorised with repeat + cumsum (no loop). Empty ranges give no pairs."""
    counts = np.maximum(np.asarray(hi) - np.asarray(lo), 0)
    row = np.repeat(np.arange(counts.size), counts)
    first = np.cumsum(counts) - counts
    return row, np.asarray(lo)[row] + (np.arange(row.size) - first[row])


def pairs_within(
    group_a: np.ndarray,
    x_a: np.ndarray,
    y_a: np.ndarray,
    reach_a: np.ndarray | float,
    group_b: np.ndarray,
    x_b: np.ndarray,
    y_b: np.ndarray,
    cell_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs (i, j) with group_a[i] == group_b[j] and squared distance <= reach_a[i]^2.

    ``group_*``: int64 group of each point (e.g. epoch index, >= 0); positions in m;
    ``reach_a``: per A point (or one value), m, may be inf (every B point of the group);
    ``cell_m``: grid cell, m (about the typical reach). Returns (i, j, squared distance)
    sorted by (i, j). Non-finite positions pair with nothing.
    """
    x_a, y_a = np.asarray(x_a, float), np.asarray(y_a, float)
    x_b, y_b = np.asarray(x_b, float), np.asarray(y_b, float)
    ga, gb = np.asarray(group_a, np.int64), np.asarray(group_b, np.int64)
    reach = np.broadcast_to(np.asarray(reach_a, float), x_a.shape)
    empty = (np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0))
    ok_b = np.isfinite(x_b) & np.isfinite(y_b)
    ok_a = np.isfinite(x_a) & np.isfinite(y_a) & (reach >= 0)
    if x_a.size == 0 or not ok_b.any() or not ok_a.any():
        return empty
    jb = np.flatnonzero(ok_b)
    x0, y0 = x_b[jb].min(), y_b[jb].min()
    cx_b = np.floor((x_b[jb] - x0) / cell_m).astype(np.int64)
    cy_b = np.floor((y_b[jb] - y0) / cell_m).astype(np.int64)
    span = max(int(cx_b.max()), int(cy_b.max())) + 2 * MAX_CELLS + 2
    if span >= 1 << _BITS:
        raise ValueError(f"grid of {span} cells: use a larger cell_m than {cell_m}")
    key_b = _key(gb[jb], cx_b, cy_b)
    order = np.argsort(key_b, kind="stable")
    key_b, jb = key_b[order], jb[order]
    ia_all = np.flatnonzero(ok_a)
    k = np.ceil(reach[ia_all] / cell_m)
    near = ia_all[k <= MAX_CELLS]
    far = ia_all[k > MAX_CELLS]
    parts_i, parts_j = [], []
    if near.size:
        cx = np.floor((x_a[near] - x0) / cell_m).astype(np.int64)
        cy = np.floor((y_a[near] - y0) / cell_m).astype(np.int64)
        # the queries in key order: each searchsorted then walks key_b forwards (numpy
        # narrows from the previous key's place), not at random (the pairs are the same)
        by_cell = np.argsort(_key(ga[near], np.maximum(cx, 0), np.maximum(cy, 0)),
                             kind="stable")
        near, cx, cy = near[by_cell], cx[by_cell], cy[by_cell]
        kn = np.ceil(reach[near] / cell_m).astype(np.int64)
        kmax = int(kn.max())
        hi_cell = (1 << _BITS) - 1
        for dx in range(-kmax, kmax + 1):
            # the cells (cx + dx, cy - k .. cy + k) are one run of keys: one range each
            sel = kn >= abs(dx)
            qx = cx[sel] + dx
            y0c, y1c = cy[sel] - kn[sel], cy[sel] + kn[sel]
            inside = (qx >= 0) & (qx <= hi_cell) & (y1c >= 0) & (y0c <= hi_cell)
            rows = near[sel][inside]
            qx, y0c, y1c = qx[inside], np.maximum(y0c[inside], 0), np.minimum(y1c[inside], hi_cell)
            lo = np.searchsorted(key_b, _key(ga[rows], qx, y0c), "left")
            hi = np.searchsorted(key_b, _key(ga[rows], qx, y1c), "right")
            r, idx = expand_ranges(lo, hi)
            parts_i.append(rows[r])
            parts_j.append(jb[idx])
    if far.size:
        g_order = np.argsort(gb[jb], kind="stable")
        gs = gb[jb][g_order]
        lo = np.searchsorted(gs, ga[far], "left")
        hi = np.searchsorted(gs, ga[far], "right")
        r, idx = expand_ranges(lo, hi)
        parts_i.append(far[r])
        parts_j.append(jb[g_order][idx])
    if not parts_i:
        return empty
    i = np.concatenate(parts_i)
    j = np.concatenate(parts_j)
    d2 = (x_a[i] - x_b[j]) ** 2 + (y_a[i] - y_b[j]) ** 2
    keep = d2 <= reach[i] ** 2
    i, j, d2 = i[keep], j[keep], d2[keep]
    order = np.lexsort((j, i))
    return i[order], j[order], d2[order]


def _key(group: np.ndarray, cx: np.ndarray, cy: np.ndarray) -> np.ndarray:
    return (group << (2 * _BITS)) | (cx << _BITS) | cy
