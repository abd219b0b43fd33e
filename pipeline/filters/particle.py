"""Bootstrap particle filter kernels with exogenous constraints.

Distributed maritime observation paper (rough Russian OCR in ``seeds/``), eq. 3-7, and
the Smith-Gelfand weighted bootstrap it rests on. With ``N`` samples x*(i) of the
prior p(x_k | D_{k-1}) (the prediction, eq. 3 pushed through the transition), the
posterior of eq. 4,

.. math:: p(x_k | D_k) = \\frac{p(y_k | x_k)\\, p(x_k | D_{k-1})\\, u_k(x_k)}{p(y_k | D_{k-1})}

is represented by the same samples with the weights of eq. 7

.. math:: q_i = \\frac{p(y_k | x_k^*(i))\\, u_k(x_k^*(i))}
              {\\sum_j p(y_k | x_k^*(j))\\, u_k(x_k^*(j))}

where u_k is the exogenous density: uniform over an admissible polygon (water, fairway)
and zero outside, so a particle outside gets weight 0 (log-weight ``-inf``). Resampling
N times from {x*(i), q_i} gives an equally weighted sample of the posterior. When the
weights degenerate (the likelihood or the admissible area is narrow against the prior)
the paper's remedy is "to increase the number of points emulated from the prior": see
:func:`replenish`.

Everything is vectorised over a batch of independent filters: particles are
``(G, N, d)`` arrays (G filters, e.g. one per data gap, N particles, d state
components) and log-weights ``(G, N)``. Weights are kept as natural logarithms and
normalised with ``logsumexp``. Randomness comes only from the ``rng`` argument.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

try:  # the transition's arithmetic in one pass (optional: built when a C compiler is present)
    from pipeline.filters import _particle
except ImportError:  # pragma: no cover - the same numbers, ~1.6x slower
    _particle = None

Propagate = Callable[[np.ndarray, np.ndarray, np.random.Generator], np.ndarray]
"""``(particles (g, M, d), rows (g,), rng) -> propagated (g, M, d)``: a draw from the
prior; ``rows`` are the filters' indices in the caller's batch (for per-filter dt)."""

# state columns of the ship motion model (regional ENU plane)
X, Y, SPEED, COURSE = range(4)


# --- weights ---------------------------------------------------------------------


def logsumexp(a: np.ndarray, axis: int = -1) -> np.ndarray:
    """log sum exp along ``axis``, stable (max subtracted); ``-inf`` for all-``-inf``
    rows. (Same as ``scipy.special.logsumexp``, without its per-call overhead.)"""
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        return np.log(np.sum(np.exp(a - m), axis=axis)) + np.squeeze(m, axis=axis)


def log_normalise(logw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalise log-weights along the last axis (eq. 7 denominator, in logs).

    Returns ``(logw - log_total, log_total)``. A row whose weights are all zero (all
    ``-inf``) has ``log_total = -inf`` and is returned unchanged.
    """
    total = logsumexp(logw, axis=-1)
    finite = np.isfinite(total)
    out = np.where(finite[..., None], logw - np.where(finite, total, 0.0)[..., None], logw)
    return out, total


def normalised_weights(logw: np.ndarray) -> np.ndarray:
    """Linear weights q_i summing to 1 per row (eq. 7); all zero for a degenerate row."""
    lw, total = log_normalise(logw)
    return np.where(np.isfinite(total)[..., None], np.exp(lw), 0.0)


def effective_sample_size(logw: np.ndarray) -> np.ndarray:
    """Kish's effective sample size 1 / sum q_i^2 per row; 0 for a degenerate row."""
    w = normalised_weights(logw)
    s2 = np.sum(w * w, axis=-1)
    return np.where(s2 > 0.0, 1.0 / np.where(s2 > 0.0, s2, 1.0), 0.0)


def apply_constraint(logw: np.ndarray, admissible: np.ndarray) -> np.ndarray:
    """Multiply by the exogenous density u_k (eq. 4, 7): uniform inside the admissible
    area (a constant that cancels in eq. 7), zero outside: log-weight ``-inf``."""
    return np.where(admissible, logw, -np.inf)


