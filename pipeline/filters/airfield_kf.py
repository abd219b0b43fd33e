"""Kalman filter per surface target with coloured, per-sensor error states (airfield
paper eq. 16–19), vectorised over targets.

State (our eq. 16, generalised: each sensor has its own error states, as the issue
asks; the paper's eq. 16 shares one set)::

    x = [p (2), v (2), e_1(k), e_1(k-1), …  (2·p_1), …, e_S(k), … (2·p_S), δW (2)]

p: position, east/north m in the common frame (the tangent plane at the reference
point: a fixed linear image of the paper's PZ-90 φ, λ at airfield scale); v: velocity,
m/s; e_s: sensor s's position error and its lags, the Markov form of the AR(p_s) model
(eq. 9); δW: the VASN velocity error, AR(1) (eq. 8).

Transition k → k+1 in one of three modes per target:

- ``MODE_VASN`` — the VASN velocity W is the known input (eq. 12–15). The paper's
  Euler step p(k+1) = p(k) + (W(k) − δW(k))Δt (eq. 14–15) is replaced by the
  trapezoidal rule p(k+1) = p(k) + ½Δt (W(k) − δW(k) + W(k+1) − δW(k+1)), exact for
  constant acceleration (an offline batch has W(k+1)); with δW(k+1) = B_W δW(k) +
  Γ_W n_W this gives F[p, δW] = −½Δt (I + B_W) and process noise −½Δt Γ_W n_W on p;
  v(k+1) = W(k+1) − δW(k+1). A white ``sigma_input_m`` covers the rest.
- ``MODE_STATIONARY`` — the VASN is silent because the target stands with engines
  off (the paper's blind case): p(k+1) = p(k) + w, v = 0.
- ``MODE_CV`` — no usable VASN (dropout, excluded channel): constant velocity driven
  by white acceleration ``sigma_accel_mps2``.

Sensor s measures z_s = p + e_s(k) + w_s (eq. 5, 18), R_s = cov w_s the white part
(quantisation). The paper's eq. 19 writes the same model with the error recursion
substituted (Φ_ZX holding B_1, B_2 and the AR innovation as measurement noise); we
keep e_s(k) in the state (state augmentation), which is the same model without a
correlation between process and measurement noise.

Shapes: x (n, d), P (n, d, d), z (n, 2), R (n, 2, 2) with n targets.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import linalg

from pipeline.filters.ar_errors import VarModel, companion, stationary_covariance

MODE_VASN, MODE_STATIONARY, MODE_CV = 0, 1, 2
MODES = ("vasn", "stationary", "cv")
SIGMA_V_RESET_MPS = 0.01  # keeps P_vv positive when v is reset by the input/stationarity


@dataclass(frozen=True)
class StateLayout:
    """Where each block sits in the state vector."""

    sensor_ids: tuple[str, ...]
    orders: tuple[int, ...]

    @property
    def dim(self) -> int:
        return 4 + 2 * sum(self.orders) + 2

    def err(self, s: int) -> slice:
        """Slice of sensor s's error block [e(k), e(k-1), …]."""
        a = 4 + 2 * sum(self.orders[:s])
        return slice(a, a + 2 * self.orders[s])

    def err0(self, s: int) -> slice:
        """Slice of sensor s's current error e_s(k)."""
        a = self.err(s).start
        return slice(a, a + 2)

    @property
    def dw(self) -> slice:
        return slice(self.dim - 2, self.dim)

    P_SLICE = slice(0, 2)
    V_SLICE = slice(2, 4)


@dataclass(frozen=True, eq=False)
class FilterModel:
    """Everything the kernels need: layout, per-mode transition F (3, d, d), process
    noise Q (3, d, d), input matrices Bk, Bk1 (3, d, 2) so that u = Bk W(k) + Bk1 W(k+1),
    and the stationary prior of the error blocks P0_err (d, d)."""

    layout: StateLayout
    F: np.ndarray
    Q: np.ndarray
    Bk: np.ndarray
    Bk1: np.ndarray
    P0_err: np.ndarray


