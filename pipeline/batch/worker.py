"""One batch work unit, as a worker runs it: read, compute, keep; later, write once.

Guarantee kept here: **a unit commits nothing and writes its outputs once.** A
:class:`BatchUnit` (a family's sub-window, small and picklable: the warehouse and the
staging folder as locations, :class:`~pipeline.warehouse.location.Location`, local
folders or object-store prefixes; never rows) is run by :func:`run_unit`: its inputs
read over each table's span around the unit (:func:`read_inputs`: a lead-in and a
look-ahead for the maritime family, this batch's staged rows of another family's output
inside the window), the family's pure ``stage`` over them, the outputs kept as Arrow IPC
files in the unit's staging folder with the family's seam (:class:`SeamFile`). Once the
unit is joined (:mod:`pipeline.batch.seams`), :func:`finalize_unit` writes it as the
tables' final Parquet data files, relabelled where the join asks. The manifest
(:class:`UnitManifest`) lists the files; only the driver commits them
(:mod:`pipeline.batch.commit`).
"""

from __future__ import annotations

import io
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import polars as pl
import pyarrow as pa

from pipeline import tables
from pipeline.config import Config
from pipeline.families import family
from pipeline.family import Family, Relabel, Window, relabel
from pipeline.time_sources import synthetic_expr
from pipeline.warehouse.delta import read_table
from pipeline.warehouse.location import Location, as_location
from pipeline.warehouse.staged import StagedFile, TableStager


@dataclass(frozen=True)
class BatchUnit:
    """One picklable work unit: a family's sub-window, read from the warehouse and
    written to the staging folder (a path or an ``s3://`` prefix, with the config's
    storage options)."""

    warehouse: str | Location
    staging_dir: str | Location
    start_ns: int
    end_ns: int
    cfg: Config
    family: str = "maritime"
    # {table: staged Parquet files}: this batch's rows of another family's output for
    # the whole window, read instead of the warehouse's rows inside the window
    overrides: tuple[tuple[str, tuple[str, ...]], ...] = ()
    window: tuple[int, int] | None = None  # the batch window the overrides cover
    site: str | None = None  # the site whose rows the unit reads (and stamps on its outputs)


@dataclass(frozen=True)
class UnitManifest:
    """What a worker staged: {table: data files ready to commit} for one family's
    sub-window, and the family's ``unit_seam`` of it (a frame stays in the unit's
    folder: :class:`SeamFile`)."""

    family: str
    start_ns: int
    files: dict[str, list]  # IPC paths after the unit, StagedFile after finalize_unit
    seam: Any = None
    staging_dir: str = ""
    elapsed_s: float = 0.0  # the unit's wall time (read, compute, IPC)
    site: str | None = None  # stamped on the outputs when they are staged
    warehouse: Location | None = None  # the storage its paths are on (None: local)

    def at(self, path: str) -> Location:
        """One of the manifest's paths on its storage."""
        return (self.warehouse or Location(".")).at(path)


@dataclass(frozen=True)
class SeamFile:
    """A unit's seam frame, kept in its staging folder until the window's units are
    joined. The driver holds a window's seams one pair at a time (:class:`Seams`), not
    all of them: a region day has 260 maritime units of ~8 MB of seam rows each (was
    2 GB of the driver's memory)."""

    path: str
    location: Location | None = None  # on object storage: where (None: a local path)

    @classmethod
    def write(cls, seam: pl.DataFrame, path: Path | Location) -> SeamFile:
        loc = as_location(path)
        if loc.is_local:
            seam.write_ipc(loc.uri, compression="lz4")
            return cls(loc.uri)
        buf = io.BytesIO()
        seam.write_ipc(buf, compression="lz4")
        loc.write_atomic(buf.getvalue())
        return cls(loc.uri, loc)

    def read(self) -> pl.DataFrame:
        if self.location is None:
            return pl.read_ipc(self.path)
        return pl.read_ipc(io.BytesIO(self.location.read_bytes()))


@dataclass(frozen=True)
class FinalizeTask:
    """Write a unit's outputs as the tables' Parquet data files, a
    :data:`~pipeline.family.Relabel` applied first (``None``: as they are)."""

    manifest: UnitManifest
    mapping: Relabel | None


