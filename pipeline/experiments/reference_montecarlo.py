"""Is the reconstructed reference honest? A seeded Monte Carlo of issue 37's acceptance.

One seed = the maritime ``channel`` scenario (the config's ``[[channel_faults]]`` unless
``clean``) and the ``airfield`` scenario (its ``[[airfield.faults]]``), each through its
family's production stage twice from the same simulated reports: once with the truth
table, once with it withheld (the stage then scores against the reconstructed
reference: ``pipeline.maritime.reference``, ``pipeline.airfield.reference``). The same
shipped SQL reports run on both outputs in DuckDB (``accuracy_by_sector``,
``detection_by_sector``, ``surface_accuracy_by_area``, ``surface_detection_by_area``),
and every figure is set beside its truth-based twin:

- accuracy: RMS and 95th percentile per sector (area) and per source (each radar or
  airfield channel, fused); within ``ACCURACY_TOLERANCE`` (10 %) relative;
- detection: PD per radar (all sectors, all classes) and per airfield channel; within
  ``PD_TOLERANCE`` (0.01) absolute.

Against truth every vessel is scored; against the reconstructed reference only the
vessels carrying AIS (the others have none): the comparison is of the figure a user
would read, not of the same points.
"""

from __future__ import annotations

from dataclasses import dataclass

import duckdb
import polars as pl

from pipeline.airfield.stage import airfield_stage
from pipeline.config import Config
from pipeline.executors import make_executor
from pipeline.experiments.channel_montecarlo import maritime_inputs
from pipeline.family import Window
from pipeline.maritime.config import without_faults
from pipeline.maritime.stage import stage as maritime_stage
from pipeline.reports import run_report
from pipeline.requirements import requirements_config
from pipeline.simulate import DEFAULT_START_NS
from pipeline.simulate.airfield import simulate_airfield
from pipeline.units import NS

ACCURACY_TOLERANCE = 0.10
PD_TOLERANCE = 0.01
MIN_SAMPLES = 100
"""Figures of fewer scored samples (either side) are listed but not judged."""


@dataclass(frozen=True)
class McUnit:
    """One seed (picklable)."""

    cfg: Config
    seed: int
    duration_s: float
    clean: bool = False
    start_ns: int = DEFAULT_START_NS
    scenes: tuple[str, ...] = ("maritime", "airfield")


def _con(frames: dict[str, pl.DataFrame]) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB whose views are the stage's tables (site 'default')."""
    con = duckdb.connect()
    con.execute("SET enable_progress_bar = false")
    for name, df in frames.items():
        t = df if "site" in df.columns else df.with_columns(pl.lit("default").alias("site"))
        con.register(name, t.to_arrow())
    return con


def _report(con: duckdb.DuckDBPyConnection, name: str, w: Window, cfg: Config) -> pl.DataFrame:
    return pl.from_arrow(run_report(con, name, start_ns=w.start_ns, end_ns=w.end_ns,
                                    requirements=requirements_config(cfg)))


def _maritime(unit: McUnit) -> list[dict]:
    cfg = without_faults(unit.cfg) if unit.clean else unit.cfg
    w = Window(unit.start_ns, unit.start_ns + round(unit.duration_s * NS))
    inputs, _ = maritime_inputs(cfg, unit.seed, unit.start_ns, unit.duration_s)
    out = {}
    for kind, tables in (("truth", inputs),
                         ("reference", {k: v for k, v in inputs.items() if k != "truth"})):
        o = maritime_stage(tables, w, cfg)
        con = _con({k: o[k] for k in ("track_errors", "radar_detection")})
        out[kind] = (_report(con, "accuracy_by_sector", w, cfg),
                     _report(con, "detection_by_sector", w, cfg))
    rows = []
    (acc_t, det_t), (acc_r, det_r) = out["truth"], out["reference"]
    for t in acc_t.iter_rows(named=True):
        r = acc_r.filter((pl.col("sector") == t["sector"]) & (pl.col("source") == t["source"]))
        r = r.row(0, named=True) if r.height else {}
        for metric, col in (("rms", "rms_error_m"), ("p95", "p95_error_m")):
            rows.append(_row("maritime", unit.seed, metric, t["sector"], t["source"], t[col],
                             r.get(col), t["samples"], r.get("samples"),
                             r.get("reference_p95_m")))
    pd_t = _pd_per_radar(det_t)
    pd_r = _pd_per_radar(det_r)
    for radar, (v, n) in pd_t.items():
        vr, nr = pd_r.get(radar, (None, 0))
        rows.append(_row("maritime", unit.seed, "pd", "(all sectors)", radar, v, vr, n, nr, None))
    return rows


def _pd_per_radar(det: pl.DataFrame) -> dict[str, tuple[float, int]]:
    d = det.filter(pl.col("target_class") == "(all classes)").group_by("radar").agg(
        pl.col("expected_scans").sum(), pl.col("missed_scans").sum())
    return {r["radar"]: (1.0 - r["missed_scans"] / r["expected_scans"], r["expected_scans"])
            for r in d.iter_rows(named=True) if r["expected_scans"]}