def gaussian_log_likelihood(residual: np.ndarray, R: np.ndarray) -> np.ndarray:
    """log N(r; 0, R) of residuals ``r = y - h(x)`` (eq. 6 with additive Gaussian noise).

    ``residual``: (..., N, m); ``R``: (..., m, m), one covariance per filter, broadcast
    over its N particles. Returns (..., N).

    .. math:: \\log p(y|x) = -\\tfrac12 r^T R^{-1} r - \\tfrac12 \\log\\det(2\\pi R)
    """
    m = residual.shape[-1]
    L = np.linalg.cholesky(R)  # R = L L^T
    # z = L^-1 r by forward substitution, one component at a time over all particles
    # (m is 2-4: a batched np.linalg.solve of N tiny systems per filter was 20x slower);
    # r^T R^-1 r = |z|^2
    z = np.empty(np.broadcast_shapes(residual.shape, (*L.shape[:-2], 1, m)))
    for i in range(m):
        acc = np.broadcast_to(residual[..., i], z.shape[:-1]).copy()
        for j in range(i):
            acc -= L[..., i, j][..., None] * z[..., j]
        z[..., i] = acc / L[..., i, i][..., None]
    logdet = 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
    return -0.5 * np.sum(z * z, axis=-1) - 0.5 * (logdet[..., None] + m * np.log(2.0 * np.pi))


# --- resampling ------------------------------------------------------------------


def systematic_resample(
    logw: np.ndarray, rng: np.random.Generator, n: int | None = None
) -> np.ndarray:
    """Indices of ``n`` (default: the row length M) draws per row from {i, q_i} by
    systematic resampling: one uniform offset u per row, positions (u + j) / n,
    j = 0..n-1; returns ``(G, n)`` ints into each row.

    Vectorised over rows by offsetting each row's cumulative weights by its row number,
    so one ``searchsorted`` serves the whole batch. Degenerate rows (all weights zero)
    get indices 0..n-1 (mod M): they keep their particles.
    """
    G, M = logw.shape
    n = M if n is None else n
    w = normalised_weights(logw)
    cum = np.cumsum(w, axis=1)
    ok = cum[:, -1] > 0.0
    cum = cum / np.where(ok, cum[:, -1], 1.0)[:, None]
    cum[:, -1] = 1.0  # guard against round-off below 1
    rows = np.arange(G, dtype=float)[:, None]
    positions = (rng.random((G, 1)) + np.arange(n)) / n
    idx = np.searchsorted((cum + rows).ravel(), (positions + rows).ravel(), side="right")
    idx = np.clip(idx.reshape(G, n) - np.arange(G)[:, None] * M, 0, M - 1)
    return np.where(ok[:, None], idx, np.arange(n) % M)


