"""`surveil run`: the nightly job over a growing archive.

1. scan the archive folders (``[archive] folders`` or the command's arguments): MCAP
   files, and raw recordings ``surveil import`` reads (NMEA text, AIS CSV, ASTERIX,
   pcap, ROS 1 bags), which are wrapped into ``<warehouse>/imported/`` when new or
   changed and recorded in ``import_ledger`` (:mod:`pipeline.ingest.archive`); files
   still being written (an MCAP without its footer, a raw log just modified) wait until
   they have not changed for ``[archive] settle_s``;
2. ingest the new and changed MCAP files (the ledger skips unchanged ones); a file read
   before under another site than it names now (a half-written file whose metadata was
   unread) leaves that site's derived rows of its span batched again, or removed where
   the site has no other data there;
3. find the windows that need a batch: every ledger file (ok or partial) whose time span
   is not covered by ``batch_units`` committed after the file was ingested, and every
   committed unit batched with another config than the current one (its
   ``config_digest``, :mod:`pipeline.batch.provenance`). This is read from the
   warehouse, not remembered by the job: a file ingested by a run that crashed or whose
   batch failed is found again by the next run, and nothing else is redone;
4. batch those windows, each site's alone (spans cut out to whole UTC hours and merged
   per site; ``run_batch`` of that site widens each to the committed units it overlaps;
   the place check refuses a site whose positions lie outside the config's region);
5. record the run in ``runs`` (one row per run that had work).

A run with nothing to ingest and no window pending writes nothing and says so. Exit
codes as ``ingest``'s (1 when a row was rejected, a file partial, quarantined or failed,
an import partial or failed, a unit failed) and 2 when the place check refused a site.
The caller holds the warehouse lock (:mod:`pipeline.warehouse.lock`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.batch import SitesSummary, resume_continuations, run_batch, sites_in
from pipeline.batch.driver import retire_window
from pipeline.batch.pending import pending_by_site, stale_spans, with_spans
from pipeline.batch.place import PlaceError
from pipeline.config import Config
from pipeline.errors import UsageError
from pipeline.executors import UnitResult
from pipeline.ingest import IngestSummary
from pipeline.ingest.archive import ImportResult, import_recordings, scan_folders, settled
from pipeline.ingest.driver import run_ingest
from pipeline.ingest.plan import IngestUsageError, expand_paths
from pipeline.units import iso
from pipeline.warehouse.delta import read_table, shared_handles
from pipeline.warehouse.location import as_location
from pipeline.warehouse.runs import record_run


@dataclass
class RunSummary:
    started_at_ns: int
    command: str
    files: dict[str, str] = field(default_factory=dict)  # ingested: path -> status
    files_skipped: int = 0
    ingest: IngestSummary | None = None
    imports: ImportResult = field(default_factory=ImportResult)
    deferred: list[tuple[str, str]] = field(default_factory=list)  # still being written
    skipped: list[tuple[str, str]] = field(default_factory=list)  # not regular files
    moved: list[str] = field(default_factory=list)  # files now of another site
    stale: list[str] = field(default_factory=list)  # windows of another config
    windows: list[tuple[int, int]] = field(default_factory=list)
    batches: list[SitesSummary] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)  # the place check's refusals
    ended_at_ns: int = 0

    @property
    def nothing_to_do(self) -> bool:
        return (not self.files and not self.windows and not self.failures
                and not self.imports.imported and not self.refused and not self.moved)

    @property
    def status(self) -> str:
        return "failed" if self.failures or self.refused else "ok"

    @property
    def exit_code(self) -> int:
        """As ``surveil ingest`` for what it read (1: something not used), 1 when an
        import or a unit failed, 2 when the place check refused a site's batch."""
        if self.refused:
            return 2
        codes = [1 if self.failures else 0, self.imports.exit_code]
        if self.ingest is not None:
            codes.append(self.ingest.exit_code)
        codes += [b.exit_code for b in self.batches]
        return max(codes)

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
        later = [f"  deferred {p}: {why}" for p, why in self.deferred]
        later += [f"  skipped {p}: {why}" for p, why in self.skipped]
        if self.nothing_to_do:
            return "\n".join([
                f"run: nothing to do: {self.files_skipped} file(s) unchanged"
                + (f", {len(self.deferred)} still being written" if self.deferred else "")
                + ", no window pending; nothing written", *later])
        lines = [f"run {self.status}: {len(self.files)} file(s) ingested, "
                 f"{self.files_skipped} unchanged; {len(self.windows)} window(s) batched"]
        if self.imports.imported or self.imports.failed:
            lines.append(f"  imported {len(self.imports.imported)} raw recording(s) "
                         f"({self.imports.unchanged} unchanged, {len(self.imports.failed)} "
                         f"failed, {self.imports.rejected} pieces rejected)")
        lines += later
        lines += [f"  {text}" for text in self.moved]
        lines += [f"  {text}" for text in self.stale]
        lines += [f"  window [{iso(a)}, {iso(b)})" for a, b in self.windows]
        lines += [f"  {name:<22} {n:>9} rows" for name, n in self.rows().items()]
        if self.ingest is not None and self.ingest.rejected:
            lines.append(f"  rejects (ingest) {self.ingest.rejected:>9} rows "
                         "(table rejects, stage ingest)")
        lines += [f"  WARNING: {w}" for w in (self.ingest.place_warnings if self.ingest
                                               else [])]
        lines += [f"  failed: {f}" for f in self.failures]
        lines += [f"  NOT BATCHED: {r}" for r in self.refused]
        lines.append(f"exit code {self.exit_code}")
        return "\n".join(lines)


