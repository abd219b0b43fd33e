"""The gyro/GNSS/log paper's six-state Kalman filter of a corrected gyrocompass.

State (paper, eq. 1), per filter (vessel, Monte Carlo run):

.. math:: x = [\\alpha, \\beta, \\delta, \\varphi, \\dot\\varphi, W]^T

alpha heading error of the gyrocompass (rad), beta tilt of its platform from the
horizon (rad), delta the accelerometer amplifier output (rad-equivalent), phi and
phi-dot roll angle (rad) and rate (rad/s), W the ship's acceleration along its heading
(m/s^2).

**Gyro error dynamics (OURS: the paper does not give them).** A plain linear corrected
gyrocompass: the accelerometer on the platform senses its tilt plus the horizontal
acceleration along the north axis, the amplifier is a first-order lag of that signal,
and the amplifier output drives the azimuth torquer (gain k_a) and the damping tilt
torquer (gain k_b); the horizontal Earth rate Omega_H = Omega cos(lat) tilts the
platform when it points off the meridian. Latitude and speed deviations are taken as
removed by the correction rates omega^c (paper, Fig. 1); alpha is the residual dynamic
error:

.. math::
    \\dot\\alpha = -k_a \\delta + q_\\alpha \\xi_\\alpha, \\qquad
    \\dot\\beta = \\Omega_H \\alpha - k_b \\delta + q_\\beta \\xi_\\beta, \\qquad
    \\dot\\delta = (\\beta + a_N / g - \\delta) / T_a

with the north acceleration at the gyro (paper, the accelerometer signal under Fig. 1)

.. math:: a_N = W \\cos K + z \\ddot\\varphi \\sin K - a_s \\sin K

(K heading, z height of the gyro above the centre of mass, a_s the centripetal
acceleration to starboard, V dK/dt in a turn). Roll is the paper's irregular roll
(eq. 6) as the shaping filter whose correlation is D e^{-mu|tau|}(cos nu tau + mu/nu
sin nu|tau|):

.. math::
    \\ddot\\varphi = -(\\nu^2 + \\mu^2) \\varphi - 2 \\mu \\dot\\varphi
    + \\sqrt{4 \\mu D (\\nu^2 + \\mu^2)}\\, \\xi_\\varphi

and W a first-order Gauss-Markov process, dW/dt = -W/tau_W + q_W xi_W. The undamped
period is 2 pi / sqrt(k_a Omega_H); k_a is larger than a Schuler-tuned compass's, so
accelerations leave ballistic deflections of many degrees (the paper reports > 14 deg
for its gyro under roll and a full turn).

**Measurements (paper, eq. 2)** at the end of step k (length dt):

.. math:: Y = C x_k + D w_{k-1} + V + U_y

- y1: the accelerometer signal, the mean of beta + a_N/g over the step (an integrating
  sampler). Its roll term is the mean roll acceleration (phi-dot_k - phi-dot_{k-1})/dt;
  written with the exact discrete roll block F_r it is a row of C on (phi, phi-dot)_k
  plus a term D in the roll process noise w_{k-1}: the paper's correlated noise. For
  dt -> 0 that row tends to z sin K / g * (-(nu^2 + mu^2), -2 mu); the paper prints
  (nu^2, 2 mu) -- same magnitude to 0.03 % (mu << nu), the sign is our convention's.
  The mean of beta is beta_k - dt/2 (Omega_H alpha_k - k_b delta_k) (delta swings with
  the roll, so this is not negligible at 1 s).
- y2: the amplifier output delta.
- y3: W from the GNSS velocity: the change of the GNSS velocity vector since the last
  accepted fix, projected on the heading in the middle of the step (the projection
  keeps the water current out: with a constant current d v_g/dt = d v_w/dt).
- U_y = -a_s sin K / g, the paper's deterministic term -(V/g) K-dot sin(K0 + K-dot t),
  with a_s = V_w K-dot. V_w is the speed through water, |v_g - c| with the current c
  from :mod:`pipeline.filters.current_log`, smoothed over ``speed_smoothing_s``: V from
  SOG would put the current into the term (measured: 0.35 deg RMS heading error with a
  0.3 m/s current against 0.07 deg without). K-dot is the gyro heading change minus the
  change of alpha over the step, (dK_P - alpha_k + alpha_{k-1}) / dt, with alpha_{k-1}
  cloned into the state for the step, so a_s is linear in the state (no iteration, and
  a correction of alpha's level is not read as a turn). The errors of a_s beyond that
  (speed through water, ``cross_accel_sigma_mps2``) enter Q, R11 and M like the roll
  noise.

**Heading in the model (extended Kalman filter).** The filter's heading is K_P - alpha^,
so every sin K / cos K above depends on the state. The mean is propagated and predicted
with the estimated heading; the covariance and gain use the derivatives with respect to
alpha of W cos K and a_s sin K in the prediction (dF/dK, dGamma/dK, exact by Van Loan)
and in y1. A speed change and a turn thus inform alpha; without these derivatives the
filter was overconfident while converging (NEES ~4 at 300-600 s) and its heading RMS
after 600 s exceeded 0.1 deg on 6-17 % of seeds (docs/ownship.md §4).

**Gate (paper, eq. 3)** before each update with a GNSS acceleration:
|W_o - W^-| <= n_sigma sqrt(P66^- + sigma_w^2), n_sigma = 3; when it fails, W keeps its
prediction: y3 is not used and the fix is not used later (deviation: the paper keeps the
prediction of the whole state; we still use y1 and y2, the gyro's own signals, which a
GNSS fault does not touch -- dropping them at the turn start cost ~1 deg). We apply the
same 3-sigma rule to the cross-heading GNSS acceleration against the predicted a_s (our
addition); a fix must pass both.

**Modes**: the structure is the same in the emergency mode; only y3 changes (the log
speed difference with the log's sigma instead of GNSS), as the paper says.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.filters import kalman
from pipeline.filters.current_log import CurrentLogSettings

G_MPS2 = 9.80665
EARTH_RATE_RADPS = 7.2921150e-5
N_STATE = 6
IA, IB, ID, IPHI, IPHID, IW = range(N_STATE)


@dataclass(frozen=True)
class GyroModel:
    """Our linear corrected-gyrocompass model (see module docstring); SI units."""

    azimuth_gain_per_s: float = 0.24  # k_a
    tilt_damping_per_s: float = 2.8e-3  # k_b
    amplifier_time_constant_s: float = 2.0  # T_a
    mount_height_m: float = 3.0  # z, gyro above the centre of mass (paper: 3 m)
    azimuth_noise_rad_per_sqrt_s: float = 1e-6  # q_alpha (gyro drift noise)
    tilt_noise_rad_per_sqrt_s: float = 1e-6  # q_beta


@dataclass(frozen=True)
class RollModel:
    """Irregular roll (paper, eq. 6): D rad^2, nu rad/s, mu 1/s."""

    variance_rad2: float = 0.12
    frequency_radps: float = 0.6
    irregularity_per_s: float = 0.01

    @property
    def omega0_sq(self) -> float:
        return self.frequency_radps**2 + self.irregularity_per_s**2

    @property
    def noise_intensity(self) -> float:
        """q_phi = sqrt(4 mu D (nu^2 + mu^2)) of the shaping filter, rad/s^1.5."""
        return float(np.sqrt(4.0 * self.irregularity_per_s * self.variance_rad2 * self.omega0_sq))


@dataclass(frozen=True)
class FilterSettings:
    """Noise, gate and prior settings of the filter; SI units."""

    accel_sigma_mps2: float = 0.02  # stationary sigma of the W model
    accel_tau_s: float = 60.0  # correlation time of the W model
    accelerometer_sigma_rad: float = 1e-4  # y1 white noise
    amplifier_sigma_rad: float = 1e-5  # y2 white noise
    gnss_accel_sigma_mps2: float = 0.019  # sigma_w of y3 in the main mode (paper: 0.019)
    log_accel_sigma_mps2: float = 0.7  # sigma of y3 in the emergency mode (log 0.5 m/s, 1 s)
    gate_n_sigma: float = 3.0  # eq. 3
    cross_accel_sigma_mps2: float = 0.002  # a_s = V_w K-dot beyond the current's share
    speed_smoothing_s: float = 60.0  # time constant of the speed through water for a_s
    max_difference_gap_s: float = 3.0  # a fix longer after the last accepted one restarts
    prior_alpha_sigma_rad: float = np.radians(2.0)
    prior_beta_sigma_rad: float = 1e-3
    prior_delta_sigma_rad: float = 1e-3
    prior_accel_sigma_mps2: float = 0.1


@dataclass(frozen=True)
class NavFilterModel:
    gyro: GyroModel = GyroModel()
    roll: RollModel = RollModel()
    settings: FilterSettings = FilterSettings()


def continuous_model(
    lat_rad: np.ndarray, heading_rad: np.ndarray, m: NavFilterModel
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, G, B)`` of dx/dt = A x + B a_s + G xi for n filters.

    lat_rad, heading_rad: (n,). A: (n, 6, 6); G: (n, 6, 4) for unit white noises
    (xi_alpha, xi_beta, xi_phi, xi_W); B: (n, 6, 1) for the centripetal input a_s (m/s^2).
    """
    g, r, s = m.gyro, m.roll, m.settings
    n = np.shape(lat_rad)[0]
    sK, cK = np.sin(heading_rad), np.cos(heading_rad)
    Ta, z = g.amplifier_time_constant_s, g.mount_height_m
    A = np.zeros((n, N_STATE, N_STATE))
    A[:, IA, ID] = -g.azimuth_gain_per_s
    A[:, IB, IA] = EARTH_RATE_RADPS * np.cos(lat_rad)
    A[:, IB, ID] = -g.tilt_damping_per_s
    A[:, ID, IB] = 1.0 / Ta
    A[:, ID, ID] = -1.0 / Ta
    A[:, ID, IW] = cK / (G_MPS2 * Ta)
    A[:, ID, IPHI] = -z * sK * r.omega0_sq / (G_MPS2 * Ta)
    A[:, ID, IPHID] = -z * sK * 2.0 * r.irregularity_per_s / (G_MPS2 * Ta)
    A[:, IPHI, IPHID] = 1.0
    A[:, IPHID, IPHI] = -r.omega0_sq
    A[:, IPHID, IPHID] = -2.0 * r.irregularity_per_s
    A[:, IW, IW] = -1.0 / s.accel_tau_s
    G = np.zeros((n, N_STATE, 4))
    G[:, IA, 0] = g.azimuth_noise_rad_per_sqrt_s
    G[:, IB, 1] = g.tilt_noise_rad_per_sqrt_s
    G[:, IPHID, 2] = r.noise_intensity
    G[:, ID, 2] = z * sK * r.noise_intensity / (G_MPS2 * Ta)
    G[:, IW, 3] = s.accel_sigma_mps2 * np.sqrt(2.0 / s.accel_tau_s)
    B = np.zeros((n, N_STATE, 1))
    B[:, ID, 0] = -sK / (G_MPS2 * Ta)
    return A, G, B


