"""pipeline.filters.kalman: the equations recomputed inline, batch vs per-filter, Van
Loan against closed forms, and the correlated-noise update against a Monte Carlo."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from pipeline.filters import kalman


def _spd(rng: np.random.Generator, d: int) -> np.ndarray:
    A = rng.normal(size=(d, d))
    return A @ A.T + d * np.eye(d)


@pytest.fixture
def problem():
    rng = np.random.default_rng(3)
    n, d, m = 3, 4, 2
    return dict(
        x=rng.normal(size=(n, d)), P=np.stack([_spd(rng, d) for _ in range(n)]),
        F=rng.normal(size=(d, d)), Q=_spd(rng, d), H=rng.normal(size=(n, m, d)),
        R=_spd(rng, m), z=rng.normal(size=(n, m)), M=0.1 * rng.normal(size=(d, m)),
        U=rng.normal(size=(n, m)))


def test_predict_inline(problem):
    p = problem
    x, P = kalman.predict(p["x"], p["P"], p["F"], p["Q"], Gamma_u=p["x"] * 0.5)
    for i in range(3):
        assert np.allclose(x[i], p["F"] @ p["x"][i] + 0.5 * p["x"][i])
        assert np.allclose(P[i], p["F"] @ p["P"][i] @ p["F"].T + p["Q"])


@pytest.mark.parametrize("correlated", [False, True])
def test_update_inline(problem, correlated):
    """Simon 2006 §7.1: S = HPH'+HM+M'H'+R, K = (PH'+M)S^-1, P = P - KSK'."""
    p = problem
    M = p["M"] if correlated else None
    x, P, y, S = kalman.update(p["x"], p["P"], p["z"], p["H"], p["R"], M, p["U"])
    for i in range(3):
        H, Pi, Mi = p["H"][i], p["P"][i], (p["M"] if correlated else np.zeros((4, 2)))
        Si = H @ Pi @ H.T + H @ Mi + Mi.T @ H.T + p["R"]
        Ki = (Pi @ H.T + Mi) @ np.linalg.inv(Si)
        yi = p["z"][i] - H @ p["x"][i] - p["U"][i]
        assert np.allclose(y[i], yi) and np.allclose(S[i], Si)
        assert np.allclose(x[i], p["x"][i] + Ki @ yi)
        assert np.allclose(P[i], Pi - Ki @ Si @ Ki.T, atol=1e-9)
        assert np.all(np.linalg.eigvalsh(P[i]) > 0)


def test_update_masked_equals_update_without_the_row(problem):
    p = problem
    use = np.array([[True, False], [True, True], [False, False]])
    x, P, nis = kalman.update_masked(p["x"], p["P"], p["z"], p["H"], p["R"], use, p["M"])
    # filter 0: only row 0
    x0, P0, _, _ = kalman.update(p["x"][:1], p["P"][:1], p["z"][:1, :1], p["H"][:1, :1],
                                 p["R"][:1, :1], p["M"][:, :1])
    assert np.allclose(x[0], x0[0]) and np.allclose(P[0], P0[0])
    # filter 1: both rows; filter 2: nothing changes
    x1, P1, _, _ = kalman.update(p["x"][1:2], p["P"][1:2], p["z"][1:2], p["H"][1:2], p["R"],
                                 p["M"])
    assert np.allclose(x[1], x1[0]) and np.allclose(P[1], P1[0])
    assert np.allclose(x[2], p["x"][2]) and np.allclose(P[2], p["P"][2])
    assert np.isnan(nis[2]) and np.isfinite(nis[:2]).all()


