"""Reconstructed reference trajectories: a fixed-interval Rauch–Tung–Striebel smoother
with outlier gating and manoeuvre handling, vectorised over targets (pure kernels).

What surveillance evaluation tools do before they score a sensor against data that has
no ground truth (OpenATS COMPASS's reconstructor: a uniform-motion Kalman filter or an
IMM with an RTS smoother per target; EUROCONTROL SASS-C's reference trajectories): a
per-target trajectory, smoothed over the whole interval, with its own covariance.

**Model.** Per target and per horizontal axis (east, north) a nearly-constant-velocity
state (p, v) driven by white acceleration of power spectral density ``q`` (m²/s³),

.. math::
    F(h) = \\begin{bmatrix} 1 & h \\\\ 0 & 1 \\end{bmatrix}, \\qquad
    Q(h) = q \\begin{bmatrix} h^3/3 & h^2/2 \\\\ h^2/2 & h \\end{bmatrix}

(Bar-Shalom, Li, Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, 2001, §6.2.2), measured in position with variance ``r_pos`` per axis and,
where the sensor gives it (AIS SOG/COG), in velocity with variance ``r_vel`` per axis.
Both measurement covariances are isotropic (a velocity covariance J diag(σ_SOG²,
(SOG σ_COG)²) Jᵀ is replaced by its larger eigenvalue times I: conservative), so the
two axes decouple exactly and every step is closed-form scalar arithmetic on (n, 2)
arrays: P per axis is three numbers (P_pp, P_pv, P_vv). Nothing is inverted but 2×2
blocks in closed form.

**Manoeuvres (an IMM equivalent).** A forward IMM (Blom & Bar-Shalom 1988; Bar-Shalom
et al. 2001 §11.6) of two such models, ``q_low`` (steady course and speed) and
``q_high`` (turning, accelerating), with sojourn times ``sojourn_*_s`` (Markov switching
P(stay) = exp(−h/τ)), gives each report's probability of the manoeuvre model; the same
IMM run backwards in time (a CV model is time-reversible: t → −t, v → −v) gives it from
the future, since a forward IMM notices a manoeuvre only after it began
(:func:`manoeuvre_probability`; the cheaper stand-in :func:`lookahead_max` moves the
forward probability back over the few reports the forward filter needs). The
manoeuvre probability of an interval is the larger of the two at its ends, and the final
smoother is the RTS smoother of the linear model whose interval k → k+1 has
q_k = q_low + μ_k (q_high − q_low). We smooth this linear model rather than
implementing the IMM smoother itself (Helmick, Blair, Hoffman 1995): its covariance is
then exactly the posterior covariance of that model, and the reference error between
reports has a closed form (:func:`interpolate`).

**Outliers.** In the forward IMM a position report whose NIS under the manoeuvre model
exceeds ``gate`` (χ²₂) updates nothing and is marked rejected; a velocity whose NIS
exceeds it is dropped alone. After ``max_rejections`` rejections in a row the target
has jumped (another transponder, a frozen GNSS that thawed): the filter restarts at
that report and the caller starts a new segment there (:func:`imm_forward` returns the
restarts).

**RTS** (Rauch, Tung, Striebel 1965):

.. math::
    G_k = P_{k|k} F^T P_{k+1|k}^{-1}, \\quad
    x_{k|N} = x_{k|k} + G_k (x_{k+1|N} - x_{k+1|k}), \\quad
    P_{k|N} = P_{k|k} + G_k (P_{k+1|N} - P_{k+1|k}) G_k^T

**Between reports** (:func:`interpolate`) the same smoother at an intermediate time τ
in (t_k, t_k + h): x(τ) given the data up to k is x_p = F(τ) x_{k|k}, P_p = F(τ) P_{k|k}
F(τ)ᵀ + Q(τ), its cross-covariance with x(k+1) is P_p F(h − τ)ᵀ, so
G = P_p F(h−τ)ᵀ P_{k+1|k}⁻¹ and x(τ|N) = x_p + G (x_{k+1|N} − x_{k+1|k}),
P(τ|N) = P_p + G (P_{k+1|N} − P_{k+1|k}) Gᵀ: exact for the model, no spline.

Layout: targets (segments) are rows of padded arrays sorted by length, longest first
(:func:`pack`), so the rows alive at column j are the first ``n_j``: every step works on
views ``[:n_j]``, no gather. The loops run over columns (reports of one target in time
order); everything inside is array work over targets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.filters.quantiles import chi2_ppf, normal_ppf

V0_VAR_M2PS2 = 15.0**2
"""Prior velocity variance per axis at a segment start without a velocity report."""
MU0_HIGH = 0.1
"""Prior probability of the manoeuvre model at a segment start."""


@dataclass(frozen=True)
class MotionModel:
    """The two motion models of the IMM and the gate (module docstring)."""

    q_low: float = 1e-4          # m^2/s^3: steady course and speed
    q_high: float = 0.1          # m^2/s^3: turning / accelerating
    sojourn_low_s: float = 600.0
    sojourn_high_s: float = 60.0
    gate_probability: float = 0.9999
    max_rejections: int = 3

    @property
    def gate(self) -> float:
        return float(chi2_ppf(self.gate_probability, 2))


@dataclass(frozen=True, eq=False)
class Packed:
    """Ragged groups as padded (n, L) arrays, rows sorted by length (longest first).

    ``order``: the input rows in packed order (row r, column j is input
    ``order[start[r] + j]``); ``group``: the input group code of each packed row;
    ``lengths`` (n,); ``alive[j]``: rows with more than j entries (the first alive[j]
    rows)."""

    order: np.ndarray
    start: np.ndarray
    group: np.ndarray
    lengths: np.ndarray
    alive: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return (self.lengths.size, int(self.lengths.max(initial=0)))

    def grid(self, values: np.ndarray, fill: float = np.nan) -> np.ndarray:
        """Input values (m, ...) scattered onto the (n, L, ...) grid."""
        n, L = self.shape
        out = np.full((n, L, *values.shape[1:]), fill, dtype=float)
        rows, cols = self.cells()
        out[rows, cols] = values[self.order]
        return out

    def cells(self) -> tuple[np.ndarray, np.ndarray]:
        """(row, column) of each packed entry, in ``order``."""
        rows = np.repeat(np.arange(self.lengths.size), self.lengths)
        cols = np.arange(rows.size) - np.repeat(np.cumsum(self.lengths) - self.lengths,
                                                self.lengths)
        return rows, cols

    def flat(self, grid: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`grid`: (n, L, ...) -> input rows (m, ...)."""
        rows, cols = self.cells()
        out = np.empty((self.order.size, *grid.shape[2:]), grid.dtype)
        out[self.order] = grid[rows, cols]
        return out


