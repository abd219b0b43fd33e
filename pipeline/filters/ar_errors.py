"""Vector autoregressive (VAR) models of coloured measurement errors (airfield paper).

The airfield paper models each surveillance channel's error as a vector autoregression
driven by standard white Gaussian noise,

.. math:: Y(k) = \\sum_{i=1}^{p} B_i Y(k-i) + \\Gamma N(k)        \\qquad \\text{(eq. 2)}

with Γ lower triangular and non-singular; it finds p = 2 adequate for position errors
(eq. 7) and p = 1 for velocity errors (eq. 8). This module simulates such models and
fits them to archived error series (sensor minus reference) by least squares and by
Yule–Walker, with the order chosen by the Bayesian information criterion.

**Order criterion: BIC** (Schwarz), ``BIC(p) = M ln det Σ̂_p + p d² ln M``, all orders
compared on the same M rows (those with ``max_order`` lags). BIC is consistent: with
the 10⁴–10⁵ samples of one calibration hour it picks the true order with probability
→ 1, whereas AIC's fixed penalty 2 p d² keeps a non-vanishing chance of over-fitting
(and an over-fitted order adds 2 × 2 error states per sensor to the Kalman filter for
nothing). The paper compared orders 1–3 for the same reason.

**White measurement noise (quantisation).** A recorded error is the AR process plus
white noise w of known covariance R (ASTERIX CAT010 carries positions with a 1 m LSB:
R = LSB²/12 per axis). Plain least squares then under-estimates |B| (errors in the
regressors). We use the bias-compensated estimator: with lag-0 blocks of XᵀX reduced by
M·R̄ (R̄ the mean of R over the rows),

.. math:: \\hat\\beta = (X^T X - M \\bar R_p)^{-1} X^T Y, \\qquad
          \\hat\\Sigma = \\hat\\Sigma_\\varepsilon - \\bar R - \\sum_i B_i \\bar R B_i^T

(Σ̂_ε the residual covariance, since ε(k) = Γ N(k) + w(k) − Σ B_i w(k−i)); the same
correction on γ(0) gives the compensated Yule–Walker estimate. Coefficient standard
errors come from the sandwich form of the estimating equation (robust to the MA
structure w adds to ε only to first order; the Monte Carlo coverage is in
docs/airfield.md). Confidence intervals of Γ come from a seeded parametric (Wishart)
bootstrap of Σ̂.

Shapes: an error series is ``(N, d)`` (d = 2: east, north, m or m/s); ``B`` is
``(p, d, d)``; ``Gamma`` ``(d, d)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

Z_95 = 1.959963984540054


@dataclass(frozen=True, eq=False)
class VarModel:
    """Y(k) = Σ_i B[i-1] Y(k-i) + Gamma N(k) (airfield paper eq. 2).

    ``B``: (p, d, d) coefficient matrices; ``Gamma``: (d, d) lower-triangular shaping
    matrix of the standard white noise N(k)."""

    B: np.ndarray
    Gamma: np.ndarray

    def __post_init__(self) -> None:
        B = np.asarray(self.B, float)
        G = np.asarray(self.Gamma, float)
        if B.ndim != 3 or B.shape[1] != B.shape[2] or G.shape != B.shape[1:]:
            raise ValueError(f"B must be (p, d, d) and Gamma (d, d); got {B.shape}, {G.shape}")
        object.__setattr__(self, "B", B)
        object.__setattr__(self, "Gamma", G)

    @property
    def order(self) -> int:
        return self.B.shape[0]

    @property
    def dim(self) -> int:
        return self.B.shape[1]

    @property
    def sigma(self) -> np.ndarray:
        """Innovation covariance Γ Γᵀ."""
        return self.Gamma @ self.Gamma.T


def companion(model: VarModel) -> tuple[np.ndarray, np.ndarray]:
    """(A, G): the Markov form of eq. 2 as in the paper's eq. 9, state
    [Y(k), Y(k-1), …, Y(k-p+1)] of size d·p: x(k+1) = A x(k) + G N(k)."""
    p, d = model.order, model.dim
    A = np.zeros((d * p, d * p))
    A[:d, :] = np.concatenate(list(model.B), axis=1)
    A[d:, :-d] = np.eye(d * (p - 1))
    G = np.zeros((d * p, d))
    G[:d] = model.Gamma
    return A, G


def is_stable(model: VarModel) -> bool:
    """True when every eigenvalue of the companion matrix lies inside the unit circle."""
    A, _ = companion(model)
    return bool(np.max(np.abs(np.linalg.eigvals(A))) < 1.0)


def stationary_covariance(model: VarModel) -> np.ndarray:
    """Covariance (d·p, d·p) of the stationary companion state (discrete Lyapunov
    equation P = A P Aᵀ + G Gᵀ); its top-left (d, d) block is Var Y."""
    if not is_stable(model):
        raise ValueError("VAR model is not stable: no stationary covariance")
    # scipy imported here, not at module level: the airfield config imports this module,
    # and a report command (which never solves a Lyapunov equation) should not pay ~0.3 s
    from scipy import linalg

    A, G = companion(model)
    P = linalg.solve_discrete_lyapunov(A, G @ G.T)
    return 0.5 * (P + P.T)


def simulate_var(
    model: VarModel, n_steps: int, n_series: int, rng: np.random.Generator
) -> np.ndarray:
    """``n_series`` independent stationary realisations, (n_series, n_steps, d).

    Loops over time steps (the recursion), vectorised over series. The first p values
    are drawn from the stationary distribution, so there is no transient."""
    p, d = model.order, model.dim
    A, _ = companion(model)
    L = np.linalg.cholesky(stationary_covariance(model) + 1e-12 * np.eye(d * p))
    x = rng.standard_normal((n_series, d * p)) @ L.T
    out = np.empty((n_series, n_steps, d))
    noise = rng.standard_normal((n_steps, n_series, d)) @ model.Gamma.T
    for k in range(n_steps):
        out[:, k] = x[:, :d]
        nxt = x @ A.T
        nxt[:, :d] += noise[k]
        x = nxt
    return out


# --- design matrices over gappy, segmented series ----------------------------------------


def lagged_rows(
    series: np.ndarray, segment: np.ndarray, step: np.ndarray, order: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows (targets, regressors, index) for an AR(``order``) regression.

    ``series`` (N, d) is sorted by (segment, step); ``segment`` (N,) labels independent
    series (one per sensor track); ``step`` (N,) is the integer epoch. A row exists at
    sample j when samples j-1 … j-order are in the same segment at steps exactly
    step[j]-1 … step[j]-order (gaps break the lags). Returns Y (M, d), X (M, d·order)
    = [Y(k-1), …, Y(k-order)] and the sample index (M,) of each row."""
    n = series.shape[0]
    ok = np.ones(n, bool)
    ok[:order] = False
    for lag in range(1, order + 1):
        prev = np.arange(n) - lag
        valid = prev >= 0
        same = np.zeros(n, bool)
        same[valid] = (segment[prev[valid]] == segment[valid]) & (
            step[prev[valid]] == step[valid] - lag
        )
        ok &= same
    idx = np.flatnonzero(ok)
    Y = series[idx]
    X = np.concatenate([series[idx - lag] for lag in range(1, order + 1)], axis=1)
    return Y, X, idx


