"""Calibrated uncertainty (slow, seeded Monte Carlo over the channel scenario): the NEES
of fused positions averages 2 (its dimension) within [0.8, 1.2] x 2, while the
multi-radar paper's eq. 15 reports sigmas that are too small where the channels differ.

Run: .venv/bin/pytest -m slow tests/maritime/test_nees.py -s (prints the figures)."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from maritime_helpers import batch_tables

from pipeline.maritime.fuse import paper_eq15_sigma

SEEDS = (1, 2, 3, 4, 5)
DURATION_S = 1200.0


@pytest.fixture(scope="module")
def runs(cfg) -> dict[int, dict[str, pl.DataFrame]]:
    return {s: batch_tables(cfg, duration_s=DURATION_S, seed=s) for s in SEEDS}


@pytest.mark.slow
def test_fused_nees_is_calibrated(runs):
    means = {}
    for seed, out in runs.items():
        e = out["track_errors"].filter((pl.col("source") == "fused")
                                       & (pl.col("reference") == "truth"))
        means[seed] = (e["nees"].mean(), e.height,
                       e.filter(pl.col("system_track_id").is_not_null())["nees"].median())
    print("\nfused NEES per seed (mean, points, median):", means)
    overall = np.average([m[0] for m in means.values()], weights=[m[1] for m in means.values()])
    print(f"fused NEES over {len(SEEDS)} seeds: {overall:.3f}")
    assert 0.8 * 2 <= overall <= 1.2 * 2
    for m, _, _ in means.values():
        assert 0.8 * 2 <= m <= 1.2 * 2


@pytest.mark.slow
def test_eq15_sigma_too_small_when_channels_differ(runs):
    """For each epoch where two radars see a ship: the eq. 14 per-axis mean of their
    east (and, separately, north) coordinates, its error against truth, and its sigma
    by (sum w)^-1/2 (ours) or by eq. 15. 1-D NEES should average 1."""
    rows = []
    for out in runs.values():
        a = out["associations"].select("time_ns", "system_track_id", pl.col("site_id").alias(
            "source"), "sigma_x_m", "sigma_y_m")
        e = out["track_errors"].filter((pl.col("source") != "fused")
                                       & (pl.col("reference") == "truth"))
        j = e.join(a, on=["time_ns", "system_track_id", "source"])
        two = j.filter(pl.len().over("time_ns", "system_track_id") == 2).sort(
            "time_ns", "system_track_id", "source")
        for axis in (("error_east_m", "sigma_x_m"), ("error_north_m", "sigma_y_m")):
            rows.append(two.select(*axis).to_numpy().reshape(-1, 2, 2))
    pairs = np.concatenate(rows)  # (n, radar, [error, sigma])
    err, sig = pairs[:, :, 0], pairs[:, :, 1]
    w = sig**-2
    e_hat = (w * err).sum(1) / w.sum(1)
    ours = w.sum(1) ** -0.5
    eq15 = np.array([paper_eq15_sigma(s) for s in sig])
    ratio = sig.max(1) / sig.min(1)
    print(f"\n{len(e_hat)} two-radar points x axes")
    for lo, hi in ((1, 1.5), (1.5, 3), (3, 100)):
        m = (ratio >= lo) & (ratio < hi)
        n_ours, n_15 = np.mean((e_hat[m] / ours[m]) ** 2), np.mean((e_hat[m] / eq15[m]) ** 2)
        print(f"sigma ratio [{lo}, {hi}): n={m.sum()}, NEES ours {n_ours:.3f}, eq. 15 "
              f"{n_15:.3f}, eq15/ours sigma {np.mean(eq15[m] / ours[m]):.3f}")
    differ = ratio >= 3
    assert differ.sum() > 1000
    nees_ours = np.mean((e_hat[differ] / ours[differ]) ** 2)
    nees_15 = np.mean((e_hat[differ] / eq15[differ]) ** 2)
    assert 0.8 <= nees_ours <= 1.2
    assert nees_15 > 1.2 and nees_15 > nees_ours * 1.15
    assert np.all(eq15 <= ours + 1e-12)  # Cauchy-Schwarz: never larger
