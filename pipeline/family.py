"""The contract every sensor family exports to the batch.

A family (``pipeline.maritime``, ``pipeline.airfield``, ``pipeline.nav``,
``pipeline.gaps``) is one :class:`Family` value, listed in ``pipeline.families``:

- ``sections`` and ``parse_config``: the TOML sections it owns and the function
  ``parse_config(doc, core)`` that reads them from the
  :class:`~pipeline.configspec.Document` into the family's typed config object
  (``doc.read(SomeConfig, "section")``: types and ranges declared on the dataclass;
  cross-field problems via ``doc.problem``). It runs when the config file loads, for
  every command: a bad value is an exit-2 error at start, never a failed unit; ``core``
  is None when the core sections themselves are invalid;
- ``inputs(cfg)``: the tables its stage reads, each with the margins it needs around the
  window (:class:`TableInput`); the batch job reads exactly those;
- ``stage(inputs, window, cfg)``: a pure function of those tables, the window and the
  config, returning ``{table: frame}`` for the tables in ``outputs`` (plus ``rejects``;
  a name starting with ``_`` is for the family's ``unit_seam`` only, never committed);
- ``outputs``: the derived tables it owns (no other family writes them);
- ``unit_rows`` and ``unit_table``: units are also cut so that none reads more than about
  ``unit_rows`` rows of ``unit_table`` (counted per second from its time column): memory
  per worker bounded by data volume, not by a fixed hour;
- ``sorted_outputs``: the stage returns every frame sorted by its table's sort key (the
  batch then writes it as it is instead of sorting it);
- ``unit_s``: the work unit length (the window is cut at UTC multiples of it), or
  ``None`` for one unit per window (filters that need continuity);
- ``unit_seam`` and ``join_units``: how consecutive units join into the window's tables
  (e.g. system track ids stitched across unit seams), or ``None`` to concatenate. The
  worker keeps ``unit_seam(outputs)`` (e.g. the rows of a unit's first and last epochs;
  a frame is kept in the unit's staging folder); the driver gives the seams of a
  window's units, in time order, to ``join_units`` as a sequence that reads each seam
  when it is looked up; it returns per unit ``None`` or a :data:`Relabel` to apply to
  every output of that unit (the units' outputs themselves never travel to the driver).
  The join must be a chain, as the driver joins units as they finish: a unit's
  relabelling depends on the units before it only through the seam just before it,
  relabelled (a frame seam, relabelled with :func:`relabel`).
- ``stitch_lookback_s``: how far before a window the batch reads the family's committed
  outputs; their ``unit_seam`` leads the window's seams given to ``join_units`` (ids
  continue across the window's leading edge); 0: the window's units are joined alone.
  ``seam_columns``: the columns ``unit_seam`` reads of each table ({table: columns};
  a table not named: every column): those committed rows are read with these only (the
  maritime seam reads 4 of the 19 columns of 10 minutes of associations: ~6x less work).
- ``config_fields``: the fields of the core :class:`~pipeline.config.Config` its stage
  reads (besides its own sections): with them, the digest each committed unit records
  (``pipeline.batch.provenance``), so a config change re-batches exactly the families
  whose config changed.

Nothing here reads files: the job reads the inputs, runs the stage in a worker and
commits what it returns.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import polars as pl

from pipeline.config import Config
from pipeline.configspec import Document
from pipeline.units import NS


@dataclass(frozen=True)
class Window:
    """A half-open time window [start_ns, end_ns), int64 ns UTC."""

    start_ns: int
    end_ns: int

    def __post_init__(self) -> None:
        if self.end_ns <= self.start_ns:
            raise ValueError(f"empty window [{self.start_ns}, {self.end_ns})")


@dataclass(frozen=True)
class TableInput:
    """One table a stage reads: rows whose time lies in
    [start - before_s, end + after_s) of the unit's window, or every row
    (``whole_table``, e.g. stored calibrations); ``columns``: None = all."""

    table: str
    before_s: float = 0.0
    after_s: float = 0.0
    columns: tuple[str, ...] | None = None
    whole_table: bool = False
    sorted: bool = True
    """False: the stage does not need the rows in the table's sort order (saves a sort
    of every row read)."""

    def span_ns(self, window: Window) -> tuple[int, int]:
        return (window.start_ns - round(self.before_s * NS),
                window.end_ns + round(self.after_s * NS))


Inputs = Mapping[str, pl.DataFrame]
Outputs = dict[str, pl.DataFrame]
Stage = Callable[[Inputs, Window, Config], Outputs]
Relabel = Mapping[str, Mapping[Any, Any]]
"""{column: {old value: new value}} to apply to a unit's outputs (columns it lacks are
left alone)."""


def relabel(frame: pl.DataFrame, mapping: Relabel) -> pl.DataFrame:
    """Apply a :data:`Relabel` to ``frame``."""
    cols = [pl.col(c).replace(dict(m)) for c, m in mapping.items()
            if m and c in frame.columns]
    return frame.with_columns(cols) if cols and frame.height else frame


@dataclass(frozen=True)
class FamilyDeclaration:
    """What reading a warehouse's provenance needs of a family, without importing its
    stage (``surveil report`` and the audit name the config digests behind the rows):
    the core config fields its stage reads and the tables it writes. Declared in the
    family's config module; its ``Family`` takes both from there."""

    name: str
    config_fields: tuple[str, ...]
    outputs: tuple[str, ...]


@dataclass(frozen=True)
class Family:
    """A sensor family as the batch sees it (see the module docstring)."""

    name: str
    sections: tuple[str, ...]
    parse_config: Callable[[Document, Config | None], Any]
    inputs: Callable[[Config], tuple[TableInput, ...]]
    outputs: tuple[str, ...]
    stage: Stage
    unit_s: int | None = 3600
    unit_rows: int | None = None
    unit_table: str = ""
    sorted_outputs: bool = False
    unit_seam: Callable[[Outputs], Any] | None = None
    join_units: Callable[[Sequence[Any]], list[Relabel | None]] | None = None
    stitch_lookback_s: float = 0.0
    seam_columns: Mapping[str, tuple[str, ...]] | None = None
    config_fields: tuple[str, ...] = ("region", "radar_sites", "ais", "fairway_legs", "sectors")