def pack(group: np.ndarray) -> Packed:
    """Pack input rows by ``group`` (int codes, the rows of one group already in time
    order and contiguous or not: a stable sort keeps their order)."""
    group = np.asarray(group)
    order0 = np.argsort(group, kind="stable")
    g = group[order0]
    bounds = np.flatnonzero(np.r_[True, g[1:] != g[:-1]]) if g.size else np.empty(0, int)
    lengths0 = np.diff(np.r_[bounds, g.size])
    by_len = np.argsort(-lengths0, kind="stable")
    lengths = lengths0[by_len]
    starts0 = bounds[by_len]
    order = (np.concatenate([order0[s:s + n] for s, n in zip(starts0, lengths, strict=True)])
             if lengths.size else np.empty(0, np.int64))
    start = np.cumsum(lengths) - lengths
    L = int(lengths.max(initial=0))
    alive = (lengths[None, :] > np.arange(L)[:, None]).sum(axis=1)
    return Packed(order, start, g[starts0] if g.size else g, lengths, alive)


# --- predict and update, per axis: arrays (n, 2) or (n, models, 2) ---------------------------


def predict(p, v, a, b, c, h, q):
    """CV prediction over h with PSD q: per axis p, v and P = [[a, b], [b, c]]; h and q
    broadcast against the state's leading axes ((n, 1) for (n, 2) states)."""
    qh = q * h
    p = p + h * v
    a = a + h * (2.0 * b + h * c) + qh * h * h / 3.0
    b = b + h * c + 0.5 * qh * h
    c = c + qh
    return p, v, a, b, c


