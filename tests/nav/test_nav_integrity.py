"""The own ship's GNSS position test (pipeline/nav/integrity.py, issue 22): its sigma,
its false alarms against q, a position jump flagged at once, held out while it lasts and
readmitted after it, outages restarting the reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from pipeline.nav.integrity import check_positions, difference_sigma_m, nominal_q

SIGMA_P, TAU_P, SIGMA_V, TAU_V = 3.2, 60.0, 0.053, 15.0


def gauss_markov(rng, n, sigma, tau, dims=2):
    a = math.exp(-1.0 / tau)
    w = rng.normal(0.0, sigma * math.sqrt(1 - a * a), (n, dims))
    w[0] = rng.normal(0.0, sigma, dims)
    return lfilter([1.0], [1.0, -a], w, axis=0)


def track(n=3600, seed=3, jump=None):
    """A ship at 5 m/s east: GNSS positions and velocities with Gauss-Markov errors."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    pos = np.column_stack([5.0 * t, np.zeros(n)]) + gauss_markov(rng, n, SIGMA_P, TAU_P)
    vel = np.column_stack([np.full(n, 5.0), np.zeros(n)]) + gauss_markov(rng, n, SIGMA_V, TAU_V)
    if jump is not None:
        a, b, off = jump
        pos[a:b] += off
    return pos, vel


def run(pos, vel, *, q=0.001, fix=None, emergency=None, exclusion=True):
    n = pos.shape[0]
    fix = np.ones(n, bool) if fix is None else fix
    emergency = np.zeros(n, bool) if emergency is None else emergency
    return check_positions(pos[:, 0], pos[:, 1], vel[:, 0], vel[:, 1], fix, np.ones(n, bool),
                           emergency, step_s=1.0, q=q, readmit_run=5, sigma_p_m=SIGMA_P,
                           tau_p_s=TAU_P, sigma_v_mps=SIGMA_V, tau_v_s=TAU_V,
                           exclusion=exclusion)


def test_difference_sigma_limits():
    assert difference_sigma_m(0.0, SIGMA_P, TAU_P, SIGMA_V, TAU_V) == pytest.approx(0.1)
    one = difference_sigma_m(1.0, SIGMA_P, TAU_P, SIGMA_V, TAU_V)
    assert one == pytest.approx(math.sqrt(2 * SIGMA_P**2 * (1 - math.exp(-1 / 60))
                                          + SIGMA_V**2 * (1 - 2 / 3 / 15) + 0.01), rel=0.01)
    # far apart: two independent fixes plus the integrated velocity error (a random walk)
    far = difference_sigma_m(6000.0, SIGMA_P, TAU_P, SIGMA_V, TAU_V)
    assert far == pytest.approx(math.sqrt(2 * SIGMA_P**2 + 2 * SIGMA_V**2 * TAU_V * (6000 - TAU_V)
                                          + 0.01), rel=0.01)


def test_nominal_q_adds_the_gate_tail():
    assert nominal_q(0.001, 3.0) == pytest.approx(1 - 0.999 * (1 - 0.0026998), rel=1e-4)


def test_fault_free_false_alarms_about_q():
    flags = decisions = 0
    xis = []
    for seed in range(5):
        g = run(*track(seed=seed), q=0.01)
        d = g.eta >= 0
        decisions += d.sum()
        flags += (g.eta == 1).sum()
        xis.append(g.xi[d])
    assert 0.005 < flags / decisions < 0.02
    assert 1.8 < np.mean(np.concatenate(xis)) < 2.2  # chi2(2)


def test_jump_flagged_at_its_first_fix_held_out_and_readmitted():
    pos, vel = track(jump=(1000, 1060, np.array([50.0, -30.0])))
    g = run(pos, vel)
    assert g.eta[1000] == 1 and g.excluded[1000]
    assert g.excluded[1000:1060].all()
    assert not g.excluded[1066:1200].any()  # 5 passes after the jump ends
    off = run(pos, vel, exclusion=False)
    assert not off.excluded.any() and off.eta[1000] == 1


def test_an_outage_starts_a_new_reference():
    pos, vel = track()
    fix = np.ones(pos.shape[0], bool)
    emergency = np.zeros(pos.shape[0], bool)
    fix[500:620] = False
    emergency[503:620] = True
    pos[620:] += np.array([400.0, 0.0])  # the ship is elsewhere after the outage
    g = run(pos, vel, fix=fix, emergency=emergency)
    assert g.eta[620] == -1 and not g.excluded[620:640].any()
