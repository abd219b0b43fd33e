"""Water current and log bias from GNSS, heading and log: the gyro/GNSS/log paper's log
correction (Fig. 1, summator 1) in vector form.

The paper corrects the log with the scalar difference of the GNSS and log speeds,
dV = dV_gnss - dV_log - V_T (log error and current along the heading), kept constant
in the emergency mode. A log measures speed through water ALONG the heading only, so a
current with a cross-heading component, or a turn, breaks the scalar correction. We
estimate the three constants it mixes: the current c = (c_E, c_N) and the log bias b
(OUR extension; with a constant heading it reduces to the paper's dV).

State s = [c_E, c_N, b] (m/s), random walk. With u = (sin K, cos K) the heading unit
vector, v_g the GNSS velocity, V_log the log speed, a_s the GNSS acceleration across the
heading and K-dot the turn rate, assuming the ship moves through the water along its
heading (v_g = V_w u + c):

- log:                     V_log - v_g . u = b - c . u
- turn (centripetal):      a_s - (v_g . u) K-dot = -(c . u) K-dot   (only while turning)

The speed through water is then V_w = |v_g - c|. With a constant heading the rows see
only b - c . u (and V_w needs only c . u to first order); a turn separates c and b.
The cross-heading velocity v_g . u_s = c . u_s is NOT used: its error is V times the
heading error, which moves in step with the heading estimate while the gyro filter
converges, and would be read as a rotation of the current (measured: c drifted to
~3 m/s before the turn).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.filters import kalman


@dataclass(frozen=True)
class CurrentLogSettings:
    """Priors, random-walk intensities and measurement sigmas, SI units."""

    prior_current_sigma_mps: float = 0.5
    prior_log_bias_sigma_mps: float = 0.5
    current_walk_mps_per_sqrt_s: float = 2e-4
    log_bias_walk_mps_per_sqrt_s: float = 1e-5
    gnss_velocity_sigma_mps: float = 0.053
    gnss_velocity_tau_s: float = 15.0  # correlation of the GNSS velocity error
    gnss_accel_sigma_mps2: float = 0.019
    log_sigma_mps: float = 0.5
    turn_rate_sigma_radps: float = 5e-4  # error of K-dot from the gyro heading
    min_turn_rate_radps: float = 0.0035  # the turn row is used above this (0.2 deg/s)


def initial(n: int, st: CurrentLogSettings) -> tuple[np.ndarray, np.ndarray]:
    """Zero current and bias with their prior covariance, (n, 3) and (n, 3, 3)."""
    sig = np.array(
        [st.prior_current_sigma_mps, st.prior_current_sigma_mps, st.prior_log_bias_sigma_mps]
    )
    return np.zeros((n, 3)), np.broadcast_to(np.diag(sig**2), (n, 3, 3)).copy()


def predict(
    s: np.ndarray, P: np.ndarray, dt_s: float, st: CurrentLogSettings
) -> tuple[np.ndarray, np.ndarray]:
    """Random walk over dt_s: P += diag(q_c^2, q_c^2, q_b^2) dt."""
    q = np.array([st.current_walk_mps_per_sqrt_s] * 2 + [st.log_bias_walk_mps_per_sqrt_s])
    return kalman.predict(s, P, np.eye(3), np.diag(q**2 * dt_s))


def update(
    s: np.ndarray,
    P: np.ndarray,
    *,
    v_gnss: np.ndarray,
    heading_rad: np.ndarray,
    log_speed_mps: np.ndarray,
    cross_accel_mps2: np.ndarray,
    turn_rate_radps: np.ndarray,
    turn_rate_sigma_radps: np.ndarray,
    dt_s: float,
    use: np.ndarray,
    st: CurrentLogSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """One update of n estimators with the rows of the module docstring.

    v_gnss: (n, 2) east/north m/s; heading_rad: (n,) heading at the fix;
    log_speed_mps, cross_accel_mps2 (n,) NaN when absent; turn_rate_radps and its sigma
    (n,) (the turn row is used only when the rate exceeds ``min_turn_rate_radps`` and
    three of its sigmas);
    use: (n,) a fix accepted this step. The GNSS velocity error is correlated over tau,
    so its rows use the variance of one independent sample, sigma^2 * 2 tau / dt.
    """
    u = np.stack([np.sin(heading_rad), np.cos(heading_rad)], axis=1)
    v_along = np.einsum("ni,ni->n", v_gnss, u)
    n = s.shape[0]
    H = np.zeros((n, 2, 3))
    H[:, 0, :2] = -u
    H[:, 0, 2] = 1.0
    H[:, 1, :2] = -u * turn_rate_radps[:, None]
    z = np.stack([log_speed_mps - v_along, cross_accel_mps2 - v_along * turn_rate_radps], axis=1)
    var_v = st.gnss_velocity_sigma_mps**2 * max(1.0, 2.0 * st.gnss_velocity_tau_s / dt_s)
    R = np.zeros((n, 2, 2))
    R[:, 0, 0] = st.log_sigma_mps**2 + var_v
    R[:, 1, 1] = (
        st.gnss_accel_sigma_mps2**2
        + turn_rate_radps**2 * var_v
        + (v_along * turn_rate_sigma_radps) ** 2
    )
    rows = np.isfinite(z) & use[:, None]
    # with K-dot ~ 0 the turn row says nothing but (c . u) K-dot ~ 0 and any small
    # turn-rate error would pull c . u towards the speed: only in turns
    rows[:, 1] &= np.abs(turn_rate_radps) >= np.maximum(
        st.min_turn_rate_radps, 3.0 * turn_rate_sigma_radps)
    s_new, P_new, _ = kalman.update_masked(s, P, np.nan_to_num(z), H, R, rows)
    return s_new, P_new


def water_speed(s: np.ndarray, P: np.ndarray, v_gnss: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Speed through water V_w = |v_g - c| (n,) and its sigma from the current's
    covariance along v_g - c (the GNSS velocity's own error is left out)."""
    rel = v_gnss - s[:, :2]
    V = np.hypot(rel[:, 0], rel[:, 1])
    e = rel / np.maximum(V, 1e-9)[:, None]
    var = np.einsum("ni,nij,nj->n", e, P[:, :2, :2], e)
    return V, np.sqrt(np.maximum(var, 0.0))
