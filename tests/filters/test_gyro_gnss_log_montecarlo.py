"""Seeded Monte Carlo of the ownship acceptance figures (slow): 24 scenario seeds run as
24 filters in one vectorised call. Prints the distribution (pytest -s)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.families import load_config
from pipeline.filters.gyro_gnss_log import FilterInputs, run_filter
from pipeline.nav.config import ownship_config
from pipeline.simulate.ownship import simulate_ownship

pytestmark = pytest.mark.slow
SEEDS = range(1, 25)
CONVERGED_S = 600


def _stack(scs) -> tuple[FilterInputs, np.ndarray, np.ndarray, np.ndarray]:
    cols = {k: [] for k in ("acc", "amp", "kp", "lat", "ve", "vn", "log", "em")}
    heading, alpha, outlier = [], [], []
    for sc in scs:
        g = sc.gnss
        q = g["fix_quality"].to_numpy()
        cols["acc"].append(sc.gyro_signals["accel_signal_rad"].to_numpy())
        cols["amp"].append(sc.gyro_signals["amplifier_rad"].to_numpy())
        cols["kp"].append(sc.gyro_heading["heading_rad"].to_numpy())
        cols["lat"].append(np.radians(g["lat_deg"].fill_null(strategy="forward").to_numpy()))
        cols["ve"].append((g["sog_mps"] * g["cog_rad"].sin()).fill_null(np.nan).to_numpy())
        cols["vn"].append((g["sog_mps"] * g["cog_rad"].cos()).fill_null(np.nan).to_numpy())
        cols["log"].append(sc.speed_log["speed_water_mps"].to_numpy())
        cols["em"].append(q == 0)
        heading.append(sc.truth["heading_rad"].to_numpy())
        alpha.append(sc.truth["gyro_error_rad"].to_numpy())
        outlier.append(g["is_outlier"].to_numpy())
    a = {k: np.stack(v) for k, v in cols.items()}
    inp = FilterInputs(1.0, a["acc"], a["amp"], a["kp"], a["lat"], a["ve"], a["vn"],
                       a["log"], a["em"])
    return inp, np.stack(heading), np.stack(alpha), np.stack(outlier)


def test_acceptance_figures_over_seeds():
    oc = ownship_config(load_config())
    scs = [simulate_ownship(oc.scenario, start_ns=0, duration_s=1800.0, seed=s) for s in SEEDS]
    inp, heading, alpha, outlier = _stack(scs)
    out = run_filter(inp, oc.model, oc.current)
    err = np.degrees(np.angle(np.exp(1j * (out.heading_rad - heading))))[:, CONVERGED_S:]
    rms = np.sqrt(np.mean(err**2, axis=1))
    mx = np.abs(err).max(axis=1)
    gyro = np.degrees(np.abs(alpha).max(axis=1))
    rejected = out.gate_passed == 0
    false_alarm = (rejected & ~outlier).sum() / np.isfinite(out.gate_passed).sum()
    print(f"\nownship Monte Carlo, {len(SEEDS)} seeds, converged = t >= {CONVERGED_S} s")
    print(f"  integrated heading RMS deg: median {np.median(rms):.4f}  mean {rms.mean():.4f}"
          f"  max {rms.max():.4f}  share <= 0.1: {(rms <= 0.1).mean():.2f}")
    print(f"  integrated heading max deg: median {np.median(mx):.4f}  max {mx.max():.4f}"
          f"  share <= 0.3: {(mx <= 0.3).mean():.2f}")
    print(f"  gyro alone max deg: min {gyro.min():.2f}  median {np.median(gyro):.2f}")
    print(f"  outliers rejected: {rejected[outlier].sum()}/{outlier.sum()}"
          f"  false rejections: {false_alarm:.4f} of fixes")
    assert (gyro > 10.0).all()
    assert rejected[outlier].all()
    assert np.median(rms) <= 0.1 and (rms <= 0.1).mean() >= 0.7
    assert np.median(mx) <= 0.3
    assert false_alarm < 0.02
