"""What every job shares: time parsing, logging setup, exit codes."""

from __future__ import annotations

import json
import logging
import re
import sys
from datetime import UTC, datetime
from pathlib import Path

from pipeline.errors import UsageError
from pipeline.tables import SITE_NAME_RULE, is_site_name
from pipeline.units import iso
from pipeline.warehouse.location import checked_warehouse, refuse_pre_sites, require_warehouse

__all__ = ["UsageError", "checked_warehouse", "iso", "refuse_pre_sites", "require_warehouse"]

EXIT_OK = 0
EXIT_UNITS_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


def checked_site(name: str) -> str:
    """A ``--site`` name: 1-64 letters, digits, ``.``, ``_``, ``-``, starting with a
    letter or digit (:data:`pipeline.tables.SITE_NAME`); :class:`UsageError` otherwise."""
    if not is_site_name(name):
        raise UsageError(f"--site {name!r}: {SITE_NAME_RULE}")
    return name


def warehouse_sites(warehouse: Path) -> list[str]:
    """The sites a warehouse holds: of its ingest ledger's files and its committed batch
    units, sorted."""
    import polars as pl

    from pipeline.warehouse.delta import read_table

    found: set[str] = set()
    for table in ("ingest_ledger", "batch_units"):
        found |= set(pl.from_arrow(read_table(warehouse, table, columns=["site"]))["site"]
                     .to_list())
    return sorted(found)


def require_site(warehouse: Path, site: str | None) -> str | None:
    """``site`` when the warehouse holds it (or None); :class:`UsageError` (exit 2)
    naming the warehouse's sites otherwise: a typo in ``--site`` must not read as a site
    without data (was: ``report --site nosuch`` exit 0 blaming the gyro signals, ``batch
    --site nosuch`` committed empty units)."""
    if site is None:
        return None
    known = warehouse_sites(warehouse)
    if site not in known:
        raise UsageError(f"no site {site!r} in warehouse {warehouse} (its sites: "
                         f"{', '.join(known) or 'none: ingest recordings first'})")
    return site


def one_site(warehouse: Path, site: str | None, start_ns: int, end_ns: int) -> str | None:
    """``site`` as given (None: every site). A command drawing one picture (audit,
    export) over several sites without ``--site`` warns: their rows are drawn together
    (each report row keeps its ``site``), fine for sites of different families (the demo's
    channel, airfield and own ship), confusing for two VTS sites."""
    if site is None:
        from pipeline.batch import sites_in

        found = sites_in(warehouse, start_ns, end_ns)
        if len(found) > 1:
            logging.getLogger(__name__).warning(
                "the window holds data of %d sites (%s), drawn together; --site NAME for one",
                len(found), ", ".join(found))
    return site


def parse_time_ns(text: str) -> int:
    """ISO 8601 (``2026-01-15T01:00:00Z``, naive means UTC) or an integer ns timestamp."""
    t = text.strip()
    if t.lstrip("-").isdigit():
        return _in_range(int(t), text)
    try:
        dt = datetime.fromisoformat(t.replace("Z", "+00:00"))
    except ValueError as exc:
        raise UsageError(f"not a time: {text!r} (use ISO 8601, e.g. 2026-01-15T01:00:00Z)") from exc
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=UTC)
    delta = dt - datetime(1970, 1, 1, tzinfo=UTC)
    return _in_range((delta.days * 86_400 + delta.seconds) * 1_000_000_000
                     + delta.microseconds * 1000, text)  # fmt: skip


def _in_range(t_ns: int, text: str) -> int:
    """``t_ns`` if it is a time the warehouse can hold (int64 ns since 1970), else a
    :class:`UsageError` (``--to 9999-01-01``: exit 2, not a traceback)."""
    if not 0 <= t_ns <= 2**63 - 1:
        raise UsageError(f"time {text!r} is outside 1970-01-01 .. 2262-04-11 UTC (int64 ns)")
    return t_ns


_DURATION = re.compile(
    r"^(?:(?P<h>\d+(?:\.\d+)?)h)?(?:(?P<m>\d+(?:\.\d+)?)m)?(?:(?P<s>\d+(?:\.\d+)?)s)?$")


def parse_duration(text: str) -> float:
    """``"1h"``, ``"30m"``, ``"90s"``, ``"2h30m"``, ``"1.5h"`` or plain seconds
    (``"600"``) -> seconds. Raises ValueError for anything else or a zero duration."""
    t = text.strip().lower()
    try:
        seconds = float(t)
    except ValueError:
        m = _DURATION.match(t)
        if not t or m is None:
            raise ValueError(
                f"invalid duration {text!r}: use e.g. 1h, 30m, 90s, 2h30m or seconds"
            ) from None
        seconds = (float(m["h"] or 0) * 3600.0 + float(m["m"] or 0) * 60.0
                   + float(m["s"] or 0))
    if not seconds > 0 or seconds == float("inf"):
        raise ValueError(f"invalid duration {text!r}: must be positive and finite")
    return seconds


class _JsonLines(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        doc = {
            "time": datetime.fromtimestamp(record.created, UTC).isoformat(),
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": record.getMessage(),
        }
        if record.exc_info:
            doc["exception"] = self.formatException(record.exc_info)
        return json.dumps(doc)


def setup_logging(level: str = "INFO", json_lines: bool | None = None) -> None:
    """Readable logs on a terminal (rich), JSON lines otherwise (cron, orchestrators)."""
    root = logging.getLogger()
    root.handlers.clear()
    root.setLevel(level.upper())
    as_json = (not sys.stderr.isatty()) if json_lines is None else json_lines
    if as_json:
        handler: logging.Handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(_JsonLines())
    else:
        from rich.logging import RichHandler

        handler = RichHandler(show_path=False, rich_tracebacks=False)
    root.addHandler(handler)