def read_inputs(fam: Family, warehouse: Path | Location, cfg: Config, window: Window,
                overrides: dict[str, tuple[str, ...]] | None = None,
                batch_window: tuple[int, int] | None = None,
                site: str | None = None) -> dict[str, pl.DataFrame]:
    """The tables ``fam``'s stage declares, each over its own span around ``window``. A
    table in ``overrides`` (another family's output of this same batch) is read from
    those files inside ``batch_window`` and from the warehouse outside it. ``site``: that
    site's rows only (the stage sees one site: its ids are unique)."""
    out = {}
    for spec in fam.inputs(cfg):
        columns = list(spec.columns) if spec.columns else None
        at = site if site is not None and tables.has_site(spec.table) else None
        if overrides and spec.table in overrides and batch_window is not None:
            lo, hi = (None, None) if spec.whole_table else spec.span_ns(window)
            out[spec.table] = _overridden(warehouse, spec.table, overrides[spec.table],
                                          batch_window, lo, hi, columns, at)
            continue
        timed = TIME_SOURCE in tables.spec(spec.table).schema.names
        if timed and columns is not None and TIME_SOURCE not in columns:
            columns = [*columns, TIME_SOURCE]
        if spec.whole_table:
            table = read_table(warehouse, spec.table, columns=columns, sort=spec.sorted,
                               site=at)
        else:
            lo, hi = spec.span_ns(window)
            table = read_table(warehouse, spec.table, start_ns=lo, end_ns=hi, columns=columns,
                               sort=spec.sorted, site=at)
        frame = pl.from_arrow(table)
        if timed and TIME_SOURCE in frame.columns:  # synthetic times: never batch input
            frame = frame.filter(~synthetic_expr(TIME_SOURCE))
            if spec.columns and TIME_SOURCE not in spec.columns:
                frame = frame.drop(TIME_SOURCE)
        out[spec.table] = frame
    return out


TIME_SOURCE = "time_source"
"""Rows whose ``time_source`` is synthetic (:func:`pipeline.time_sources.is_synthetic`:
a file without any time, 1970-01-01 + 1 ms per line) are no family's input: no
association, identity or integrity decision is made on reports 1 ms apart."""


def _overridden(warehouse: Path | Location, name: str, paths: tuple[str, ...],
                batch_window: tuple[int, int],
                lo: int | None, hi: int | None, columns: list[str] | None,
                site: str | None = None) -> pl.DataFrame:
    """Rows of ``name`` in [lo, hi): this batch's (``paths``: one site's) inside
    ``batch_window``, the warehouse's (of ``site``) outside it, sorted by the table's
    sort key."""
    w_lo, w_hi = batch_window
    time_col = tables.spec(name).time_column
    parts = []  # in time order: before the batch window, in it, after it
    if lo is None or lo < w_lo:  # the warehouse's rows before the batch window
        parts.append(pl.from_arrow(read_table(warehouse, name, start_ns=lo, end_ns=w_lo,
                                              columns=columns, site=site)))
    keep = pl.lit(True)
    if lo is not None:
        keep = keep & (pl.col(time_col) >= max(lo, w_lo))
    if hi is not None:
        keep = keep & (pl.col(time_col) < min(hi, w_hi))
    # the staged files of the whole batch, pruned by their row groups' time statistics:
    # an hourly unit of a day's batch reads its hour, not the day (was: read whole, 2+ GB)
    loc = as_location(warehouse)
    options = {"storage_options": _polars_options(loc)} if not loc.is_local else {}
    mine = (pl.scan_parquet(list(paths), **options).filter(keep).select(columns or pl.all())
            .collect() if paths else pl.from_arrow(tables.empty(name)).select(columns or pl.all()))
    parts.append(mine)
    if hi is None or hi > w_hi:  # and the warehouse's after it
        parts.append(pl.from_arrow(read_table(warehouse, name, start_ns=w_hi, end_ns=hi,
                                              columns=columns, site=site)))
    frame = pl.concat([p for p in parts if p.width], how="vertical_relaxed")
    keys = [k for k in tables.spec(name).sort_by if k in frame.columns]
    # the parts are in time order and each unit's files sorted by the key (a stage's
    # contract), so the rows usually are already: a sort would copy them all (a gaps
    # unit of a dense hour: ~0.85 GB more RSS for its 4 M system-track rows)
    return frame if not keys or is_sorted_by(frame, keys) else frame.sort(keys)