def resample(
    particles: np.ndarray,
    logw: np.ndarray,
    rng: np.random.Generator,
    *,
    ess_fraction: float = 0.5,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resample the rows whose effective sample size is below ``ess_fraction * N``.

    Returns (particles, log-weights, resampled (G,) bool). Resampled rows get equal
    weights ``-log N``; the others keep theirs.
    """
    N = particles.shape[1]
    todo = effective_sample_size(logw) < ess_fraction * N
    if not np.any(todo):
        return particles, logw, todo
    idx = systematic_resample(logw[todo], rng)
    particles = particles.copy()
    logw = logw.copy()
    particles[todo] = np.take_along_axis(particles[todo], idx[..., None], axis=1)
    logw[todo] = -np.log(N)
    return particles, logw, todo


def regularise(
    particles: np.ndarray,
    rng: np.random.Generator,
    *,
    columns: tuple[int, ...],
    scale: float = 1.0,
) -> np.ndarray:
    """Regularised PF jitter (Musso, Oudjane, Le Gland 2001): after resampling, move each
    particle by a Gaussian kernel draw ``h L e`` in the chosen state ``columns``, with
    L L^T the empirical covariance of those columns per row and the Gaussian-optimal
    bandwidth h = (4 / (N (d + 2)))^(1 / (d + 4)), times ``scale``.
    Restores diversity lost by duplicating particles; rows are independent.
    """
    cols = list(columns)
    sub = particles[..., cols]
    G, N, d = sub.shape
    centred = sub - sub.mean(axis=1, keepdims=True)
    cov = np.einsum("gni,gnj->gij", centred, centred) / max(N - 1, 1)
    cov += 1e-9 * np.eye(d)  # a collapsed row still has a factorisable covariance
    L = np.linalg.cholesky(cov)
    h = scale * (4.0 / (N * (d + 2))) ** (1.0 / (d + 4))
    jitter = h * np.einsum("gij,gnj->gni", L, rng.standard_normal((G, N, d)))
    out = particles.copy()
    out[..., cols] = sub + jitter
    return out


# --- one filter step, and more particles from the prior on degeneracy ----------------

Admissible = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""``(particles (g, M, d), rows (g,)) -> (g, M) bool``: inside the admissible area
(u_k > 0); ``rows`` are the filters' indices in the caller's batch."""
LogLikelihood = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""``(particles (g, M, d), rows (g,) indices into the batch) -> log p(y_k | x) (g, M)``."""


@dataclass(frozen=True)
class StepResult:
    """One bootstrap step for a batch of G filters.

    - ``particles`` (G, N, d), ``logw`` (G, N): the posterior sample (normalised logs);
    - ``ess`` (G,): effective sample size after weighting (eq. 7), before resampling and
      before any replenishment;
    - ``admissible_mass`` (G,): share of the prior mass inside the admissible area;
    - ``rounds`` (G,): rounds of extra prior draws (0: the weights were healthy);
    - ``infeasible`` (G,): no admissible particle at all even after replenishment: the
      constraint was dropped for that filter at this step (weights = likelihood only);
    - ``resampled`` (G,): the row was resampled;
    - ``weighted``, ``weighted_logw``: the weighted sample {x*(i), q_i} of eq. 7 before
      resampling (the same posterior, without the duplicates resampling makes: what
      summaries and density estimates should use).
    """

    particles: np.ndarray
    logw: np.ndarray
    ess: np.ndarray
    admissible_mass: np.ndarray
    rounds: np.ndarray
    infeasible: np.ndarray
    resampled: np.ndarray
    weighted: np.ndarray
    weighted_logw: np.ndarray


def _log_weight(
    x: np.ndarray, rows: np.ndarray, loglik: LogLikelihood | None, admissible: Admissible | None
) -> np.ndarray:
    lw = np.zeros(x.shape[:2]) if loglik is None else loglik(x, rows)
    return lw if admissible is None else apply_constraint(lw, admissible(x, rows))


def bootstrap_step(
    particles: np.ndarray,
    logw: np.ndarray,
    rng: np.random.Generator,
    *,
    propagate: Propagate,
    loglik: LogLikelihood | None = None,
    admissible: Admissible | None = None,
    replenish_with: tuple[Propagate, ...] = (),
    max_rounds: int = 4,
    min_ess: float = 1.0,
    ess_fraction: float = 0.5,
    jitter: Propagate | None = None,
    regularise_below: float = 0.0,
    redraw: tuple[Propagate, ...] = (),
) -> StepResult:
    """Predict (eq. 3), weight by likelihood x exogenous density (eq. 6-7), replenish
    degenerate filters from the prior, resample (Smith-Gelfand) when ESS < ess_fraction N.

    ``replenish_with``: the prior draws tried, in order, for filters whose ESS after
    weighting is below ``min_ess`` (e.g. the same transition, then a wider "manoeuvre"
    one), each for up to ``max_rounds`` rounds of N extra particles (:func:`replenish`).
    ``jitter`` (e.g. :func:`regularise`) is applied after resampling to the filters whose
    ESS was below ``regularise_below * N``: the regularised PF, on degeneracy only.
    ``redraw``: transitions tried in turn, per particle, for particles predicted outside
    the admissible area (:func:`redraw_outside`), before the weights are computed.
    """
    G, N, _ = particles.shape
    rows = np.arange(G)
    prior_logw, _ = log_normalise(logw)
    x = propagate(particles, rows, rng)
    inside = np.ones((G, N), bool) if admissible is None else admissible(x, rows)
    if redraw and admissible is not None and not inside.all():
        x, inside = redraw_outside(particles, x, inside, rng, redraw=redraw, admissible=admissible)
    # 1 - the mass outside, not the sum of the mass inside: exactly 1 when no particle is
    # outside (the weights' float sum may be 1 - 1e-16, a constraint then "active"), 0
    # when all are (the sum may be 1 + 1e-16) and for a degenerate filter (no weight)
    q = normalised_weights(prior_logw)
    outside = np.sum(np.where(inside, 0.0, q), axis=1)
    admissible_mass = np.where(q.any(axis=1), np.maximum(1.0 - outside, 0.0), 0.0)
    lik = np.zeros((G, N)) if loglik is None else loglik(x, rows)
    lw = prior_logw + apply_constraint(lik, inside)
    ess = effective_sample_size(lw)
    rounds = np.zeros(G, dtype=np.int64)
    bad = ess < min_ess
    for prop in replenish_with:
        if not np.any(bad):
            break
        r = replenish(
            particles[bad],
            prior_logw[bad],
            x[bad],
            lw[bad],
            rows[bad],
            rng,
            propagate=prop,
            log_weight=lambda z, rr: _log_weight(z, rr, loglik, admissible),
            min_ess=min_ess,
            max_rounds=max_rounds,
        )
        x[bad], lw[bad] = r.particles, r.logw
        rounds[bad] += r.rounds
        still = np.zeros(G, bool)
        still[bad] = r.degenerate
        bad = still
    infeasible = ~np.isfinite(logsumexp(lw, axis=1))
    if np.any(infeasible):  # nothing admissible: keep the prediction, drop u_k here
        lw[infeasible] = prior_logw[infeasible] + lik[infeasible]
    lw, _ = log_normalise(lw)
    x_w, lw_w = x, lw
    x, lw, resampled = resample(x, lw, rng, ess_fraction=ess_fraction)
    rough = resampled & (ess < regularise_below * N)
    if jitter is not None and np.any(rough):
        x = x.copy() if x is x_w else x
        x[rough] = _jitter_inside(x[rough], rows[rough], rng, jitter, admissible)
    return StepResult(x, lw, ess, admissible_mass, rounds, infeasible, resampled, x_w, lw_w)


def _jitter_inside(
    x: np.ndarray,
    rows: np.ndarray,
    rng: np.random.Generator,
    jitter: Propagate,
    admissible: Admissible | None,
) -> np.ndarray:
    """Regularise resampled particles; a particle the jitter moved out of the admissible
    area stays where it was (the kernel is truncated to u_k > 0)."""
    moved = jitter(x, rows, rng)
    if admissible is None:
        return moved
    ok = admissible(moved, rows) | ~admissible(x, rows)
    return np.where(ok[..., None], moved, x)


def redraw_outside(
    particles: np.ndarray,
    x: np.ndarray,
    inside: np.ndarray,
    rng: np.random.Generator,
    *,
    redraw: tuple[Propagate, ...],
    admissible: Admissible,
) -> tuple[np.ndarray, np.ndarray]:
    """Per particle, "more points from the prior": a particle whose prediction ``x``
    left the admissible area is predicted again from its own previous state
    (``particles``), with each transition of ``redraw`` in turn, until it lands inside.

    This samples the transition truncated to the admissible area,
    p(x_k | x_{k-1}, x_k in U) (a ship steers to stay in water), instead of weighting
    the untruncated prediction by u_k: each ancestor keeps its weight unless every try
    fails (then u_k = 0 still removes it). The selected particles are flattened to a
    (M, 1, d) batch whose ``rows`` are their filters' indices. Returns (x, inside).
    """
    x, inside = x.copy(), inside.copy()
    for prop in redraw:
        g, n = np.nonzero(~inside)
        if g.size == 0:
            break
        again = prop(particles[g, n][:, None, :], g, rng)
        ok = admissible(again, g)[:, 0]
        x[g[ok], n[ok]] = again[ok, 0]
        inside[g[ok], n[ok]] = True
    return x, inside


@dataclass(frozen=True)
class Replenished:
    """Result of :func:`replenish` for the g rows it worked on: particles (g, N, d),
    normalised log-weights (g, N), rounds of extra draws, and whether a row is still
    degenerate (no particle with non-zero weight: returned as given)."""

    particles: np.ndarray
    logw: np.ndarray
    rounds: np.ndarray
    degenerate: np.ndarray


def replenish(
    prior_particles: np.ndarray,
    prior_logw: np.ndarray,
    propagated: np.ndarray,
    logw: np.ndarray,
    rows: np.ndarray,
    rng: np.random.Generator,
    *,
    propagate: Propagate,
    log_weight: Callable[[np.ndarray, np.ndarray], np.ndarray],
    min_ess: float,
    max_rounds: int,
) -> Replenished:
    """The paper's remedy for degenerate weights: draw more points from the prior.

    For filters whose effective sample size after weighting is below ``min_ess``, draw
    another N samples from the prior (resample the previous posterior
    ``prior_particles, prior_logw`` and ``propagate`` them: a draw from
    p(x_k | D_{k-1})), weight them with ``log_weight`` (log-likelihood + log u_k,
    eq. 7) and pool them with the ones already drawn, up to ``max_rounds`` times. Every
    sub-sample of the pool is an importance sample of the same prior (the first with
    the prior's weights ``logw = log q_prior + log p(y|x) + log u``, the extra ones
    equally weighted, ``-log N + ...``), so the pool's normalised weights are again
    eq. 7 over M = N (1 + rounds) points. The pool is resampled back to N.

    Arrays are the batch rows being worked on: ``prior_particles`` (g, N, d),
    normalised ``prior_logw`` (g, N), ``propagated`` (g, N, d), ``logw`` (g, N);
    ``rows`` (g,) are their indices in the caller's batch (passed to ``log_weight``).
    """
    g, N, _ = propagated.shape
    pool_x, pool_w = [propagated], [logw]
    rounds = np.zeros(g, dtype=np.int64)
    active = effective_sample_size(logw) < min_ess
    for _ in range(max_rounds):
        if not np.any(active):
            break
        idx = systematic_resample(prior_logw[active], rng)
        start = np.take_along_axis(prior_particles[active], idx[..., None], axis=1)
        extra_x = propagate(start, rows[active], rng)
        full_x = propagated.copy()
        full_w = np.full((g, N), -np.inf)
        full_x[active] = extra_x
        full_w[active] = log_weight(extra_x, rows[active]) - np.log(N)
        pool_x.append(full_x)
        pool_w.append(full_w)
        rounds[active] += 1
        active &= effective_sample_size(np.concatenate(pool_w, axis=1)) < min_ess
    big_w = np.concatenate(pool_w, axis=1)
    degenerate = ~np.isfinite(logsumexp(big_w, axis=1))
    idx = systematic_resample(big_w, rng, N)
    out_x = np.take_along_axis(np.concatenate(pool_x, axis=1), idx[..., None], axis=1)
    out_x = np.where(degenerate[:, None, None], propagated, out_x)
    out_w = np.where(degenerate[:, None], logw, -np.log(N))
    return Replenished(out_x, out_w, rounds, degenerate)


# --- ship motion model (the transition f_k of eq. 3) ------------------------------


@dataclass(frozen=True)
class MotionNoise:
    """Process noise of :func:`propagate_speed_course`.

    - ``course_rad_per_sqrt_s``, ``speed_mps_per_sqrt_s``: course and speed random walks
      (rad/sqrt(s), (m/s)/sqrt(s));
    - ``turn_rate_per_s``, ``turn_sigma_rad``: course jumps (a ship following a route
      turns at its waypoints): a Poisson stream of rate lambda per particle, each jump
      N(0, turn_sigma^2);
    - speeds are kept in [0, ``max_speed_mps``].
    """

    course_rad_per_sqrt_s: float
    speed_mps_per_sqrt_s: float
    max_speed_mps: float = 25.0
    turn_rate_per_s: float = 0.0
    turn_sigma_rad: float = 0.0


def propagate_speed_course(
    particles: np.ndarray,
    dt_s: np.ndarray | float,
    noise: MotionNoise,
    rng: np.random.Generator,
) -> np.ndarray:
    r"""One transition x_k = f(x_{k-1}, w_{k-1}) (eq. 3) of a ship that keeps speed and
    course up to random walks and occasional turns: state (x_m, y_m, speed_mps,
    course_rad), ENU, course clockwise from north.

    .. math::
        c^+ = c_{k-1} + J \sigma_J \varepsilon_J,\quad
        J \sim \mathrm{Bernoulli}(1 - e^{-\lambda \Delta t}),
        \quad c_k = c^+ + \sigma_c \sqrt{\Delta t}\, \varepsilon_c,
        \quad v_k = |v_{k-1} + \sigma_v \sqrt{\Delta t}\, \varepsilon_v|,

        (x, y)_k = (x, y)_{k-1} + \tfrac{v_{k-1} + v_k}{2} \Delta t\,
            (\sin \bar c, \cos \bar c),\quad \bar c = \tfrac{c^+ + c_k}{2}

    ``particles``: (G, N, 4); ``dt_s``: scalar or (G,) per filter (0 leaves a row
    unchanged). Returns a new array.
    """
    G, N, _ = particles.shape
    dt = np.broadcast_to(np.asarray(dt_s, float), (G,))[:, None]
    e = rng.standard_normal((G, N, 2))
    c0 = particles[..., COURSE]
    if noise.turn_rate_per_s > 0.0:
        p_turn = -np.expm1(-noise.turn_rate_per_s * np.maximum(dt, 0.0))
        turn = rng.random((G, N)) < p_turn
        c0 = c0.copy()  # a jump drawn for the turning particles only (a few per cent)
        c0[turn] += noise.turn_sigma_rad * rng.standard_normal(np.count_nonzero(turn))
    if _particle is not None and G * N:
        out = np.empty((G, N, 4))
        _particle.propagate_speed_course(
            G, N, np.ascontiguousarray(particles, float), np.ascontiguousarray(c0, float), e,
            np.ascontiguousarray(dt[:, 0], float), out, float(noise.course_rad_per_sqrt_s),
            float(noise.speed_mps_per_sqrt_s), float(noise.max_speed_mps),
        )
        return out
    return _transition(particles, c0, e, dt, noise)


def _transition(
    particles: np.ndarray, c0: np.ndarray, e: np.ndarray, dt: np.ndarray, noise: MotionNoise
) -> np.ndarray:
    """The arithmetic of :func:`propagate_speed_course` given its draws (the reference of
    ``_particle.c``, which computes the same numbers in one pass)."""
    sq = np.sqrt(np.maximum(dt, 0.0))
    v0 = particles[..., SPEED]
    c1 = c0 + noise.course_rad_per_sqrt_s * sq * e[..., 0]
    v1 = np.minimum(np.abs(v0 + noise.speed_mps_per_sqrt_s * sq * e[..., 1]), noise.max_speed_mps)
    cm, vm = 0.5 * (c0 + c1), 0.5 * (v0 + v1)
    out = np.empty_like(particles)
    out[..., X] = particles[..., X] + vm * dt * np.sin(cm)
    out[..., Y] = particles[..., Y] + vm * dt * np.cos(cm)
    out[..., SPEED] = v1
    out[..., COURSE] = c1 - 2.0 * np.pi * np.floor(c1 / (2.0 * np.pi))  # np.mod, faster
    return out


def weighted_mean_cov(values: np.ndarray, logw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean (G, m) and covariance (G, m, m) of ``values`` (G, N, m)."""
    w = normalised_weights(logw)
    mean = np.einsum("gn,gnm->gm", w, values)
    d = values - mean[:, None, :]
    cov = np.einsum("gn,gni,gnj->gij", w, d, d)
    return mean, cov
