"""`surveil experiment ...`: the two-radar identification paper's simulation experiment,
run with the production association code.

Identification (the paper's experiment): two stationary targets, target 0 at the
origin and target 1 at (dx, dy) m, seen by two radars whose position errors are
independent, Gaussian, with sigma_x = sigma_y = sigma. Each trial draws the four reports
and asks whether the association pairs radar 1's report of target t with radar 2's
report of target t, for both targets ("correct identification"). Three estimates:

- ``probability_correct``: the batch association, ``associate_tracks`` of
  pipeline/maritime/associate.py, exactly as ``surveil batch`` runs it (every
  trial is one synchronised epoch; epochs are 60 s apart, beyond the track timeout, so
  trials do not share state). It includes the chi-square gate: a correct pair beyond
  the gate is not formed and the trial counts as wrong.
- ``hypothesis_test``: the paper's test as written (pipeline/maritime/hypothesis.py,
  least Sigma_k over H1..H4, eq. 12-16), no gate.
- ``closed_form``: an independent, separately coded value. With equal isotropic sigmas
  and the targets' vectors unknown (maximum likelihood), the right pairing wins iff
  (s + u) . (s + v) > 0 with s the separation and u, v independent N(0, 2 sigma^2 I)
  (u = difference of radar 1's two errors, v of radar 2's), so

  .. math:: P = E_U\\left[\\Phi\\left(\\frac{s \\cdot U}{\\sqrt 2\\, \\sigma |U|}\\right)\\right],
            \\qquad U \\sim N(s, 2 \\sigma^2 I)

  evaluated by Gauss-Hermite quadrature. It depends on |s| / sigma only, hence the same
  for separations along x and along y.

The interval is the Wilson score interval (95 %) of a binomial proportion.

Velocity (the paper's open question): the same two radars, the targets now moving at
``speed_mps`` with courses ``course_difference_deg`` apart; reports carry speed and
course with the configured sigmas of radar R1. Estimates: position-only hypothesis
test, position + velocity hypothesis test (d = 4), and the batch association twice:
as configured (``[association] velocity_cost``, by default the position + velocity
cost with the 4-dof gate) and with the position-only cost (2 dof), both with the
course/speed gates.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
import polars as pl
from scipy.special import ndtr

from pipeline.config import Config
from pipeline.errors import UsageError
from pipeline.maritime.associate import associate_tracks
from pipeline.maritime.config import maritime_config
from pipeline.maritime.hypothesis import hypothesis_sums, paper_hypotheses, state_vectors
from pipeline.units import NS

TRIAL_SPACING_S = 60
"""Epochs of the batch-association run are this far apart (> track_timeout_s)."""
Z95 = 1.959963984540054


@dataclass(frozen=True)
class Estimate:
    """A Monte Carlo proportion with its 95 % Wilson interval."""

    probability_correct: float
    ci_low: float
    ci_high: float
    correct: int
    trials: int


def wilson(correct: int, trials: int, z: float = Z95) -> Estimate:
    """Wilson score interval of ``correct`` successes in ``trials``."""
    if trials <= 0:
        raise UsageError("trials must be positive")
    p = correct / trials
    den = 1.0 + z * z / trials
    centre = (p + z * z / (2 * trials)) / den
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / den
    return Estimate(p, max(0.0, centre - half), min(1.0, centre + half), int(correct), trials)


def closed_form_probability(sigma_m: float, dx_m: float, dy_m: float, nodes: int = 96) -> float:
    """P[(s + u) . (s + v) > 0], u, v ~ N(0, 2 sigma^2 I) independent (see the module
    docstring), by 2-D Gauss-Hermite quadrature over u: coded without any association
    code, as an independent check."""
    s = math.hypot(dx_m, dy_m)
    z, w = np.polynomial.hermite_e.hermegauss(nodes)  # weight exp(-z^2/2)
    w = w / math.sqrt(2 * math.pi)
    zx, zy = np.meshgrid(z, z, indexing="ij")
    ux = s + math.sqrt(2.0) * sigma_m * zx
    uy = math.sqrt(2.0) * sigma_m * zy
    norm = np.hypot(ux, uy)
    # given U = s + u, (s + v) . U ~ N(s . U, 2 sigma^2 |U|^2)
    p = ndtr(s * ux / (math.sqrt(2.0) * sigma_m * np.where(norm > 0, norm, 1.0)))
    return float(np.einsum("i,j,ij->", w, w, p))


def _reports(rng: np.random.Generator, trials: int, sigma_m: float, dx_m: float, dy_m: float,
             ) -> np.ndarray:
    """(trials, radar, target, 2) noisy positions of target 0 at the origin and target 1
    at (dx, dy)."""
    truth = np.array([[0.0, 0.0], [dx_m, dy_m]])
    return truth[None, None] + sigma_m * rng.standard_normal((trials, 2, 2, 2))


def _hypothesis_correct(X: list[np.ndarray], P: list[np.ndarray]) -> np.ndarray:
    """Per trial: does the least-Sigma_k hypothesis pair the two radars' reports of the
    same target (report j of both radars is target j)?"""
    hyps = paper_hypotheses(2, 2)
    right = np.array([h.targets[0] == h.targets[1] for h in hyps])
    return right[np.argmin(hypothesis_sums(X, P, hyps), axis=-1)]


def _batch_correct(z: np.ndarray, var: np.ndarray, speed: np.ndarray, course: np.ndarray,
                   cfg: Config, velocity_cost: bool | None = None) -> np.ndarray:
    """Per trial: does ``associate_tracks`` put radar 1's and radar 2's report of each
    target in one system track (and the two targets in different ones)?

    ``z`` (trials, radar, target, 2) positions, ``var`` their variance per axis (m^2),
    ``speed``/``course`` (trials, radar, target); ``velocity_cost`` overrides the
    config's ``[association] velocity_cost`` (None: as configured)."""
    trials = z.shape[0]
    trial, radar, _target = (a.ravel() for a in np.meshgrid(
        np.arange(trials), np.arange(2), np.arange(2), indexing="ij"))
    site = cfg.radar_sites[0]
    synced = pl.DataFrame({
        "time_ns": trial.astype(np.int64) * TRIAL_SPACING_S * NS,
        "site_id": np.array(["R1", "R2"])[radar],
        "local_track_id": np.arange(trial.size, dtype=np.int64),
        "x_enu_m": z[..., 0].ravel(), "y_enu_m": z[..., 1].ravel(),
        "P_xx": np.full(trial.size, var), "P_yy": np.full(trial.size, var),
        "P_xy": np.zeros(trial.size),
        "course_rad": course.ravel(), "speed_mps": speed.ravel(),
        "sigma_course_rad": np.full(trial.size, site.sigma_course_rad),
        "sigma_speed_mps": np.full(trial.size, site.sigma_speed_mps),
    })
    association = maritime_config(cfg).association
    if velocity_cost is not None:
        association = replace(association, velocity_cost=velocity_cost)
    out = associate_tracks(synced, cfg=association).sort("local_track_id")
    sid = out["system_track_id"].to_numpy().reshape(trials, 2, 2)
    return (sid[:, 0, 0] == sid[:, 1, 0]) & (sid[:, 0, 1] == sid[:, 1, 1]) & (
        sid[:, 0, 0] != sid[:, 0, 1])


