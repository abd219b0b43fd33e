"""Batch job: every sensor family's derived tables for one time window.

A *batch family* (maritime radar + AIS here; own-ship navigation and airfield surface
surveillance plug in the same way) reads its inputs from the warehouse for a sub-window
and returns its derived tables. The window is cut into work units (family, sub-window:
one per UTC hour, or the whole window for families whose filters need continuity); each
unit writes its outputs as staged Parquet files under a deterministic name. Only when
every unit of the window has succeeded does the driver commit, one atomic Delta
overwrite per derived table whose predicate is the window; a failure or a crash before
that leaves the previous data of the window untouched.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow.parquet as pq

from jobs.batch_airfield import OUTPUTS as AIRFIELD_OUTPUTS
from jobs.batch_airfield import UNIT_S as AIRFIELD_UNIT_S
from jobs.batch_airfield import airfield_unit
from jobs.batch_gaps import OUTPUTS as GAPS_OUTPUTS
from jobs.batch_gaps import gaps_unit
from jobs.batch_nav import OUTPUTS as NAV_OUTPUTS
from jobs.batch_nav import nav_unit
from pipeline import tables
from pipeline.align import align_reports
from pipeline.associate.identity import identify
from pipeline.associate.stitch import relabel, stitch_track_ids
from pipeline.associate.track_to_track import associate_tracks
from pipeline.config import Config
from pipeline.cross_track_eval import cross_track_by_leg
from pipeline.executors import make_executor
from pipeline.fuse import fuse
from pipeline.geometry import add_geodetic, assign_sectors, cross_track
from pipeline.metrics.siap import siap_by_sector, siap_config
from pipeline.score import score_tracks
from pipeline.sync import epoch_grid, synchronise
from pipeline.warehouse.delta import read_table, replace_rows, replace_window
from pipeline.warehouse.views import rebuild_views_file, warm_up

log = logging.getLogger(__name__)

NS = 1_000_000_000
UNIT_S = 3600
DERIVED_TABLES = ("associations", "system_tracks", "identifications", "track_errors")
# maritime audit tables (docs/maritime.md): SIAP against truth, cross-track error per leg
AUDIT_TABLES = ("siap_by_sector", "cross_track_by_leg")


@dataclass(frozen=True)
class BatchInputs:
    radar_tracks: pl.DataFrame
    ais_reports: pl.DataFrame
    truth: pl.DataFrame | None


UnitCompute = Callable[[Path, Config, int, int], dict[str, pl.DataFrame]]
"""(warehouse, cfg, start_ns, end_ns) -> {table: frame}; reads its inputs by path."""


@dataclass(frozen=True)
class BatchFamily:
    """A sensor family's batch: the derived tables it owns and how one unit computes
    them. ``unit_s`` cuts the window at UTC multiples of it (None: one unit for the
    whole window). ``stitch`` relabels system track ids across unit seams. A unit may
    also return ``rejects`` rows (stage 'batch') logged inside its sub-window."""

    name: str
    outputs: tuple[str, ...]
    compute_unit: UnitCompute
    unit_s: int | None = UNIT_S
    stitch: bool = False


@dataclass(frozen=True)
class BatchUnit:
    """One picklable work unit: a family's sub-window, read and written by path."""

    warehouse: str
    staging_dir: str
    start_ns: int
    end_ns: int
    cfg: Config
    family: str = "maritime"


@dataclass
class BatchSummary:
    start_ns: int
    end_ns: int
    units_total: int = 0
    failed_units: list[str] = field(default_factory=list)
    rows: dict[str, int] = field(default_factory=dict)
    rejects: int = 0
    committed: bool = False

    @property
    def exit_code(self) -> int:
        return 0 if self.committed and not self.failed_units else 1

    def render(self) -> str:
        lines = [
            f"batch window [{_iso(self.start_ns)}, {_iso(self.end_ns)}): "
            f"{self.units_total} unit(s), {len(self.failed_units)} failed, "
            f"{'committed' if self.committed else 'NOT committed (previous data kept)'}"
        ]
        lines += [f"  {name:<16} {n:>9} rows" for name, n in self.rows.items()]
        if self.rejects:
            lines.append(f"  rejects (batch)  {self.rejects:>9} rows")
        lines += [f"  failed: {u}" for u in self.failed_units]
        return "\n".join(lines)


