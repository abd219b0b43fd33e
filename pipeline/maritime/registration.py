"""Online registration and estimated accuracy of each radar, applied before fusion
(issue 38 items 1-2): the fused picture should not be worse than the best radar when
one radar has a range, azimuth or clock bias, a range gain error or degraded noise.

The evidence is the channel integrity's (:mod:`pipeline.maritime.integrity`): per epoch
k and radar group (site c, sector g) the leave-one-out residuals r_i = p_i - p_ref of
the tracks tested against the picture without the radar (their AIS report where the
track carries one, two or more other radars otherwise), S_i = P_i + P_ref, and the
registration model of the integrity's test (airfield paper eq. 21-23 on the residual of
multi-radar paper eq. 14) with the range gain g (measured range = (1 + g) true range +
b_r, the range scale error of a radar's range clock or its trigger delay's drift),

.. math:: r_i = H_i \\theta + e_i, \\quad H_i = [u_r, \\rho u_{az}, -v, \\rho u_r], \\quad
          \\theta = (b_r, b_{az}, \\Delta t, g)

summed per epoch and group: A_k = sum H^T S^-1 H, b_k = sum H^T S^-1 r, the NIS sum
N_k = sum r^T S^-1 r, the tracks n_k and T_k = sum tr(S^-1 P_i).

**Radar-radar pairs** (:func:`~pipeline.maritime.integrity._pair_evidence`): a track
without AIS that exactly two sites c, d report is no evidence for the leave-one-out test
(xi_1 = xi_2), but its difference r = p_c - p_d = H_c theta_c - H_d theta_d + e is one
equation in both registrations. Where a window holds such pairs every site's estimate
is made at once (:func:`_joint_fit`): the sites' own sums on the block diagonal of a (4C,
4C) system, the pairs' across, each site's estimate and covariance its block of the
joint ones; the radars' geometry (two sites see a ship along different lines of sight)
tells which of them is off, so registration works where no ship carries AIS. Not
observable from pairs alone: a clock offset common to both radars (only their difference
is), which the prior splits between them (the estimate then differs from zero by less
than its interval and is not applied).

**Registration** (per site, every sector's evidence; per sector where the site's sectors
differ, below). Over a window W of epochs, the weighted least-squares estimate with the
integrity's wide prior P_0,

.. math:: \\hat\\theta_W = (A_W + P_0^{-1})^{-1} b_W, \\qquad
          P_{\\theta,W} = f_W (A_W + P_0^{-1})^{-1}, \\qquad
          f_W = c \\max(1, \\tilde N_W / (2 n_W - 4))

with A_W, b_W, N_W the sums over W, the corrected NIS sum
N~_W = N_W - 2 theta^T b_W + theta^T A_W theta, and c = ``decorrelation_s`` / epoch
period (at most the window's epochs): a radar tracker's errors are correlated over
many scans, so an epoch carries 1/c of an independent sample (in a joint fit, a site
without ``min_tracks`` of its own takes the joint f_W: N~ and n of every site and of the
pairs, 4C parameters). Three windows per epoch:
the ``window_s`` before it (past), after it (future), both. Both, unless the past and
future estimates disagree (d = (theta_p - theta_f)^T (P_p + P_f)^-1 (theta_p - theta_f)
above chi2_4(1 - ``jump_q``): a registration jump), then the side whose corrected NIS
per dof is the smaller (the side that does not straddle the jump). The estimate is
applied once the window holds ``min_tracks`` track-epochs and it differs from zero,
theta^T P_theta^-1 theta >= chi2_4(1 - ``apply_q``) (else nothing is corrected: a
clean radar's reports stay as reported), and both its windows lie within the rows (not
within ``window_s`` of their first or last epoch, where one side is cut short and a
jump there unseen: a fault from the first epoch on would be corrected before its onset
too). Windows only (no filter over the whole recording): a unit's lead-in and look-ahead
(``continuity_margins_s``, >= 300 s) hold every window, so results do not depend on
where units are cut.

**Per sector where it differs** (``per_sector``): a radar's error need not be the same
at every azimuth (an encoder error over part of the rotation, a range error on one
bearing's path). On the site's side of the window each sector g (of the site's radar
groups, "outside every sector" among them) is fitted on its own sums alone (no pairs),
and the likelihood-ratio test of one registration for the site's sectors with
``min_tracks`` against one each (:func:`_sectors_differ`, chi2 of 4(E - 1) dof at
``apply_q``) decides whether they differ. Where it rejects in most epochs of the window
both sides (a decision that does not flicker: a track's reports corrected at one epoch
and not the next fuse into a wrong track), each sector with ``min_tracks`` takes its
own estimate and covariance (``registration_scope`` = sector), applied whether it
differs from zero or not: the site is off somewhere, and a sector half in the fault has
an estimate short of that test whose reports, left as reported, split off the other
radars' tracks. The other sectors keep the site's. A site whose sectors agree keeps one
registration, to the last digit.

**Correction before the association** (the stage's second pass): where the first pass
(association, integrity, this step on the reports as reported) applied an estimate
anywhere, :func:`correct_reports` corrects each synchronised report of site c (of its
sector where that has its own estimate) at epoch k, p <- p - H theta, P <- P + H
P_theta H^T (H of the report as reported, its site's geometry and its velocity; the
estimate's own error, honest NEES), and association,
integrity and this step run again on them: the corrected radar's tracks join the other
radars' system tracks instead of splitting off as tracks of their own (duplicates of the
ships the other radar tracks). The second pass estimates nothing again
(``corrected_by``): its variance scale is the covariance matching of the corrected
residuals (theta = 0 below) and its readmission tests them where the first pass's
estimate is applied. Where nothing is applied anywhere there is no second pass: the
rows are the first pass's, to the last digit.

**Correction in the fusion** (each pass): each report of site c at epoch k, p <- p - H
theta, P <- s P + H P_theta H^T (in the second pass theta = 0: the variance scale).

**Estimated accuracy** (per site and sector, the site's window): covariance matching of
the corrected residuals, E[N~] = 2n + (s - 1) T for a radar whose covariance is s P,

.. math:: s = 1 + (\\tilde N_W - 2 n_W) / T_W

used when the window holds ``min_tracks`` track-epochs and N~_W / c leaves the
equal-tail chi-square interval of 2 n_W / c dof at ``apply_q`` (else the site's s by
the same rule, else 1), clipped to [``MIN_SCALE``, ``max_scale``]: a degraded radar is
down-weighted smoothly, a radar as good as its sigmas keeps them.

**Exclusion only on the integrity test**: a radar group the integrity excluded is fused
again at an epoch where its site's registration is applied (the correction explains the
failure: a radar that is only noisier than its sigmas stays excluded; its scale down-
weights it where the integrity keeps it) and its corrected and rescaled residuals, xi_i
= (r_i - H_i theta)^T (S_i + (s - 1) P_i)^-1 (r_i - H_i theta), pass the same NIS-sum
test (sum xi_i < chi2_2n(1 - radar_q / 4)) with no outlier among them (xi_i > chi2_2(1 -
outlier_q): the integrity leaves a minority of outliers out of its sum, a readmission
may not), in the group where it has tracks tested and over the site; of its rows, those
whose own xi_i is no outlier (a row with no other channel on its track is not gated);
unless its scan check fails at that epoch (an outage) or its variance scale exceeds
``readmit_max_scale`` (a radar much noisier than its sigmas stays excluded: the scale of
the tracks still tested underestimates it, the association having split the worst ones
off). A coverage failure does not block it: a bias or a noisy radar splits tracks off
the association, which the coverage check counts as missed ships; in blanked azimuths
the radar has no reports to fuse.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import polars as pl
from numpy.lib.stride_tricks import sliding_window_view

from pipeline.config import RegionConfig, Sector
from pipeline.filters.quantiles import chi2_ppf, normal_ppf
from pipeline.frames import velocity_enu, wrap_angle
from pipeline.geometry import sector_indices
from pipeline.maritime.config import RegistrationConfig
from pipeline.maritime.integrity import (
    DIM,
    THETA_PRIOR,
    RegistrationEvidence,
    _d2,
    registration_jacobian,
)

MIN_SCALE = 0.25
"""The smallest variance scale: a radar at most twice as accurate as its sigmas say."""

PAST, FUTURE, BOTH = 0, 1, 2
_SIDES = ("past", "future", "both")
_A, _B = slice(0, DIM * DIM), slice(DIM * DIM, DIM * DIM + DIM)
_NIS, _N, _TRACE, _NAIS = (DIM * DIM + DIM + i for i in range(4))
_WIDTH = _NAIS + 1


REPORTED_COLUMNS = ("x_enu_m", "y_enu_m", "P_xx", "P_yy", "P_xy", "sigma_speed_mps",
                    "sigma_course_rad")
"""The columns :func:`correct_reports` corrects and :func:`scale_covariances` scales (kept
as reported in ``reported_*``)."""


@dataclass(frozen=True, eq=False)
class Estimate:
    """Each radar group's registration per epoch (group = site * (G + 1) + sector, as in
    ``RegistrationEvidence``): ``theta`` (K, n_groups, 4: range bias m, azimuth bias rad,
    time offset s, range gain), its covariance ``P`` (K, n_groups, 4, 4), the ``side`` of
    its window, the track-epochs ``n`` in it, of them ``n_ais`` against AIS and
    ``n_pair`` radar-radar pairs without AIS, whether it is ``applied`` and whether it is
    the sector's ``own`` (else its site's, the same in each of the site's groups), (K,
    n_groups); ``epochs`` (K,), ``groups_per_site`` G + 1."""

    epochs: np.ndarray
    theta: np.ndarray
    P: np.ndarray
    side: np.ndarray
    n: np.ndarray
    n_ais: np.ndarray
    n_pair: np.ndarray
    applied: np.ndarray
    own: np.ndarray
    groups_per_site: int

    @property
    def theta_used(self) -> np.ndarray:
        """theta where applied, else 0."""
        return np.where(self.applied[..., None], self.theta, 0.0)

    @property
    def cov_used(self) -> np.ndarray:
        """P where applied, else 0."""
        return np.where(self.applied[..., None, None], self.P, 0.0)


@dataclass(frozen=True, eq=False)
class Registration:
    """What :func:`register` returns: ``associations`` (the input rows, ``used`` with the
    readmitted ones), ``corrected`` (the same rows as fused: positions corrected,
    covariances rescaled and widened), ``table`` (``sensor_registration`` rows) and the
    ``estimate`` (what :func:`correct_reports` applies in a second pass)."""

    associations: pl.DataFrame
    corrected: pl.DataFrame
    table: pl.DataFrame
    estimate: Estimate


@dataclass(frozen=True, eq=False)
class _Fit:
    """A window's estimate per (epoch, site): theta (K, C, 4), its covariance P (K, C, 4,
    4), corrected NIS sum, tracks and tracks against AIS."""

    theta: np.ndarray
    P: np.ndarray
    nis: np.ndarray
    n: np.ndarray
    n_ais: np.ndarray
    n_pair: np.ndarray


def _evidence(ev: RegistrationEvidence) -> np.ndarray:
    """(K, n_groups, 24) the sums A (16), b (4), NIS, tracks, trace, tracks with AIS."""
    K, ng = ev.n.shape
    return np.concatenate([ev.A.reshape(K, ng, DIM * DIM), ev.b, ev.nis[..., None],
                           ev.n[..., None].astype(float), ev.trace[..., None],
                           ev.n_ais[..., None]], axis=2)


def _windows(x: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(past, future, both) sums over epochs k-w..k, k..k+w, k-w..k+w of ``x`` (K, ...):
    each sum of the same terms in the same order wherever the series starts."""
    pad = np.zeros((w, *x.shape[1:]))
    win = sliding_window_view(np.concatenate([pad, x, pad]), w + 1, axis=0)
    past = win[: x.shape[0]].sum(axis=-1)
    future = win[w:].sum(axis=-1)
    return past, future, past + future - x


