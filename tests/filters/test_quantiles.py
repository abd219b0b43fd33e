"""The gates' quantiles equal scipy.stats' to the bit, and no stage imports scipy.stats."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from pipeline.filters.quantiles import chi2_ppf, normal_ppf

P = np.r_[1e-12, 1e-6, 0.0005, 0.01, 0.025, 0.5, 0.9, 0.95, 0.99, 0.995, 0.9995, 1 - 1e-9]


def test_chi_square_quantiles_equal_scipy_stats_to_the_bit() -> None:
    for dof in [1, 2, 3, 4, 6, 10, 2 * np.arange(1, 40)]:
        p = P if np.ndim(dof) == 0 else np.resize(P, np.size(dof))
        assert np.array_equal(chi2_ppf(p, dof), stats.chi2.ppf(p, dof))
    # 2 dof: the exponential with mean 2, x = -2 ln(1 - p)
    assert float(chi2_ppf(0.99, 2)) == pytest.approx(-2 * np.log(0.01), rel=1e-14)


def test_normal_quantiles_equal_scipy_stats_to_the_bit() -> None:
    assert np.array_equal(normal_ppf(P), stats.norm.ppf(P))
    assert normal_ppf(0.5) == 0.0


def test_a_worker_imports_the_stages_without_scipy_stats() -> None:
    """~0.5 s of every batch worker's start (scipy.stats is only for calibration)."""
    code = ("import sys, pipeline.batch, pipeline.families as f\n"
            "[fam.stage for fam in f.FAMILIES]\n"
            "import pipeline.maritime.stage, pipeline.gaps.stage, pipeline.airfield.stage, "
            "pipeline.nav.stage\n"
            "print('scipy.stats' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