def _mean_white(white_cov: np.ndarray | None, idx: np.ndarray, d: int) -> np.ndarray:
    if white_cov is None:
        return np.zeros((d, d))
    w = np.asarray(white_cov, float)
    return w if w.ndim == 2 else w[idx].mean(axis=0)


# --- fits ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class VarFit:
    """A fitted VAR model with its uncertainty.

    ``se_b``: standard errors of B (p, d, d); ``gamma_ci``: (2, d, d) lower/upper 95%
    bounds of Γ (bootstrap); ``n_rows``: regression rows; ``bic``: criterion value of
    this order on the comparison rows (nan when not compared); ``white_cov``: the R̄
    removed by the bias compensation."""

    model: VarModel
    se_b: np.ndarray
    gamma_ci: np.ndarray
    n_rows: int
    white_cov: np.ndarray
    bic: float = float("nan")
    bic_by_order: dict[int, float] = field(default_factory=dict)

    def b_ci(self, z: float = Z_95) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) bounds of B at ±z standard errors."""
        return self.model.B - z * self.se_b, self.model.B + z * self.se_b


def _cholesky_lower(S: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor; a non-positive-definite estimate (possible after the bias
    compensation on tiny samples) is projected onto the PD cone first."""
    S = 0.5 * (S + S.T)
    w, V = np.linalg.eigh(S)
    if w.min() <= 0:
        S = (V * np.maximum(w, 1e-12 * max(w.max(), 1e-12))) @ V.T
    return np.linalg.cholesky(S)