def run_nightly(cfg: Config, warehouse: Path, *, folders: list[str] | None = None,
                executor_kind: str | None = None, command: str = "surveil run",
                progress: Any = None, site: str | None = None,
                ignore_place: bool = False, now_ns: int | None = None) -> RunSummary:
    """Scan, import and ingest what is new or changed, batch the pending windows (each
    site's alone), record the run. ``site``: the site of files whose metadata names none,
    and the only site batched (default: files without a site are ``default``; every
    site). ``now_ns``: the clock the settle time is measured against (tests)."""
    chosen = list(folders or cfg.archive_folders)
    if not chosen:
        raise UsageError("no archive folders: set [archive] folders in the config or name "
                         "them: surveil run FOLDER...")
    local = [f for f in chosen if "://" not in str(f)]
    where = as_location(warehouse)
    scan = scan_folders(local, exclude=[where.path] if where.is_local else [])
    remote = [f for f in chosen if "://" in str(f)]
    try:  # object-store prefixes: their MCAP objects (an object is whole once written)
        objects = expand_paths(remote, warehouse) if remote else []
    except IngestUsageError as exc:
        raise UsageError(str(exc)) from None
    if not scan.mcap and not scan.raw and not objects:
        raise UsageError(f"no recordings (MCAP, or NMEA text, AIS CSV, ASTERIX, pcap, ROS 1 "
                         f"bags) under: {', '.join(map(str, chosen))}" + "".join(
                             f"; skipped {p}: {why}" for p, why in scan.skipped[:5]))
    summary = RunSummary(started_at_ns=time.time_ns(), command=command, skipped=scan.skipped)
    settle_s = cfg.archive_settle_s
    raws, deferred_raw = settled(scan.raw, settle_s, now_ns, raw=True)
    if raws and not where.is_local:  # imported/ is a local folder of the warehouse
        summary.failures += [f"import {p}: raw recordings are imported into a local "
                             "warehouse only; wrap them first (`surveil import ... --out "
                             "ARCHIVE`) and name that archive" for p in raws]
        raws = []
    summary.imports = import_recordings(raws, warehouse, cfg, site=site)
    summary.failures += [f"import {p}: {err}" for p, err in summary.imports.failed]
    files, deferred = settled([*scan.mcap, *summary.imports.mcap], settle_s, now_ns)
    files += objects
    summary.deferred = [(str(p), why) for p, why in [*deferred_raw, *deferred]]
    before = _ledger_sites(warehouse)
    results: list[UnitResult] = []

    def seen(res: UnitResult) -> None:
        results.append(res)
        if progress is not None:
            progress.ingest_result(res)

    if files:
        if progress is not None:
            progress.ingest_total(files)
        summary.ingest = run_ingest(files, cfg, warehouse, executor=executor_kind,
                                    on_result=seen, site=site)
    for res in results:
        if res.ok and res.value.skipped:
            summary.files_skipped += 1
        elif res.ok and not res.value.changed_while_read:
            summary.files[res.value.source_file] = res.value.status
    if summary.ingest is not None:
        summary.failures += [f"ingest {path}: {err}" for path, err in summary.ingest.failed]
        summary.failures += [f"ingest {path}: changed while being read"
                             for path in summary.ingest.changed]
    summary.failures += [f"ingest {path}: {status}" for path, status in summary.files.items()
                         if status == "quarantined"]
    moved = _moved_sites(warehouse, before, summary)
    with shared_handles():  # each table's log read once per version over the run's batches
        _batch_pending(cfg, warehouse, summary, moved, site=site,
                       executor_kind=executor_kind, progress=progress,
                       ignore_place=ignore_place)
    summary.ended_at_ns = time.time_ns()
    if not summary.nothing_to_do:
        record_run(warehouse, cfg, summary)
    return summary


