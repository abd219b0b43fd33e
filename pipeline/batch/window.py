"""Bound a batch / reprocess window before any work starts (issue 18, item 3).

:func:`bounded_window` clips ``[start_ns, end_ns)`` to the hours the ingest ledger knows
data in (files ok or partial), so that a window reaching far beyond the data (``--to
2200-01-01`` over one hour of recordings) costs what the data costs: the hours outside
have no raw rows, hence no derived rows to replace. It refuses (:class:`UsageError`,
exit 2, before anything is staged) when the clipped window is longer than
``[execution] max_window_days``, or when its estimated memory exceeds ``[execution]
memory_budget_mb`` (0: 80% of the machine's memory). The estimate is coarse on purpose:
the raw rows of the largest work unit (:func:`largest_unit_rows`, from the ledger's rows
per table over each file's span) times ``BYTES_PER_ROW_IN_UNIT`` times the workers running
at once. When the ledger knows no
data in the window (a warehouse filled by windowed ingests only, which write no ledger
rows), the window is kept as asked and only its length is bounded.

A window before 1980 (where the synthetic times of recordings without any time lie) is
batched as asked, with a note saying why it stays empty: those rows are no batch input
(:data:`pipeline.batch.worker.TIME_SOURCE`).

Times beyond int64 ns (``--to 9999-01-01``) never get here: :func:`pipeline.options.parse_time_ns`
refuses them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from pipeline.config import Config
from pipeline.errors import UsageError
from pipeline.families import FAMILIES
from pipeline.threads import machine_memory_bytes
from pipeline.units import iso
from pipeline.warehouse.delta import read_table

HOUR_NS = 3600 * 10**9
DAY_NS = 24 * HOUR_NS
BYTES_PER_ROW_IN_UNIT = 2048  # raw row + its staged and derived frames in a batch unit
REAL_TIMES_FROM_NS = 315_532_800 * 10**9
"""1980-01-01 UTC: before it no recording carries its own time (the GPS epoch is
1980-01-06); rows before it have synthetic times."""


@dataclass(frozen=True)
class BoundedWindow:
    """The window to run, and a note when it differs from the one asked for."""

    start_ns: int
    end_ns: int
    note: str = ""


def bounded_window(cfg: Config, warehouse: Path, start_ns: int, end_ns: int,
                   site: str | None = None) -> BoundedWindow:
    """``[start_ns, end_ns)`` clipped to the ledger's data hours (of ``site``, when given),
    or refused (module docstring)."""
    cols = ["status", "start_time_ns", "end_time_ns", "rows_json"]
    try:
        ledger = read_table(warehouse, "ingest_ledger", columns=cols,
                            site=site).to_pylist()
    except Exception:  # no warehouse / ledger yet: nothing known, nothing to clip to
        ledger = []
    files = [
        r for r in ledger
        if r["status"] in ("ok", "partial") and r["start_time_ns"] is not None
        and r["end_time_ns"] is not None and r["start_time_ns"] < end_ns
        and r["end_time_ns"] >= start_ns
    ]  # fmt: skip
    if files:
        lo = min(r["start_time_ns"] for r in files) // HOUR_NS * HOUR_NS
        hi = -(-(max(r["end_time_ns"] for r in files) + 1) // HOUR_NS) * HOUR_NS
        s, e = max(start_ns, lo), min(end_ns, hi)
    else:  # windowed ingests write no ledger rows: the window as asked, bounded below
        s, e = start_ns, end_ns
    ex = cfg.execution
    if e - s > ex.max_window_days * DAY_NS:
        raise UsageError(
            f"the window holds {(e - s) / DAY_NS:.1f} days of data ({iso(s)} .. {iso(e)}); "
            f"at most {ex.max_window_days:g} days per run ([execution] max_window_days): "
            "split it into shorter windows"
        )
    name, peak = largest_unit_rows(cfg, files)
    need_mb = peak * BYTES_PER_ROW_IN_UNIT * ex.max_workers / 2**20
    budget = ex.memory_budget_mb or int(0.8 * (machine_memory_bytes() // 2**20 or 8192))
    if need_mb > budget:
        raise UsageError(
            f"the largest work unit of this window ({name}) reads ~{peak:,.0f} raw rows: "
            f"{ex.max_workers} workers would need ~{need_mb:,.0f} MB, over the budget of "
            f"{budget:,} MB ([execution] memory_budget_mb); use fewer workers or a larger "
            "budget"
        )
    note = ""
    if (s, e) != (start_ns, end_ns):
        note = f"window clipped to the data the ledger knows: {iso(s)} .. {iso(e)}"
    if s < REAL_TIMES_FROM_NS:
        why = (f"the window {'lies' if e <= REAL_TIMES_FROM_NS else 'begins'} before "
               f"{iso(REAL_TIMES_FROM_NS)}: no recording's own times lie there; rows there "
               "have synthetic times (recordings without any time, times of day without a "
               "date) and are no batch input, so that part of the window stays empty; give "
               "such recordings their time with `surveil import --base-time` and ingest them "
               "again")
        note = f"{note}\n{why}" if note else why
    return BoundedWindow(s, e, note)


def largest_unit_rows(cfg: Config, files: list[dict]) -> tuple[str, float]:
    """The family whose largest work unit reads the most raw rows, and that count, from
    the ledger rows of ``files`` (rows per table over each file's span): an hourly family
    reads its input tables' densest hour, scaled down where it cuts units by volume
    (``unit_rows`` of ``unit_table``, e.g. 300,000 radar reports), plus the margins its
    inputs read around a unit (the maritime lead-in and look-ahead); a family with one
    unit per window reads the whole window. Derived inputs (gaps reads system_tracks)
    are not in the ledger and not counted."""
    per_file = [(json.loads(r["rows_json"] or "{}"),
                 max(1.0, (r["end_time_ns"] - r["start_time_ns"]) / HOUR_NS)) for r in files]
    best = ("", 0.0)
    for fam in FAMILIES:
        tables = {i.table for i in fam.inputs(cfg)}
        if fam.unit_s is None:  # one unit per window
            unit = sum(rows.get(t, 0) for rows, _ in per_file for t in tables)
        else:
            unit = 0.0
            margin_h = {i.table: (i.before_s + i.after_s) / 3600.0 for i in fam.inputs(cfg)
                        if not i.whole_table}
            for rows, hours in per_file:
                volume = rows.get(fam.unit_table, 0) / hours
                unit_h = min(1.0, fam.unit_rows / volume) if fam.unit_rows and volume else 1.0
                unit = max(unit, sum(rows.get(t, 0) / hours * (unit_h + margin_h.get(t, 0.0))
                                     for t in tables))
        best = max(best, (fam.name, float(unit)), key=lambda b: b[1])
    return best