def _airfield(unit: McUnit) -> list[dict]:
    acfg = unit.cfg.family("airfield")
    if acfg is None:
        return []
    if unit.clean:
        acfg = acfg.with_faults(())
    sc = simulate_airfield(acfg, start_ns=unit.start_ns, duration_s=unit.duration_s,
                           seed=unit.seed)
    w = Window(sc.start_ns, sc.end_ns)
    models = pl.DataFrame(schema={"fit_start_ns": pl.Int64, "fit_end_ns": pl.Int64,
                                  "sensor_id": pl.String})
    out = {}
    for kind, truth in (("truth", sc.truth), ("reference", None)):
        o = airfield_stage(sc.reports, truth, models, acfg, start_ns=sc.start_ns,
                           end_ns=sc.end_ns)
        con = _con({"airfield_tracks": o.tracks, "channel_health": o.health})
        out[kind] = (_report(con, "surface_accuracy_by_area", w, unit.cfg),
                     _report(con, "surface_detection_by_area", w, unit.cfg))
    rows = []
    (acc_t, det_t), (acc_r, det_r) = out["truth"], out["reference"]
    for t in acc_t.filter(pl.col("reference") == "truth").iter_rows(named=True):
        r = acc_r.filter((pl.col("area") == t["area"]) & (pl.col("source") == t["source"])
                         & (pl.col("reference") == "reconstructed"))
        r = r.row(0, named=True) if r.height else {}
        for metric, col in (("rms", "rms_error_m"), ("p95", "p95_error_m")):
            rows.append(_row("airfield", unit.seed, metric, t["area"], t["source"], t[col],
                             r.get(col), t["scored"], r.get("scored"), r.get("reference_p95_m")))
    for src in det_t["source"].unique().to_list():
        def pd(d: pl.DataFrame, src: str = src) -> tuple[float | None, int]:
            x = d.filter(pl.col("source") == src).select(pl.col("expected_intervals").sum(),
                                                          pl.col("reported_intervals").sum())
            n, k = x.row(0)
            return (k / n if n else None), int(n or 0)
        (v, n), (vr, nr) = pd(det_t), pd(det_r)
        rows.append(_row("airfield", unit.seed, "pd", "(all areas)", src, v, vr, n, nr, None))
    return rows


def _row(scenario: str, seed: int, metric: str, scope: str, source: str, truth: float | None,
         ref: float | None, n_truth: int | None, n_ref: int | None,
         ref_p95: float | None) -> dict:
    judged = bool(n_truth and n_ref and n_truth >= MIN_SAMPLES and n_ref >= MIN_SAMPLES
                  and truth is not None and ref is not None)
    if metric == "pd":
        diff = None if not judged else ref - truth
        ok = None if not judged else abs(diff) <= PD_TOLERANCE
    else:
        diff = None if not judged or not truth else ref / truth - 1.0
        ok = None if diff is None else abs(diff) <= ACCURACY_TOLERANCE
    return {"scenario": scenario, "seed": seed, "metric": metric, "scope": scope,
            "source": source, "truth_value": truth, "reference_value": ref,
            "truth_samples": n_truth, "reference_samples": n_ref,
            "reference_own_p95_m": ref_p95, "difference": diff, "within_tolerance": ok}


def run_seed(unit: McUnit) -> pl.DataFrame:
    """Every figure of one seed, truth-based beside reference-based."""
    rows = (_maritime(unit) if "maritime" in unit.scenes else []) + (
        _airfield(unit) if "airfield" in unit.scenes else [])
    return pl.DataFrame(rows, infer_schema_length=None)


def run_montecarlo(cfg: Config, *, seeds: range | list[int], duration_s: float = 3600.0,
                   clean: bool = False, executor: str = "process",
                   scenes: tuple[str, ...] = ("maritime", "airfield")) -> pl.DataFrame:
    """Every seed's figures, concatenated; raises if a seed fails."""
    units = [McUnit(cfg, int(s), duration_s, clean, scenes=scenes) for s in seeds]
    ex = make_executor(executor, min(cfg.execution.max_workers, len(units)),
                       cfg.execution.threads_per_worker)
    parts = []
    for r in ex.map_units(run_seed, units):
        if not r.ok:
            raise RuntimeError(f"seed {r.unit.seed} failed: {r.error}")
        parts.append(r.value)
    return pl.concat(parts, how="diagonal_relaxed").sort("scenario", "metric", "scope",
                                                         "source", "seed")


def summarise(figures: pl.DataFrame) -> pl.DataFrame:
    """One row per (scenario, metric, scope, source): seeds judged, the truth-based and
    reference-based values (mean over seeds), the mean and the worst difference
    (relative for rms / p95, absolute for pd) and the share of seeds within tolerance."""
    judged = figures.filter(pl.col("within_tolerance").is_not_null())
    return judged.group_by("scenario", "metric", "scope", "source").agg(
        pl.len().alias("seeds"),
        pl.col("truth_value").mean().alias("truth_mean"),
        pl.col("reference_value").mean().alias("reference_mean"),
        pl.col("reference_own_p95_m").mean().alias("reference_own_p95_m"),
        pl.col("difference").mean().alias("mean_difference"),
        pl.col("difference").abs().max().alias("worst_abs_difference"),
        pl.col("within_tolerance").mean().alias("share_within"),
        (pl.col("reference_samples").sum() / pl.col("truth_samples").sum())
        .alias("scored_share"),
    ).sort("scenario", "metric", "scope", "source")
