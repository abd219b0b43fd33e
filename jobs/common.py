"""What every job shares: exit codes and the names the commands import."""

from __future__ import annotations

from pipeline.errors import UsageError
from pipeline.logs import setup_logging
from pipeline.options import checked_site, parse_duration, parse_origin, parse_time_ns
from pipeline.units import iso
from pipeline.warehouse.location import checked_warehouse, refuse_pre_sites, require_warehouse
from pipeline.warehouse.sites import one_site, require_site, warehouse_sites

__all__ = ["UsageError", "checked_site", "checked_warehouse", "iso", "one_site",
           "parse_duration", "parse_origin", "parse_time_ns", "refuse_pre_sites", "require_site",
           "require_warehouse", "setup_logging", "warehouse_sites"]

EXIT_OK = 0
EXIT_UNITS_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
