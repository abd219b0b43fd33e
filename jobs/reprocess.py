"""Reprocess one window: re-ingest the archived files that overlap it, re-run the batch.

Both steps replace exactly the window (raw rows of those files inside the window, derived
rows of the window), so running it twice leaves every table with the same rows.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from jobs.common import UsageError
from pipeline.batch import SitesSummary, run_batch, sites_in
from pipeline.batch.place import check_places
from pipeline.config import Config
from pipeline.ingest.driver import IngestSummary, run_ingest
from pipeline.warehouse.ledger import files_overlapping
from pipeline.warehouse.location import as_location


@dataclass
class ReprocessSummary:
    ingest: IngestSummary | None
    batch: SitesSummary
    missing_files: list[str]

    @property
    def exit_code(self) -> int:
        codes = [self.batch.exit_code, 1 if self.missing_files else 0]
        if self.ingest is not None:
            codes.append(self.ingest.exit_code)
        return max(codes)

    def render(self) -> str:
        parts = [self.ingest.render()] if self.ingest is not None else []
        parts += [f"missing archived file: {f}" for f in self.missing_files]
        parts.append(self.batch.render())
        return "\n".join(parts)


def run_reprocess(
    cfg: Config, warehouse: Path, *, start_ns: int, end_ns: int, executor_kind: str | None = None,
    progress: Any = None, site: str | None = None, ignore_place: bool = False,
) -> ReprocessSummary:
    """Re-ingest the files overlapping the window, then batch it. ``site``: that site's
    files and rows only (default: every site, each batched alone). ``progress``: the
    CLI's :class:`~jobs.progress.TerminalProgress` (or None). The place check
    (:mod:`pipeline.batch.place`) runs first, before the re-ingest, unless
    ``ignore_place``."""
    if end_ns <= start_ns:
        raise UsageError("--to must be after --from")
    if not ignore_place:
        sites = [site] if site is not None else sites_in(warehouse, start_ns, end_ns)
        check_places(warehouse, cfg, sites, start_ns, end_ns)
    files = files_overlapping(warehouse, start_ns, end_ns, site)
    where = as_location(warehouse)  # an archived file may be an s3:// object
    present = [f for f in files if (Path(f).is_file() if where.at(f).is_local
                                    else where.at(f).exists())]
    missing = [f for f in files if f not in present]
    ingest = None
    if present:
        if progress is not None:
            progress.ingest_total(present)
        ingest = run_ingest(
            present, cfg, warehouse,
            start_ns=start_ns, end_ns=end_ns, force=True, executor=executor_kind,
            on_result=progress.ingest_result if progress is not None else None,
        )
    batch = run_batch(cfg, warehouse, start_ns=start_ns, end_ns=end_ns,
                      executor_kind=executor_kind, progress=progress, site=site,
                      ignore_place=True)  # checked above
    return ReprocessSummary(ingest=ingest, batch=batch, missing_files=missing)