def _polars_options(loc: Location) -> dict[str, str]:
    """The location's storage options polars' object store takes (its S3 client's keys:
    deltalake's, without delta-rs's own)."""
    return {k: v for k, v in loc.storage_options.items()
            if k not in ("aws_conditional_put", "aws_s3_locking_provider",
                         "aws_s3_allow_unsafe_rename")}


def is_sorted_by(frame: pl.DataFrame, keys: list[str]) -> bool:
    """Whether the rows are in ascending lexicographic order of ``keys`` (no nulls)."""
    if frame.height < 2:
        return True
    if frame.select(pl.any_horizontal(pl.col(keys).is_null().any())).item():
        return False
    later = pl.lit(False)  # the row is after the previous one on the keys seen so far
    tie = pl.lit(True)
    for k in keys:
        later = later | (tie & (pl.col(k) > pl.col(k).shift(1)))
        tie = tie & (pl.col(k) == pl.col(k).shift(1))
    return bool(frame.select((later | tie).slice(1).all()).item())


def run_unit(unit: BatchUnit) -> UnitManifest:
    """Worker: read, compute, keep the outputs as Arrow IPC files (lz4: cheap to write and
    to read back) until the window's units are joined; return the manifest. The stage
    returns its frames sorted by the tables' sort keys (its contract)."""
    t0 = time.perf_counter()
    fam = family(unit.family)
    window = Window(unit.start_ns, unit.end_ns)
    warehouse = as_location(unit.warehouse)
    inputs = read_inputs(fam, warehouse, unit.cfg, window, dict(unit.overrides),
                         unit.window, unit.site)
    out = fam.stage(inputs, window, unit.cfg)
    seam = fam.unit_seam(out) if fam.unit_seam is not None else None
    out = {name: frame for name, frame in out.items() if not name.startswith("_")}
    unknown = set(out) - set(fam.outputs) - {"rejects"}
    if unknown:
        raise ValueError(f"family {fam.name} returned tables it does not own: {unknown}")
    folder = warehouse.at(unit.staging_dir) / f"{unit.family}-{unit.start_ns}"
    folder.rmtree()
    folder.mkdir()
    if isinstance(seam, pl.DataFrame):
        seam = SeamFile.write(seam, folder / "_seam.arrow")
    files: dict[str, list[str]] = {}
    for name, frame in out.items():
        if frame.height:
            ordered = fam.sorted_outputs and name != "rejects"
            table = tables.shape(name, frame) if ordered else tables.conform(name, frame)
            path = folder / f"{name}.arrow"
            options = pa.ipc.IpcWriteOptions(compression="lz4")
            with path.open_output() as sink, pa.ipc.new_file(
                sink, table.schema, options=options
            ) as w:
                w.write_table(table)
            files[name] = [str(path)]
    return UnitManifest(unit.family, unit.start_ns, files, seam, str(folder),
                        time.perf_counter() - t0, unit.site, warehouse)


def finalize_unit(task: FinalizeTask) -> UnitManifest:
    """Worker: a unit's outputs (Arrow IPC) relabelled if its family's join asks for it
    and written once as final Parquet data files (``TableStager``: sorted row groups,
    Delta statistics); the manifest then lists those files."""
    m = task.manifest
    folder = m.at(m.staging_dir + "-parquet")
    folder.rmtree()
    stager = TableStager(folder, threaded=False, presorted=True,
                         site=m.site if m.site is not None else tables.default_site())
    for name, paths in m.files.items():
        for path in paths:
            with m.at(path).open_input() as source:
                table = pa.ipc.open_file(source).read_all()
            if task.mapping:
                table = tables.shape(name, relabel(pl.from_arrow(table), task.mapping))
            stager.add(name, table)
            del table
    files: dict[str, list[StagedFile]] = {}
    for f in stager.close():
        files.setdefault(f.table, []).append(f)
    m.at(m.staging_dir).rmtree()
    return UnitManifest(m.family, m.start_ns, files, m.seam, str(folder), m.elapsed_s,
                        m.site, m.warehouse)


def batch_task(task: BatchUnit | FinalizeTask) -> UnitManifest:
    """Worker: a batch unit (:func:`run_unit`) or a unit's finalisation
    (:func:`finalize_unit`), the two kinds of task of a wave's one map."""
    return finalize_unit(task) if isinstance(task, FinalizeTask) else run_unit(task)
