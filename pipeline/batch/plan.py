"""Planning a batch: the window a batch owns, its work units and their cuts.

Guarantee kept here: **exact reprocess.** Every committed unit is recorded in
``batch_units`` (family, start, end). A batch whose window overlaps committed units is
widened to cover them whole (:func:`owned_window`, repeated until no unit straddles an
edge), and each family's units inside are cut as a single pass cuts them
(:func:`unit_cuts`): at the family's unit grid (UTC hours) and inside each grid cell by
that *whole cell's* volume (``volume_cuts``, ~300k radar reports per unit); a family
without a grid (one unit per window) at the edges of its committed units. So a
reprocess of any sub-window re-runs exactly the units that own it, with the same
inputs, and replaces their rows: every table equals the single-pass result.

Families with one unit per window plan no unit where their inputs hold no row
(:func:`has_input_rows`), so they never own, nor widen a reprocess to, a window they
have nothing in; a unit recorded before this rule without input rows is ignored
(:func:`unit_is_live`). Families reading another family's output run in a later wave
(:func:`family_waves`: gaps after maritime). :func:`granted` gives a lone unit of a wave
the cores the others leave idle.
"""

from __future__ import annotations

import hashlib
import itertools
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import polars as pl

from pipeline import tables
from pipeline.batch.worker import BatchUnit
from pipeline.config import Config
from pipeline.families import FAMILIES
from pipeline.family import Family
from pipeline.units import NS
from pipeline.warehouse.delta import has_rows, read_table, rows_per_second, volume_cuts
from pipeline.warehouse.location import Location, as_location


def owned_window(warehouse: Path, start_ns: int, end_ns: int, site: str | None = None,
                 live: Callable[[str, int, int], bool] | None = None
                 ) -> tuple[int, int, dict[str, list[int]]]:
    """``[start_ns, end_ns)`` widened until no committed unit (``batch_units``, of
    ``site`` when given) of any family straddles its edges, and per family the edges of
    its committed units inside the widened window: (start, end, {family: cuts}).

    ``live(family, start, end)``: False for a committed unit that owns no rows now (a
    one-unit-per-window family's unit without input rows, as batches recorded before
    such units were skipped): it neither widens the window nor cuts it."""
    units = pl.from_arrow(read_table(warehouse, "batch_units",
                                     columns=["family", "start_ns", "end_ns"], site=site))
    dead: set[tuple[str, int, int]] = set()
    lo, hi = start_ns, end_ns
    while True:
        touched = units.filter((pl.col("start_ns") < hi) & (pl.col("end_ns") > lo))
        if live is not None:
            dead |= {u for u in touched.iter_rows() if u not in dead and not live(*u)}
            touched = touched.filter(~_keyed(touched, dead))
        if touched.height == 0:
            break
        new_lo = min(lo, int(touched["start_ns"].min()))
        new_hi = max(hi, int(touched["end_ns"].max()))
        if (new_lo, new_hi) == (lo, hi):
            break
        lo, hi = new_lo, new_hi
    inside = units.filter((pl.col("start_ns") >= lo) & (pl.col("end_ns") <= hi))
    inside = inside.filter(~_keyed(inside, dead))
    cuts: dict[str, list[int]] = {}
    for (name,), rows in inside.group_by(["family"]):
        edges = set(rows["start_ns"].to_list()) | set(rows["end_ns"].to_list())
        cuts[str(name)] = sorted(t for t in edges if lo < t < hi)
    return lo, hi, cuts


def _keyed(units: pl.DataFrame, keys: set[tuple[str, int, int]]) -> pl.Series:
    """Which rows of ``units`` (family, start_ns, end_ns) are in ``keys``."""
    return pl.Series([u in keys for u in units.iter_rows()], dtype=pl.Boolean)


def has_input_rows(warehouse: Path, fam: Family, cfg: Config, start_ns: int, end_ns: int,
                   site: str | None = None, derived: frozenset[str] = frozenset()) -> bool:
    """True when one of ``fam``'s input tables (``whole_table`` ones aside) holds a row
    of ``site`` in ``[start_ns, end_ns)``, or when it reads one of ``derived`` (another
    family's output, maybe written by this same batch: not known before it runs). Reads
    the time column of the window only (partitions and row groups pruned)."""
    for spec in fam.inputs(cfg):
        if spec.whole_table:
            continue
        if spec.table in derived:
            return True
        at = site if site is not None and tables.has_site(spec.table) else None
        if has_rows(warehouse, spec.table, start_ns, end_ns, at):
            return True
    return False


def unit_is_live(warehouse: Path, cfg: Config, site: str | None = None
                 ) -> Callable[[str, int, int], bool]:
    """``owned_window``'s ``live``: a committed unit of a one-unit-per-window family owns
    rows only while its inputs hold rows in its span (:func:`plan_units` plans no such
    unit otherwise); every other unit (and one of a family no longer registered) does."""
    owners = {f.name: f for f in FAMILIES}
    derived = frozenset(n for f in FAMILIES for n in f.outputs)

    def live(name: str, start_ns: int, end_ns: int) -> bool:
        fam = owners.get(name)
        return (fam is None or fam.unit_s is not None
                or has_input_rows(warehouse, fam, cfg, start_ns, end_ns, site, derived))

    return live