def batch_window(
    inputs: BatchInputs, *, start_ns: int, end_ns: int, cfg: Config
) -> dict[str, pl.DataFrame]:
    """Compose the pure batch stages for the epochs in [start_ns, end_ns).

    Returns frames for ``associations``, ``system_tracks``, ``identifications``,
    ``track_errors``, ``siap_by_sector`` (empty without truth), ``cross_track_by_leg``
    and batch ``rejects`` (reports from unknown sites).
    """
    aligned, unknown = align_reports(inputs.radar_tracks, cfg)
    epochs = epoch_grid(start_ns, end_ns, cfg.sync.epoch_period_s)
    synced = synchronise(aligned, epochs_ns=epochs, sync=cfg.sync)
    id_base = (start_ns // NS) * 10_000
    associated = associate_tracks(synced, cfg=cfg.association, id_base=id_base)
    fused = fuse(associated)
    fused = add_geodetic(fused, cfg.region)
    fused = assign_sectors(fused, cfg.sectors, cfg.region)
    fused = cross_track(fused, cfg.fairway_legs, cfg.region, cfg.max_cross_track_m)
    identifications, fused = identify(fused, inputs.ais_reports, cfg=cfg.ais, region=cfg.region)
    associated = assign_sectors(associated, cfg.sectors, cfg.region)
    errors = score_tracks(
        fused,
        associated,
        truth=inputs.truth,
        ais_reports=inputs.ais_reports,
        region=cfg.region,
        sectors=cfg.sectors,
    )
    associations = associated.with_columns(
        pl.col("P_xx").sqrt().alias("sigma_x_m"),
        pl.col("P_yy").sqrt().alias("sigma_y_m"),
        pl.col("P_xy").alias("cov_xy_m2"),
    )
    siap = siap_by_sector(
        fused, inputs.truth, epochs_ns=epochs, epoch_period_s=cfg.sync.epoch_period_s,
        region=cfg.region, sectors=cfg.sectors, cfg=siap_config(cfg), start_ns=start_ns,
        end_ns=end_ns,
    )
    cross = cross_track_by_leg(
        fused, associations, errors, legs=cfg.fairway_legs, region=cfg.region,
        sites=cfg.radar_sites,
    )
    return {
        "associations": associations,
        "system_tracks": fused,
        "identifications": identifications,
        "track_errors": errors,
        "siap_by_sector": siap,
        "cross_track_by_leg": cross,
        "rejects": _unknown_site_rejects(unknown, start_ns, end_ns),
    }


def _unknown_site_rejects(unknown: pl.DataFrame, start_ns: int, end_ns: int) -> pl.DataFrame:
    """Reports from sites missing in the config: rejects rows (those logged in the window)."""
    unknown = unknown.filter(pl.col("log_time_ns").is_between(start_ns, end_ns, closed="left"))
    if unknown.height == 0:
        return pl.DataFrame()
    return unknown.select(
        pl.col("log_time_ns"),
        pl.col("source_file"),
        pl.col("topic"),
        pl.lit("batch").alias("stage"),
        pl.lit("unknown_site").alias("reason_code"),
        (pl.lit("radar site not in config: ") + pl.col("site_id")).alias("reason"),
    )


def read_inputs(warehouse: Path, cfg: Config, start_ns: int, end_ns: int) -> BatchInputs:
    """Read a unit's inputs, with the margins the stages need before the window
    (one scan for synchronisation, the AIS report age for identification)."""
    # an epoch takes each radar's latest scan ending within one period before it, and a
    # scan's reports start one period before its end: two periods of margin, plus slack
    scan_margin_ns = int((2 * max(s.scan_period_s for s in cfg.radar_sites) + 1.0) * NS)
    ais_margin_ns = int(cfg.ais.max_report_age_s * NS)
    radar = read_table(warehouse, "radar_tracks", start_ns=start_ns - scan_margin_ns, end_ns=end_ns)
    ais = read_table(warehouse, "ais_reports", start_ns=start_ns - ais_margin_ns, end_ns=end_ns)
    truth = read_table(warehouse, "truth", start_ns=start_ns - 2 * NS, end_ns=end_ns + 2 * NS)
    return BatchInputs(
        radar_tracks=pl.from_arrow(radar),
        ais_reports=pl.from_arrow(ais),
        truth=pl.from_arrow(truth) if truth.num_rows else None,
    )


def maritime_unit(warehouse: Path, cfg: Config, start_ns: int, end_ns: int) -> dict:
    """Maritime family: radar + AIS association, fusion, identification, scoring."""
    inputs = read_inputs(warehouse, cfg, start_ns, end_ns)
    return batch_window(inputs, start_ns=start_ns, end_ns=end_ns, cfg=cfg)


MARITIME = BatchFamily("maritime", DERIVED_TABLES + AUDIT_TABLES, maritime_unit, stitch=True)

# airfield surface surveillance (jobs/batch_airfield.py; built here: BatchFamily lives here)
AIRFIELD = BatchFamily("airfield", AIRFIELD_OUTPUTS, airfield_unit, unit_s=AIRFIELD_UNIT_S)

# forecasts across data gaps (jobs/batch_gaps.py): one unit per window (filter continuity)
GAPS = BatchFamily("gaps", GAPS_OUTPUTS, gaps_unit, unit_s=None)

# Every family the batch runs; each family adds its own line.
NAV = BatchFamily("nav", NAV_OUTPUTS, nav_unit, unit_s=None)
FAMILIES: tuple[BatchFamily, ...] = (MARITIME, AIRFIELD, GAPS, NAV)


def family(name: str) -> BatchFamily:
    return next(f for f in FAMILIES if f.name == name)


@dataclass(frozen=True)
class UnitManifest:
    """What a worker staged: {table: parquet path} for one family's sub-window."""

    family: str
    start_ns: int
    files: dict[str, str]


def run_unit(unit: BatchUnit) -> UnitManifest:
    """Worker: read, compute, stage."""
    fam = family(unit.family)
    out = fam.compute_unit(Path(unit.warehouse), unit.cfg, unit.start_ns, unit.end_ns)
    unknown = set(out) - set(fam.outputs) - {"rejects"}
    if unknown:
        raise ValueError(f"family {fam.name} returned tables it does not own: {unknown}")
    manifest = {}
    for name, frame in out.items():
        if name == "rejects" and frame.height == 0:
            continue
        table = tables.conform(name, frame)
        path = Path(unit.staging_dir) / name / f"{unit.family}-{unit.start_ns}.parquet"
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        pq.write_table(table, tmp)
        tmp.replace(path)
        manifest[name] = str(path)
    return UnitManifest(unit.family, unit.start_ns, manifest)


def plan_units(
    warehouse: Path, cfg: Config, start_ns: int, end_ns: int, staging_dir: Path
) -> list[BatchUnit]:
    """Cut [start_ns, end_ns) into each family's work units (at UTC multiples of its
    ``unit_s``, or one unit for the whole window)."""
    units = []
    for fam in FAMILIES:
        if fam.unit_s is None:
            cuts = [start_ns, end_ns]
        else:
            step = fam.unit_s * NS
            cuts = [start_ns, *range((start_ns // step + 1) * step, end_ns, step), end_ns]
        units += [
            BatchUnit(str(warehouse), str(staging_dir), a, b, cfg, fam.name)
            for a, b in itertools.pairwise(cuts)
            if b > a
        ]
    return units


def run_batch(
    cfg: Config,
    warehouse: Path,
    *,
    start_ns: int,
    end_ns: int,
    executor_kind: str | None = None,
) -> BatchSummary:
    """Run the batch for [start_ns, end_ns) and commit it atomically per table."""
    if end_ns <= start_ns:
        raise ValueError("--to must be after --from")
    warm_up()  # the views file's DuckDB instance, built while the batch runs
    staging = warehouse / "_staging" / f"batch-{start_ns}-{end_ns}"
    shutil.rmtree(staging, ignore_errors=True)
    units = plan_units(warehouse, cfg, start_ns, end_ns, staging)
    summary = BatchSummary(start_ns=start_ns, end_ns=end_ns, units_total=len(units))
    ex = cfg.execution
    executor = make_executor(
        executor_kind or ex.executor, min(ex.max_workers, len(units)), ex.threads_per_worker
    )
    manifests = []
    for result in executor.map_units(run_unit, units):
        if result.ok:
            manifests.append(result.value)
        else:
            u = result.unit
            label = f"{u.family} [{_iso(u.start_ns)}, {_iso(u.end_ns)}): {result.error}"
            summary.failed_units.append(label)
            log.error("batch unit failed %s", label)
    if summary.failed_units:
        return summary
    _commit(warehouse, manifests, summary)
    shutil.rmtree(staging, ignore_errors=True)
    with contextlib.suppress(OSError):  # only when empty: another job may be staging
        (warehouse / "_staging").rmdir()
    rebuild_views_file(warehouse)
    return summary


def _commit(warehouse: Path, manifests: list[UnitManifest], summary: BatchSummary) -> None:
    """Stitch ids across unit seams, then one atomic overwrite per derived table whose
    predicate is the window. Only the driver commits."""
    for fam in FAMILIES:
        ours = sorted((m for m in manifests if m.family == fam.name), key=lambda m: m.start_ns)
        parts = {name: [pl.read_parquet(m.files[name]) for m in ours if name in m.files]
                 for name in fam.outputs}
        mapping = stitch_track_ids(parts.get("associations", [])) if fam.stitch else {}
        for name in fam.outputs:
            frames = [relabel(p, mapping) for p in parts[name]]
            table = tables.conform(name, pl.concat(frames) if frames else tables.empty(name))
            replace_window(
                warehouse, name, table, start_ns=summary.start_ns, end_ns=summary.end_ns
            )
            summary.rows[name] = table.num_rows
    frames = [pl.read_parquet(m.files["rejects"]) for m in manifests if "rejects" in m.files]
    rejects = tables.conform("rejects", pl.concat(frames) if frames else tables.empty("rejects"))
    replace_rows(
        warehouse,
        "rejects",
        rejects,
        predicate_sql=(
            f"stage = 'batch' AND log_time_ns >= {int(summary.start_ns)} "
            f"AND log_time_ns < {int(summary.end_ns)}"
        ),
    )
    summary.rejects = rejects.num_rows
    summary.committed = True


def _iso(t_ns: int) -> str:
    return str(np.datetime64(int(t_ns), "ns").astype("datetime64[s]")) + "Z"