def build_model(
    sensor_ids: Sequence[str],
    position_models: Mapping[str, VarModel],
    velocity_model: VarModel,
    *,
    dt_s: float,
    sigma_input_m: float,
    sigma_stationary_m: float,
    sigma_accel_mps2: float,
) -> FilterModel:
    """Assemble eq. 17 (per mode) from the sensors' AR models."""
    if velocity_model.order != 1:
        raise ValueError("the VASN velocity-error model must be AR(1) (eq. 8)")
    lay = StateLayout(tuple(sensor_ids), tuple(position_models[s].order for s in sensor_ids))
    d = lay.dim
    P, V, W = lay.P_SLICE, lay.V_SLICE, lay.dw
    I2 = np.eye(2)
    BW, GW = velocity_model.B[0], velocity_model.Gamma

    base = np.zeros((d, d))
    G_err = np.zeros((d, d))  # error-state and δW noise, shared by all modes
    P0 = np.zeros((d, d))
    for s, sid in enumerate(lay.sensor_ids):
        A, G = companion(position_models[sid])
        sl = lay.err(s)
        base[sl, sl] = A
        G_err[sl, sl.start : sl.start + 2] = G
        P0[sl, sl] = stationary_covariance(position_models[sid])
    base[W, W] = BW
    G_err[W, W] = GW
    P0[W, W] = stationary_covariance(velocity_model)
    Q_err = G_err @ G_err.T

    F = np.repeat(base[None], 3, axis=0)
    Q = np.repeat(Q_err[None], 3, axis=0)
    Bk = np.zeros((3, d, 2))
    Bk1 = np.zeros((3, d, 2))
    # VASN input (trapezoid of eq. 14-15)
    F[MODE_VASN][P, P] = I2
    F[MODE_VASN][P, W] = -0.5 * dt_s * (I2 + BW)
    F[MODE_VASN][V, W] = -BW
    Gv = np.zeros((d, 2))
    Gv[P] = -0.5 * dt_s * GW
    Gv[V] = -GW
    Gv[W] = GW
    Q[MODE_VASN] = Q_err - _block(d, W, GW @ GW.T) + Gv @ Gv.T
    Q[MODE_VASN][P, P] += sigma_input_m**2 * I2
    Q[MODE_VASN][V, V] += SIGMA_V_RESET_MPS**2 * I2
    Bk[MODE_VASN][P] = 0.5 * dt_s * I2
    Bk1[MODE_VASN][P] = 0.5 * dt_s * I2
    Bk1[MODE_VASN][V] = I2
    # stationary (engines off)
    F[MODE_STATIONARY][P, P] = I2
    Q[MODE_STATIONARY][P, P] += sigma_stationary_m**2 * I2
    Q[MODE_STATIONARY][V, V] += SIGMA_V_RESET_MPS**2 * I2
    # constant velocity, white acceleration
    F[MODE_CV][P, P] = I2
    F[MODE_CV][P, V] = dt_s * I2
    F[MODE_CV][V, V] = I2
    Ga = np.zeros((d, 2))
    Ga[P] = 0.5 * dt_s**2 * sigma_accel_mps2 * I2
    Ga[V] = dt_s * sigma_accel_mps2 * I2
    Q[MODE_CV] = Q[MODE_CV] + Ga @ Ga.T
    return FilterModel(lay, F, Q, Bk, Bk1, P0)


def _block(d: int, sl: slice, M: np.ndarray) -> np.ndarray:
    out = np.zeros((d, d))
    out[sl, sl] = M
    return out


def prior(
    model: FilterModel, p0: np.ndarray, v0: np.ndarray, sigma_p0_m: float, sigma_v0_mps: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Birth prior for n targets: p ~ N(p0, σ_p0² I) (diffuse against the sensor
    errors), v ~ N(v0, σ_v0² I), error states at their stationary covariance."""
    n = p0.shape[0]
    d = model.layout.dim
    x = np.zeros((n, d))
    x[:, 0:2] = p0
    x[:, 2:4] = v0
    P = np.repeat(model.P0_err[None], n, axis=0)
    P[:, 0, 0] = P[:, 1, 1] = sigma_p0_m**2
    P[:, 2, 2] = P[:, 3, 3] = np.asarray(sigma_v0_mps, float) ** 2
    return x, P


def predict(
    model: FilterModel,
    x: np.ndarray,
    P: np.ndarray,
    mode: np.ndarray,
    W_k: np.ndarray,
    W_k1: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """x⁻ = F x + Bk W(k) + Bk1 W(k+1), P⁻ = F P Fᵀ + Q (eq. 17), per target's mode.

    ``mode`` (n,) in {MODE_VASN, MODE_STATIONARY, MODE_CV}; W (n, 2) (ignored unless
    MODE_VASN)."""
    F = model.F[mode]
    u = np.einsum("ndk,nk->nd", model.Bk[mode], W_k) + np.einsum(
        "ndk,nk->nd", model.Bk1[mode], W_k1
    )
    x_new = np.einsum("nij,nj->ni", F, x) + u
    P_new = F @ P @ np.transpose(F, (0, 2, 1)) + model.Q[mode]
    return x_new, 0.5 * (P_new + np.transpose(P_new, (0, 2, 1)))


def innovation(
    model: FilterModel, x: np.ndarray, P: np.ndarray, s: int, z: np.ndarray, R: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sensor s's innovation r = z − (p + e_s), its covariance S = H P Hᵀ + R (the
    matrix inverted in eq. 21) and P Hᵀ (n, d, 2), with H = [I at p, I at e_s(k)]."""
    e = model.layout.err0(s)
    r = z - x[:, 0:2] - x[:, e]
    PHt = P[:, :, 0:2] + P[:, :, e]
    S = PHt[:, 0:2, :] + PHt[:, e, :] + R
    return r, 0.5 * (S + np.transpose(S, (0, 2, 1))), PHt


def inv2(S: np.ndarray) -> np.ndarray:
    """Inverse of a stack of symmetric 2×2 matrices (n, 2, 2), in closed form."""
    a, b, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    det = a * d - b * b
    out = np.empty_like(S)
    out[:, 0, 0] = d / det
    out[:, 1, 1] = a / det
    out[:, 0, 1] = out[:, 1, 0] = -b / det
    return out


def update(
    model: FilterModel, x: np.ndarray, P: np.ndarray, s: int, z: np.ndarray, R: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update of every given target with sensor s: K = P Hᵀ S⁻¹, x + K r,
    P − K (P Hᵀ)ᵀ (symmetrised). Pass the subset of targets that use the sensor."""
    r, S, PHt = innovation(model, x, P, s, z, R)
    K = PHt @ inv2(S)  # (n, d, 2)
    Pn = P - K @ np.transpose(PHt, (0, 2, 1))
    return x + np.einsum("ndk,nk->nd", K, r), 0.5 * (Pn + np.transpose(Pn, (0, 2, 1)))


def check_model(model: FilterModel) -> None:
    """Raise when a mode's Q is not positive semi-definite (a bad model)."""
    for q in model.Q:
        if linalg.eigvalsh(q).min() < -1e-9:
            raise ValueError("process noise is not positive semi-definite")