def update_position(p, v, a, b, c, z, r):
    """Position update with variance r per axis (broadcast against the state); returns the
    state and the innovation NIS per row (summed over the axes)."""
    S = a + r
    nu = z - p
    nis = (nu * nu / S).sum(axis=-1)
    kp, kv = a / S, b / S
    return p + kp * nu, v + kv * nu, a - kp * a, b - kp * b, c - kv * b, nis, S


def update_velocity(p, v, a, b, c, zv, rv):
    """Velocity update with variance rv per axis; as :func:`update_position`."""
    S = c + rv
    nu = zv - v
    nis = (nu * nu / S).sum(axis=-1)
    kp, kv = b / S, c / S
    return p + kp * nu, v + kv * nu, a - kp * b, b - kp * c, c - kv * c, nis, S


def _where(mask, new, old):
    return tuple(np.where(mask, x, y) for x, y in zip(new, old, strict=True))


def _init(z, r, zv, rv):
    """Segment start: p = z, v = the velocity report (or 0, diffuse)."""
    hv = np.isfinite(zv[:, 0])
    p = z.copy()
    v = np.where(hv[:, None], np.nan_to_num(zv), 0.0)
    a = np.repeat(r[:, None], 2, axis=1)
    b = np.zeros_like(a)
    c = np.repeat(np.where(hv, rv, V0_VAR_M2PS2)[:, None], 2, axis=1)
    return p, v, a, b, c


# --- the forward IMM: manoeuvre probabilities and gating -----------------------------------


@dataclass(frozen=True, eq=False)
class ImmResult:
    """Per packed cell (n, L): probability of the manoeuvre model after the report,
    accepted position, accepted velocity, restart (the filter started again here)."""

    mu_high: np.ndarray
    accepted: np.ndarray
    velocity_used: np.ndarray
    restart: np.ndarray


def imm_forward(pk: Packed, t: np.ndarray, z: np.ndarray, r: np.ndarray, zv: np.ndarray,
                rv: np.ndarray, model: MotionModel, *, gating: bool = True) -> ImmResult:
    """The two-model IMM over every packed row (module docstring).

    t (n, L) s; z (n, L, 2) positions, m; r (n, L) position variance per axis, m²; zv
    (n, L, 2) velocities (nan: none), m/s; rv (n, L) their variance per axis. The two
    models are one more array axis: state arrays are (n, 2 models, 2 axes)."""
    n, L = pk.shape
    q = np.array([model.q_low, model.q_high])[None, :, None]
    inv_tau = np.array([1.0 / model.sojourn_low_s, 1.0 / model.sojourn_high_s])[None, :]
    gate = model.gate if gating else np.inf
    mu_out = np.full((n, L), np.nan)
    acc = np.zeros((n, L), bool)
    vel = np.zeros((n, L), bool)
    restart = np.zeros((n, L), bool)
    if n == 0:
        return ImmResult(mu_out, acc, vel, restart)
    hv_all = np.isfinite(zv[..., 0])
    zv0 = np.where(hv_all[..., None], zv, 0.0)
    st = [np.repeat(x[:, None], 2, axis=1) for x in _init(z[:, 0], r[:, 0], zv[:, 0],
                                                          rv[:, 0])]
    mu = np.tile([1.0 - MU0_HIGH, MU0_HIGH], (n, 1))
    acc[:, 0] = True
    vel[:, 0] = hv_all[:, 0]
    restart[:, 0] = True
    mu_out[:, 0] = mu[:, 1]
    rej = np.zeros(n, np.int64)
    for j in range(1, L):
        m = int(pk.alive[j])
        h = (t[:m, j] - t[:m, j - 1])[:, None]
        # mixing (Markov switching over h): Pi[i, j]
        stay = np.exp(-h * inv_tau)  # (m, 2)
        mu_m = mu[:m]
        keep = mu_m * stay                     # i -> i
        move = mu_m * (1.0 - stay)             # i -> the other
        cj = keep + move[:, ::-1]              # predicted mode probabilities (m, 2)
        # w[:, i, j] = mu_i|j
        w = np.empty((m, 2, 2))
        w[:, 0, 0], w[:, 1, 1] = keep[:, 0], keep[:, 1]
        w[:, 1, 0], w[:, 0, 1] = move[:, 1], move[:, 0]
        w /= np.maximum(cj[:, None, :], 1e-300)
        p_, v_, a_, b_, c_ = (x[:m] for x in st)
        p0 = np.einsum("mij,mia->mja", w, p_)
        v0 = np.einsum("mij,mia->mja", w, v_)
        dp = p_[:, :, None] - p0[:, None]     # (m, i, j, axis)
        dv = v_[:, :, None] - v0[:, None]
        a0 = np.einsum("mij,mija->mja", w, a_[:, :, None] + dp * dp)
        b0 = np.einsum("mij,mija->mja", w, b_[:, :, None] + dp * dv)
        c0 = np.einsum("mij,mija->mja", w, c_[:, :, None] + dv * dv)
        pred = predict(p0, v0, a0, b0, c0, h[:, :, None], q)
        zj, rj = z[:m, j][:, None], r[:m, j][:, None, None]
        zvj, rvj = zv0[:m, j][:, None], rv[:m, j][:, None, None]
        hv = hv_all[:m, j]
        upd = update_position(*pred, zj, rj)
        ok = upd[5][:, 1] <= gate            # gate on the manoeuvre model (the wider one)
        upv = update_velocity(*upd[:5], zvj, rvj)
        okv = ok & hv & (upv[5][:, 1] <= gate)
        # log-likelihoods of the used parts, per model
        ll = -0.5 * (upd[5] + np.log(upd[6]).sum(axis=-1)) * ok[:, None]
        ll = ll - 0.5 * (upv[5] + np.log(upv[6]).sum(axis=-1)) * okv[:, None]
        new = _where(okv[:, None, None], upv[:5], upd[:5])
        new = _where(ok[:, None, None], new, pred)
        for x, y in zip(st, new, strict=True):
            x[:m] = y
        ll -= ll.max(axis=1, keepdims=True)
        post = cj * np.exp(ll)
        mu[:m] = post / post.sum(axis=1, keepdims=True)
        # consecutive rejections -> restart here
        rej[:m] = np.where(ok, 0, rej[:m] + 1)
        again = rej[:m] >= model.max_rejections
        if again.any():
            ia = np.flatnonzero(again)
            init = _init(z[ia, j], r[ia, j], zv[ia, j], rv[ia, j])
            for x, y in zip(st, init, strict=True):
                x[ia] = y[:, None]
            mu[ia] = (1.0 - MU0_HIGH, MU0_HIGH)
            rej[ia] = 0
            okv = np.where(again, hv, okv)
            ok = ok | again
            restart[ia, j] = True
        acc[:m, j] = ok
        vel[:m, j] = okv
        mu_out[:m, j] = mu[:m, 1]
    return ImmResult(mu_out, acc, vel, restart)