def plan_units(
    warehouse: Path | Location, cfg: Config, start_ns: int, end_ns: int,
    staging_dir: Path | Location,
    families: tuple[Family, ...] = FAMILIES,
    committed_cuts: dict[str, list[int]] | None = None,
    site: str | None = None,
) -> list[BatchUnit]:
    """Cut [start_ns, end_ns) into each family's work units (:func:`unit_cuts`), planned
    only where the family's inputs hold a row (:func:`has_input_rows`): per grid cell
    (hour) for a family with a grid, whose unit without input rows has no output rows
    either (an AIS-only archive plans no airfield unit; a day with two busy hours, two
    units); per piece for a family with one unit per window, whose needless unit would
    own, and a reprocess of any part of it would re-run, the whole window."""
    derived = frozenset(n for f in FAMILIES for n in f.outputs)
    where = as_location(warehouse)
    units = []
    for fam in families:
        kept = (committed_cuts or {}).get(fam.name, [])
        cuts = unit_cuts(warehouse, fam, start_ns, end_ns, kept, site)
        pieces = [(a, b) for a, b in itertools.pairwise(cuts) if b > a]
        if fam.unit_s is None:
            pieces = [(a, b) for a, b in pieces
                      if has_input_rows(warehouse, fam, cfg, a, b, site, derived)]
        else:
            step = fam.unit_s * NS
            cells = {a // step for a, _ in pieces}
            live = {c for c in cells if has_input_rows(warehouse, fam, cfg, max(c * step, start_ns),
                                                        min((c + 1) * step, end_ns), site, derived)}
            pieces = [(a, b) for a, b in pieces if a // step in live]
        units += [BatchUnit(where, where.at(staging_dir), a, b, cfg, fam.name, site=site)
                  for a, b in pieces]
    return units


def unit_cuts(warehouse: Path, fam: Family, start_ns: int, end_ns: int,
              kept: list[int], site: str | None = None) -> list[int]:
    """``fam``'s unit edges in [start_ns, end_ns), both ends included.

    A family with a ``unit_s`` grid is cut at its UTC multiples, and, with ``unit_rows``,
    inside each grid cell wherever the rows of its ``unit_table`` in the *whole cell*
    call for it (:func:`volume_cuts`, on whole seconds). So the cuts are a function of
    the cell's rows and the config, not of the window asked for nor of the files that
    hold the rows: a day batched at once, hour by hour or reprocessed over any
    sub-window (widened to the committed units it touches) is cut at the same times and
    its units see the same inputs. A family without a grid (one unit per window) is
    cut at ``kept``, the edges of its committed units (:func:`owned_window`), and by
    volume over the window."""
    if fam.unit_s is None:
        cuts = {start_ns, end_ns, *kept}
        cells = [(start_ns, end_ns)]
    else:
        step = fam.unit_s * NS
        cells = [(t, t + step) for t in range(start_ns // step * step, end_ns, step)]
        cuts = {start_ns, end_ns, *(a for a, _ in cells if a > start_ns)}
    if fam.unit_rows is not None and fam.unit_table:
        for a, b in cells:  # one cell's time column at a time
            per_s = rows_per_second(warehouse, fam.unit_table, a, b, site)
            cuts |= {c for c in volume_cuts(per_s, a, fam.unit_rows) if start_ns < c < end_ns}
    return sorted(cuts)


def family_waves(families: tuple[Family, ...], cfg: Config) -> list[list[Family]]:
    """The families in waves: a family that reads another family's output (gaps reads
    maritime's system_tracks) runs in a wave after it, on this batch's rows of it."""
    owner = {name: f.name for f in families for name in f.outputs}
    needs = {f.name: {owner[i.table] for i in f.inputs(cfg) if i.table in owner} - {f.name}
             for f in families}
    waves: list[list[Family]] = []
    done: set[str] = set()
    while len(done) < len(families):
        wave = [f for f in families if f.name not in done and needs[f.name] <= done]
        if not wave:
            raise ValueError(f"families read each other's outputs in a cycle: {needs}")
        waves.append(wave)
        done |= {f.name for f in wave}
    return waves


def granted(units: list[BatchUnit], kind: str, workers: int) -> list[BatchUnit]:
    """The units of a wave with the cores it leaves idle: a wave of fewer units than the
    process pool's workers (a reprocessed hour's one gaps unit after its maritime wave)
    gives each unit ``workers // len(units)`` times its ``threads_per_worker``, for a
    stage that runs its own threads (gaps). Not for Ray, whose tasks ask for one CPU."""
    if kind != "process" or not units or len(units) >= workers:
        return units
    share = workers // len(units)
    return [replace(u, cfg=replace(u.cfg, execution=replace(
        u.cfg.execution, threads_per_worker=u.cfg.execution.threads_per_worker * share)))
        for u in units]


def safe_name(site: str) -> str:
    """A site as a folder name part (any site name is a valid string, not a path)."""
    return hashlib.sha256(site.encode()).hexdigest()[:12]
