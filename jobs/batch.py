"""`surveil batch`: every sensor family's derived tables for one window.

The engine is :mod:`pipeline.batch` (plan, units, seams, continuations, the commit);
the CLI bounds the window (:func:`pipeline.batch.window.bounded_window`), takes the
writer lock and calls :func:`run_batch`, which tests also call directly.
"""

from __future__ import annotations

from pipeline.batch import BatchSummary, SitesSummary, run_batch, sites_in

__all__ = ["BatchSummary", "SitesSummary", "run_batch", "sites_in"]