def _batch_pending(cfg: Config, warehouse: Path, summary: RunSummary,
                   moved: list[tuple[str, int, int]], *, site: str | None,
                   executor_kind: str | None, progress: Any, ignore_place: bool) -> None:
    """The chains killed jobs left, then every pending window (each site's alone), into
    ``summary``."""
    # chains a killed job left (the rows at a window's end changed, the units after it
    # not batched again): done first, even when no window is pending
    resumed = resume_continuations(cfg, warehouse, site=site, executor_kind=executor_kind,
                                   progress=progress)
    if resumed:
        summary.batches.append(SitesSummary({}, 0, 0, resumed=resumed))
        summary.windows += [(c.start_ns, c.end_ns) for r in resumed for c in r.continued]
        summary.failures += [f"batch [{iso(c.start_ns)}, {iso(c.end_ns)}): {u}"
                             for r in resumed for c in r.continued for u in c.failed_units]
    stale = stale_spans(warehouse, cfg)
    summary.stale = [f"site {s}: [{iso(a)}, {iso(b)}) batched with another config than the "
                     "current one: batched again" for s, a, b in _merged_spans(stale)]
    by_site = with_spans(pending_by_site(warehouse), [*stale, *moved])
    moved_sites = {name for name, _, _ in moved}  # whatever --site says: this run moved them
    pending = [(start, end, name) for name, windows in by_site.items()
               if site in (None, name) or name in moved_sites for start, end in windows]
    for start, end, name in sorted(pending):
        if name not in sites_in(warehouse, start, end):  # its files went to another site
            retire_window(cfg, warehouse, site=name, start_ns=start, end_ns=end)
            summary.moved.append(f"site {name}: [{iso(start)}, {iso(end)}) holds no file "
                                 "of it any more: its derived rows and units removed")
            continue
        try:
            batch = run_batch(cfg, warehouse, start_ns=start, end_ns=end,  # chains: above
                              executor_kind=executor_kind, progress=progress, site=name,
                              resume=False, ignore_place=ignore_place)
        except PlaceError as exc:  # the rows stay, the window stays pending
            summary.refused.append(str(exc))
            continue
        summary.windows.append((start, end))
        summary.batches.append(batch)
        summary.failures += [f"batch [{iso(start)}, {iso(end)}): {u}"
                             for u in batch.failed_units]


def _ledger_sites(warehouse: Path) -> dict[str, tuple[str, int | None, int | None]]:
    """{source file: (site, start, end)} of the ledger's ingested files."""
    rows = read_table(warehouse, "ingest_ledger", columns=[
        "source_file", "site", "status", "start_time_ns", "end_time_ns"]).to_pylist()
    return {r["source_file"]: (r["site"], r["start_time_ns"], r["end_time_ns"])
            for r in rows if r["status"] in ("ok", "partial")}


def _moved_sites(warehouse: Path, before: dict[str, tuple[str, int | None, int | None]],
                 summary: RunSummary) -> list[tuple[str, int, int]]:
    """(old site, start, end) of the files this run ingested under another site than the
    ledger had them (a half-written file read before its site metadata was): the old
    site's rows of their spans are batched again (or removed, with no file left)."""
    if summary.ingest is None:
        return []
    out = []
    for path, new_site in summary.ingest.file_sites.items():
        old = before.get(path)
        if old is None or old[0] == new_site or old[1] is None or old[2] is None:
            continue
        out.append((old[0], int(old[1]), int(old[2]) + 1))
        summary.moved.append(f"{path}: read before as site {old[0]!r}, now names "
                             f"{new_site!r}: its rows moved to {new_site!r}")
    return out


def _merged_spans(spans: list[tuple[str, int, int]]) -> list[tuple[str, int, int]]:
    """Per site, touching spans merged (for the summary's lines)."""
    out: list[tuple[str, int, int]] = []
    for s, a, b in sorted(spans):
        if out and out[-1][0] == s and a <= out[-1][2]:
            out[-1] = (s, out[-1][1], max(out[-1][2], b))
        else:
            out.append((s, a, b))
    return out
