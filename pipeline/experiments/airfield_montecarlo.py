"""Acceptance metrics of the airfield scenario and its seeded Monte Carlo.

One run = simulate (pure) -> the reports exactly as the decoder returns them from CAT010
/ JSON (the simulator rounds to the wire LSBs; the round trip is tested) -> common frame
-> fusion + integrity -> score against truth. Per injected fault (:class:`FaultConfig`):

- *flagged within 5 s*: at least half of the targets the faulty channel reported in the
  first ``DETECT_S`` seconds of the fault got η = 1 (a NIS or outage decision) in that
  time; also the share of those targets flagged and the median first-flag delay;
- the fused 95% horizontal error on the manoeuvring area during the fault.

Fault-free runs give the share of checks flagged (η = 1 among all decisions), which
should be q.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl

from pipeline.airfield.config import AirfieldConfig, FaultConfig
from pipeline.airfield.frames import sensor_rows, to_common_frame
from pipeline.airfield.fusion import ChannelModels, config_models, fuse_airfield
from pipeline.airfield.score import score
from pipeline.simulate.airfield import simulate_airfield
from pipeline.units import NS

DETECT_S = 5.0
MC_START_NS = 1_768_435_200 * NS
MC_DURATION_S = 600.0


def mc_faults(cfg: AirfieldConfig) -> tuple[FaultConfig, ...]:
    """The compressed fault schedule of a Monte Carlo run (600 s): SMR jamming ×10 at
    120 s, MLAT bias 30 m at 240 s, VASN dropout at 360 s, SMR jamming + MLAT bias at
    480 s; 60 s each."""
    smr = cfg.sensor_of_kind("smr").sensor_id
    mlat = cfg.sensor_of_kind("mlat").sensor_id
    vasn = cfg.sensor_of_kind("vasn").sensor_id
    return (
        FaultConfig("jam", smr, 120.0, 60.0),
        FaultConfig("bias", mlat, 240.0, 60.0),
        FaultConfig("dropout", vasn, 360.0, 60.0),
        FaultConfig("jam", smr, 480.0, 60.0),
        FaultConfig("bias", mlat, 480.0, 60.0, direction_rad=np.radians(200.0)),
    )


@dataclass(frozen=True, eq=False)
class RunResult:
    tracks: pl.DataFrame
    health: pl.DataFrame
    start_ns: int
    faults: tuple[FaultConfig, ...]


def run_scenario(
    cfg: AirfieldConfig,
    seed: int,
    *,
    duration_s: float = MC_DURATION_S,
    start_ns: int = MC_START_NS,
    models: ChannelModels | None = None,
) -> RunResult:
    """Simulate, fuse and score one run of ``cfg`` (its faults, its integrity settings)."""
    sc = simulate_airfield(cfg, start_ns=start_ns, duration_s=duration_s, seed=seed)
    obs = to_common_frame(sensor_rows(sc.reports, cfg), cfg)
    tracks, health = fuse_airfield(
        obs, cfg, models or config_models(cfg), start_ns=sc.start_ns, end_ns=sc.end_ns
    )
    tracks, health = score(tracks, health, sc.truth, cfg)
    return RunResult(tracks, health, sc.start_ns, tuple(cfg.faults))


def _t(df: pl.DataFrame, start_ns: int) -> pl.DataFrame:
    return df.with_columns(((pl.col("time_ns") - start_ns) // NS).cast(pl.Float64).alias("t_s"))


def _num(x: object) -> float:
    return float("nan") if x is None else float(x)


def fault_metrics(run: RunResult) -> pl.DataFrame:
    """One row per fault: detected, share of targets flagged within DETECT_S, median
    first-flag delay, fused p95 on the manoeuvring area during the fault."""
    h = _t(run.health, run.start_ns)
    tr = _t(run.tracks, run.start_ns)
    rows = []
    for f in run.faults:
        ch = h.filter(pl.col("channel") == f.sensor_id)
        early = ch.filter((pl.col("t_s") >= f.start_s) & (pl.col("t_s") < f.start_s + DETECT_S))
        per = early.group_by("track_id").agg((pl.col("eta") == 1).any().alias("hit"))
        flagged = (
            ch.filter((pl.col("t_s") >= f.start_s) & (pl.col("eta") == 1))
            .group_by("track_id")
            .agg((pl.col("t_s").min() - f.start_s).alias("delay"))
        )
        during = tr.filter(
            (pl.col("t_s") >= f.start_s)
            & (pl.col("t_s") < f.end_s)
            & (pl.col("area") == "manoeuvring")
        )
        share = float(per["hit"].mean()) if per.height else float("nan")
        rows.append(
            {
                "kind": f.kind,
                "sensor_id": f.sensor_id,
                "start_s": f.start_s,
                "targets": per.height,
                "flagged_share": share,
                "detected": bool(per.height and share >= 0.5),
                "median_delay_s": _num(
                    flagged.filter(pl.col("track_id").is_in(per["track_id"].to_list()))[
                        "delay"
                    ].median()
                ),
                "fused_p95_manoeuvring_m": _num(during["error_m"].quantile(0.95)),
                "fused_samples": during["error_m"].drop_nulls().len(),
            }
        )
    return pl.DataFrame(rows)


def false_alarm_share(run: RunResult) -> tuple[int, int]:
    """(flagged, decisions) over the NIS checks of a run (use fault-free runs)."""
    d = run.health.filter(pl.col("eta").is_not_null() & (pl.col("check") == "nis"))
    return int((d["eta"] == 1).sum()), d.height


def p95_by_area(run: RunResult) -> dict[str, float]:
    """Fused 95% error per area over the whole run."""
    g = (
        run.tracks.filter(pl.col("error_m").is_not_null())
        .group_by("area")
        .agg(pl.col("error_m").quantile(0.95))
    )
    return {a: float(v) for a, v in g.iter_rows() if a is not None}


def _fault_run(args: tuple[AirfieldConfig, int]) -> pl.DataFrame:
    cfg, seed = args
    return fault_metrics(run_scenario(cfg, seed)).with_columns(pl.lit(seed).alias("seed"))


def _clean_run(args: tuple[AirfieldConfig, int]) -> dict[str, float]:
    cfg, seed = args
    run = run_scenario(cfg, seed)
    flagged, decisions = false_alarm_share(run)
    return {
        "seed": seed,
        "flagged": flagged,
        "decisions": decisions,
        **{f"p95_{k}_m": v for k, v in p95_by_area(run).items()},
    }


def _map(fn, items: list, workers: int) -> list:
    if workers <= 1:
        return [fn(i) for i in items]
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    # spawn: forking a process that has started polars' thread pool can deadlock
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as ex:
        return list(ex.map(fn, items))


def monte_carlo_faults(cfg: AirfieldConfig, seeds: list[int], *, workers: int = 1) -> pl.DataFrame:
    """Per seed and injected fault (``cfg``'s faults): :func:`fault_metrics` rows."""
    return pl.concat(_map(_fault_run, [(cfg, s) for s in seeds], workers))


def monte_carlo_fault_free(
    cfg: AirfieldConfig, seeds: list[int], *, workers: int = 1
) -> pl.DataFrame:
    """Per seed of a fault-free run: flagged checks, decisions, fused p95 per area."""
    clean = cfg.with_faults(())
    return pl.DataFrame(_map(_clean_run, [(clean, s) for s in seeds], workers))