def _corrected_nis(v: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """N - 2 theta^T b + theta^T A theta of sums ``v`` (..., 24), >= 0."""
    A = v[..., _A].reshape(*v.shape[:-1], DIM, DIM)
    quad = np.einsum("...i,...ij,...j->...", theta, A, theta)
    return np.maximum(v[..., _NIS] - 2 * np.einsum("...i,...i->...", theta, v[..., _B]) + quad,
                      0.0)


def _fit(v: np.ndarray, corr: float) -> _Fit:
    """The weighted least-squares estimate of sums ``v`` (K, C, 24) (module docstring)."""
    A = v[..., _A].reshape(*v.shape[:-1], DIM, DIM) + np.diag(THETA_PRIOR**-2.0)
    cov = np.linalg.inv(A)
    theta = np.einsum("...ij,...j->...i", cov, v[..., _B])
    nis = _corrected_nis(v, theta)
    n = v[..., _N]
    f = corr * np.maximum(1.0, nis / np.maximum(2 * n - DIM, 1.0))
    return _Fit(theta, cov * f[..., None, None], nis, n, v[..., _NAIS], np.zeros_like(n))


@dataclass(frozen=True, eq=False)
class _Pairs:
    """One window's sums of the radar-radar evidence (``RegistrationEvidence.pair_*``)."""

    A: np.ndarray  # (K, 4C, 4C)
    b: np.ndarray  # (K, 4C)
    nis: np.ndarray  # (K,)
    n: np.ndarray  # (K, C)


def _joint_fit(v: np.ndarray, pairs: _Pairs, corr: float, min_tracks: int) -> _Fit:
    """Every site's registration at once where the window holds radar-radar pairs
    (module docstring): the sites' own sums on the block diagonal, the pairs' across,

    .. math:: \\hat\\Theta = (\\mathrm{diag}(A_c) + A_{pairs} + P_0^{-1})^{-1}
              (b + b_{pairs}), \\qquad f = c \\max(1, \\tilde N / (2 (n + m) - 4C))

    (n the sites' track-epochs, m the pairs, N~ the corrected NIS of both; a site with
    ``min_tracks`` track-epochs of its own takes f of its own residuals), each site's
    estimate and covariance its block of the joint ones. Epochs without pairs in the
    window: :func:`_fit`, to the last digit."""
    own = _fit(v, corr)
    idx = np.flatnonzero(pairs.n.sum(axis=-1) > 0)
    if idx.size == 0:
        return own
    C = v.shape[1]
    vi = v[idx]
    A_site = vi[..., _A].reshape(-1, C, DIM, DIM)
    A_data = pairs.A[idx].copy()
    for c in range(C):
        A_data[:, c * DIM:(c + 1) * DIM, c * DIM:(c + 1) * DIM] += A_site[:, c]
    b = pairs.b[idx] + vi[..., _B].reshape(-1, C * DIM)
    cov = np.linalg.inv(A_data + np.diag(np.tile(THETA_PRIOR**-2.0, C)))
    theta = np.einsum("kij,kj->ki", cov, b)
    nis = np.maximum(vi[..., _NIS].sum(axis=-1) + pairs.nis[idx] - 2 * np.einsum(
        "ki,ki->k", theta, b) + np.einsum("ki,kij,kj->k", theta, A_data, theta), 0.0)
    dof = 2 * (vi[..., _N].sum(axis=-1) + pairs.n[idx].sum(axis=-1) / 2) - C * DIM
    f_joint = np.maximum(1.0, nis / np.maximum(dof, 1.0))
    # a site with evidence of its own (min_tracks track-epochs against AIS or a majority)
    # takes the inflation of its own residuals: the pairs' (association errors of
    # untested tracks among them) would widen every site's interval
    theta_c = theta.reshape(-1, C, DIM)
    n_own = vi[..., _N]
    f_own = np.maximum(1.0, _corrected_nis(vi, theta_c) / np.maximum(2 * n_own - DIM, 1.0))
    f = corr * np.where(n_own >= min_tracks, f_own, f_joint[:, None])
    blocks = np.moveaxis(np.diagonal(cov.reshape(-1, C, DIM, C, DIM), axis1=1, axis2=3), -1, 1)
    out_theta, out_P = own.theta.copy(), own.P.copy()
    out_theta[idx] = theta_c
    out_P[idx] = blocks * f[..., None, None]
    return _Fit(out_theta, out_P, own.nis, own.n + pairs.n, own.n_ais, pairs.n)


def _mahalanobis(x: np.ndarray, P: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", x, np.linalg.solve(P, x[..., None])[..., 0])


def _choose(fits: tuple[_Fit, _Fit, _Fit], cur: np.ndarray, corr: float,
            rc: RegistrationConfig) -> np.ndarray:
    """(K, C) the window of each epoch and site: both, unless past and future disagree
    (a jump; tested without the decorrelation factor: a false jump costs half the
    window, a missed one a wrong correction), then the side whose estimate fits the
    epoch's own residuals the better."""
    past, future, _ = fits
    d = corr * _mahalanobis(past.theta - future.theta, past.P + future.P)
    enough = (past.n >= rc.min_tracks) & (future.n >= rc.min_tracks)
    jump = enough & (d > chi2_ppf(1.0 - rc.jump_q, DIM))
    side = np.where(_corrected_nis(cur, past.theta) <= _corrected_nis(cur, future.theta),
                    PAST, FUTURE)
    return np.where(jump, side, BOTH)


def _choose_scale(wins: tuple[np.ndarray, ...], cur: np.ndarray, nis: list[np.ndarray],
                  corr: float, rc: RegistrationConfig) -> np.ndarray:
    """(K, C) the window of each epoch and site for the variance scale: both, unless the
    corrected NIS per dof before and after differ (an F test of 2n / corr dof each side
    at ``jump_q``: the radar's noise changed), then the side whose NIS per dof is
    nearer the epoch's own (in ratio). ``nis``: the corrected NIS sums of the past and
    future windows and of the epoch."""
    per_dof = [x / np.maximum(2 * v[..., _N], 1.0)
               for x, v in zip(nis, (*wins[:2], cur), strict=True)]
    dof = [np.maximum(2 * v[..., _N] / corr, 1.0) for v in wins[:2]]
    with np.errstate(divide="ignore", invalid="ignore"):
        log_f = np.log(np.maximum(per_dof[0], 1e-9) / np.maximum(per_dof[1], 1e-9))
        # log of an F(d1, d2) variable: about normal, variance 2/d1 + 2/d2
        z = log_f / np.sqrt(2 / dof[0] + 2 / dof[1])
        near = [np.abs(np.log(np.maximum(per_dof[2], 1e-9) / np.maximum(p, 1e-9)))
                for p in per_dof[:2]]
    enough = (wins[0][..., _N] >= rc.min_tracks) & (wins[1][..., _N] >= rc.min_tracks)
    jump = enough & (np.abs(z) > normal_ppf(1.0 - rc.jump_q / 2))
    return np.where(jump, np.where(near[0] <= near[1], PAST, FUTURE), BOTH)


def _pick(x: list[np.ndarray], side: np.ndarray) -> np.ndarray:
    """x[side] elementwise; ``side`` (K, C) broadcast over x's trailing axes."""
    stacked = np.stack(x)
    idx = side.reshape(1, *side.shape, *([1] * (stacked.ndim - 1 - side.ndim)))
    return np.take_along_axis(stacked, np.broadcast_to(idx, (1, *stacked.shape[1:])),
                              axis=0)[0]


def _scale(v: np.ndarray, nis: np.ndarray, corr: float, rc: RegistrationConfig
           ) -> tuple[np.ndarray, np.ndarray]:
    """(scale, applied) of sums ``v`` (..., 24) whose corrected NIS sum is ``nis``:
    covariance matching of the corrected residuals (module docstring)."""
    dof = 2 * v[..., _N]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = 1.0 + (nis - dof) / v[..., _TRACE]
        eff = np.maximum(dof / corr, 1e-9)
        lo, hi = chi2_ppf(rc.apply_q / 2, eff), chi2_ppf(1.0 - rc.apply_q / 2, eff)
    stat = nis / corr
    applied = (v[..., _N] >= rc.min_tracks) & ((stat <= lo) | (stat >= hi))
    return np.clip(np.where(applied, s, 1.0), MIN_SCALE, rc.max_scale), applied


def _readmitted(ev: RegistrationEvidence, theta_row: np.ndarray, scale: np.ndarray,
                applied: np.ndarray, rc: RegistrationConfig, radar_q: float, outlier_q: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """(group (K, n_groups), row (n,)) readmission: a group excluded by the integrity
    whose site's registration is applied (a correction explains the failure; a radar
    only noisier than its sigmas stays excluded) and whose corrected and rescaled
    residuals of the epoch, xi_i = (r_i - H_i theta)^T
    (S_i + (s - 1) P_i)^-1 (r_i - H_i theta) over its tracks tested, pass the NIS-sum
    test with no outlier (xi_i above chi2_2(1 - outlier_q)) in the group and over the
    site, whose scan check passes and whose variance scale is at most
    ``readmit_max_scale``; and of its rows, those without an outlier residual against the
    other channels (a row without any other channel on its track is not gated)."""
    K, ng = ev.n.shape
    C, G1 = ev.C, ev.G + 1
    gid = ev.row_k * ng + ev.row_group
    s_row = scale.reshape(-1)[gid]
    r = ev.row_r - np.einsum("nij,nj->ni", ev.H, theta_row)
    S = ev.row_innov_cov + (s_row - 1.0)[:, None] * ev.row_cov
    with np.errstate(invalid="ignore", divide="ignore"):
        det = S[:, 0] * S[:, 1] - S[:, 2] ** 2
        xi = (S[:, 1] * r[:, 0] ** 2 - 2 * S[:, 2] * r[:, 0] * r[:, 1]
              + S[:, 0] * r[:, 1] ** 2) / det
    gated = np.isfinite(xi)
    outlier = gated & (xi > chi2_ppf(1.0 - outlier_q, 2))
    tested = ev.row_tested & gated
    sums = np.stack([np.bincount(gid, weights=w, minlength=K * ng) for w in (
        tested, np.where(tested, xi, 0.0), tested & outlier)], axis=-1).reshape(K, ng, 3)
    site = sums.reshape(K, C, G1, 3).sum(axis=2)
    n_max = int(max(sums[..., 0].max(initial=0), site[..., 0].max(initial=0)))
    d2 = np.r_[np.inf, chi2_ppf(1.0 - radar_q / 4.0, 2 * np.arange(1, n_max + 1))]

    def passing(v: np.ndarray) -> np.ndarray:
        n = v[..., 0].astype(np.int64)
        return (v[..., 1] < d2[n]) & (v[..., 2] == 0)

    group_ok = (sums[..., 0] == 0) | passing(sums)
    site_ok = (site[..., 0] > 0) & passing(site)
    group = (ev.excluded & ~ev.blocked & group_ok & np.repeat(site_ok, G1, axis=1) & applied
             & (scale <= rc.readmit_max_scale))
    return group, group.reshape(-1)[gid] & ~outlier


def register(
    associations: pl.DataFrame, ev: RegistrationEvidence, rc: RegistrationConfig, *,
    radar_q: float, outlier_q: float, epoch_period_s: float, sites: list[str],
    sector_names: list[str], corrected_by: Estimate | None = None,
) -> Registration:
    """Estimate, apply and tabulate each radar's registration and variance scale.

    Consumes ``associations`` (``IntegrityResult.associations``: rows in the order of
    ``ev``'s rows, with x_enu_m, y_enu_m, P_xx, P_yy, P_xy, used) and ``ev`` (its
    evidence); ``radar_q``, ``outlier_q``: the integrity's false-alarm probabilities (the
    readmission test's thresholds). ``corrected_by``: the first pass's estimate when the
    reports were corrected by it before the association (the second pass,
    :func:`correct_reports`): nothing is estimated or corrected again; the variance
    scale and the readmission test take the residuals as they are (theta = 0), a group
    readmitted where that estimate is applied, and the table reports that estimate."""
    K, ng = ev.n.shape
    C, G1 = ev.C, ev.G + 1
    w = max(1, round(rc.window_s / epoch_period_s))
    corr = float(np.clip(rc.decorrelation_s / epoch_period_s, 1.0, 2 * w + 1))
    cur = _evidence(ev)
    per_site = cur.reshape(K, C, G1, _WIDTH).sum(axis=2)
    site_wins, group_wins = _windows(per_site, w), _windows(cur, w)
    if corrected_by is None:
        pair_wins = [_Pairs(*x) for x in zip(*(_windows(a, w) for a in (
            ev.pair_info, ev.pair_b, ev.pair_nis, ev.pair_n)), strict=True)]
        est = _estimate(site_wins, group_wins, pair_wins, per_site, corr, w, rc, ev.epochs, G1)
        theta_used, P_used = est.theta_used, est.cov_used
        own_site = est.own.reshape(K, C, G1).any(axis=-1)
    else:
        est = corrected_by
        theta_used, P_used = np.zeros_like(est.theta), np.zeros_like(est.P)
        own_site = np.zeros((K, C), bool)
    site_theta = theta_used.reshape(K, C, G1, DIM)[:, :, 0]  # where no sector has its own

    def site_nis(site_v: np.ndarray, group_v: np.ndarray) -> np.ndarray:
        # a site whose sectors are registered on their own: the sum of its sectors'
        nis = _corrected_nis(site_v, site_theta)
        if own_site.any():
            nis = np.where(own_site, _corrected_nis(group_v, theta_used).reshape(K, C, G1)
                           .sum(axis=-1), nis)
        return nis

    # the variance scale per (site, sector) on the site's window; else the site's
    side_s = _choose_scale(site_wins, per_site, [
        site_nis(site_wins[PAST], group_wins[PAST]), site_nis(site_wins[FUTURE],
                                                              group_wins[FUTURE]),
        site_nis(per_site, cur)], corr, rc)
    site_win = _pick(list(site_wins), side_s)
    group_win = _pick(list(group_wins), np.repeat(side_s, G1, axis=1))
    s_group, s_group_ok = _scale(group_win, _corrected_nis(group_win, theta_used), corr, rc)
    s_site, s_site_ok = _scale(site_win, site_nis(site_win, group_win), corr, rc)
    s_site_g = np.repeat(s_site, G1, axis=1)
    scale = np.where(s_group_ok, s_group, np.where(np.repeat(s_site_ok, G1, axis=1), s_site_g,
                                                   1.0))
    scale_ok = s_group_ok | np.repeat(s_site_ok, G1, axis=1)
    rk, rg = ev.row_k, ev.row_group
    readmit, readmit_row = _readmitted(ev, theta_used[rk, rg], scale, est.applied, rc, radar_q,
                                       outlier_q)
    used = associations["used"].to_numpy() | readmit_row
    out = associations.with_columns(pl.Series("used", used))
    corrected = _correct(out, ev.H, theta_used[rk, rg], P_used[rk, rg], scale[rk, rg])
    present = np.bincount(rk * ng + rg, minlength=K * ng).reshape(K, ng) > 0
    table = _table(ev, present, est, scale, scale_ok, group_win[..., _N], readmit, sites,
                   sector_names)
    return Registration(out, corrected, table, est)


def _estimate(site_wins: tuple[np.ndarray, ...], group_wins: tuple[np.ndarray, ...],
              pair_wins: list[_Pairs], per_site: np.ndarray, corr: float, w: int,
              rc: RegistrationConfig, epochs: np.ndarray, G1: int) -> Estimate:
    """Each site's registration on its windows' sums, a sector's own where the site's
    sectors differ (module docstring)."""
    fits = tuple(_joint_fit(v, pw, corr, rc.min_tracks)
                 for v, pw in zip(site_wins, pair_wins, strict=True))
    side = _choose(fits, per_site, corr, rc)
    theta = _pick([f.theta for f in fits], side)
    P = _pick([f.P for f in fits], side)
    n, n_ais = _pick([f.n for f in fits], side), _pick([f.n_ais for f in fits], side)
    n_pair = _pick([f.n_pair for f in fits], side)
    # both sides whole: within a window of the rows' first or last epoch one side is cut
    # short and a jump there unseen (a fault from the first epoch on would be corrected
    # before its onset too)
    k = np.arange(epochs.size)
    whole = ((k >= w) & (k < epochs.size - w))[:, None]
    applied = (n >= rc.min_tracks) & _differs_from_zero(theta, P, rc) & whole
    # the sectors (G1 groups per site), on the site's side of the window
    v_sector = _pick(list(group_wins), np.repeat(side, G1, axis=1))
    sector = _fit(v_sector, corr)
    # the test's decision in most of the window's epochs: a sector's correction does not
    # flicker on and off where the test is near its threshold (a track's reports corrected
    # at one epoch and not the next fuse into a wrong track)
    split = np.zeros_like(applied)
    if rc.per_sector:
        differs = _windows(_sectors_differ(v_sector, sector, theta, corr, rc).astype(float), w)
        split = differs[BOTH] > 0.5 * _windows(np.ones((epochs.size, 1)), w)[BOTH]
    own = np.repeat(split, G1, axis=1) & (sector.n >= rc.min_tracks)

    def by_group(of_sector: np.ndarray, of_site: np.ndarray) -> np.ndarray:
        return np.where(own.reshape(*own.shape, *[1] * (of_site.ndim - 2)), of_sector,
                        np.repeat(of_site, G1, axis=1))

    # a sector of a site whose sectors differ applies its own estimate, zero or not: the
    # site is off somewhere, and no sector's registration is known to be zero (a sector
    # half in the fault has an estimate short of its test, and left uncorrected its
    # reports split off the other radars' tracks: duplicates x2 in the Monte Carlo)
    return Estimate(epochs, by_group(sector.theta, theta), by_group(sector.P, P),
                    np.repeat(side, G1, axis=1), by_group(sector.n, n),
                    by_group(sector.n_ais, n_ais), by_group(np.zeros_like(sector.n), n_pair),
                    by_group(np.broadcast_to(whole, own.shape), applied), own, G1)


def _differs_from_zero(theta: np.ndarray, P: np.ndarray, rc: RegistrationConfig) -> np.ndarray:
    """theta^T P^-1 theta >= chi2_4(1 - ``apply_q``): the estimate is not zero."""
    return _mahalanobis(theta, P) >= chi2_ppf(1.0 - rc.apply_q, DIM)


def _sectors_differ(v: np.ndarray, sector: _Fit, theta_site: np.ndarray, corr: float,
                    rc: RegistrationConfig) -> np.ndarray:
    """(K, C) whether a site's sectors need registrations of their own (``v``: the
    sectors' sums (K, n_groups, 24), ``sector`` their fits): the likelihood-
    ratio test of one registration for every sector of the site with ``min_tracks``
    track-epochs (E of them) against one per sector,

    .. math:: \\Lambda = \\sum_g [\\tilde N_g(\\hat\\theta_{site}) - \\tilde N_g(\\hat\\theta_g)]
              / (c f) > \\chi^2_{4(E - 1)}(1 - q)

    (c the decorrelation factor, f = max(1, sum N~_g(theta_g) / (2 sum n_g - 4E)) the
    sectors' own inflation, q = ``apply_q``): a radar whose error is not the same at
    every azimuth (an encoder error over part of the rotation, a range error on one
    bearing's path)."""
    (K, ng), C = sector.n.shape, theta_site.shape[1]
    G1 = ng // max(C, 1)
    enough = sector.n >= rc.min_tracks
    v_site = _corrected_nis(v, np.repeat(theta_site, G1, axis=1))
    gain = np.where(enough, np.maximum(v_site - sector.nis, 0.0), 0.0).reshape(K, C, G1)
    E = enough.reshape(K, C, G1).sum(axis=-1)
    nis = np.where(enough, sector.nis, 0.0).reshape(K, C, G1).sum(axis=-1)
    n = np.where(enough, sector.n, 0.0).reshape(K, C, G1).sum(axis=-1)
    f = np.maximum(1.0, nis / np.maximum(2 * n - DIM * E, 1.0))
    dof = np.maximum(DIM * (E - 1), 1)
    return (E >= 2) & (gain.sum(axis=-1) / (corr * f) > chi2_ppf(1.0 - rc.apply_q, dof))


def correct_reports(synced: pl.DataFrame, est: Estimate, site_xy: np.ndarray,
                    sites: list[str], sectors: Sequence[Sector], region: RegionConfig
                    ) -> pl.DataFrame:
    """The synchronised reports (``synchronise``'s rows) corrected by the registration
    ``est`` applied at their site, sector (of the report as reported, ``sectors`` in
    ``region``) and epoch: p <- p - H theta, P <- P + H P_theta H^T, H
    (:func:`~pipeline.maritime.integrity.registration_jacobian`) of the report as
    reported, seen from its site (``site_xy`` (C, 2) in the order of ``sites``); the
    reports as reported kept in ``reported_<column>`` (:func:`as_reported`). Rows of
    an epoch and site where nothing is applied stay as they are, to the last digit
    (reports already scaled by :func:`scale_covariances` keep their ``reported_*``)."""
    k, c = _epoch_and_site(synced, est.epochs, sites)
    xy = synced.select("x_enu_m", "y_enu_m").to_numpy()
    # a site's groups share its estimate unless a sector has its own
    g = c * est.groups_per_site
    if est.own.any():
        g = g + sector_indices(xy[:, 0], xy[:, 1], sectors, region)
    vx, vy = velocity_enu(synced["speed_mps"].to_numpy(), synced["course_rad"].to_numpy())
    H = registration_jacobian(xy, site_xy[c], vx, vy)
    kept = synced if "reported_P_xx" in synced.columns else synced.with_columns(
        pl.col(col).alias(f"reported_{col}") for col in REPORTED_COLUMNS)
    # where nothing is applied, x - 0 and 1 P + 0: the bits as reported
    return _correct(kept, H, est.theta_used[k, g], est.cov_used[k, g], np.ones(k.size))


ACCURACY_BUCKET_S = 60.0
"""The stated-accuracy check's time bins (UTC minutes: the same bins in every unit)."""
ACCURACY_QUANTILE = 0.25
"""Of the bins around an epoch, the quantile taken: a fault in up to three quarters of
them does not move it; a standing misstatement is in all of them."""
ACCURACY_MIN_BINS = 5
"""Bins with ``min_tracks`` tested rows needed around an epoch before anything is
scaled there."""
STATED_AXES = ("range", "azimuth")
"""The axes the stated-accuracy check scales on their own: along the line of sight
(the radar's range sigma) and across it (rho times its azimuth sigma)."""
VELOCITY_AXES = ("speed", "course")
"""The velocity's: the radar's speed and course sigmas."""
MIN_COURSE_SPEED_MPS = 1.0
"""Slower than this (the radar's track or the AIS report), the course is not compared
(a drifting ship's COG is noise) and the row is left out of the velocity check."""


def _quadratic(axes: np.ndarray, P: np.ndarray) -> np.ndarray:
    """(n, 2) u^T P u for each row's two ``axes`` (n, 2, 2) and its covariance ``P``
    (n, 3: xx, yy, xy)."""
    return (axes[..., 0] ** 2 * P[:, None, 0] + 2 * axes[..., 0] * axes[..., 1] * P[:, None, 2]
            + axes[..., 1] ** 2 * P[:, None, 1])


def _row_nis(ev: RegistrationEvidence) -> np.ndarray:
    """(n, 5) each row's normalised squared residual, each divided by its median where
    S is right (1 then): r^T S^-1 r / ln 4 (chi2 with 2 dof), and along its line of
    sight and across it, z = (u^T r)^2 / (u^T S u) / chi2_1^-1(0.5) (u_r: the first
    column of the row's registration Jacobian ``ev.H``, u_az its normal); then the
    radar's own share of u^T S u on each axis, f = u^T P u / u^T S u."""
    S, r = ev.row_innov_cov, ev.row_r
    u = ev.H[:, :, 0]
    axes = np.stack([u, np.stack([u[:, 1], -u[:, 0]], axis=-1)], axis=1)  # (n, 2 axes, 2)
    ur = np.einsum("nai,ni->na", axes, r)
    uSu = _quadratic(axes, S)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.column_stack([_d2(r, S) / np.log(4.0), ur**2 / uSu / chi2_ppf(0.5, 1),
                                _quadratic(axes, ev.row_cov) / uSu])


def stated_accuracy_scale(ev: RegistrationEvidence, rc: RegistrationConfig) -> np.ndarray:
    """(K, C, 2) the variance scale each site's stated covariances need at each epoch
    along the line of sight and across it (:data:`STATED_AXES`), 1 where they are right
    (issue 38, item 2: estimated accuracy in place of the stated).

    A radar whose reports are noisier than their sigmas say fails the integrity test all
    the time; with every radar so, nothing is fused. Per site and UTC minute, the
    covariance matching of its rows tested (against their AIS report or two other
    radars: ``ev.row_r``, ``ev.row_innov_cov``) by the median, robust to a minority of
    outliers: s = median(xi) / ln 4 (the median of chi2 with 2 dof), xi = r^T S^-1 r,
    with ``min_tracks`` rows or more; per epoch, its standing value
    (:func:`_standing`): a fault of a few minutes (the integrity's to find) leaves it
    below ``accuracy_min_scale``, a misstatement that lasts raises every minute. Where
    it reaches it, each axis takes its own scale by the same rule (z = (u^T r)^2 / (u^T
    S u), chi2 with 1 dof, :func:`_row_nis`), clipped to ``max_scale``, 1 on an axis
    below the threshold: range and azimuth sigmas are stated apart (a site config, a
    recorder), the cross-range error rho sigma_az grows with range and the range error
    does not, so one factor on both is wrong at every range (azimuth sigmas stated at
    half: ~2 where the cross-range needs 4). The reference's own covariance is in S: an
    axis's scale is the radar's, s = 1 + (m - 1) / f with m the matched factor of u^T S
    u and f the radar's median share of it (the reference as stated: an AIS report;
    against two other radars stated as wrongly s reads high, a conservative weight)."""
    z = _row_nis(ev)
    ok = ev.row_tested & np.isfinite(z).all(axis=1)
    return _standing(ev, ok, z, rc)


def stated_velocity_scale(ev: RegistrationEvidence, rc: RegistrationConfig,
                          sigma_sog_mps: float, sigma_cog_rad: float) -> np.ndarray:
    """(K, C, 2) the variance scale each site's stated speed and course sigmas need at
    each epoch (:data:`VELOCITY_AXES`), 1 where they are right: the check of
    :func:`stated_accuracy_scale` on the velocity. A radar's velocity sigmas stated too
    small split its tracks in the association (its velocity cost): all four sigmas of
    both radars stated at half, 532 (epoch, ship) pairs followed by two fused tracks for
    18 and 65.8 m fused RMS for 40.4 with the position sigmas alone scaled (20 seeds,
    docs/integrity.md §9; with this check 52 and 46.2 m). Rows whose
    track carries an AIS report (``ev.row_ais_velocity``) and both move at least
    :data:`MIN_COURSE_SPEED_MPS`: z = (v - SOG)^2 / (sigma_v^2 + sigma_sog^2) and
    wrap(c - COG)^2 / (sigma_c^2 + sigma_cog^2), each over chi2_1's median, the radar's
    share f = sigma^2 / (sigma^2 + sigma_AIS^2) (the transponder's as configured: the
    integrity's ``ais_sigma_sog_mps``, ``ais_sigma_cog_rad``), gated by their sum over
    ln 4 as the position's."""
    v, va = ev.row_velocity, ev.row_ais_velocity
    with np.errstate(invalid="ignore"):
        ok = (np.isfinite(va).all(axis=1) & np.isfinite(v).all(axis=1)
              & (v[:, 0] >= MIN_COURSE_SPEED_MPS) & (va[:, 0] >= MIN_COURSE_SPEED_MPS))
    var_radar = v[:, 2:] ** 2
    var = var_radar + np.array([sigma_sog_mps, sigma_cog_rad]) ** 2
    d = np.column_stack([v[:, 0] - va[:, 0], wrap_angle(v[:, 1] - va[:, 1])])
    with np.errstate(invalid="ignore", divide="ignore"):
        zz = d**2 / var
        z = np.column_stack([zz.sum(axis=1) / np.log(4.0), zz / chi2_ppf(0.5, 1),
                             var_radar / var])
    return _standing(ev, ok & np.isfinite(z).all(axis=1), z, rc)


def _standing(ev: RegistrationEvidence, ok: np.ndarray, z: np.ndarray,
              rc: RegistrationConfig) -> np.ndarray:
    """(K, C, 2) the standing scales of the rows ``ok`` with ``z`` (n, 5: the whole
    normalised square, the two axes' and the radar's share of each, each 1 where the
    sigmas are right): per site and UTC minute with ``min_tracks`` rows the medians, an
    axis's m taken to the radar's own s = 1 + (m - 1) / f; per epoch the
    ``ACCURACY_QUANTILE`` of its minute and the whole minutes within
    ``accuracy_window_s`` on either side (9 for 300 s; at least ``ACCURACY_MIN_BINS``
    of them with rows enough); an axis's where it and the whole reach
    ``accuracy_min_scale``, clipped to ``max_scale``, else 1."""
    K, C, G1 = ev.epochs.size, ev.C, ev.G + 1
    if K == 0 or not ok.any():
        return np.ones((K, C, 2))
    bin_ns = round(ACCURACY_BUCKET_S * 1e9)
    epoch_bin = ev.epochs // bin_ns
    first = int(epoch_bin[0])
    axes, share = ["z_0", "z_1"], ["share_0", "share_1"]
    per_bin = (pl.DataFrame(z[ok], schema=["z", *axes, *share], orient="row").with_columns(
        site=(ev.row_group[ok] // G1).astype(np.int64), bin=epoch_bin[ev.row_k[ok]] - first)
        .group_by("site", "bin").agg(pl.all().median(), pl.len().alias("n"))
        .filter(pl.col("n") >= rc.min_tracks)
        # the radar's own variance s times its share, the reference's as stated
        .with_columns((1.0 + (pl.col(a) - 1.0) / pl.col(f)).alias(a)
                      for a, f in zip(axes, share, strict=True)))
    nb = int(epoch_bin[-1]) - first + 1
    # whole minutes within the window: the last one ends by t + accuracy_window_s, so a
    # unit's look-ahead holds every one of them (results do not depend on unit cuts)
    w = int(rc.accuracy_window_s // ACCURACY_BUCKET_S) - 1
    dense = np.full((nb + 2 * w, C, 3), np.nan)
    dense[per_bin["bin"].to_numpy() + w, per_bin["site"].to_numpy()] = (
        per_bin.select("z", *axes).to_numpy())
    around = sliding_window_view(dense, 2 * w + 1, axis=0)  # (nb, C, 3, 2w + 1)
    enough = np.sum(np.isfinite(around), axis=-1) >= ACCURACY_MIN_BINS
    with np.errstate(invalid="ignore"):
        q = np.where(enough, np.nanquantile(np.where(enough[..., None], around, 0.0),
                                            ACCURACY_QUANTILE, axis=-1), 1.0)
    scaled = (q[..., :1] >= rc.accuracy_min_scale) & (q[..., 1:] >= rc.accuracy_min_scale)
    scale = np.where(scaled, np.minimum(q[..., 1:], rc.max_scale), 1.0)
    return scale[epoch_bin - first]


def scale_covariances(synced: pl.DataFrame, epochs: np.ndarray, scale: np.ndarray,
                      velocity_scale: np.ndarray, sites: list[str], site_xy: np.ndarray
                      ) -> pl.DataFrame:
    """The synchronised reports with each site's covariance scaled by ``scale`` (K, C, 2:
    range, azimuth) at their epoch (``epochs``, sites in the order of ``sites`` at
    ``site_xy``), P <- D P D with D = sqrt(s_r) u_r u_r^T + sqrt(s_az) u_az u_az^T (u_r
    the report's line of sight: a covariance stated in range and azimuth scaled on each,
    positive definite whatever its axes), and its speed and course sigmas by the square
    roots of ``velocity_scale`` (K, C, 2); the reports as reported kept in
    ``reported_<column>`` (:func:`as_reported`); a report whose scales are 1: the bits
    as reported."""
    k, c = _epoch_and_site(synced, epochs, sites)
    s = scale[k, c]
    d = synced.select("x_enu_m", "y_enu_m").to_numpy() - site_xy[c]
    u = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1.0)[:, None]
    a, b = np.sqrt(s[:, 0]), np.sqrt(s[:, 1])
    D = np.empty((synced.height, 2, 2))
    D[:, 0, 0] = a * u[:, 0] ** 2 + b * u[:, 1] ** 2
    D[:, 1, 1] = a * u[:, 1] ** 2 + b * u[:, 0] ** 2
    D[:, 0, 1] = D[:, 1, 0] = (a - b) * u[:, 0] * u[:, 1]
    xx, xy, yy = (synced[col].to_numpy() for col in ("P_xx", "P_xy", "P_yy"))
    P = np.stack([xx, xy, xy, yy], axis=-1).reshape(-1, 2, 2)
    DPD = np.einsum("nij,njk,nlk->nil", D, P, D)
    same = (s == 1.0).all(axis=1)
    scaled = {col: np.where(same, P[:, i, j], DPD[:, i, j])
              for col, (i, j) in (("P_xx", (0, 0)), ("P_yy", (1, 1)), ("P_xy", (0, 1)))}
    sv = np.sqrt(velocity_scale[k, c])  # x * 1.0: the bits as reported
    scaled |= {"sigma_speed_mps": synced["sigma_speed_mps"].to_numpy() * sv[:, 0],
               "sigma_course_rad": synced["sigma_course_rad"].to_numpy() * sv[:, 1]}
    return synced.with_columns(pl.col(col).alias(f"reported_{col}") for col in REPORTED_COLUMNS
                               ).with_columns(pl.Series(col, v) for col, v in scaled.items())


def with_stated_scale(table: pl.DataFrame, epochs: np.ndarray,
                      stated: tuple[np.ndarray, np.ndarray] | None, sites: list[str]
                      ) -> pl.DataFrame:
    """``sensor_registration`` rows with ``stated_<axis>_variance_scale`` of the
    position's (range, azimuth) and velocity's (speed, course) ``stated`` scales: the
    factors their site's stated sigmas were tracked on (1: as stated)."""
    names = [f"stated_{axis}_variance_scale" for axis in (*STATED_AXES, *VELOCITY_AXES)]
    if stated is None:
        return table.with_columns(pl.lit(1.0).alias(n) for n in names)
    at = _epoch_and_site(table, epochs, sites)
    s = np.concatenate([stated[0][at], stated[1][at]], axis=1)
    return table.with_columns(pl.Series(n, s[:, i]) for i, n in enumerate(names))


def _epoch_and_site(rows: pl.DataFrame, epochs: np.ndarray, sites: list[str]
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(epoch index in ``epochs``, site index in ``sites``) of each row (time_ns, site_id)."""
    return (np.searchsorted(epochs, rows["time_ns"].to_numpy()),
            rows["site_id"].replace_strict(sites, list(range(len(sites))),
                                           return_dtype=pl.Int64).to_numpy())


SECOND_PASS_SIGMA = 1.0
"""A correction moves a report when it shifts it by more than this many of its own
position sigmas (Mahalanobis distance): less cannot take a report out of its track's
association gate (chi2_2(0.999), ~3.7 sigma), so no duplicate can be born of it."""


def moves_a_report(synced: pl.DataFrame, corrected: pl.DataFrame) -> bool:
    """Whether :func:`correct_reports` shifted any report by more than
    :data:`SECOND_PASS_SIGMA` of its own position covariance (the stage then runs the
    association again on the corrected reports; else the first pass's association
    stands and only the fusion takes the corrected reports)."""
    dx = (corrected["x_enu_m"] - synced["x_enu_m"]).to_numpy()
    dy = (corrected["y_enu_m"] - synced["y_enu_m"]).to_numpy()
    a, b, c = (synced[k].to_numpy() for k in ("P_xx", "P_xy", "P_yy"))
    d2 = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / (a * c - b * b)
    return bool(np.any(d2 > SECOND_PASS_SIGMA**2))


def as_reported(associations: pl.DataFrame) -> pl.DataFrame:
    """Rows of reports corrected by :func:`correct_reports` with their positions and
    covariances as reported again (the ``reported_*`` columns dropped)."""
    return associations.with_columns(
        pl.col(f"reported_{col}").alias(col) for col in REPORTED_COLUMNS
    ).drop(f"reported_{col}" for col in REPORTED_COLUMNS)


def _correct(df: pl.DataFrame, H: np.ndarray, theta: np.ndarray, P_theta: np.ndarray,
             scale: np.ndarray) -> pl.DataFrame:
    """p <- p - H theta, P <- s P + H P_theta H^T per row."""
    dp = np.einsum("nij,nj->ni", H, theta)
    HPH = np.einsum("nij,njk,nlk->nil", H, P_theta, H)
    return df.with_columns(
        (pl.col("x_enu_m") - dp[:, 0]).alias("x_enu_m"),
        (pl.col("y_enu_m") - dp[:, 1]).alias("y_enu_m"),
        (pl.col("P_xx") * scale + HPH[:, 0, 0]).alias("P_xx"),
        (pl.col("P_yy") * scale + HPH[:, 1, 1]).alias("P_yy"),
        (pl.col("P_xy") * scale + HPH[:, 0, 1]).alias("P_xy"),
    )


def _table(ev: RegistrationEvidence, present: np.ndarray, est: Estimate, scale: np.ndarray,
           scale_ok: np.ndarray, scale_n: np.ndarray, readmit: np.ndarray, sites: list[str],
           sector_names: list[str]) -> pl.DataFrame:
    """``sensor_registration`` rows: one per epoch and (site, sector) with reports."""
    G1 = ev.G + 1
    kk, gg = np.nonzero(present)
    cc = gg // G1
    names = [*sector_names, None]
    sigma = np.sqrt(np.diagonal(est.P, axis1=-2, axis2=-1))[kk, gg]
    th = est.theta[kk, gg]
    return pl.DataFrame({
        "time_ns": ev.epochs[kk],
        "site_id": pl.Series([sites[i] for i in cc.tolist()], dtype=pl.String),
        "sector": pl.Series([names[i] for i in (gg % G1).tolist()], dtype=pl.String),
        "range_bias_m": th[:, 0],
        "azimuth_bias_rad": th[:, 1],
        "time_offset_s": th[:, 2],
        "range_gain": th[:, 3],
        "sigma_range_bias_m": sigma[:, 0],
        "sigma_azimuth_bias_rad": sigma[:, 1],
        "sigma_time_offset_s": sigma[:, 2],
        "sigma_range_gain": sigma[:, 3],
        "window": pl.Series([_SIDES[i] for i in est.side[kk, gg].tolist()], dtype=pl.String),
        "tracks": est.n[kk, gg].astype(np.int32),
        "tracks_ais": est.n_ais[kk, gg].astype(np.int32),
        "tracks_pair": est.n_pair[kk, gg].astype(np.int32),
        "registration_scope": pl.Series(np.where(est.own[kk, gg], "sector", "site"),
                                        dtype=pl.String),
        "registration_applied": est.applied[kk, gg],
        "variance_scale": scale[kk, gg],
        "scale_tracks": scale_n[kk, gg].astype(np.int32),
        "scale_applied": scale_ok[kk, gg],
        "readmitted": readmit[kk, gg],
    }, schema_overrides={"time_ns": pl.Int64}).sort("time_ns", "site_id", "sector",
                                                    nulls_last=True)
