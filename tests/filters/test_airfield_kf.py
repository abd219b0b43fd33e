"""The airfield Kalman filter kernels (airfield paper eq. 16-19), checked against the
equations recomputed inline and on data drawn from the model itself."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.filters import airfield_kf as kf
from pipeline.filters.ar_errors import VarModel, stationary_covariance
from pipeline.filters.integrity import chi2_thresholds, eta, nis

POS = {
    "S": VarModel([[[1.30, 0.10], [-0.05, 1.20]], [[-0.45, -0.06], [0.04, -0.35]]],
                  [[1.00, 0.0], [0.25, 0.90]]),
    "M": VarModel([[[1.50, 0.0], [0.05, 1.45]], [[-0.60, 0.0], [-0.04, -0.55]]],
                  [[0.80, 0.0], [0.15, 0.75]]),
    "V": VarModel([[[0.95, 0.05], [0.0, 0.90]], [[-0.20, 0.0], [0.0, -0.15]]],
                  [[1.40, 0.0], [0.30, 1.30]]),
}
VEL = VarModel([[[0.80, 0.05], [0.0, 0.75]]], [[0.15, 0.0], [0.03, 0.18]])


@pytest.fixture(scope="module")
def model() -> kf.FilterModel:
    return kf.build_model(("S", "M", "V"), POS, VEL, dt_s=1.0, sigma_input_m=0.2,
                          sigma_stationary_m=0.05, sigma_accel_mps2=1.5)


def test_layout_and_shapes(model):
    lay = model.layout
    assert lay.dim == 2 + 2 + 3 * 4 + 2
    assert model.F.shape == (3, lay.dim, lay.dim) and model.Q.shape == model.F.shape
    assert [lay.err(s).start for s in range(3)] == [4, 8, 12]
    assert lay.dw == slice(16, 18)
    kf.check_model(model)  # every mode's Q is PSD


def test_error_blocks_are_the_sensors_ar_models(model):
    for s, sid in enumerate(("S", "M", "V")):
        blk = model.F[kf.MODE_CV][model.layout.err(s), model.layout.err(s)]
        np.testing.assert_array_equal(blk[:2, :2], POS[sid].B[0])
        np.testing.assert_array_equal(blk[:2, 2:], POS[sid].B[1])
        np.testing.assert_allclose(model.P0_err[model.layout.err(s), model.layout.err(s)],
                                   stationary_covariance(POS[sid]))


def test_vasn_input_is_the_trapezoid_of_eq_14_15(model):
    """Constant acceleration, exact VASN velocity and zero errors: the prediction is exact."""
    a, v0, p0 = np.array([0.7, -0.3]), np.array([5.0, 2.0]), np.array([10.0, -20.0])
    x = np.zeros((1, model.layout.dim))
    x[0, :2], x[0, 2:4] = p0, v0
    P = np.repeat(np.eye(model.layout.dim)[None], 1, axis=0)
    xp, _ = kf.predict(model, x, P, np.array([kf.MODE_VASN]), v0[None], (v0 + a)[None])
    np.testing.assert_allclose(xp[0, :2], p0 + v0 + 0.5 * a)
    np.testing.assert_allclose(xp[0, 2:4], v0 + a)
    # Euler (eq. 14 as printed) would be off by a/2: the trapezoid is what we claim
    assert np.linalg.norm(xp[0, :2] - (p0 + v0)) > 0.3


def test_vasn_velocity_error_enters_with_both_ends(model):
    """dW(k) biases the integrated velocity by -dt/2 (I + B_W) dW(k) (the derivation)."""
    x = np.zeros((1, model.layout.dim))
    dw = np.array([0.4, -0.2])
    x[0, model.layout.dw] = dw
    P = np.repeat(np.eye(model.layout.dim)[None], 1, axis=0)
    W = np.zeros((1, 2))
    xp, _ = kf.predict(model, x, P, np.array([kf.MODE_VASN]), W, W)
    np.testing.assert_allclose(xp[0, :2], -0.5 * (np.eye(2) + VEL.B[0]) @ dw)
    np.testing.assert_allclose(xp[0, 2:4], -VEL.B[0] @ dw)


def test_predict_matches_a_per_target_reference(model):
    rng = np.random.default_rng(3)
    n, d = 6, model.layout.dim
    x = rng.normal(size=(n, d))
    A = rng.normal(size=(n, d, d))
    P = A @ np.transpose(A, (0, 2, 1))
    mode = np.array([0, 1, 2, 0, 1, 2])
    Wk, Wk1 = rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    xp, Pp = kf.predict(model, x, P, mode, Wk, Wk1)
    for i in range(n):  # scalar reference of eq. 17
        F, Q = model.F[mode[i]], model.Q[mode[i]]
        u = model.Bk[mode[i]] @ Wk[i] + model.Bk1[mode[i]] @ Wk1[i]
        np.testing.assert_allclose(xp[i], F @ x[i] + u, atol=1e-12)
        np.testing.assert_allclose(Pp[i], F @ P[i] @ F.T + Q, atol=1e-9)


def test_update_matches_the_joseph_form(model):
    rng = np.random.default_rng(4)
    n, d = 5, model.layout.dim
    x = rng.normal(size=(n, d))
    A = rng.normal(size=(n, d, d))
    P = A @ np.transpose(A, (0, 2, 1)) + np.eye(d)
    z = rng.normal(size=(n, 2))
    R = np.repeat(np.diag([0.09, 0.12])[None], n, axis=0)
    xu, Pu = kf.update(model, x, P, 1, z, R)
    H = np.zeros((2, d))
    H[:, :2] = np.eye(2)
    H[:, model.layout.err0(1)] = np.eye(2)
    for i in range(n):
        S = H @ P[i] @ H.T + R[i]
        K = P[i] @ H.T @ np.linalg.inv(S)
        ikh = np.eye(d) - K @ H
        np.testing.assert_allclose(xu[i], x[i] + K @ (z[i] - H @ x[i]), atol=1e-9)
        np.testing.assert_allclose(Pu[i], ikh @ P[i] @ ikh.T + K @ R[i] @ K.T, atol=1e-8)


def test_nis_is_chi_square_on_data_drawn_from_the_model(model):
    """Simulate eq. 17/19 in stationary mode with the filter's own F and Q: the NIS of
    each channel has mean 2 and its flagged share is q."""
    rng = np.random.default_rng(9)
    n, steps, d = 200, 50, model.layout.dim
    F, Q = model.F[kf.MODE_STATIONARY], model.Q[kf.MODE_STATIONARY]
    L = np.linalg.cholesky(Q + 1e-12 * np.eye(d))
    P0 = model.P0_err.copy()
    P0[:2, :2] = 25.0 * np.eye(2)
    P0[2:4, 2:4] = 1e-4 * np.eye(2)
    truth = rng.standard_normal((n, d)) @ np.linalg.cholesky(P0).T
    x = np.zeros((n, d))
    P = np.repeat(P0[None], n, axis=0)
    R = np.repeat((np.eye(2) / 12.0)[None], n, axis=0)
    Rl = np.linalg.cholesky(R[0])
    zero = np.zeros((n, 2))
    mode = np.full(n, kf.MODE_STATIONARY)
    xis = []
    for k in range(steps):
        if k:
            truth = truth @ F.T + rng.standard_normal((n, d)) @ L.T
            x, P = kf.predict(model, x, P, mode, zero, zero)
        for s in range(3):
            e = model.layout.err0(s)
            z = truth[:, :2] + truth[:, e] + rng.standard_normal((n, 2)) @ Rl.T
            r, S, _ = kf.innovation(model, x, P, s, z, R)
            if k >= 3:
                xis.append(nis(r, S))
            x, P = kf.update(model, x, P, s, z, R)
    xi = np.concatenate(xis)
    assert xi.mean() == pytest.approx(2.0, rel=0.03)
    d1, d2 = chi2_thresholds(0.01, 2)
    assert 0.005 < eta(xi, d1, d2).mean() < 0.02
