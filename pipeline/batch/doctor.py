"""`surveil doctor [--repair]` with the batch: find what is damaged, repair what can be.

The checks and the warehouse's own repairs are :mod:`pipeline.warehouse.doctor`; this
composes them with the batch: under the writer lock, ``--repair`` moves broken log
entries aside (the table reads as at its last good version), removes the references to
missing data files (FSCK), batches again the units whose derived rows went with them (and
the windows of crashed batches), rebuilds the views file, and names what it cannot
restore: the archive files whose raw rows are gone, with the ``surveil ingest --force``
command that brings them back. Then it examines the warehouse again.

Exit codes: 0 healthy (after ``--repair``: healthy now, nothing left to do), 1 problems
found (after ``--repair``: some remain, or a command is left to run), 2 usage error.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.batch import SitesSummary, run_batch
from pipeline.batch.pending import pending_by_site
from pipeline.config import Config
from pipeline.families import FAMILIES
from pipeline.render import format_report
from pipeline.units import iso
from pipeline.warehouse.doctor import (
    Examination,
    LostRows,
    TableDamage,
    backup_folder,
    examine,
    findings_table,
    forget_files,
    lost_rows,
    record_lost_raw,
    restore_log,
    set_aside_log,
)
from pipeline.warehouse.location import Location, as_location
from pipeline.warehouse.lock import warehouse_lock
from pipeline.warehouse.views import refresh_views_file

EXIT_HEALTHY = 0
EXIT_PROBLEMS = 1


@dataclass
class DoctorResult:
    """What doctor found (``before``) and, with ``--repair``, what it did (``done``,
    ``batches``), what is left to the operator (``todo``) and what it finds after
    (``after``)."""

    warehouse: str
    before: Examination
    after: Examination | None = None
    done: list[str] = field(default_factory=list)
    todo: list[str] = field(default_factory=list)
    batches: list[SitesSummary] = field(default_factory=list)

    @property
    def exit_code(self) -> int:
        last = self.after if self.after is not None else self.before
        ok = last.healthy and not self.todo and all(b.exit_code == 0 for b in self.batches)
        return EXIT_HEALTHY if ok else EXIT_PROBLEMS

    def render(self, fmt: str = "table") -> str:
        parts = [_findings(self.warehouse, self.before, "found")]
        if self.before.busy is not None:
            b = self.before.busy
            parts.append(f"a job holds the warehouse (pid {b.get('pid', '?')}: "
                         f"{b.get('command', '?')}): its staging and pending markers are its "
                         "own and were not checked; run doctor again after it")
        if self.after is None:
            if not self.before.healthy:
                parts.append("`surveil doctor --repair` makes the repairs listed (but those "
                             "marked none)")
            return "\n".join(parts)
        parts += ["repaired:", *(f"  {line}" for line in self.done or ["nothing"])]
        parts += [b.render() for b in self.batches]
        if self.todo:
            parts += ["left to do (doctor cannot restore these):",
                      *(f"  {line}" for line in self.todo)]
        parts.append(_findings(self.warehouse, self.after, "after the repair"))
        return "\n".join(parts)


def _findings(warehouse: str, exam: Examination, when: str) -> str:
    if exam.healthy:
        return (f"{when}: warehouse {warehouse} is healthy (every table's log reads, every "
                "data file is there with its recorded size, schemas as declared, views fresh, "
                "no leftovers)")
    return format_report(findings_table(exam.findings), "table",
                         title=f"{when}: {len(exam.findings)} problem(s) in {warehouse}")


_BATCHED = frozenset(n for fam in FAMILIES for n in fam.outputs)  # tables the batch writes


def run_doctor(cfg: Config, warehouse: Path | Location, *, repair: bool = False,
               executor_kind: str | None = None, command: str = "surveil doctor --repair"
               ) -> DoctorResult:
    """Examine ``warehouse``; with ``repair``, repair it under its writer lock and
    examine it again (module docstring)."""
    result = DoctorResult(str(warehouse), examine(warehouse))
    if not repair:
        return result
    with warehouse_lock(warehouse, command=command):  # (removes dead jobs' staging)
        _repair(cfg, warehouse, result, executor_kind)
        result.after = examine(warehouse, holding_lock=True)
    return result


def _repair(cfg: Config, warehouse: Path | Location, result: DoctorResult,
            executor_kind: str | None) -> None:
    exam = examine(warehouse, holding_lock=True)
    backup = backup_folder(warehouse)
    treated: list[TableDamage] = []
    for d in exam.damaged.values():
        if d.log_error is None:
            continue
        if d.good_version is None and d.name in _BATCHED:  # the batch makes it again
            set_aside_log(warehouse, d, backup)
            treated.append(dataclasses.replace(d, good_at_ns=0))  # every unit re-batched
            result.done.append(f"{d.name}: no version of its log reads; its log moved to "
                               f"{backup}, the table re-made by batching every unit again")
            continue
        if d.good_version is None:
            result.todo.append(f"{d.name}: no version of its log reads; rebuild it from the "
                               "archive (docs/operations.md, 'A damaged warehouse')")
            continue
        restore_log(warehouse, d, backup)
        treated.append(d)
        result.done.append(f"{d.name}: log entries {', '.join(d.broken_entries)} moved to "
                           f"{backup}; the table reads as at version {d.good_version} "
                           f"({iso(d.good_at_ns or 0)})")
    for d in examine(warehouse, holding_lock=True).damaged.values():  # restored logs too
        if d.bad_files:
            removed = forget_files(warehouse, d, backup)
            treated.append(d)
            result.done.append(f"{d.name}: references to {len(removed)} missing or "
                               f"rewritten data file(s) removed (FSCK): {', '.join(removed)}")
    lost = lost_rows(warehouse, treated)
    _rebatch(cfg, warehouse, result, lost, exam, executor_kind)
    _name_reingests(warehouse, result, lost, exam)
    if refresh_views_file(warehouse):
        result.done.append("views file surveil.duckdb rebuilt")


def _rebatch(cfg: Config, warehouse: Path | Location, result: DoctorResult, lost: LostRows,
             exam: Examination, executor_kind: str | None) -> None:
    """Batch again the units that owned lost derived rows, the windows of crashed
    batches (their pending markers) and, when ``batch_units`` lost entries, the windows
    the ledger holds that no unit covers now."""
    spans = list(lost.spans)
    spans += [(doc.get("site"), *doc["window"]) for _, doc in exam.markers
              if doc.get("job") == "batch" and doc.get("window")]
    if "batch_units" in lost.ledgers:
        spans += [(site, a, b) for site, ws in pending_by_site(warehouse).items()
                  for a, b in ws]
    for d in exam.damaged.values():
        if d.kind == "derived" and d.name not in _BATCHED:
            result.todo.append(f"{d.name}: its rows come from a calibration, not the batch: "
                               "run `surveil calibrate` / `surveil calibrate-radars` again "
                               "over the windows it covered")
    for site, lo, hi in _merged(spans):
        if any(s in (None, site) and a < hi and lo < b for s, a, b in lost.raw_spans):
            result.todo.append(  # its inputs lack rows until the ingest: batched after it
                f"batch [{iso(lo)}, {iso(hi)}){' of site ' + site if site else ''} again "
                "after the ingest below (`surveil run` does: the window is pending then)")
            continue
        summary = run_batch(cfg, warehouse, start_ns=lo, end_ns=hi, site=site,  # type: ignore[arg-type]
                            executor_kind=executor_kind, ignore_place=True)
        result.batches.append(summary)
        result.done.append(f"re-batched [{iso(lo)}, {iso(hi)})"
                           f"{' of site ' + site if site else ''}: exit {summary.exit_code}")


def _merged(spans: list[tuple[str | None, int, int]]) -> list[tuple[str | None, int, int]]:
    """The spans merged per site where they meet; by site, then time."""
    out: list[tuple[str | None, int, int]] = []
    for site, a, b in sorted(spans, key=lambda s: (s[0] or "", s[1], s[2])):
        if out and out[-1][0] == site and a <= out[-1][2]:
            out[-1] = (site, out[-1][1], max(out[-1][2], b))
        else:
            out.append((site, a, b))
    return out


def _name_reingests(warehouse: Path | Location, result: DoctorResult, lost: LostRows,
                    exam: Examination) -> None:
    where = as_location(warehouse)
    if lost.archive_files:
        record_lost_raw(warehouse, lost.archive_files)  # doctor names them until ingested
    for f in sorted(lost.archive_files):
        gone = "" if where.at(f).exists() else " (the archive file is gone too: its rows " \
                                                "cannot be restored)"
        result.todo.append(f"raw rows of {f} were lost: `surveil ingest --force {f}`, then "
                           f"`surveil run` batches its windows again{gone}")
    for _, doc in exam.markers:
        if doc.get("job") != "batch" and doc.get("source_file"):
            result.todo.append(f"a crashed ingest of {doc['source_file']}: `surveil ingest "
                               f"--force {doc['source_file']}`")
    if "ingest_ledger" in lost.ledgers:
        result.todo.append("ingest_ledger lost entries: `surveil run` (or `surveil ingest "
                           "FILE`) ingests the files it no longer lists again")
