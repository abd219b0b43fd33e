"""Seeded Monte Carlo of the own-ship heading (gyro/GNSS/log paper; issue 21 item 5).

For each seed: simulate the ``ownship`` scenario in memory (the paper's: speed-up to
9 m/s, a full turn in minutes 15-19, roll D = 0.12 rad^2, GNSS outliers and outages) and
run the filter of :mod:`pipeline.filters.gyro_gnss_log` on its samples. The seeds of a
work unit run as one vectorised call (n filters); units go to the executor (at most
``max_workers`` processes).

Scored per seed against truth, after convergence (t >= ``converged_s`` from the start,
the batch's ``[ownship] convergence_s``): RMS and max of the integrated heading error,
the same RMS before the turn, in the turn (and the minute after it) and after; the max
error of the gyro alone; the mean normalised squared heading error (NEES of alpha, ~1
when the filter's sigma is honest); GNSS outliers rejected by the gate and other fixes
rejected. The NMEA encoding, ingest and the batch's segmenting are skipped on purpose
(``tests/nav/test_nav_seed3.py`` runs the whole chain on one seed): this is the
measurement, repeated over seeds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl

from pipeline.config import Config
from pipeline.executors import make_executor
from pipeline.filters.gyro_gnss_log import IA, FilterInputs, run_filter
from pipeline.nav.config import ownship_config
from pipeline.simulate.ownship import OwnshipScenario, simulate_ownship

AFTER_TURN_S = 60.0  # the minute after the turn still counts as "turn"


def stack_inputs(scs: list[OwnshipScenario]) -> tuple[FilterInputs, dict[str, np.ndarray]]:
    """The scenarios' samples as the filter's (n, T) inputs (a fix of quality 0 puts the
    step in the emergency mode at once), and the truth: ``heading``, ``alpha`` (the
    gyro's own error), ``outlier`` (n, T)."""
    cols: dict[str, list[np.ndarray]] = {k: [] for k in (
        "acc", "amp", "kp", "lat", "ve", "vn", "log", "em", "heading", "alpha", "outlier")}
    for sc in scs:
        g = sc.gnss
        cols["acc"].append(sc.gyro_signals["accel_signal_rad"].to_numpy())
        cols["amp"].append(sc.gyro_signals["amplifier_rad"].to_numpy())
        cols["kp"].append(sc.gyro_heading["heading_rad"].to_numpy())
        cols["lat"].append(np.radians(g["lat_deg"].fill_null(strategy="forward").to_numpy()))
        cols["ve"].append((g["sog_mps"] * g["cog_rad"].sin()).fill_null(np.nan).to_numpy())
        cols["vn"].append((g["sog_mps"] * g["cog_rad"].cos()).fill_null(np.nan).to_numpy())
        cols["log"].append(sc.speed_log["speed_water_mps"].to_numpy())
        cols["em"].append(g["fix_quality"].to_numpy() == 0)
        cols["heading"].append(sc.truth["heading_rad"].to_numpy())
        cols["alpha"].append(sc.truth["gyro_error_rad"].to_numpy())
        cols["outlier"].append(g["is_outlier"].to_numpy())
    a = {k: np.stack(v) for k, v in cols.items()}
    inp = FilterInputs(1.0, a["acc"], a["amp"], a["kp"], a["lat"], a["ve"], a["vn"], a["log"],
                       a["em"])
    return inp, {k: a[k] for k in ("heading", "alpha", "outlier")}


@dataclass(frozen=True)
class McUnit:
    """Seeds run as one vectorised filter call (picklable)."""

    cfg: Config
    seeds: tuple[int, ...]
    duration_s: float
    converged_s: float


def run_unit(unit: McUnit) -> pl.DataFrame:
    """One row per seed of the unit (columns: see the module docstring)."""
    oc = ownship_config(unit.cfg)
    sc = oc.scenario
    scs = [simulate_ownship(sc, start_ns=0, duration_s=unit.duration_s, seed=s)
           for s in unit.seeds]
    inp, truth = stack_inputs(scs)
    out = run_filter(inp, oc.model, oc.current)
    t = np.arange(1, inp.accel_signal_rad.shape[1] + 1) * inp.dt_s  # sample times, s
    err = np.angle(np.exp(1j * (out.heading_rad - truth["heading"])))  # (n, T) rad
    sig = np.sqrt(out.P_diag[:, :, IA])
    conv = t >= unit.converged_s
    turn_end = sc.turn_start_s + sc.turn_duration_s + AFTER_TURN_S
    phases = {"before_turn": conv & (t < sc.turn_start_s),
              "turn": conv & (t >= sc.turn_start_s) & (t < turn_end),
              "after_turn": conv & (t >= turn_end)}
    deg = np.degrees
    rejected = out.gate_passed == 0
    fixes = np.isfinite(out.gate_passed)
    outlier = truth["outlier"]
    cols = {
        "seed": list(unit.seeds),
        "heading_rms_deg": deg(_rms(err[:, conv])),
        "heading_max_deg": deg(np.abs(err[:, conv]).max(axis=1)),
        "heading_max_at_s": t[conv][np.abs(err[:, conv]).argmax(axis=1)],
        **{f"rms_{k}_deg": deg(_rms(err[:, m])) if m.any() else np.full(len(scs), np.nan)
           for k, m in phases.items()},
        "error_at_converged_deg": deg(err[:, np.argmax(conv)]),
        "sigma_at_converged_deg": deg(sig[:, np.argmax(conv)]),
        "nees": np.mean((err[:, conv] / sig[:, conv]) ** 2, axis=1),
        "gyro_max_deg": deg(np.abs(truth["alpha"]).max(axis=1)),
        "outliers": outlier.sum(axis=1),
        "outliers_rejected": (rejected & outlier).sum(axis=1),
        "other_rejected": (rejected & ~outlier).sum(axis=1),
        "fixes": fixes.sum(axis=1),
    }
    return pl.DataFrame(cols).fill_nan(None)  # a phase outside the run: null


def _rms(e: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(e**2, axis=1))


def run_montecarlo(cfg: Config, *, seeds: range | list[int], duration_s: float = 1800.0,
                   converged_s: float | None = None, executor: str = "process") -> pl.DataFrame:
    """Per-seed table for ``seeds``, sorted by seed; raises if a unit fails. The seeds are
    dealt to ``min(max_workers, 2)`` units (each one vectorised call)."""
    conv = ownship_config(cfg).nav.convergence_s if converged_s is None else converged_s
    seeds = [int(s) for s in seeds]
    n_units = max(1, min(cfg.execution.max_workers, 2, len(seeds)))
    units = [McUnit(cfg, tuple(seeds[i::n_units]), float(duration_s), float(conv))
             for i in range(n_units)]
    ex = make_executor(executor, n_units, cfg.execution.threads_per_worker)
    frames = []
    for r in ex.map_units(run_unit, units):
        if not r.ok:
            raise RuntimeError(f"seeds {r.unit.seeds} failed: {r.error}")
        frames.append(r.value)
    return pl.concat(frames).sort("seed")


def summarise(table: pl.DataFrame, *, rms_goal_deg: float = 0.1,
              max_goal_deg: float = 0.3) -> pl.DataFrame:
    """One row: seeds, share and count of seeds with heading RMS <= ``rms_goal_deg``,
    median / max RMS, share with max <= ``max_goal_deg``, the largest max, the mean NEES,
    the smallest gyro-alone max, outliers rejected / injected, other rejections per fix."""
    return table.select(
        pl.len().alias("seeds"),
        (pl.col("heading_rms_deg") <= rms_goal_deg).mean().alias("share_rms_le_goal"),
        (pl.col("heading_rms_deg") > rms_goal_deg).sum().alias("seeds_rms_above_goal"),
        pl.col("heading_rms_deg").median().alias("rms_median_deg"),
        pl.col("heading_rms_deg").max().alias("rms_max_deg"),
        (pl.col("heading_max_deg") <= max_goal_deg).mean().alias("share_max_le_goal"),
        pl.col("heading_max_deg").max().alias("max_max_deg"),
        pl.col("nees").mean().alias("nees_mean"),
        pl.col("gyro_max_deg").min().alias("gyro_max_min_deg"),
        pl.col("outliers_rejected").sum().alias("outliers_rejected"),
        pl.col("outliers").sum().alias("outliers"),
        (pl.col("other_rejected").sum() / pl.col("fixes").sum()).alias("false_rejection_share"),
    )