def reverse_rows(pk: Packed, *grids: np.ndarray) -> tuple[np.ndarray, ...]:
    """Each row of each (n, L, ...) grid in reverse order (column j <- len - 1 - j);
    applied twice it is the identity on the alive cells."""
    n, L = pk.shape
    cols = pk.lengths[:, None] - 1 - np.arange(L)[None, :]
    valid = cols >= 0
    rows = np.arange(n)[:, None]
    cols = np.where(valid, cols, np.arange(L)[None, :])
    return tuple(g[rows, cols] for g in grids)


def manoeuvre_probability(pk: Packed, t: np.ndarray, z: np.ndarray, r: np.ndarray,
                          zv: np.ndarray, rv: np.ndarray, model: MotionModel,
                          forward: np.ndarray | None = None) -> np.ndarray:
    """(n, L) probability that the target manoeuvred around each report: the larger of
    the forward IMM's (``forward`` when already run) and the backward (time-reversed)
    IMM's (module docstring). The rows hold accepted reports only (no gating here)."""
    if forward is None:
        forward = imm_forward(pk, t, z, r, zv, rv, model, gating=False).mu_high
    tr, zr, rr, zvr, rvr = reverse_rows(pk, t, z, r, zv, rv)
    back = imm_forward(pk, -tr, zr, rr, -zvr, rvr, model, gating=False).mu_high
    (back,) = reverse_rows(pk, back)
    return np.fmax(forward, back)


def lookahead_max(mu: np.ndarray, ahead: int) -> np.ndarray:
    """(n, L) max of each cell and the ``ahead`` next cells of its row (nan cells, the
    padding, ignored): the forward IMM's manoeuvre probability moved back to the reports
    before the filter noticed the manoeuvre, the cheap stand-in for the backward pass
    of :func:`manoeuvre_probability`."""
    out = mu.copy()
    for k in range(1, ahead + 1):
        out[:, :-k] = np.fmax(out[:, :-k], mu[:, k:])
    return out


