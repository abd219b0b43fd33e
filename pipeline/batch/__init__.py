"""Batch: raw tables of a window -> every sensor family's derived tables, committed once.

The batch kernel, beside the ingest kernel (:mod:`pipeline.ingest`): it runs the
families' pure stages (:mod:`pipeline.families`) over work units and commits their
outputs; ``jobs/batch.py``, ``jobs/reprocess.py`` and the CLI only call it and print;
:mod:`~pipeline.batch.nightly` is ``surveil run`` (scan, import, ingest, batch what is
pending). Each guarantee is kept in one module:

- :mod:`~pipeline.batch.window`: a window bounded before any work (clipped to the data
  the ledger knows; refused, exit 2, when too long or too big for the memory budget);
- :mod:`~pipeline.batch.plan`: **exact reprocess**: the window widened to the committed
  units it overlaps and cut as a single pass cuts it (hours, volume cuts), so a
  reprocess of any sub-window re-runs exactly the units that own it;
- :mod:`~pipeline.batch.worker`: one work unit (:class:`BatchUnit`, picklable, read and
  written by path) -> Arrow IPC outputs and a seam; later its final Parquet files. A
  worker commits nothing;
- :mod:`~pipeline.batch.seams`: **ids stitched**: units joined in time order as they
  finish, system track ids relabelled across unit seams and the window's leading edge;
- :mod:`~pipeline.batch.continuation`: **ids continue across the trailing edge**: the
  units after a window batched again when its end changed, a promise recorded before
  the commit so a killed job's chain is finished by the next batch;
- :mod:`~pipeline.batch.commit`: **one window, one commit**: one Delta transaction per
  derived table, by the driver alone, between a pending marker and its removal;
- :mod:`~pipeline.batch.place`: **the config describes the recordings' place**: each
  site's positions against the region, refused (exit 2) before any work when most lie
  outside it;
- :mod:`~pipeline.batch.provenance`: **which config computed the rows**: each committed
  unit's config digest, the windows of another config, what reports name;
- :mod:`~pipeline.batch.pending`: what a nightly run must batch (files no unit covers,
  units of another config);
- :mod:`~pipeline.batch.driver`: the order of it all, site by site
  (:func:`run_batch`);
- :mod:`~pipeline.batch.summary`: what a batch did (:class:`BatchSummary`,
  :class:`SitesSummary`), the exit code.

The walk of one unit: docs/architecture.md, "One batch unit, from plan to commit".
"""

import importlib
from typing import Any

_EXPORTS = {
    "BatchSummary": "pipeline.batch.summary",
    "BatchUnit": "pipeline.batch.worker",
    "SitesSummary": "pipeline.batch.summary",
    "UnitManifest": "pipeline.batch.worker",
    "read_inputs": "pipeline.batch.worker",
    "resume_continuations": "pipeline.batch.driver",
    "run_batch": "pipeline.batch.driver",
    "run_site": "pipeline.batch.driver",
    "run_unit": "pipeline.batch.worker",
    "sites_in": "pipeline.warehouse.sites",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    """The kernel's entry points, imported on first use (PEP 562): a command that reads
    one module of the package (``surveil report``: :mod:`~pipeline.batch.provenance`)
    does not import the batch's driver and every family's stage with it."""
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
