"""The airfield's reconstructed reference: the fixed-interval Rauch–Tung–Striebel smoother
of the fused filter itself (issue 37), and how an error against it is corrected for the
reference's own error.

**Why every channel, not only the best cooperative one.** A reference has to be better
than what it judges. The fused surface tracks are 1.1–1.6 m RMS from truth on the
simulator's airfield, the MLAT channel 3.8–4.1 m with errors correlated over seconds
(AR(2), airfield paper eq. 7): no smoothing of MLAT alone gets below the fused picture,
and MLAT sees only the cooperative targets. OpenATS COMPASS's reconstructor also uses
every sensor's reports. Here the reference is the RTS smoother of the same model, the
same reports and the same exclusions as the fused filter (airfield paper eq. 16–19,
:func:`pipeline.airfield.fusion.run_filter` with ``record``), run backwards from the end
of the unit:

.. math::
    P^-_{k+1} = F_k P_k F_k^T + Q_k, \\quad G_k = P_k F_k^T (P^-_{k+1})^{-1},

    x^s_k = x_k + G_k (x^s_{k+1} - x^-_{k+1}), \\quad
    P^s_k = P_k + G_k (P^s_{k+1} - P^-_{k+1}) G_k^T

(F_k, Q_k of the mode the filter predicted k → k+1 in, x^-_{k+1} with its VASN input).

**What an error against it means.** Such a reference is made of the very data it
judges, so its error is correlated with theirs. For the smoother of the right model the
error e_s = x^s − x is orthogonal to every function of the data (the Gaussian posterior),
the fused estimate and every report used included. Then for the fused track
d = x^f − x^s = e_f − e_s, E[e_s d^T] = 0 and

.. math:: E|e_f|^2 = E|d|^2 + \\mathrm{tr} P^s

and the same for a report z that the smoother used (E[e_s (z − x)^T] = P^s ⇒
E|z − x|² = E|z − x^s|² + tr P^s); for a report it did not use (excluded by the
integrity check) the errors are independent and E|z − x|² = E|z − x^s|² − tr P^s. The
column ``reference_correction_m2`` holds that signed term per row, and the reports add
it to the mean squared error (``surface_accuracy_by_area``: the RMS against the
reference corrected; its 95th percentile scaled by the same ratio, exact when the
errors are Gaussian). Without the correction the fused picture would look 20 % better
than it is.
"""

from __future__ import annotations

import numpy as np
import polars as pl

from pipeline.airfield.fusion import FilterRun
from pipeline.filters.smoother import radial_p95

REFERENCE_COLUMNS = ("time_ns", "track_id", "x_m", "y_m", "vx_mps", "vy_mps", "sigma_x_m",
                     "sigma_y_m", "cov_xy_m2", "p95_m")


def empty_reference() -> pl.DataFrame:
    return pl.DataFrame(schema={"time_ns": pl.Int64, "track_id": pl.String,
                                **{c: pl.Float64 for c in REFERENCE_COLUMNS[2:]}})


def smooth(run: FilterRun) -> pl.DataFrame:
    """The smoothed position and velocity of every (epoch, target) of the run with its
    position covariance (module docstring): REFERENCE_COLUMNS, unsorted."""
    g, out, model = run.grids, run.out, run.model
    if out.x_full is None or out.P_full is None:
        raise ValueError("the filter run was not recorded (run_filter(record=True))")
    K, N, d = out.x_full.shape
    xs = out.x_full.copy()
    Ps = np.zeros((N, d, d))
    pos = np.full((K, N, 3), np.nan)  # var_x, var_y, cov_xy
    for k in range(K - 1, -1, -1):  # backwards over epochs, targets vectorised
        if k not in out.P_full:
            continue
        ia, Pk32 = out.P_full[k]
        Pk = Pk32.astype(float)
        new = Pk.copy()
        step = g.last[ia] > k  # alive at k + 1 too (a target's epochs are contiguous)
        if np.any(step):
            n = ia[step]
            Pn = Pk[step]
            mode = out.mode[k + 1, n]
            F = model.F[mode]
            Pp = F @ Pn @ np.transpose(F, (0, 2, 1)) + model.Q[mode]
            Pp = 0.5 * (Pp + np.transpose(Pp, (0, 2, 1)))
            # G = P F' Pp^-1 = (Pp^-1 F P)'
            G = np.transpose(np.linalg.solve(Pp, F @ Pn), (0, 2, 1))
            dx = xs[k + 1, n] - out.x_prior[k + 1, n]
            xs[k, n] = out.x_full[k, n] + np.einsum("nij,nj->ni", G, dx)
            Ps_k = Pn + G @ (Ps[n] - Pp) @ np.transpose(G, (0, 2, 1))
            new[step] = 0.5 * (Ps_k + np.transpose(Ps_k, (0, 2, 1)))
        Ps[ia] = new
        pos[k, ia, 0], pos[k, ia, 1], pos[k, ia, 2] = new[:, 0, 0], new[:, 1, 1], new[:, 0, 1]
    kk, nn = np.nonzero(~np.isnan(out.x_full[:, :, 0]))
    x = xs[kk, nn]
    p = pos[kk, nn]
    return pl.DataFrame({
        "time_ns": (g.e0 + kk).astype(np.int64) * run.step_ns,
        "track_id": g.track_ids[nn],
        "x_m": x[:, 0], "y_m": x[:, 1], "vx_mps": x[:, 2], "vy_mps": x[:, 3],
        "sigma_x_m": np.sqrt(np.maximum(p[:, 0], 0.0)),
        "sigma_y_m": np.sqrt(np.maximum(p[:, 1], 0.0)),
        "cov_xy_m2": p[:, 2],
        "p95_m": radial_p95(p[:, 0], p[:, 1], p[:, 2]),
    }, schema_overrides={"track_id": pl.String})