def _check(sigma_m: float, trials: int) -> None:
    if not sigma_m > 0:
        raise UsageError("--sigma must be positive")
    if trials <= 0:
        raise UsageError("--trials must be positive")


def identification_experiment(
    cfg: Config, *, sigma_m: float, dx_m: float, dy_m: float, trials: int, seed: int
) -> dict:
    """The paper's experiment (module docstring); a JSON-ready dict with at least
    probability_correct, ci_low, ci_high, trials."""
    _check(sigma_m, trials)
    rng = np.random.default_rng([seed, 1])
    z = _reports(rng, trials, sigma_m, dx_m, dy_m)
    P = np.broadcast_to(sigma_m**2 * np.eye(2), (trials, 2, 2, 2))
    hyp = _hypothesis_correct([z[:, 0], z[:, 1]], [P, P])
    still = np.zeros((trials, 2, 2))
    batch = _batch_correct(z, sigma_m**2, still, still, cfg)
    est = wilson(int(batch.sum()), trials)
    return {
        "experiment": "identification", "sigma_m": sigma_m, "dx_m": dx_m, "dy_m": dy_m,
        "seed": seed, **asdict(est),
        "hypothesis_test": asdict(wilson(int(hyp.sum()), trials)),
        "closed_form": closed_form_probability(sigma_m, dx_m, dy_m),
    }