def difference_variance(pk: Packed, t: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(n,) position noise variance per axis of each packed row from its reports alone,
    by the difference-based estimator of Gasser, Sroka & Jennen-Steinmetz (1986,
    *Biometrika* 73, 625–633): the pseudo-residual of report k against the straight line
    through its neighbours, e_k = (h2 z_{k-1} + h1 z_{k+1}) / (h1 + h2) − z_k
    (h1, h2 the gaps), has variance σ² (1 + a² + b²), a, b the two weights, when the
    target moves on a straight line at constant speed. The median of e_k² / (1 + a² +
    b²) over both axes, divided by the median of χ²₁ (0.4549), makes it robust to the
    reports in turns and to outliers. NaN for a row of fewer than 5 reports."""
    n, L = pk.shape
    out = np.full(n, np.nan)
    if L < 3:
        return out
    h1 = t[:, 1:-1] - t[:, :-2]
    h2 = t[:, 2:] - t[:, 1:-1]
    a, b = h2 / (h1 + h2), h1 / (h1 + h2)
    e = a[..., None] * z[:, :-2] + b[..., None] * z[:, 2:] - z[:, 1:-1]
    w = (e * e / (1.0 + a * a + b * b)[..., None]).reshape(n, -1)  # both axes
    ok = (pk.lengths >= 5)
    if ok.any():
        out[ok] = np.nanmedian(w[ok], axis=1) / 0.45493642311957283
    return out


# --- the RTS smoother ------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Smoothed:
    """Per packed cell: filtered (``*_f``) and smoothed (``*_s``) state per axis (n, L, 2)
    p, v and covariance a = P_pp, b = P_pv, c = P_vv; ``q`` (n, L): the PSD of the
    interval ending at that report (q[:, 0] = that of the first interval), m²/s³; the
    forward NIS of each position report (n, L) (nan at a segment start)."""

    t: np.ndarray
    pf: np.ndarray
    vf: np.ndarray
    af: np.ndarray
    bf: np.ndarray
    cf: np.ndarray
    ps: np.ndarray
    vs: np.ndarray
    as_: np.ndarray
    bs: np.ndarray
    cs: np.ndarray
    q: np.ndarray
    nis: np.ndarray


def rts_smooth(pk: Packed, t: np.ndarray, z: np.ndarray, r: np.ndarray, zv: np.ndarray,
               rv: np.ndarray, q: np.ndarray) -> Smoothed:
    """Kalman filter and RTS smoother of every packed row (one segment each, every
    report used; velocity where finite); ``q`` (n, L): PSD of the interval (j-1, j]."""
    n, L = pk.shape
    shape2 = (n, L, 2)
    pf, vf, af, bf, cf = (np.full(shape2, np.nan) for _ in range(5))
    pp, vp, ap, bp, cp = (np.full(shape2, np.nan) for _ in range(5))
    nis = np.full((n, L), np.nan)
    if n == 0:
        return Smoothed(t, pf, vf, af, bf, cf, pf, vf, af, bf, cf, q, nis)
    s = _init(z[:, 0], r[:, 0], zv[:, 0], rv[:, 0])
    pf[:, 0], vf[:, 0], af[:, 0], bf[:, 0], cf[:, 0] = s
    hv_all = np.isfinite(zv[..., 0])
    zv0 = np.where(hv_all[..., None], zv, 0.0)
    for j in range(1, L):
        m = int(pk.alive[j])
        h = (t[:m, j] - t[:m, j - 1])[:, None]
        s = predict(pf[:m, j - 1], vf[:m, j - 1], af[:m, j - 1], bf[:m, j - 1],
                    cf[:m, j - 1], h, q[:m, j][:, None])
        pp[:m, j], vp[:m, j], ap[:m, j], bp[:m, j], cp[:m, j] = s
        *s, nis[:m, j], _ = update_position(*s, z[:m, j], r[:m, j][:, None])
        hv = hv_all[:m, j]
        if hv.any():
            *sv, _, _ = update_velocity(*s, zv0[:m, j], rv[:m, j][:, None])
            s = sv if hv.all() else _where(hv[:, None], sv, s)
        pf[:m, j], vf[:m, j], af[:m, j], bf[:m, j], cf[:m, j] = s
    ps, vs, as_, bs, cs = (x.copy() for x in (pf, vf, af, bf, cf))
    for j in range(L - 2, -1, -1):
        m = int(pk.alive[j + 1])
        h = (t[:m, j + 1] - t[:m, j])[:, None]
        a, b, c = af[:m, j], bf[:m, j], cf[:m, j]
        # G = P_f F' P_p^-1, F = [[1, h], [0, 1]]
        m11, m12, m21, m22 = a + b * h, b, b + c * h, c
        A, B, C = ap[:m, j + 1], bp[:m, j + 1], cp[:m, j + 1]
        det = A * C - B * B
        g11 = (m11 * C - m12 * B) / det
        g12 = (m12 * A - m11 * B) / det
        g21 = (m21 * C - m22 * B) / det
        g22 = (m22 * A - m21 * B) / det
        dp, dv = ps[:m, j + 1] - pp[:m, j + 1], vs[:m, j + 1] - vp[:m, j + 1]
        ps[:m, j] = pf[:m, j] + g11 * dp + g12 * dv
        vs[:m, j] = vf[:m, j] + g21 * dp + g22 * dv
        d11, d12, d22 = as_[:m, j + 1] - A, bs[:m, j + 1] - B, cs[:m, j + 1] - C
        # P_s = P_f + G D G'
        as_[:m, j] = a + g11 * (g11 * d11 + g12 * d12) + g12 * (g11 * d12 + g12 * d22)
        bs[:m, j] = b + g11 * (g21 * d11 + g22 * d12) + g12 * (g21 * d12 + g22 * d22)
        cs[:m, j] = c + g21 * (g21 * d11 + g22 * d12) + g22 * (g21 * d12 + g22 * d22)
    return Smoothed(t, pf, vf, af, bf, cf, ps, vs, as_, bs, cs, q, nis)


def interpolate(sm: Smoothed, row: np.ndarray, col: np.ndarray, tq: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The smoothed state at query times ``tq`` (m,) s of packed rows ``row`` (m,),
    ``col`` (m,) = the last report at or before the query (-1: before the first report);
    exact for the model between reports (module docstring); outside a row's span,
    the first/last smoothed state moved on with the CV model (its covariance grows with
    q of the nearest interval). Returns p (m, 2), v (m, 2), P_pp (m, 2), P_vv (m, 2)."""
    L = sm.t.shape[1]
    n_of = (~np.isnan(sm.t)).sum(axis=1)
    last = n_of[row] - 1
    k = np.clip(col, 0, None)
    has_next = (col >= 0) & (col < last)
    k1 = np.minimum(k + 1, L - 1)
    tk = sm.t[row, k]
    tau = (tq - tk)[:, None]
    # outside / at the last report: move the smoothed state of the nearest report
    base_q = np.where(col < 0, sm.q[row, np.minimum(1, L - 1)], sm.q[row, k])
    base_q = np.nan_to_num(base_q, nan=float(np.nanmax(sm.q, initial=0.0)))[:, None]
    p, v = sm.ps[row, k], sm.vs[row, k]
    a, b, c = sm.as_[row, k], sm.bs[row, k], sm.cs[row, k]
    at = np.abs(tau)
    po = p + tau * v
    ao = a + 2.0 * tau * b + tau * tau * c + base_q * at**3 / 3.0
    co = c + base_q * at
    if not has_next.any():
        return po, v, ao, co
    # inside: the RTS formula at tau
    hq = np.flatnonzero(has_next)
    rr, kk, kn = row[hq], k[hq], k1[hq]
    h = (sm.t[rr, kn] - sm.t[rr, kk])[:, None]
    ta = tau[hq]
    qq = sm.q[rr, kn][:, None]
    af, bf, cf = sm.af[rr, kk], sm.bf[rr, kk], sm.cf[rr, kk]
    # P_p(tau) = F(tau) P_f F(tau)' + Q(tau)
    A1 = af + ta * (2.0 * bf + ta * cf) + qq * ta**3 / 3.0
    B1 = bf + ta * cf + 0.5 * qq * ta**2
    C1 = cf + qq * ta
    # P_p(h) (prediction of the next report)
    A2 = af + h * (2.0 * bf + h * cf) + qq * h**3 / 3.0
    B2 = bf + h * cf + 0.5 * qq * h**2
    C2 = cf + qq * h
    # cross-covariance M = P_p(tau) F(h - tau)'
    s_ = h - ta
    m11, m12, m21, m22 = A1 + B1 * s_, B1, B1 + C1 * s_, C1
    det = A2 * C2 - B2 * B2
    g11 = (m11 * C2 - m12 * B2) / det
    g12 = (m12 * A2 - m11 * B2) / det
    g21 = (m21 * C2 - m22 * B2) / det
    g22 = (m22 * A2 - m21 * B2) / det
    pfk, vfk = sm.pf[rr, kk], sm.vf[rr, kk]
    dp = sm.ps[rr, kn] - (pfk + h * vfk)
    dv = sm.vs[rr, kn] - vfk
    pi = pfk + ta * vfk + g11 * dp + g12 * dv
    vi = vfk + g21 * dp + g22 * dv
    d11, d12, d22 = sm.as_[rr, kn] - A2, sm.bs[rr, kn] - B2, sm.cs[rr, kn] - C2
    ai = A1 + g11 * (g11 * d11 + g12 * d12) + g12 * (g11 * d12 + g12 * d22)
    ci = C1 + g21 * (g21 * d11 + g22 * d12) + g22 * (g21 * d12 + g22 * d22)
    po[hq], ao[hq] = pi, ai
    vo = v.copy()
    vo[hq], co[hq] = vi, ci
    return po, vo, ao, co


# --- the 95 % radial error of a 2-D Gaussian ------------------------------------------------

_RATIOS = np.linspace(0.0, 1.0, 201)


def _radial_quantile_table(p: float) -> np.ndarray:
    """R_p / sigma_max of a 2-D Gaussian with sigmas (1, rho), rho on ``_RATIOS``:
    P(|e| <= R) = 1/(2 pi s1 s2) int_0^2pi (1 - exp(-R^2 u/2)) / u dtheta with
    u = cos^2/s1^2 + sin^2/s2^2 (the radial integral in closed form; midpoint rule on a
    quarter turn), solved by bisection for every rho at once; rho = 0 is the 1-D normal
    quantile."""
    th = (np.arange(2048) + 0.5) * (0.5 * np.pi / 2048)
    rho = np.maximum(_RATIOS, 1e-3)[:, None]
    u = np.cos(th) ** 2 + np.sin(th) ** 2 / rho**2
    lo, hi = np.zeros(_RATIOS.size), np.full(_RATIOS.size, 10.0)
    for _ in range(50):
        R = 0.5 * (lo + hi)
        P = np.mean((1.0 - np.exp(-(R * R)[:, None] * u / 2.0)) / u, axis=1) / rho[:, 0]
        lo, hi = np.where(p > P, R, lo), np.where(p > P, hi, R)
    out = 0.5 * (lo + hi)
    out[0] = float(normal_ppf(0.5 + p / 2.0))
    return out


_TABLE95 = _radial_quantile_table(0.95)


def radial_p95(var_a: np.ndarray, var_b: np.ndarray, cov_ab: np.ndarray | float = 0.0
               ) -> np.ndarray:
    """95th percentile of the horizontal error |e| of a zero-mean 2-D Gaussian with
    covariance [[var_a, cov_ab], [cov_ab, var_b]] (m² -> m): the eigen-sigmas, then the
    tabulated quantile of :func:`_radial_quantile_table` (interpolated in their
    ratio; 2.4477 sigma when isotropic, 1.96 sigma when one-dimensional)."""
    var_a, var_b = np.asarray(var_a, float), np.asarray(var_b, float)
    mean = 0.5 * (var_a + var_b)
    dif = np.sqrt((0.5 * (var_a - var_b)) ** 2 + np.asarray(cov_ab, float) ** 2)
    s1 = np.sqrt(np.maximum(mean + dif, 0.0))
    s2 = np.sqrt(np.maximum(mean - dif, 0.0))
    rho = np.where(s1 > 0, s2 / np.where(s1 > 0, s1, 1.0), 1.0)
    return s1 * np.interp(rho, _RATIOS, _TABLE95)
