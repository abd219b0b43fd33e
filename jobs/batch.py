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
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pyarrow.parquet as pq

from pipeline import tables
from pipeline.config import Config
from pipeline.executors import make_executor
from pipeline.families import FAMILIES, family
from pipeline.family import Family, Window
from pipeline.units import NS
from pipeline.warehouse.delta import read_table, replace_rows, replace_window
from pipeline.warehouse.views import rebuild_views_file, warm_up

log = logging.getLogger(__name__)


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
    family_s: dict[str, float] = field(default_factory=dict)  # summed unit wall time
    commit_s: float = 0.0

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
        if self.family_s:
            lines.append("  time: " + ", ".join(f"{fam} {s:.1f} s" for fam, s in
                                                 self.family_s.items())
                         + f" (summed over units); commit {self.commit_s:.1f} s")
        if self.rejects:
            lines.append(f"  rejects (batch)  {self.rejects:>9} rows")
        lines += [f"  failed: {u}" for u in self.failed_units]
        return "\n".join(lines)


def read_inputs(fam: Family, warehouse: Path, cfg: Config, window: Window
                ) -> dict[str, pl.DataFrame]:
    """The tables ``fam``'s stage declares, each over its own span around ``window``."""
    out = {}
    for spec in fam.inputs(cfg):
        columns = list(spec.columns) if spec.columns else None
        if spec.whole_table:
            table = read_table(warehouse, spec.table, columns=columns)
        else:
            lo, hi = spec.span_ns(window)
            table = read_table(warehouse, spec.table, start_ns=lo, end_ns=hi, columns=columns)
        out[spec.table] = pl.from_arrow(table)
    return out


@dataclass(frozen=True)
class UnitManifest:
    """What a worker staged: {table: parquet path} for one family's sub-window."""

    family: str
    start_ns: int
    files: dict[str, str]
    elapsed_s: float = 0.0


def run_unit(unit: BatchUnit) -> UnitManifest:
    """Worker: read, compute, stage."""
    t0 = time.perf_counter()
    fam = family(unit.family)
    window = Window(unit.start_ns, unit.end_ns)
    out = fam.stage(read_inputs(fam, Path(unit.warehouse), unit.cfg, window), window, unit.cfg)
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
    return UnitManifest(unit.family, unit.start_ns, manifest, time.perf_counter() - t0)


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
    progress: Any = None,
) -> BatchSummary:
    """Run the batch for [start_ns, end_ns) and commit it atomically per table.
    ``progress``: the CLI's :class:`~jobs.progress.TerminalProgress` (or None)."""
    if end_ns <= start_ns:
        raise ValueError("--to must be after --from")
    warm_up(warehouse)  # the views file's DuckDB instance, built while the batch runs
    staging = warehouse / "_staging" / f"batch-{start_ns}-{end_ns}"
    shutil.rmtree(staging, ignore_errors=True)
    units = plan_units(warehouse, cfg, start_ns, end_ns, staging)
    summary = BatchSummary(start_ns=start_ns, end_ns=end_ns, units_total=len(units))
    ex = cfg.execution
    executor = make_executor(
        executor_kind or ex.executor, min(ex.max_workers, len(units)), ex.threads_per_worker
    )
    manifests = []
    if progress is not None:
        progress.batch_units(len(units))
    for result in executor.map_units(run_unit, units):
        if progress is not None:
            progress.batch_result(result)
        if result.ok:
            manifests.append(result.value)
            m = result.value
            summary.family_s[m.family] = summary.family_s.get(m.family, 0.0) + m.elapsed_s
        else:
            u = result.unit
            label = f"{u.family} [{_iso(u.start_ns)}, {_iso(u.end_ns)}): {result.error}"
            summary.failed_units.append(label)
            log.error("batch unit failed %s", label)
    if summary.failed_units:
        return summary
    t0 = time.perf_counter()
    _commit(warehouse, manifests, summary)
    summary.commit_s = time.perf_counter() - t0
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
        if fam.join_units is not None:
            parts = fam.join_units(parts)
        for name in fam.outputs:
            frames = parts[name]
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