def _gamma_ci(
    Sigma_eps: np.ndarray, correction: np.ndarray, n: int, seed: int = 0, draws: int = 400
) -> np.ndarray:
    """95% interval of Γ = chol(Σ_ε − correction): Σ_ε is drawn from Wishart(n, Σ_ε/n)
    (the residual covariance is what the data estimate; the white-noise correction is
    known), each draw corrected and factorised."""
    from scipy import stats  # ~1 s of imports: only calibration needs it, not every command

    d = Sigma_eps.shape[0]
    df = max(n, d + 1)
    sims = stats.wishart(df=df, scale=Sigma_eps / df).rvs(size=draws, random_state=seed)
    sims = np.asarray(sims).reshape(draws, d, d) - correction[None]
    L = np.array([_cholesky_lower(s) for s in sims])  # small loop over bootstrap draws
    return np.quantile(L, [0.025, 0.975], axis=0)


def _ls_core(Y: np.ndarray, X: np.ndarray, Rbar: np.ndarray, order: int):
    """Bias-compensated LS: (beta (d·p, d), residuals, Sxx_c, Sigma_eps, Sigma)."""
    M, d = Y.shape
    Rp = np.kron(np.eye(order), Rbar)
    Sxx_c = X.T @ X - M * Rp
    beta = np.linalg.solve(Sxx_c, X.T @ Y)
    resid = Y - X @ beta
    Sigma_eps = resid.T @ resid / max(M - d * order, 1)
    B = beta.T.reshape(d, order, d).transpose(1, 0, 2)
    Sigma = Sigma_eps - Rbar - sum(B[i] @ Rbar @ B[i].T for i in range(order))
    return beta, resid, Sxx_c, Sigma_eps, 0.5 * (Sigma + Sigma.T)


def _sandwich_se(
    X: np.ndarray,
    resid: np.ndarray,
    beta: np.ndarray,
    Sxx_c: np.ndarray,
    Rbar: np.ndarray,
    order: int,
) -> np.ndarray:
    """Standard errors of beta (d·p, d) from the estimating equation
    Σ_k [x_k ε_kj + R̄_p β_j] = 0 (HC0 sandwich, one equation j per column)."""
    Rp = np.kron(np.eye(order), Rbar)
    Ainv = np.linalg.inv(Sxx_c)
    se = np.empty_like(beta)
    for j in range(beta.shape[1]):  # d equations (2): not a per-sample loop
        g = X * resid[:, j : j + 1] + (Rp @ beta[:, j])[None, :]
        meat = g.T @ g
        se[:, j] = np.sqrt(np.clip(np.diag(Ainv @ meat @ Ainv), 0.0, None))
    return se


