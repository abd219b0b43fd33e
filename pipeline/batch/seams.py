"""Joining the units of a window: system track ids stitched across every seam.

Guarantee kept here: **ids stitched.** A family with a ``join_units`` (maritime: system
track ids) gives each unit a *seam* (its rows near the unit's edges, ``unit_seam``);
the units of a window are joined in time order as they finish (:class:`Joiner`), each
unit's ids relabelled so that a ship keeps its system track id across the unit cut. The
join is a chain: a unit's relabelling depends on the units before it only through the
seam of the unit just before, relabelled, so units are finalised as soon as they and
their family's earlier units are done. The chain is led by the seam of the rows
committed just before the window (:func:`stored_before`, ``stitch_lookback_s``), so ids
continue across the window's leading edge as they do across unit seams.
:func:`trailing_digests` fingerprints the rows at a window's end, for the trailing edge
(:mod:`pipeline.batch.continuation`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator, Mapping, Sequence, Sized
from pathlib import Path
from typing import Any

import polars as pl

from pipeline.batch.summary import BatchSummary
from pipeline.batch.worker import FinalizeTask, SeamFile, UnitManifest
from pipeline.family import Family, Relabel, relabel
from pipeline.units import NS
from pipeline.warehouse.delta import read_table


class StoredOutputs(Mapping[str, pl.DataFrame]):
    """A family's committed outputs in ``[start_ns, end_ns)``, each table read from the
    warehouse when first looked up (the maritime seam reads one of eight tables)."""

    def __init__(self, warehouse: Path, names: tuple[str, ...], start_ns: int,
                 end_ns: int, site: str | None = None,
                 columns: Mapping[str, tuple[str, ...]] | None = None) -> None:
        self._warehouse, self._names, self._site = warehouse, names, site
        self._window = (start_ns, end_ns)
        self._columns = dict(columns or {})
        self._read: dict[str, pl.DataFrame] = {}

    def __getitem__(self, name: str) -> pl.DataFrame:
        if name not in self._names:
            raise KeyError(name)
        if name not in self._read:
            lo, hi = self._window
            cols = self._columns.get(name)
            self._read[name] = pl.from_arrow(read_table(
                self._warehouse, name, start_ns=lo, end_ns=hi, site=self._site,
                columns=list(cols) if cols else None))
        return self._read[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)


def stored_before(warehouse: Path, fam: Family, start_ns: int, site: str | None = None
                   ) -> Mapping[str, pl.DataFrame]:
    """``fam``'s committed outputs (of ``site``) in the ``stitch_lookback_s`` before
    ``start_ns``: the unit before the window as its ``join_units`` sees a unit (a
    pseudo-unit); tables are read when the family's ``unit_seam`` looks them up."""
    lo = start_ns - round(fam.stitch_lookback_s * NS)
    return StoredOutputs(warehouse, tuple(fam.outputs), lo, start_ns, site, fam.seam_columns)


def trailing_seams(warehouse: Path, fams: tuple[Family, ...], end_ns: int,
                    site: str | None) -> dict[str, Any]:
    """Per family with a ``join_units``, the ``unit_seam`` of its committed rows just
    before ``end_ns``: what the units after ``end_ns`` continued."""
    return {fam.name: fam.unit_seam(stored_before(warehouse, fam, end_ns, site))
            for fam in fams
            if fam.join_units is not None and fam.unit_seam is not None
            and fam.stitch_lookback_s}


def trailing_digests(warehouse: Path, fams: tuple[Family, ...], end_ns: int,
                      site: str | None) -> dict[str, str]:
    """:func:`seam_digest` of each :func:`trailing_seams`."""
    return {name: seam_digest(seam)
            for name, seam in trailing_seams(warehouse, fams, end_ns, site).items()}


def seam_digest(seam: Any) -> str:
    """sha256 of a seam's rows (a frame in any row order, or any value's repr)."""
    if isinstance(seam, pl.DataFrame):
        text = seam.sort(seam.columns).write_csv() if seam.height else ",".join(seam.columns)
    else:
        text = repr(seam)
    return hashlib.sha256(text.encode()).hexdigest()


def _has_rows(seam: Any) -> bool:
    """A seam with rows (a frame or any sized value; anything else counts as rows)."""
    return len(seam) > 0 if isinstance(seam, Sized) else seam is not None


class Seams(Sequence):
    """The seams given to a family's ``join_units``: a :class:`SeamFile` is read when
    its item is looked up (``join_units`` walks them in order)."""

    def __init__(self, items: list[Any]) -> None:
        self.items = items

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int) -> Any:  # type: ignore[override]
        item = self.items[i]
        return item.read() if isinstance(item, SeamFile) else item


class Joiner:
    """A family's units of a wave joined in time order as they finish (``join_units``):
    :meth:`ready` takes a finished unit and gives the :class:`FinalizeTask` of every unit
    that is now joined (it and the units after it that waited on it). A family without
    a ``join_units`` has nothing to relabel: each unit is finalised as soon as it is done,
    in any order.

    The join is a chain: a unit's relabelling depends on the units before it only through
    the seam of the unit just before, relabelled. So the join of ``[seam of the last
    joined unit, relabelled; seams of the units now done]`` gives the units now done the
    relabelling the join of every seam at once gives them. The chain is led by the seam
    of the rows committed just before the window (``stitch_lookback_s``)."""

    def __init__(self, fam: Family, starts: list[int], summary: BatchSummary,
                 warehouse: Path | None) -> None:
        self.fam, self.summary, self.warehouse = fam, summary, warehouse
        self.order = sorted(starts)
        self.joined = 0
        self.waiting: dict[int, UnitManifest] = {}
        self.last_seam: Any = None  # the seam the next unit continues (None: none)

    def ready(self, m: UnitManifest) -> list[FinalizeTask]:
        if self.fam.join_units is None:  # nothing to relabel: finalised as soon as done
            return [FinalizeTask(m, None)]
        self.waiting[m.start_ns] = m
        now: list[UnitManifest] = []
        while self.joined < len(self.order) and self.order[self.joined] in self.waiting:
            now.append(self.waiting.pop(self.order[self.joined]))
            self.joined += 1
        if not now:
            return []
        if self.joined == len(now):  # the first units of the window
            self.last_seam = self._lead()
        seams = [s for s in (self.last_seam,) if s is not None] + [u.seam for u in now]
        lead = len(seams) - len(now)
        maps = (self.fam.join_units(Seams(seams))[lead:] if len(seams) > 1
                else [None] * len(now))
        self.last_seam = relabelled_seam(now[-1].seam, maps[-1])
        return [FinalizeTask(u, mapping) for u, mapping in zip(now, maps, strict=True)]

    def _lead(self) -> Any:
        """The seam of the rows committed before the window, None when there are none."""
        fam = self.fam
        if fam.unit_seam is None or not fam.stitch_lookback_s or self.warehouse is None:
            return None
        seam = fam.unit_seam(stored_before(self.warehouse, fam, self.summary.start_ns,
                                            self.summary.site))
        return seam if _has_rows(seam) else None


def relabelled_seam(seam: Any, mapping: Relabel | None) -> Any:
    """A unit's seam with its relabelling applied. A :class:`SeamFile` is read now: the
    unit's finalisation, sent next, removes its staging folder."""
    frame = seam.read() if isinstance(seam, SeamFile) else seam
    if not mapping:
        return frame
    if not isinstance(frame, pl.DataFrame):
        raise TypeError(f"a seam to relabel must be a frame, not {type(frame).__name__}")
    return relabel(frame, mapping)
