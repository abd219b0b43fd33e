"""Seeded Monte Carlo of the data-gap forecasts (issue 5, part 2 acceptance).

For each seed: simulate the ``gaps`` scenario in memory, decode its AIS sentences with
the ingest decoder (:func:`pipeline.decode.ais.decode_ais_sentences`), and run the
``gaps`` stage twice on the same inputs with the same random seed: with the exogenous
constraint (the config's admissible area) and without it. Every forecast with truth is
scored: is the true position inside the 90% region, how far is the particle mean from
it, what probability did the forecast give the zone the vessel was really in.

The archive and warehouse are skipped here on purpose (the same stage runs in
``surveil batch``; ``tests/simulate/test_gaps_scenario.py`` runs the whole chain):
this is the measurement, repeated over many seeds.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np
import polars as pl

from pipeline.config import Config
from pipeline.decode.ais import decode_ais_sentences
from pipeline.executors import make_executor
from pipeline.gaps.config import GapsConfig, gaps_config
from pipeline.gaps.forecast import forecast_gaps
from pipeline.simulate import DEFAULT_START_NS
from pipeline.simulate.gaps import simulate_gaps

LEAD_BANDS_S = (600.0, 1200.0, 1800.0, 2700.0)


@dataclass(frozen=True)
class McUnit:
    """One seed of the Monte Carlo (picklable)."""

    cfg: Config
    gaps: GapsConfig
    seed: int
    duration_s: float
    start_ns: int = DEFAULT_START_NS


def run_seed(unit: McUnit) -> pl.DataFrame:
    """Forecasts of one simulated run, with (``constrained`` true) and without the
    constraint, from the same inputs and the same random seed."""
    sc = simulate_gaps(unit.cfg, start_ns=unit.start_ns, duration_s=unit.duration_s, seed=unit.seed)
    s = sc.ais_sentences
    reports, _, _ = decode_ais_sentences(
        [x.encode() for x in s["sentence"].to_list()],
        s["log_time_ns"].to_numpy(),
        source_file="simulated",
        topic="/ais/nmea",
    )
    ais = pl.from_arrow(reports)
    end_ns = sc.end_ns
    out = []
    for constrained in (True, False):
        f = forecast_gaps(
            ais,
            None,
            sc.truth,
            cfg=unit.cfg,
            gaps_cfg=replace(unit.gaps, constrain=constrained),
            start_ns=unit.start_ns,
            end_ns=end_ns,
            data_end_ns=end_ns,
            rng=np.random.default_rng([unit.seed, 5]),
        )
        out.append(
            f.with_columns(
                pl.lit(unit.seed).alias("seed"), pl.lit(constrained).alias("constrained")
            )
        )
    return pl.concat(out)


def run_montecarlo(
    cfg: Config,
    *,
    seeds: range | list[int],
    duration_s: float,
    particles: int | None = None,
    executor: str = "process",
) -> pl.DataFrame:
    """All forecasts of all seeds (both variants), sorted; raises if a seed fails."""
    g = gaps_config(cfg)
    if particles is not None:
        g = replace(g, particles=int(particles))
    units = [McUnit(cfg, g, int(s), float(duration_s)) for s in seeds]
    ex = make_executor(
        executor, min(cfg.execution.max_workers, len(units)), cfg.execution.threads_per_worker
    )
    frames = []
    for r in ex.map_units(run_seed, units):
        if not r.ok:
            raise RuntimeError(f"seed {r.unit.seed} failed: {r.error}")
        frames.append(r.value)
    return pl.concat(frames).sort(["seed", "constrained", "mmsi", "gap_start_ns", "lead_s"])


def summarise(forecasts: pl.DataFrame, *, by_lead: bool = False) -> pl.DataFrame:
    """Scores of the forecasts with truth, per variant (and lead band): forecasts, gaps,
    share of truths inside the 90% region, error of the particle mean (mean, median, RMS,
    95th percentile), particle-averaged error, mean probability of the true zone, share
    where the most likely zone was the true one."""
    f = forecasts.filter(pl.col("reference") == "truth")
    keys = ["constrained"]
    if by_lead:
        f = f.with_columns(_lead_band().alias("lead_band"))
        keys = ["lead_band", "constrained"]
    return (
        f.group_by(keys)
        .agg(
            pl.len().alias("forecasts"),
            pl.struct("seed", "mmsi", "gap_start_ns").n_unique().alias("gaps"),
            pl.col("true_in_region").mean().alias("in_region90_share"),
            pl.col("error_m").mean().alias("error_mean_m"),
            pl.col("error_m").median().alias("error_median_m"),
            (pl.col("error_m") ** 2).mean().sqrt().alias("error_rms_m"),
            pl.col("error_m").quantile(0.95).alias("error_p95_m"),
            pl.col("expected_error_m").mean().alias("particle_error_mean_m"),
            pl.col("true_zone_probability").mean().alias("true_zone_p_mean"),
            (pl.col("most_likely_zone") == pl.col("true_zone")).mean().alias("zone_hit_share"),
        )
        .sort(keys, descending=[False] * (len(keys) - 1) + [True])
    )


def _lead_band() -> pl.Expr:
    edges = [0.0, *LEAD_BANDS_S]
    names = [f"{int(a // 60):02d}-{int(b // 60):02d} min" for a, b in itertools.pairwise(edges)]
    expr = pl.when(pl.col("lead_s") <= LEAD_BANDS_S[0]).then(pl.lit(names[0]))
    for edge, name in zip(LEAD_BANDS_S[1:], names[1:], strict=True):
        expr = expr.when(pl.col("lead_s") <= edge).then(pl.lit(name))
    return expr.otherwise(pl.lit(f"{int(LEAD_BANDS_S[-1] // 60)}+ min"))