def heading_derivative(
    heading_rad: np.ndarray, m: NavFilterModel
) -> tuple[np.ndarray, np.ndarray]:
    """``(dA/dK, dB/dK)`` of :func:`continuous_model` for the terms of a_N whose size is
    known apart from the gyro: W cos K (W from GNSS) and -a_s sin K (a_s from the turn
    rate and the speed). Shapes (n, 6, 6) and (n, 6, 1).

    The roll term z phi-ddot sin K is left out on purpose: roll reaches the gyro only
    through that product, so a heading error in it is a rescaling of the roll states by
    (1 + e cot K), which they absorb; its derivative is not an independent direction
    (measured: with it, alpha converged slower at a 60 deg heading, same at 90 deg).
    """
    n = np.shape(heading_rad)[0]
    Ta = m.gyro.amplifier_time_constant_s
    dA = np.zeros((n, N_STATE, N_STATE))
    dA[:, ID, IW] = -np.sin(heading_rad) / (G_MPS2 * Ta)
    dB = np.zeros((n, N_STATE, 1))
    dB[:, ID, 0] = -np.cos(heading_rad) / (G_MPS2 * Ta)
    return dA, dB


def discrete_heading_derivative(
    A: np.ndarray, B: np.ndarray, dA: np.ndarray, dB: np.ndarray, dt_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(dF/dK, dGamma/dK)`` of the step's F = e^{A dt} and Gamma = int e^{As} ds B,
    exactly: with C = [[A, B], [0, 0]], the derivative of e^{C dt} along dC is the
    upper-right block of exp([[C, dC], [0, C]] dt) (Van Loan 1978)."""
    n, d, p = B.shape
    q = d + p
    C = np.zeros((n, q, q))
    C[:, :d, :d], C[:, :d, d:] = A, B
    dC = np.zeros((n, q, q))
    dC[:, :d, :d], dC[:, :d, d:] = dA, dB
    big = np.zeros((n, 2 * q, 2 * q))
    big[:, :q, :q] = C
    big[:, :q, q:] = dC
    big[:, q:, q:] = C
    dE = kalman.expm(big * dt_s)[:, :q, q:]
    return dE[:, :d, :d], dE[:, :d, d:]


@dataclass(frozen=True)
class StepModel:
    """Discrete model of one step for n filters (see :func:`step_model`)."""

    F: np.ndarray  # (n, 6, 6)
    Q: np.ndarray  # (n, 6, 6)
    Gamma: np.ndarray  # (n, 6, 1) centripetal input
    H: np.ndarray  # (n, 3, 6) rows y1 accelerometer, y2 amplifier, y3 GNSS acceleration
    R: np.ndarray  # (n, 3, 3) main-mode measurement covariance incl. the D w term
    M: np.ndarray  # (n, 6, 3) E[w_{k-1} v_k']
    u_gain: np.ndarray  # (n,) U_y = u_gain * a_s
    F_dheading: np.ndarray  # (n, 6, 6) derivative of F with respect to the heading
    Gamma_dheading: np.ndarray  # (n, 6, 1) derivative of Gamma with respect to the heading


def step_model(
    lat_rad: np.ndarray, heading_rad: np.ndarray, dt_s: float, m: NavFilterModel
) -> StepModel:
    """Discretise over ``dt_s`` (Van Loan) and build eq. 2's C, D, V, U_y for n filters.

    heading_rad: (n,) heading in the middle of the step. Roll block inverted exactly:
    (phi, phi-dot)_{k-1} = F_r^-1 ((phi, phi-dot)_k - w_r), so the mean roll acceleration
    over the step is c_r . (phi, phi-dot)_k + d_r . w_r with c_r = (e2 - F_r^-T e2) / dt,
    d_r = F_r^-T e2 / dt.
    """
    A, G, B = continuous_model(lat_rad, heading_rad, m)
    F, Q, Gamma = kalman.discretize(A, G, dt_s, B)
    n = A.shape[0]
    sK, cK = np.sin(heading_rad), np.cos(heading_rad)
    zg = m.gyro.mount_height_m / G_MPS2
    roll = slice(IPHI, IPHID + 1)
    Fr_inv_T = np.swapaxes(np.linalg.inv(F[:, roll, roll]), -1, -2)
    e2 = np.array([0.0, 1.0])
    d_r = Fr_inv_T @ e2 / dt_s  # (n, 2)
    c_r = (e2 - Fr_inv_T @ e2) / dt_s
    H = np.zeros((n, 3, N_STATE))
    # mean of beta over the step ~ beta_k - dt/2 d(beta)/dt = beta_k - dt/2 (Omega_H alpha
    # - k_b delta): delta swings with the roll, and this term is not negligible
    H[:, 0, IB] = 1.0
    H[:, 0, IA] = -0.5 * dt_s * EARTH_RATE_RADPS * np.cos(lat_rad)
    H[:, 0, ID] = 0.5 * dt_s * m.gyro.tilt_damping_per_s
    H[:, 0, roll] = (zg * sK)[:, None] * c_r
    H[:, 0, IW] = cK / G_MPS2
    H[:, 1, ID] = 1.0
    H[:, 2, IW] = 1.0
    d1 = (zg * sK)[:, None] * d_r  # D row of y1 on the roll noise w_r (n, 2)
    M = np.zeros((n, N_STATE, 3))
    M[:, :, 0] = np.einsum("nij,nj->ni", Q[:, :, roll], d1)  # E[w v1'] = Q[:, roll] d1
    s = m.settings
    R = np.zeros((n, 3, 3))
    R[:, 0, 0] = s.accelerometer_sigma_rad**2 + np.einsum("ni,nij,nj->n", d1, Q[:, roll, roll], d1)
    R[:, 1, 1] = s.amplifier_sigma_rad**2
    R[:, 2, 2] = s.gnss_accel_sigma_mps2**2
    dF, dGamma = discrete_heading_derivative(A, B, *heading_derivative(heading_rad, m), dt_s)
    return StepModel(F, Q, Gamma, H, R, M, -sK / G_MPS2, dF, dGamma)


def cross_input_noise(
    sm: StepModel, sigma_mps2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(dQ, dR11, dM1)`` of an error e (sigma (n,)) in the centripetal input a_s: it
    drives delta through Gamma and enters y1 through U_y = u a_s, so
    Q += Gamma Gamma' s^2, R11 += u^2 s^2, M[:, 0] += Gamma u s^2."""
    var = sigma_mps2**2
    g = sm.Gamma[:, :, 0]
    dQ = np.einsum("ni,nj->nij", g, g) * var[:, None, None]
    return dQ, sm.u_gain**2 * var, g * (sm.u_gain * var)[:, None]


@dataclass(frozen=True)
class FilterInputs:
    """Per-step inputs of n filters over T steps of ``dt_s`` (NaN = not available).

    accel_signal_rad, amplifier_rad: (n, T) gyro signals (y1, y2).
    gyro_heading_rad: (n, T) heading indicated by the gyro, K_P = K + alpha.
    lat_rad: (n, T) latitude for Omega_H (any recent value).
    gnss_vel_east_mps, gnss_vel_north_mps: (n, T) GNSS velocity of a fix with quality
      >= 1 at the step (NaN: no such fix).
    log_speed_mps: (n, T) speed through water from the log (y3 in the emergency mode).
    emergency: (n, T) bool, no valid fix for longer than the mode timeout.
    """

    dt_s: float
    accel_signal_rad: np.ndarray
    amplifier_rad: np.ndarray
    gyro_heading_rad: np.ndarray
    lat_rad: np.ndarray
    gnss_vel_east_mps: np.ndarray
    gnss_vel_north_mps: np.ndarray
    log_speed_mps: np.ndarray
    emergency: np.ndarray


@dataclass(frozen=True)
class FilterOutputs:
    """Per-step estimates of n filters over T steps."""

    x: np.ndarray  # (n, T, 6) estimate after the update
    P_diag: np.ndarray  # (n, T, 6) diagonal of P after the update
    heading_rad: np.ndarray  # (n, T) corrected heading K_P - alpha^ (NaN: no gyro heading)
    w_observed: np.ndarray  # (n, T) W_o, y3 (NaN: none at the step)
    w_innovation: np.ndarray  # (n, T) W_o - W^-
    w_innovation_sigma: np.ndarray  # (n, T) sqrt(P66^- + sigma_w^2)
    gate_passed: np.ndarray  # (n, T) float: 1 passed, 0 rejected, NaN no fix at the step
    fix_accepted: np.ndarray  # (n, T) bool: a GNSS fix at the step passed the gate
    nis: np.ndarray  # (n, T) normalised innovation squared of the update (NaN: none)
    current: np.ndarray  # (n, T, 3) current east, north and log bias, m/s
    current_sigma: np.ndarray  # (n, T, 3) their sigmas
    current_cov: np.ndarray  # (n, T, 3, 3) their covariance


def initial_state(n: int, m: NavFilterModel) -> tuple[np.ndarray, np.ndarray]:
    """Zero state, diagonal prior with the stationary roll variance."""
    s, r = m.settings, m.roll
    x = np.zeros((n, N_STATE))
    sig = np.array(
        [
            s.prior_alpha_sigma_rad,
            s.prior_beta_sigma_rad,
            s.prior_delta_sigma_rad,
            np.sqrt(r.variance_rad2),
            np.sqrt(r.variance_rad2 * r.omega0_sq),
            s.prior_accel_sigma_mps2,
        ]
    )
    return x, np.broadcast_to(np.diag(sig**2), (n, N_STATE, N_STATE)).copy()


@dataclass
class _Carry:
    """What the loop carries between steps besides the estimates, per filter."""

    v_last: np.ndarray  # (n, 2) velocity of the last accepted fix, m/s
    t_last: np.ndarray  # (n,) its step index
    kp_prev: np.ndarray  # (n,) previous gyro heading
    log_prev: np.ndarray  # (n,) previous log speed
    speed: np.ndarray  # (n,) smoothed speed through water, m/s


def _heading_mid(x: np.ndarray, kp: np.ndarray, c: _Carry, dt: float,
                 k_a: float) -> np.ndarray:
    """Corrected heading K = K_P - alpha^ in the middle of the step (alpha changes by
    about -k_a delta dt over it). Without a gyro heading: the last GNSS track."""
    track = _z(np.arctan2(c.v_last[:, 0], c.v_last[:, 1]))
    turn = _z(_wrap(kp - c.kp_prev))
    d_alpha = -k_a * x[:, ID] * dt
    has = np.isfinite(kp)
    return np.where(has, kp - 0.5 * turn - (x[:, IA] + 0.5 * d_alpha), track)


def run_filter(
    inp: FilterInputs, m: NavFilterModel, cl: CurrentLogSettings | None = None
) -> FilterOutputs:
    """Run n filters over T steps (loop over time steps; each step is vectorised over n).

    Per step: heading K = K_P - alpha^ in the middle of the step (the GNSS track when
    there is no gyro heading); the GNSS acceleration is the velocity change since the
    last ACCEPTED fix, split along (W_o, y3) and across the heading; gate eq. 3 on W_o,
    and the same 3-sigma rule across the heading against the predicted centripetal
    acceleration; a rejected fix gives no y3 (W keeps its prediction) and is not used
    for later differences. In the emergency mode y3 is the log speed difference with
    the log's sigma (paper: same structure, other covariances). Without y1/y2 (no gyro
    signals logged) only y3 updates the state and alpha keeps its prior.

    The heading K = K_P - alpha is a function of the state, and so is the turn rate
    (see :func:`_step_prior`): the step is an extended Kalman filter in alpha, with the
    previous alpha carried as a cloned state so that a_s = V_w (dK_P - alpha_k +
    alpha_{k-1}) / dt is linear in the (augmented) state.
    """
    from pipeline.filters import current_log

    cl = cl or CurrentLogSettings()
    n, T = inp.accel_signal_rad.shape
    s, dt, k_a = m.settings, inp.dt_s, m.gyro.azimuth_gain_per_s
    x, P = initial_state(n, m)
    cur, Pc = current_log.initial(n, cl)
    out = {k: np.full((n, T), np.nan) for k in
           ("heading", "w_obs", "innov", "innov_sig", "gate", "nis")}
    out_x, out_p = np.full((n, T, N_STATE), np.nan), np.full((n, T, N_STATE), np.nan)
    out_c, out_cs = np.full((n, T, 3), np.nan), np.full((n, T, 3), np.nan)
    out_cc = np.full((n, T, 3, 3), np.nan)
    accepted = np.zeros((n, T), bool)
    c = _Carry(np.full((n, 2), np.nan), np.full(n, -1), np.full(n, np.nan), np.full(n, np.nan),
               np.full(n, np.nan))
    for k in range(T):  # time steps: sequential by nature
        kp = inp.gyro_heading_rad[:, k]
        K_mid = _heading_mid(x, kp, c, dt, k_a)
        sm = step_model(_z(inp.lat_rad[:, k]), K_mid, dt, m)
        cur, Pc = current_log.predict(cur, Pc, dt, cl)
        c.speed = c.speed + _z(sm.F[:, IW, IW] * x[:, IW]) * dt  # dV_w/dt = W
        Vw, sig_Vw = _z(c.speed), _speed_sigma(Pc, cur, c, s, cl)
        pr = _step_prior(x, P, sm, K_mid, kp, c.kp_prev, Vw, sig_Vw, dt, m)
        g = _gnss_step(inp, k, c, K_mid, pr.x[:, :N_STATE], pr.P[:, :N_STATE, :N_STATE],
                       pr.a_s, pr.sig_as, s)
        z = np.stack([inp.accel_signal_rad[:, k], inp.amplifier_rad[:, k], g.w_obs], axis=1)
        use = np.isfinite(z)
        use[:, :2] &= np.isfinite(kp)[:, None]
        use[:, 2] &= g.use_w  # a failed gate: no y3 (W stays as predicted)
        R = pr.R.copy()
        R[:, 2, 2] = g.sig_w**2
        X, PX, nis_k = kalman.update_masked(pr.x, pr.P, _z(z), pr.H, R, use, pr.M, pr.U)
        x, P = X[:, :N_STATE], PX[:, :N_STATE, :N_STATE]
        # turn rate over the step from the posterior of (alpha_k, alpha_{k-1})
        d_alpha = X[:, IA] - X[:, N_STATE]
        var_d = PX[:, IA, IA] + PX[:, N_STATE, N_STATE] - 2.0 * PX[:, IA, N_STATE]
        k_dot = pr.has_turn * (pr.dkp - d_alpha) / dt
        sig_kdot = np.sqrt(cl.turn_rate_sigma_radps**2 + np.maximum(var_d, 0.0) / dt**2)
        K_end = kp - x[:, IA]
        cur, Pc = current_log.update(
            cur, Pc, v_gnss=_z(g.v), heading_rad=_z(K_end),
            log_speed_mps=inp.log_speed_mps[:, k],
            cross_accel_mps2=np.where(g.first, np.nan, g.cross), turn_rate_radps=k_dot,
            turn_rate_sigma_radps=sig_kdot, dt_s=dt,
            use=g.fix_ok & np.isfinite(kp), st=cl)
        c.speed = _smooth_speed(
            c.speed, current_log.water_speed(cur, Pc, _z(g.v))[0],
            g.fix_ok & np.isfinite(kp), dt / s.speed_smoothing_s)
        c.v_last = np.where(g.fix_ok[:, None], g.v, c.v_last)
        c.t_last = np.where(g.fix_ok, k, c.t_last)
        c.kp_prev = kp
        c.log_prev = inp.log_speed_mps[:, k]
        out_x[:, k], out_p[:, k] = x, np.diagonal(P, axis1=1, axis2=2)
        out_c[:, k], out_cs[:, k] = cur, np.sqrt(np.diagonal(Pc, axis1=1, axis2=2))
        out_cc[:, k] = Pc
        out["nis"][:, k] = nis_k
        out["heading"][:, k] = np.where(np.isfinite(kp), np.mod(kp - x[:, IA], 2 * np.pi), np.nan)
        out["w_obs"][:, k] = np.where(g.has_w, g.w_obs, np.nan)
        out["innov"][:, k] = np.where(g.has_w, g.w_obs - pr.x[:, IW], np.nan)
        out["innov_sig"][:, k] = g.sig_gate
        out["gate"][:, k] = g.gate
        accepted[:, k] = g.fix_ok
    return FilterOutputs(out_x, out_p, out["heading"], out["w_obs"], out["innov"],
                         out["innov_sig"], out["gate"], accepted, out["nis"], out_c, out_cs, out_cc)


@dataclass(frozen=True)
class _Prior:
    """One step's augmented prior and measurement model (see :func:`_step_prior`)."""

    x: np.ndarray  # (n, 7) [x_k^-, alpha_{k-1}]
    P: np.ndarray  # (n, 7, 7)
    H: np.ndarray  # (n, 3, 7)
    R: np.ndarray  # (n, 3, 3)
    M: np.ndarray  # (n, 7, 3)
    U: np.ndarray  # (n, 3)
    a_s: np.ndarray  # (n,) predicted centripetal acceleration, m/s^2
    sig_as: np.ndarray  # (n,) its error beyond the state's share
    dkp: np.ndarray  # (n,) gyro heading change over the step (0 without headings)
    has_turn: np.ndarray  # (n,) float 1 when both headings exist


def _step_prior(x: np.ndarray, P: np.ndarray, sm: StepModel, K_mid: np.ndarray,
                kp: np.ndarray, kp_prev: np.ndarray, Vw: np.ndarray, sig_Vw: np.ndarray,
                dt: float, m: NavFilterModel) -> _Prior:
    """Prediction over one step, and eq. 2's rows, with the heading a function of the
    state (extended Kalman filter in alpha).

    Turn rate: K = K_P - alpha, so over the step K-dot = (dK_P - alpha_k + alpha_{k-1})
    / dt and a_s = V_w K-dot depends on alpha at both ends. alpha_{k-1} is cloned into
    the state (its 7th element; the clone shares the update, so a correction of the
    level of alpha is not read as a turn). With g = Gamma V_w / dt, the propagation
    x_k = F x_{k-1} + Gamma a_s + w solves to

    .. math:: N x_k = (F + g e_\\alpha^T) x_{k-1} + g\\, dK_P + w, \\qquad N = I + g e_\\alpha^T

    and U_y = u a_s gives y1 the rows -u V_w/dt on alpha_k and +u V_w/dt on the clone.

    Heading Jacobian: F, Gamma and y1 depend on K = K_P - alpha through a_N = W cos K +
    z phi-ddot sin K - a_s sin K. The mean is propagated with the estimated heading;
    the covariance and the gain use the derivatives with respect to alpha of the W and
    a_s terms: -(dF/dK x + dGamma/dK a_s) for the prediction and -dh1/dK for y1, with
    dh1/dK = -(W sin K + a_s cos K) / g at the prior. They carry what a speed change and
    a turn say about the heading error (ignoring them left the filter overconfident,
    NEES ~4 at 300-600 s, and slow to converge). The roll term's derivative is left
    out: see :func:`heading_derivative`.
    """
    n = x.shape[0]
    d = N_STATE
    has_turn = (np.isfinite(kp) & np.isfinite(kp_prev)).astype(float)
    dkp = has_turn * _z(_wrap(kp - kp_prev))
    gam = sm.Gamma[:, :, 0]
    g = gam * (has_turn * Vw / dt)[:, None]
    # N^-1 = I - g e_a' / (1 + g_a) (Sherman-Morrison)
    Ninv = np.broadcast_to(np.eye(d), (n, d, d)) - g[:, :, None] * (
        np.eye(d)[IA][None, None, :] / (1.0 + g[:, IA])[:, None, None])
    Fg = sm.F.copy()
    Fg[:, :, IA] += g
    Fp = Ninv @ Fg
    x_pred = np.einsum("nij,nj->ni", Fp, x) + np.einsum("nij,nj->ni", Ninv, g * dkp[:, None])
    a_s = has_turn * Vw * (dkp - x_pred[:, IA] + x[:, IA]) / dt
    k_dot = a_s / np.maximum(Vw, 1e-9)
    sig_as = np.hypot(sig_Vw * k_dot, m.settings.cross_accel_sigma_mps2)
    dQ, dR11, dM1 = cross_input_noise(sm, sig_as)
    # heading Jacobian of the propagation (K_mid = ... - alpha_{k-1})
    J = np.einsum("nij,nj->ni", sm.F_dheading, x) + sm.Gamma_dheading[:, :, 0] * a_s[:, None]
    Fj = Fp.copy()
    Fj[:, :, IA] -= np.einsum("nij,nj->ni", Ninv, J)
    Qp = Ninv @ (sm.Q + dQ) @ np.swapaxes(Ninv, 1, 2)
    P6 = Fj @ P @ np.swapaxes(Fj, 1, 2) + Qp
    cross = np.einsum("nij,nj->ni", Fj, P[:, :, IA])  # Cov(x_k, alpha_{k-1})
    PX = np.zeros((n, d + 1, d + 1))
    PX[:, :d, :d] = P6
    PX[:, :d, d] = PX[:, d, :d] = cross
    PX[:, d, d] = P[:, IA, IA]
    PX = 0.5 * (PX + np.swapaxes(PX, 1, 2))
    X = np.concatenate([x_pred, x[:, IA:IA + 1]], axis=1)
    H = np.zeros((n, 3, d + 1))
    H[:, :, :d] = sm.H
    U = np.zeros((n, 3))
    gain = sm.u_gain * has_turn * Vw / dt
    H[:, 0, IA] -= gain  # U_y = u a_s, a_s = V_w (dK_P - alpha_k + alpha_{k-1}) / dt
    H[:, 0, d] += gain
    U[:, 0] = gain * dkp
    # heading Jacobian of y1 (linearised at the prior: the innovation is unchanged)
    dh1 = (-np.sin(K_mid) * x_pred[:, IW] - np.cos(K_mid) * a_s) / G_MPS2  # d h1 / dK
    H[:, 0, IA] -= dh1  # d h1 / d alpha = -d h1 / dK
    U[:, 0] += dh1 * x_pred[:, IA]
    R = sm.R.copy()
    R[:, 0, 0] += dR11
    M = np.zeros((n, d + 1, 3))
    M6 = sm.M.copy()
    M6[:, :, 0] += dM1
    M[:, :d] = Ninv @ M6
    return _Prior(X, PX, H, R, M, U, a_s, sig_as, dkp, has_turn)


@dataclass(frozen=True)
class _GnssStep:
    """One step's GNSS decision (see :func:`_gnss_step`), arrays (n,) or (n, 2)."""

    v: np.ndarray  # velocity of the fix at the step (NaN: none)
    cross: np.ndarray  # acceleration across the heading since the last accepted fix
    w_obs: np.ndarray  # y3: W_o (GNSS) or the log speed difference (emergency)
    sig_w: np.ndarray  # sigma_w of y3
    sig_gate: np.ndarray  # sqrt(P66^- + sigma_w^2)
    first: np.ndarray  # the fix only restarts the differences
    fix_ok: np.ndarray  # the fix is accepted
    has_w: np.ndarray  # there is a y3 value
    use_w: np.ndarray  # y3 is used (present and through the gate)
    gate: np.ndarray  # float 1 passed / 0 rejected / NaN no fix (main mode)


def _gnss_step(inp: FilterInputs, k: int, c: _Carry, K_mid: np.ndarray, x_pred: np.ndarray,
               P_pred: np.ndarray, a_s_pred: np.ndarray, sig_as_pred: np.ndarray,
               s: FilterSettings) -> _GnssStep:
    """GNSS acceleration since the last accepted fix along (W_o) and across the
    heading, the eq. 3 gate |W_o - W^-| <= 3 sqrt(P66^- + sigma_w^2), and the same
    3-sigma rule across the heading against the predicted a_s."""
    dt = inp.dt_s
    v = np.stack([inp.gnss_vel_east_mps[:, k], inp.gnss_vel_north_mps[:, k]], axis=1)
    has_fix = np.isfinite(v).all(axis=1)
    gap = np.where(c.t_last >= 0, (k - c.t_last) * dt, np.nan)
    a = (v - c.v_last) / gap[:, None]
    along = a[:, 0] * np.sin(K_mid) + a[:, 1] * np.cos(K_mid)
    cross = a[:, 0] * np.cos(K_mid) - a[:, 1] * np.sin(K_mid)
    emergency = inp.emergency[:, k]
    log_acc = (inp.log_speed_mps[:, k] - c.log_prev) / dt
    w_obs = np.where(emergency, log_acc, np.where(has_fix, along, np.nan))
    sig_w = np.where(emergency, s.log_accel_sigma_mps2, s.gnss_accel_sigma_mps2)
    sig_gate = np.sqrt(P_pred[:, IW, IW] + sig_w**2)
    passed = np.abs(w_obs - x_pred[:, IW]) <= s.gate_n_sigma * sig_gate  # eq. 3
    cross_ok = np.abs(cross - a_s_pred) <= s.gate_n_sigma * np.hypot(sig_w, sig_as_pred)
    first = has_fix & ~(gap <= s.max_difference_gap_s)  # nothing recent to difference
    fix_ok = has_fix & ~emergency & ((passed & cross_ok) | first)
    has_w = np.isfinite(w_obs) & ~first
    use_w = has_w & np.where(emergency, passed, fix_ok)
    gate = np.where(has_fix & ~emergency, fix_ok.astype(float), np.nan)
    return _GnssStep(v, cross, w_obs, sig_w, sig_gate, first, fix_ok, has_w, use_w, gate)


def _smooth_speed(speed: np.ndarray, measured: np.ndarray, use: np.ndarray,
                  gain: float) -> np.ndarray:
    """Complementary filter of the speed through water: integrated W (done in the
    prediction) pulled towards |v_gnss - c| with ``gain`` = dt / tau per accepted fix,
    which averages the GNSS velocity error (correlated over ~15 s) over tau."""
    new = np.where(np.isfinite(speed), speed + gain * (measured - speed), measured)
    return np.where(use, new, speed)


def _speed_sigma(Pc: np.ndarray, cur: np.ndarray, c: _Carry, s: FilterSettings,
                 cl: CurrentLogSettings) -> np.ndarray:
    """Sigma of the smoothed speed through water: the current's share along the track
    and the GNSS velocity error left after smoothing over tau (sigma sqrt(2 tau_v / tau))."""
    from pipeline.filters import current_log

    _, sig_c = current_log.water_speed(cur, Pc, _z(c.v_last))
    ratio = min(1.0, 2.0 * cl.gnss_velocity_tau_s / s.speed_smoothing_s)
    return np.hypot(sig_c, cl.gnss_velocity_sigma_mps * np.sqrt(ratio))


def _z(a: np.ndarray) -> np.ndarray:
    """NaN -> 0 (np.nan_to_num is several times slower on the loop's small arrays)."""
    a = np.asarray(a, float)
    return np.where(np.isnan(a), 0.0, a)


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angle difference wrapped to [-pi, pi)."""
    return np.mod(a + np.pi, 2 * np.pi) - np.pi
