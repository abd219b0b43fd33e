"""Pure, vectorised linear Kalman filter steps on stacks of independent filters.

Every function works on ``n`` filters at once (vessels, Monte Carlo runs): states
``x: (n, d)``, covariances ``P: (n, d, d)``; model matrices may be shared ``(d, d)`` or
per filter ``(n, d, d)``. Nothing is mutated; each step returns new arrays. Names follow
the textbook (FilterPy, Stone Soup): x P F Q H R S K, innovation ``y``.

Discrete model, step k-1 -> k:

.. math::
    x_k = F x_{k-1} + \\Gamma u_{k-1} + w_{k-1}, \\qquad w \\sim N(0, Q)

    z_k = H x_k + U_k + v_k, \\qquad v \\sim N(0, R), \\qquad E[w_{k-1} v_k^T] = M

``M`` is the cross-covariance of the process noise that drove the state to step k and
the measurement noise at step k: the "correlated noise" case of the gyro/GNSS/log
paper (eq. 2, the term D(t)W(t)); ``U`` is a known (deterministic) measurement term
(the paper's U_y). With ``M = 0`` and ``U = 0`` this is the plain Kalman filter.

The update with correlated noise (D. Simon, *Optimal State Estimation*, 2006, §7.1):

.. math::
    S = H P^- H^T + H M + M^T H^T + R

    K = (P^- H^T + M) S^{-1}

    x^+ = x^- + K (z - H x^- - U), \\qquad P^+ = P^- - K S K^T

:func:`discretize` turns a continuous model ``dx/dt = A x + B u + G xi`` (white ``xi``
of unit intensity) into ``F, Gamma, Q`` for a step ``dt`` with Van Loan's method
(C. F. Van Loan, *Computing integrals involving the matrix exponential*, IEEE TAC 1978),
on batches of matrices.
"""

from __future__ import annotations

import numpy as np


def _bmat(M: np.ndarray, n: int) -> np.ndarray:
    """Broadcast a ``(d, e)`` or ``(n, d, e)`` matrix to ``(n, d, e)`` (no copy)."""
    M = np.asarray(M, float)
    return np.broadcast_to(M, (n, *M.shape[-2:])) if M.ndim == 2 else M


def _tr(M: np.ndarray) -> np.ndarray:
    return np.swapaxes(M, -1, -2)


