"""Own-ship GNSS position integrity (issue 22): each fix tested against the position the
solution predicts WITHOUT it, excluded while in fault (a position jump: spoofing,
multipath, a receiver fault), like the airfield's channels (airfield paper eq. 21-23).

The filter's gate (gyro/GNSS/log paper eq. 3) tests the GNSS *acceleration* (velocity
differences): a fix whose position jumps while its velocity does not passes it. Here the
position of the fix at step k is compared with the last accepted fix moved on by the
GNSS velocities since (the step's velocity when the fix passed the gate, else the last
one that did):

.. math:: r_k = p_k - \\Big(p_a + \\sum_{i=a+1}^{k} v_i\\, \\Delta t\\Big), \\qquad
          \\xi_k = \\frac{r_k^T r_k}{\\sigma_k^2} \\sim \\chi^2_2

with sigma_k^2 per axis the variance of that difference for a Gauss-Markov position
error (sigma_p, correlation time tau_p) and Gauss-Markov velocity errors (sigma_v,
tau_v) over tau = (k - a) dt:

.. math:: \\sigma_k^2 = 2\\sigma_p^2 (1 - e^{-\\tau/\\tau_p})
          + 2\\sigma_v^2\\tau_v^2 (\\tau/\\tau_v - 1 + e^{-\\tau/\\tau_v}) + \\sigma_0^2

(sigma_0 = 0.1 m: the NMEA resolution). Thresholds d1, d2 from ``gnss_q`` (eq. 22), eta
(eq. 23); a fix with eta = 1 excludes the GNSS position until ``gnss_readmit_run`` fixes
in a row pass (:func:`pipeline.filters.integrity.step_exclusion`); meanwhile the
solution dead-reckons from the last accepted fix. The first fix of a segment and the
first after an outage (emergency mode) are accepted without a test: they start a new
reference. The loop runs over the filter steps (1 Hz) with scalars: it is the exclusion
rule's recursion, nothing else.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.filters.integrity import chi2_thresholds, eta, step_exclusion

_SIGMA_0_M = 0.1


@dataclass(frozen=True)
class GnssCheck:
    """Per step (T,): xi (NaN: no test), eta (-1: no decision, else 0/1), excluded (the
    position test holds the GNSS position out after this step's decision)."""

    xi: np.ndarray
    eta: np.ndarray
    excluded: np.ndarray


def difference_sigma_m(tau_s: float, sigma_p_m: float, tau_p_s: float, sigma_v_mps: float,
                       tau_v_s: float) -> float:
    """Per-axis sigma of (fix - earlier fix - integrated GNSS velocity) ``tau_s`` apart (m)
    for Gauss-Markov position and velocity errors (module docstring)."""
    a = 2.0 * sigma_p_m**2 * (1.0 - math.exp(-tau_s / tau_p_s))
    x = tau_s / tau_v_s
    b = 2.0 * sigma_v_mps**2 * tau_v_s**2 * (x - 1.0 + math.exp(-x))
    return math.sqrt(a + b + _SIGMA_0_M**2)


def check_positions(
    east_m: np.ndarray, north_m: np.ndarray, vel_east_mps: np.ndarray,
    vel_north_mps: np.ndarray, has_fix: np.ndarray, gate_ok: np.ndarray,
    emergency: np.ndarray, *, step_s: float, q: float, readmit_run: int, sigma_p_m: float,
    tau_p_s: float, sigma_v_mps: float, tau_v_s: float, exclusion: bool = True,
) -> GnssCheck:
    """Test every fix of one segment (arrays (T,) on the filter grid; positions on a
    local tangent plane, m). ``has_fix``: a valid fix at the step; ``gate_ok``: its
    velocity passed the filter's gate; ``emergency``: the mode."""
    n = east_m.size
    d1, d2 = chi2_thresholds(q, 2)
    xi = np.full(n, np.nan)
    out_eta = np.full(n, -1, np.int8)
    out_excl = np.zeros(n, bool)
    e, nn = east_m.tolist(), north_m.tolist()
    ve, vn = np.nan_to_num(vel_east_mps).tolist(), np.nan_to_num(vel_north_mps).tolist()
    fix, ok, emer = has_fix.tolist(), gate_ok.tolist(), emergency.tolist()
    excluded, run = np.zeros(1, bool), np.zeros(1, np.int64)
    ref_e = ref_n = 0.0  # reference: last accepted fix moved on by the velocities
    vel = (0.0, 0.0)
    anchor = -1
    for k in range(n):  # the exclusion recursion, one scalar step per filter step
        if anchor >= 0:
            ref_e += vel[0] * step_s
            ref_n += vel[1] * step_s
        if emer[k]:
            anchor = -1  # an outage: the next fix starts a new reference
            continue
        if not fix[k]:
            continue
        if ok[k]:
            vel = (ve[k], vn[k])
        if anchor < 0:
            anchor, ref_e, ref_n = k, e[k], nn[k]
            excluded[:], run[:] = False, 0
            continue
        s = difference_sigma_m((k - anchor) * step_s, sigma_p_m, tau_p_s, sigma_v_mps,
                               tau_v_s)
        x = ((e[k] - ref_e) ** 2 + (nn[k] - ref_n) ** 2) / (s * s)
        flag = bool(eta(np.array([x]), d1, d2)[0])
        if exclusion:
            excluded, run = step_exclusion(excluded, run, np.array([flag]),
                                           np.array([x < d2]), np.ones(1, bool), readmit_run)
        xi[k], out_eta[k], out_excl[k] = x, flag, excluded[0]
        if not excluded[0] and ok[k]:  # the fix the solution uses
            anchor, ref_e, ref_n = k, e[k], nn[k]
    return GnssCheck(xi, out_eta, out_excl)


def nominal_q(q: float, gate_n_sigma: float) -> float:
    """False-alarm probability of one GNSS decision: the position test's q or the
    filter's n-sigma gate on the acceleration (two-sided Gaussian tail)."""
    gate = math.erfc(gate_n_sigma / math.sqrt(2.0))
    return 1.0 - (1.0 - q) * (1.0 - gate)