def test_batch_equals_one_filter_at_a_time(problem):
    """Two paths agree: n filters at once vs a loop over n = 1."""
    p = problem
    xb, Pb, _, _ = kalman.update(*kalman.predict(p["x"], p["P"], p["F"], p["Q"]), p["z"],
                                 p["H"], p["R"], p["M"])
    for i in range(3):
        xi, Pi = kalman.predict(p["x"][i:i + 1], p["P"][i:i + 1], p["F"], p["Q"])
        xi, Pi, _, _ = kalman.update(xi, Pi, p["z"][i:i + 1], p["H"][i:i + 1], p["R"], p["M"])
        assert np.allclose(xb[i], xi[0], atol=1e-12) and np.allclose(Pb[i], Pi[0], atol=1e-12)


def test_expm_matches_scipy():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(5, 6, 6)) * np.array([0.01, 0.3, 1.0, 5.0, 20.0])[:, None, None]
    E = kalman.expm(A)
    for i in range(5):
        ref = scipy.linalg.expm(A[i])
        assert np.allclose(E[i], ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())


def test_discretize_constant_velocity_closed_form():
    """dx/dt = [[0,1],[0,0]] x + [0, q] xi: F = [[1, dt], [0, 1]],
    Q = q^2 [[dt^3/3, dt^2/2], [dt^2/2, dt]]; input u on velocity: Gamma = [dt^2/2, dt]."""
    dt, q = 0.7, 0.3
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    F, Q, Gamma = kalman.discretize(A, np.array([[0.0], [q]]), dt, B=np.array([[0.0], [1.0]]))
    assert np.allclose(F, [[1.0, dt], [0.0, 1.0]])
    assert np.allclose(Q, q**2 * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]))
    assert np.allclose(Gamma[:, 0], [dt**2 / 2, dt])


def test_discretize_batch_matches_numerical_integral():
    rng = np.random.default_rng(5)
    A = rng.normal(size=(2, 3, 3)) * 0.5
    G = rng.normal(size=(2, 3, 2))
    dt = 1.3
    F, Q, _ = kalman.discretize(A, G, dt)
    s = np.linspace(0.0, dt, 201)
    for i in range(2):
        E = kalman.expm(A[i][None] * s[:, None, None])  # checked against scipy above
        vals = E @ G[i] @ G[i].T @ np.swapaxes(E, 1, 2)
        assert np.allclose(Q[i], scipy.integrate.simpson(vals, x=s, axis=0), rtol=1e-6,
                           atol=1e-9)
        assert np.allclose(F[i], scipy.linalg.expm(A[i] * dt))


def test_correlated_noise_update_is_consistent_and_better():
    """A scalar random walk seen through a measurement that contains the step's own
    process noise (v_k = w_{k-1} + e_k): with M the filter is consistent (mean NIS ~ 1,
    mean NEES ~ 1) and more accurate than the same filter ignoring M. Seeded."""
    rng = np.random.default_rng(11)
    T, q, r = 4000, 1.0, 0.25
    w = rng.normal(0.0, np.sqrt(q), T)
    e = rng.normal(0.0, np.sqrt(r), T)
    x_true = np.cumsum(w)
    z = x_true + w + e  # measurement noise w_{k-1} + e_k
    results = {}
    for name, M in (("with_M", np.array([[q]])), ("without_M", None)):
        x, P = np.zeros((1, 1)), np.array([[[1e-6]]])
        R = np.array([[q + r]])
        nis, nees, err = [], [], []
        for k in range(T):
            x, P = kalman.predict(x, P, np.eye(1), np.array([[q]]))
            x, P, y, S = kalman.update(x, P, z[k:k + 1, None], np.eye(1), R, M)
            nis.append(kalman.nis(y, S)[0])
            nees.append((x[0, 0] - x_true[k]) ** 2 / P[0, 0, 0])
            err.append(x[0, 0] - x_true[k])
        results[name] = (np.mean(nis[100:]), np.mean(nees[100:]), np.sqrt(np.mean(
            np.square(err[100:]))))
    nis_m, nees_m, rmse_m = results["with_M"]
    assert 0.9 < nis_m < 1.1 and 0.9 < nees_m < 1.1
    assert rmse_m < 0.8 * results["without_M"][2]