def fit_var_ls(
    series: np.ndarray,
    segment: np.ndarray,
    step: np.ndarray,
    order: int,
    *,
    white_cov: np.ndarray | None = None,
    rows: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> VarFit:
    """Least-squares VAR(order) fit (airfield paper eq. 2, 7, 8), bias-compensated for
    white noise of covariance ``white_cov`` ((d, d) or per sample (N, d, d); None = 0).

    ``rows`` may pass precomputed :func:`lagged_rows` output (used for order selection
    on common rows)."""
    Y, X, idx = rows if rows is not None else lagged_rows(series, segment, step, order)
    d = series.shape[1]
    if Y.shape[0] < 10 * d * order:
        raise ValueError(f"too few rows ({Y.shape[0]}) to fit a VAR({order})")
    Rbar = _mean_white(white_cov, idx, d)
    beta, resid, Sxx_c, Sigma_eps, Sigma = _ls_core(Y, X, Rbar, order)
    se_beta = _sandwich_se(X, resid, beta, Sxx_c, Rbar, order)
    B = beta.T.reshape(d, order, d).transpose(1, 0, 2)
    se_b = se_beta.T.reshape(d, order, d).transpose(1, 0, 2)
    Gamma = _cholesky_lower(Sigma)
    return VarFit(
        model=VarModel(B, Gamma),
        se_b=se_b,
        gamma_ci=_gamma_ci(Sigma_eps, Sigma_eps - Sigma, Y.shape[0]),
        n_rows=int(Y.shape[0]),
        white_cov=Rbar,
    )


def fit_var_yule_walker(
    series: np.ndarray, segment: np.ndarray, order: int, *, white_cov: np.ndarray | None = None
) -> VarModel:
    """Yule–Walker VAR(order) estimate from autocovariances pooled over segments
    (each segment a gap-free series at consecutive epochs), γ(0) bias-compensated.

    Solves Σ_i B_i γ(h - i) = γ(h), h = 1..p, with γ(-h) = γ(h)ᵀ; Σ = γ(0) - Σ B_i γ(i)ᵀ.
    """
    d = series.shape[1]
    seg = np.asarray(segment)
    gam = np.zeros((order + 1, d, d))
    n_total = 0
    breaks = np.flatnonzero(np.diff(seg)) + 1
    for part in np.split(series, breaks):  # one pass per segment (a track), not per sample
        n = part.shape[0]
        n_total += n
        for h in range(order + 1):
            if n > h:
                gam[h] += part[h:].T @ part[: n - h]
    gam /= n_total
    if white_cov is not None:
        W = np.asarray(white_cov, float)
        gam[0] -= W if W.ndim == 2 else W.mean(axis=0)

    def g(h: int) -> np.ndarray:
        return gam[h] if h >= 0 else gam[-h].T

    # B_stack (d, d·p) @ Toeplitz (d·p, d·p) = [γ(1) … γ(p)]
    T = np.block([[g(j - i) for j in range(order)] for i in range(order)])
    rhs = np.concatenate([g(h) for h in range(1, order + 1)], axis=1)
    Bstack = np.linalg.solve(T.T, rhs.T).T
    B = Bstack.reshape(d, order, d).transpose(1, 0, 2)
    Sigma = gam[0] - sum(B[i] @ g(i + 1).T for i in range(order))
    return VarModel(B, _cholesky_lower(Sigma))


def select_order(
    series: np.ndarray,
    segment: np.ndarray,
    step: np.ndarray,
    *,
    max_order: int = 4,
    white_cov: np.ndarray | None = None,
) -> VarFit:
    """Fit orders 1..max_order, pick the BIC minimiser (compared on the common rows that
    have ``max_order`` lags), and refit that order on every row it can use."""
    d = series.shape[1]
    Y, Xmax, idx = lagged_rows(series, segment, step, max_order)
    M = Y.shape[0]
    if 10 * d * max_order > M:
        raise ValueError(f"too few rows ({M}) to compare orders up to {max_order}")
    Rbar = _mean_white(white_cov, idx, d)
    bic = {}
    for p in range(1, max_order + 1):
        *_, Sigma = _ls_core(Y, Xmax[:, : d * p], Rbar, p)
        sign, logdet = np.linalg.slogdet(Sigma)
        bic[p] = M * logdet + p * d * d * np.log(M) if sign > 0 else np.inf
    best = min(bic, key=bic.get)
    fit = fit_var_ls(series, segment, step, best, white_cov=white_cov)
    return VarFit(
        fit.model,
        fit.se_b,
        fit.gamma_ci,
        fit.n_rows,
        fit.white_cov,
        bic=float(bic[best]),
        bic_by_order={k: float(v) for k, v in bic.items()},
    )
