"""Seeded Monte Carlo of the own-ship heading (slow): the paper's scenario on seeds 1-50,
30 min each, two work units of 25 filters in one vectorised call each
(``pipeline.experiments.ownship_montecarlo``; the same as ``surveil experiment ownship
--runs 50 --per-seed``). Prints the per-seed table of docs/ownship.md §4 (pytest -s).

Goal (issue 21 item 5): heading RMS after convergence <= 0.1 deg on >= 95 % of the seeds
and max <= 0.3 deg on all. Seeds 1-50 were not used to choose anything: the filter
change was checked on seeds 100-149 first.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.experiments.ownship_montecarlo import run_montecarlo, summarise
from pipeline.families import load_config

pytestmark = pytest.mark.slow
SEEDS = range(1, 51)


def _markdown(table) -> str:
    head = ("| seed | RMS deg | max deg | max at s | RMS before turn | RMS turn | RMS after "
            "| NEES |\n|---:|---:|---:|---:|---:|---:|---:|---:|")
    rows = [f"| {r['seed']} | {r['heading_rms_deg']:.3f} | {r['heading_max_deg']:.3f} "
            f"| {r['heading_max_at_s']:.0f} | {r['rms_before_turn_deg']:.3f} "
            f"| {r['rms_turn_deg']:.3f} | {r['rms_after_turn_deg']:.3f} | {r['nees']:.2f} |"
            for r in table.iter_rows(named=True)]
    return "\n".join([head, *rows])


def test_heading_goal_over_50_seeds():
    table = run_montecarlo(load_config(), seeds=SEEDS, duration_s=1800.0)
    s = summarise(table).row(0, named=True)
    print("\n" + _markdown(table))
    print(f"\nshare RMS <= 0.1: {s['share_rms_le_goal']:.2f} ({s['seeds_rms_above_goal']} above)"
          f"  median RMS {s['rms_median_deg']:.4f}  max RMS {s['rms_max_deg']:.4f}"
          f"  share max <= 0.3: {s['share_max_le_goal']:.2f}  max {s['max_max_deg']:.4f}"
          f"  mean NEES {s['nees_mean']:.2f}  gyro alone >= {s['gyro_max_min_deg']:.2f} deg"
          f"  outliers rejected {s['outliers_rejected']}/{s['outliers']}"
          f"  false rejections {s['false_rejection_share']:.4f}")
    assert table.height == 50
    assert s["share_rms_le_goal"] >= 0.95
    assert s["max_max_deg"] <= 0.3
    assert s["gyro_max_min_deg"] > 10.0
    assert s["outliers_rejected"] == s["outliers"] == 6 * 50
    assert s["false_rejection_share"] < 0.02
    # the filter's sigma is honest: neither overconfident (the misses of the old filter,
    # NEES ~2-4 while converging) nor uselessly wide
    z = (table["error_at_converged_deg"] / table["sigma_at_converged_deg"]).to_numpy()
    assert 0.4 < np.std(z) < 1.3
    # mean NEES over the 50 seeds 0.861 (standard error 0.12; per seed 0.10-3.9): the bound
    # is that +-2 SE; the filter before issue 21's fix (af555d9) gives 1.229 on these seeds
    assert 0.6 < s["nees_mean"] < 1.1