def predict(
    x: np.ndarray,
    P: np.ndarray,
    F: np.ndarray,
    Q: np.ndarray,
    Gamma_u: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Time update of ``n`` filters.

    x: (n, d); P: (n, d, d); F, Q: (d, d) or (n, d, d); Gamma_u: (n, d) known input
    already multiplied by its input matrix, or None.
    Returns ``(x^-, P^-)``: x = F x + Gamma u, P = F P F' + Q.
    """
    n = x.shape[0]
    F = _bmat(F, n)
    x_new = np.einsum("nij,nj->ni", F, x)  # x = F x
    if Gamma_u is not None:
        x_new = x_new + Gamma_u  # + Gamma u
    P_new = F @ P @ _tr(F) + _bmat(Q, n)  # P = F P F' + Q
    return x_new, 0.5 * (P_new + _tr(P_new))


def innovation(
    x: np.ndarray,
    P: np.ndarray,
    z: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    M: np.ndarray | None = None,
    U: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Innovation ``y = z - H x - U`` (n, m) and its covariance ``S`` (n, m, m).

    z: (n, m); H: (m, d) or (n, m, d); R: (m, m) or (n, m, m); M: (d, m) or (n, d, m)
    cross-covariance E[w_{k-1} v_k'] or None; U: (n, m) known term or None.
    """
    n = x.shape[0]
    H = _bmat(H, n)
    y = z - np.einsum("nij,nj->ni", H, x)  # y = z - H x
    if U is not None:
        y = y - U  # - U
    S = H @ P @ _tr(H) + _bmat(R, n)  # S = H P H' + R
    if M is not None:
        HM = H @ _bmat(M, n)
        S = S + HM + _tr(HM)  # + H M + M' H'
    return y, 0.5 * (S + _tr(S))


def update(
    x: np.ndarray,
    P: np.ndarray,
    z: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    M: np.ndarray | None = None,
    U: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Measurement update of ``n`` filters, with correlated process/measurement noise.

    Shapes as in :func:`innovation`. Returns ``(x^+, P^+, y, S)``.
    K = (P H' + M) S^-1; x = x + K y; P = P - K S K' computed in Joseph form.
    """
    n = x.shape[0]
    Hn = _bmat(H, n)
    y, S = innovation(x, P, z, Hn, R, M, U)
    PHt = P @ _tr(Hn)
    if M is not None:
        PHt = PHt + _bmat(M, n)  # P H' + M
    K = _tr(np.linalg.solve(S, _tr(PHt)))  # K = (P H' + M) S^-1 (S symmetric)
    x_new = x + np.einsum("nij,nj->ni", K, y)  # x = x + K y
    # Joseph form, kept symmetric positive semi-definite by construction:
    # P = (I-KH) P (I-KH)' + K R K' - (I-KH) M K' - K M' (I-KH)'  (= P - K S K')
    IKH = np.eye(x.shape[1]) - K @ Hn
    P_new = IKH @ P @ _tr(IKH) + K @ _bmat(R, n) @ _tr(K)
    if M is not None:
        cross = IKH @ _bmat(M, n) @ _tr(K)
        P_new = P_new - cross - _tr(cross)
    return x_new, 0.5 * (P_new + _tr(P_new)), y, S


def update_masked(
    x: np.ndarray,
    P: np.ndarray,
    z: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    use: np.ndarray,
    M: np.ndarray | None = None,
    U: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`update` where each filter uses only its rows with ``use`` (n, m) True.

    A row not used gets a zero H row, a zero M column, zero cross terms in R and unit
    variance, and innovation 0: it carries no information, so the result equals the
    update with that row removed. Filters with no row keep (x, P). Returns
    ``(x^+, P^+, nis)`` with nis NaN for filters without any row.
    """
    n, m = use.shape
    H = np.where(use[:, :, None], _bmat(H, n), 0.0)
    R = np.where(use[:, :, None] & use[:, None, :], _bmat(R, n), 0.0)
    R[:, np.arange(m), np.arange(m)] += ~use
    if M is not None:
        M = np.where(use[:, None, :], _bmat(M, n), 0.0)
    z = np.where(use, z, 0.0)
    if U is not None:
        U = np.where(use, U, 0.0)
    x_new, P_new, y, S = update(x, P, z, H, R, M, U)
    return x_new, P_new, np.where(use.any(axis=1), nis(y, S), np.nan)


def nis(y: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Normalised innovation squared y' S^-1 y, (n,) from y (n, m) and S (n, m, m)."""
    return np.einsum("ni,ni->n", y, np.linalg.solve(S, y[..., None])[..., 0])


def expm(A: np.ndarray) -> np.ndarray:
    """Matrix exponential of a batch ``(..., d, d)``: scaling and squaring with a
    degree-14 Taylor series (relative error ~1e-15 once the scaled norm is <= 0.5)."""
    A = np.asarray(A, float)
    norm = np.abs(A).sum(axis=-2).max(axis=-1).max(initial=0.0)  # max 1-norm
    s = max(0, int(np.ceil(np.log2(norm / 0.5)))) if norm > 0.5 else 0
    As = A / 2.0**s
    eye = np.broadcast_to(np.eye(A.shape[-1]), A.shape)
    E = eye.copy()
    term = eye.copy()
    for k in range(1, 15):
        term = term @ As / k
        E = E + term
    for _ in range(s):
        E = E @ E
    return E


def discretize(
    A: np.ndarray, G: np.ndarray, dt: float, B: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Continuous ``dx/dt = A x + B u + G xi`` -> discrete ``(F, Q, Gamma)`` over ``dt``.

    A: (..., d, d); G: (..., d, q) noise input for unit-intensity white noise xi;
    B: (..., d, p) input matrix (u held constant over the step) or None.
    Van Loan (1978):

    .. math::
        \\exp\\left(\\begin{bmatrix} -A & G G^T \\\\ 0 & A^T \\end{bmatrix} dt\\right)
        = \\begin{bmatrix} \\cdot & F^{-1} Q \\\\ 0 & F^T \\end{bmatrix}

    and ``Gamma = int_0^dt e^{A s} ds B`` from ``exp([[A, B], [0, 0]] dt)``.
    """
    A = np.asarray(A, float)
    G = np.asarray(G, float)
    d = A.shape[-1]
    batch = np.broadcast_shapes(A.shape[:-2], G.shape[:-2])
    A = np.broadcast_to(A, (*batch, d, d))
    GGt = np.broadcast_to(G @ _tr(G), (*batch, d, d))
    C = np.zeros((*batch, 2 * d, 2 * d))
    C[..., :d, :d] = -A
    C[..., :d, d:] = GGt
    C[..., d:, d:] = _tr(A)
    E = expm(C * dt)
    F = _tr(E[..., d:, d:])
    Q = F @ E[..., :d, d:]
    Q = 0.5 * (Q + _tr(Q))
    Gamma = None
    if B is not None:
        B = np.broadcast_to(np.asarray(B, float), (*batch, d, np.shape(B)[-1]))
        p = B.shape[-1]
        Cb = np.zeros((*batch, d + p, d + p))
        Cb[..., :d, :d] = A
        Cb[..., :d, d:] = B
        Gamma = expm(Cb * dt)[..., :d, d:]
    return F, Q, Gamma
