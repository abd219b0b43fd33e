"""`surveil run`: the nightly job over a growing archive.

1. scan the archive folders (``[archive] folders`` or the command's arguments) and ingest
   the new and changed ``*.mcap`` files (the ledger skips unchanged ones);
2. find the windows that need a batch: every ledger file (ok or partial) whose time span
   is not covered by ``batch_units`` committed after the file was ingested. This is read
   from the warehouse, not remembered by the job: a file ingested by a run that crashed
   or whose batch failed is found again by the next run, and nothing else is redone;
3. batch those windows, each site's alone (spans cut out to whole UTC hours and merged
   per site; ``run_batch`` of that site widens each to the committed units it overlaps);
4. record the run in ``runs`` (one row per run that had work).

A run with nothing to ingest and no window pending writes nothing and says so. The
caller holds the warehouse lock (:mod:`pipeline.warehouse.lock`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from jobs.common import UsageError, iso
from jobs.ingest import expand_paths, run_ingest
from pipeline.batch import SitesSummary, resume_continuations, run_batch
from pipeline.batch.pending import pending_by_site
from pipeline.config import Config
from pipeline.executors import UnitResult
from pipeline.ingest import IngestSummary
from pipeline.ingest.plan import IngestUsageError
from pipeline.warehouse.runs import record_run


@dataclass
class RunSummary:
    started_at_ns: int
    command: str
    files: dict[str, str] = field(default_factory=dict)  # ingested: path -> status
    files_skipped: int = 0
    ingest: IngestSummary | None = None
    windows: list[tuple[int, int]] = field(default_factory=list)
    batches: list[SitesSummary] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    ended_at_ns: int = 0

    @property
    def nothing_to_do(self) -> bool:
        return not self.files and not self.windows and not self.failures

    @property
    def status(self) -> str:
        return "failed" if self.failures else "ok"

    @property
    def exit_code(self) -> int:
        return 1 if self.failures else 0

    def rows(self) -> dict[str, int]:
        out: dict[str, int] = {}
        if self.ingest is not None:
            for k, v in self.ingest.rows.items():
                if v:
                    out[k] = out.get(k, 0) + v
        for b in self.batches:
            for k, v in b.rows.items():
                out[k] = out.get(k, 0) + v
        return out

    def render(self) -> str:
        if self.nothing_to_do:
            return (f"run: nothing to do: {self.files_skipped} file(s) unchanged, no window "
                    "pending; nothing written")
        lines = [f"run {self.status}: {len(self.files)} file(s) ingested, "
                 f"{self.files_skipped} unchanged; {len(self.windows)} window(s) batched"]
        lines += [f"  window [{iso(a)}, {iso(b)})" for a, b in self.windows]
        lines += [f"  {name:<22} {n:>9} rows" for name, n in self.rows().items()]
        lines += [f"  failed: {f}" for f in self.failures]
        return "\n".join(lines)


def run_nightly(cfg: Config, warehouse: Path, *, folders: list[str] | None = None,
                executor_kind: str | None = None, command: str = "surveil run",
                progress: Any = None, site: str | None = None) -> RunSummary:
    """Scan, ingest what is new or changed, batch the pending windows (each site's
    alone), record the run. ``site``: the site of files whose metadata names none, and
    the only site batched (default: files without a site are ``default``; every site)."""
    chosen = list(folders or cfg.archive_folders)
    if not chosen:
        raise UsageError("no archive folders: set [archive] folders in the config or name "
                         "them: surveil run FOLDER...")
    try:
        files = expand_paths(chosen, warehouse)  # folders, or s3:// prefixes
    except IngestUsageError as exc:
        raise UsageError(str(exc)) from None
    summary = RunSummary(started_at_ns=time.time_ns(), command=command)
    results: list[UnitResult] = []

    def seen(res: UnitResult) -> None:
        results.append(res)
        if progress is not None:
            progress.ingest_result(res)

    if progress is not None:
        progress.ingest_total(files)
    summary.ingest = run_ingest(files, cfg, warehouse, executor=executor_kind, on_result=seen,
                                site=site)
    for res in results:
        if res.ok and res.value.skipped:
            summary.files_skipped += 1
        elif res.ok:
            summary.files[res.value.source_file] = res.value.status
    summary.failures += [f"ingest {path}: {err}" for path, err in summary.ingest.failed]
    summary.failures += [f"ingest {path}: {status}" for path, status in summary.files.items()
                         if status == "quarantined"]
    # chains a killed job left (the rows at a window's end changed, the units after it
    # not batched again): done first, even when no window is pending
    resumed = resume_continuations(cfg, warehouse, site=site, executor_kind=executor_kind,
                                   progress=progress)
    if resumed:
        summary.batches.append(SitesSummary({}, 0, 0, resumed=resumed))
        summary.windows += [(c.start_ns, c.end_ns) for r in resumed for c in r.continued]
        summary.failures += [f"batch [{iso(c.start_ns)}, {iso(c.end_ns)}): {u}"
                             for r in resumed for c in r.continued for u in c.failed_units]
    pending = [(start, end, name) for name, windows in pending_by_site(warehouse).items()
               if site in (None, name) for start, end in windows]
    for start, end, name in sorted(pending):
        summary.windows.append((start, end))
        batch = run_batch(cfg, warehouse, start_ns=start, end_ns=end,  # chains: done above
                          executor_kind=executor_kind, progress=progress, site=name,
                          resume=False)
        summary.batches.append(batch)
        summary.failures += [f"batch [{iso(start)}, {iso(end)}): {u}"
                             for u in batch.failed_units]
    summary.ended_at_ns = time.time_ns()
    if not summary.nothing_to_do:
        record_run(warehouse, cfg, summary)
    return summary
