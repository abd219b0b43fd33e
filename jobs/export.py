"""`surveil export`: a window of the warehouse as an MCAP file in Foxglove's schemas."""

from __future__ import annotations

from pathlib import Path

from jobs.common import one_site
from pipeline.config import Config
from pipeline.export import ExportSummary, write_export


def run_export(cfg: Config, warehouse: Path, out: Path, *, start_ns: int, end_ns: int,
               site: str | None = None) -> ExportSummary:
    """The window's tracks of ``site`` (None: every site, drawn together)."""
    return write_export(cfg, warehouse, out, start_ns=start_ns, end_ns=end_ns,
                        site=one_site(warehouse, site, start_ns, end_ns))
