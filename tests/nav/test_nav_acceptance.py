"""Issue 5 §1 acceptance on the `ownship` scenario, through the real chain:
simulate -> zstd MCAP -> ingest (NMEA + JSON decoders) -> Delta warehouse -> batch
(family nav) -> DuckDB report nav_quality. Seeded; ~15 s."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from jobs.batch import run_batch
from jobs.simulate import run_simulate
from pipeline.experiments.ownship_montecarlo import run_montecarlo
from pipeline.ingest.driver import run_ingest
from pipeline.nav.config import ownship_config
from pipeline.reports import run_named_report
from pipeline.simulate.ownship import simulate_ownship
from pipeline.units import NS
from pipeline.warehouse.delta import read_table

START_NS = 1_768_435_200 * NS  # 2026-01-15T00:00:00Z
DURATION_S = 1800.0
SEED = 7


@dataclass(frozen=True)
class Run:
    warehouse: Path
    solution: pl.DataFrame
    outages: pl.DataFrame
    report: pl.DataFrame
    outlier_times_ns: np.ndarray


@pytest.fixture(scope="module")
def run(tmp_path_factory, cfg) -> Run:
    root = tmp_path_factory.mktemp("ownship")
    files = run_simulate("ownship", DURATION_S, SEED, root / "archive", cfg, start_ns=START_NS)
    wh = root / "warehouse"
    ingest = run_ingest(files, cfg, wh, executor="serial")
    assert ingest.exit_code == 0, ingest.render()
    assert ingest.rows["rejects"] == 0  # every sentence's checksum and field decoded
    end = START_NS + int(DURATION_S * NS)
    batch = run_batch(cfg, wh, start_ns=START_NS, end_ns=end, executor_kind="serial")
    assert batch.exit_code == 0, batch.render()
    report = pl.from_arrow(run_named_report(wh, "nav_quality", start_ns=START_NS, end_ns=end))
    # the injected outliers: the simulator is a pure function of (config, start, seed)
    sc = simulate_ownship(ownship_config(cfg).scenario, start_ns=START_NS,
                          duration_s=DURATION_S, seed=SEED)
    outliers = sc.gnss.filter(pl.col("is_outlier"))["time_ns"].to_numpy()
    return Run(wh, pl.from_arrow(read_table(wh, "nav_solution")),
               pl.from_arrow(read_table(wh, "nav_outages")), report, outliers)


def test_gyro_alone_exceeds_10_deg_while_integrated_heading_is_within_0_1_rms(run, cfg):
    s = run.solution
    assert s.height == DURATION_S - 1  # one row per 1-s step after the first sample
    gyro_max = np.degrees(s["gyro_heading_error_rad"].abs().max())
    conv = s.filter(pl.col("converged"))
    err = np.degrees(conv["heading_error_rad"].to_numpy())
    assert gyro_max > 10.0
    assert np.sqrt(np.mean(err**2)) <= 0.1
    assert np.abs(err).max() <= 0.3
    # the reported sigma is honest on the converged part: one seed's mean NEES of alpha
    # inside the 5-95 % range of seeds 1-50 (0.12-2.63; the heading error is correlated
    # over minutes, so one run's mean spreads widely: the 20- and 50-seed means below and
    # in tests/filters/test_gyro_gnss_log_montecarlo.py are the discriminating tests) ...
    nees = float(((conv["heading_error_rad"] / conv["sigma_heading_rad"]) ** 2).mean())
    assert 0.12 < nees < 2.63
    # ... and the warehouse's figure is the in-memory filter's on the same seed (0.394 vs
    # 0.385: the NMEA decimals): what the batch stores is what the filter computed
    mc = run_montecarlo(cfg, seeds=[SEED], duration_s=DURATION_S, executor="serial")
    assert nees == pytest.approx(mc["nees"][0], rel=0.05)


def test_heading_sigma_is_not_overconfident_while_converging(cfg):
    """Seeded Monte Carlo (seeds 1-20, 10 min each, one vectorised filter call, ~7 s): the
    mean NEES of alpha at 300-600 s. The filter before issue 21's fix (af555d9) was
    overconfident there: 3.42 on these seeds (docs/ownship.md §4: 2.1-2.6 at 300-540 s);
    now 0.61 (seeds 1-50: 0.43, standard error 0.075; per seed 0.08-1.9, 5-95 %). Its
    seed 7 gives 0.654 over the converged part: inside any honest one-seed bound."""
    mc = run_montecarlo(cfg, seeds=range(1, 21), duration_s=600.0, converged_s=300.0,
                        executor="serial")
    assert 0.3 < mc["nees"].mean() < 1.2


def test_every_injected_outlier_is_rejected_by_the_gate(run):
    assert run.outlier_times_ns.size == 6
    at = run.solution.filter(pl.col("time_ns").is_in(run.outlier_times_ns))
    assert at.height == 6
    assert at["gate"].to_list() == ["reject"] * 6
    assert (at["position_source"] == "dead_reckoning").all()
    # and most fixes pass: false alarms of a 3-sigma gate stay rare
    gates = run.solution["gate"].value_counts()
    n = dict(zip(gates["gate"].to_list(), gates["count"].to_list(), strict=True))
    assert n["reject"] - 6 < 0.03 * n["pass"]


def test_outages_are_found_and_dead_reckoning_stays_inside_its_bound(run):
    o = run.outages.sort("start_ns")
    assert o["kind"].to_list() == ["no_fix", "no_fix"]
    # fixes missing in (960, 990] and (1320, 1440] s: from the last fix to the first fix
    assert o["duration_s"].to_list() == [31.0, 121.0]
    assert (o["dr_error_reference"] == "truth").all()
    assert (o["dr_error_m"] < o["dr_bound_m"]).all()
    long = o.row(1, named=True)
    assert long["dr_distance_m"] == pytest.approx(121 * 9.0, rel=0.05)
    # in the emergency mode the solution is dead-reckoned, and its error stays inside
    # its own 3-sigma at every step
    em = run.solution.filter(pl.col("mode") == "emergency")
    assert em.height > 140
    assert (em["position_source"] == "dead_reckoning").all()
    assert (em["position_error_m"] < 3 * em["sigma_position_m"]).all()


def test_report_nav_quality_agrees_with_the_tables(run):
    r = run.report
    s = run.solution
    assert r["steps"].sum() == s.height
    assert r["gate_reject"].sum() == (s["gate"] == "reject").sum()
    assert r["outages"].sum() == 2 and r["outage_total_s"].sum() == pytest.approx(152.0)
    assert r["gyro_max_deg"].max() > 10.0
    conv = s.filter(pl.col("converged"))
    worst = np.degrees(conv["heading_error_rad"].abs().max())
    assert r["heading_max_deg"].max() == pytest.approx(worst, abs=1e-4)
    assert (r["worst_dr_error_to_bound"].drop_nulls() < 1.0).all()
    # a sector filter is a bound parameter, not pasted SQL
    one = pl.from_arrow(run_named_report(run.warehouse, "nav_quality", start_ns=START_NS,
                                         end_ns=START_NS + int(DURATION_S * NS),
                                         sector="approach_sw"))
    assert one["sector"].to_list() == ["approach_sw"]