def velocity_experiment(
    cfg: Config, *, sigma_m: float, dx_m: float, dy_m: float, speed_mps: float,
    course_difference_deg: float, trials: int, seed: int,
) -> dict:
    """Moving targets (module docstring): how much velocity raises the probability of
    correct identification. Target 0 sails north, target 1 ``course_difference_deg``
    to starboard of it, both at ``speed_mps``."""
    _check(sigma_m, trials)
    site = cfg.radar_sites[0]
    sv, sc = site.sigma_speed_mps, site.sigma_course_rad
    rng = np.random.default_rng([seed, 2])
    z = _reports(rng, trials, sigma_m, dx_m, dy_m)
    c_true = np.array([0.0, math.radians(course_difference_deg)])
    speed = np.abs(speed_mps + sv * rng.standard_normal((trials, 2, 2)))
    course = np.mod(c_true + sc * rng.standard_normal((trials, 2, 2)), 2 * np.pi)
    var = np.full((trials, 2), sigma_m**2)
    zero = np.zeros((trials, 2))
    pos_only, with_vel = [], []
    for r in range(2):  # per radar: (trials, 2 targets, d)
        Xp, Pp = state_vectors(z[:, r, :, 0], z[:, r, :, 1], var, var, zero)
        Xv, Pv = state_vectors(z[:, r, :, 0], z[:, r, :, 1], var, var, zero, speed[:, r],
                               course[:, r], np.full((trials, 2), sv), np.full((trials, 2), sc))
        pos_only.append((Xp, Pp))
        with_vel.append((Xv, Pv))
    hyp_pos = _hypothesis_correct([a for a, _ in pos_only], [b for _, b in pos_only])
    hyp_vel = _hypothesis_correct([a for a, _ in with_vel], [b for _, b in with_vel])
    batch = _batch_correct(z, sigma_m**2, speed, course, cfg)
    batch_pos = _batch_correct(z, sigma_m**2, speed, course, cfg, velocity_cost=False)
    return {
        "experiment": "velocity", "sigma_m": sigma_m, "dx_m": dx_m, "dy_m": dy_m,
        "speed_mps": speed_mps, "course_difference_deg": course_difference_deg,
        "sigma_speed_mps": sv, "sigma_course_deg": math.degrees(sc), "seed": seed,
        "trials": trials,
        "position_only": asdict(wilson(int(hyp_pos.sum()), trials)),
        "position_velocity": asdict(wilson(int(hyp_vel.sum()), trials)),
        "batch_association": asdict(wilson(int(batch.sum()), trials)),
        "batch_velocity_cost": maritime_config(cfg).association.velocity_cost,
        "batch_association_position_cost": asdict(wilson(int(batch_pos.sum()), trials)),
    }


def render(result: dict) -> str:
    """Human-readable lines of an experiment result."""
    def fmt(e: dict) -> str:
        return (f"{e['probability_correct']:.4f}  [{e['ci_low']:.4f}, {e['ci_high']:.4f}]  "
                f"({e['correct']}/{e['trials']})")

    if result["experiment"] == "identification":
        return "\n".join([
            f"identification: sigma {result['sigma_m']:g} m, separation "
            f"({result['dx_m']:g}, {result['dy_m']:g}) m, {result['trials']} trials, "
            f"seed {result['seed']}",
            f"  batch association (probability_correct)  {fmt(result)}",
            f"  paper's hypothesis test (eq. 16)          {fmt(result['hypothesis_test'])}",
            f"  closed form (independent)                 {result['closed_form']:.4f}",
        ])
    cost = "position + velocity" if result["batch_velocity_cost"] else "position"
    return "\n".join([
        f"velocity: sigma {result['sigma_m']:g} m, separation ({result['dx_m']:g}, "
        f"{result['dy_m']:g}) m, speed {result['speed_mps']:g} m/s, courses "
        f"{result['course_difference_deg']:g} deg apart, {result['trials']} trials, "
        f"seed {result['seed']}",
        f"  position only (eq. 16, d = 2)       {fmt(result['position_only'])}",
        f"  position + velocity (d = 4)         {fmt(result['position_velocity'])}",
        f"  batch association ({cost} cost, as configured)  "
        f"{fmt(result['batch_association'])}",
        f"  batch association (position cost)  {fmt(result['batch_association_position_cost'])}",
    ])
