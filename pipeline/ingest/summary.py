"""Counts of one ingest run, and their one screen of text."""

from __future__ import annotations

from dataclasses import dataclass, field

from pipeline.decode.registry import RAW_TABLES
from pipeline.errors import EXIT_VIEWS_STALE, views_stale_note
from pipeline.ingest.worker import FileManifest
from pipeline.render import printable


@dataclass
class IngestSummary:
    """Counts of one ingest run; ``exit_code`` 0 when every file is ok or skipped."""

    files_total: int = 0
    files_ok: int = 0
    files_partial: int = 0
    files_quarantined: int = 0
    files_skipped: int = 0
    files_duplicate: int = 0
    messages_read: int = 0
    rows: dict[str, int] = field(default_factory=lambda: dict.fromkeys(RAW_TABLES, 0))
    rejects: dict[str, int] = field(default_factory=dict)
    not_stored: dict[str, int] = field(default_factory=dict)
    failed: list[tuple[str, str]] = field(default_factory=list)
    window: tuple[int, int] | None = None
    committed_files: list[str] = field(default_factory=list)
    overlaps: list[str] = field(default_factory=list)  # "file topic other [a, b)" warnings
    time_warnings: list[str] = field(default_factory=list)  # files with synthetic times
    file_sites: dict[str, str] = field(default_factory=dict)  # committed file -> its site
    # the place check (pipeline.batch.place): sites whose positions lie outside the region
    place_warnings: list[str] = field(default_factory=list)
    changed: list[str] = field(default_factory=list)  # changed while read: not committed
    quarantined: list[tuple[str, str]] = field(default_factory=list)  # (file, why)
    # entries of the input folders that are not regular files (a FIFO, a dangling link):
    # never opened, listed with why (pipeline.ingest.plan.not_a_file); no exit code
    not_files: list[tuple[str, str]] = field(default_factory=list)
    # the views file's rebuild after the commits failed (a full disk): why, else None
    views_error: str | None = None

    @property
    def rejected(self) -> int:
        """Rejects rows this run wrote (every one is data not used)."""
        return sum(self.rejects.values())

    @property
    def exit_code(self) -> int:
        """0: everything read was used (all files ok or skipped, no rejects row); 1: some
        row was rejected, some file partial/quarantined or changed while it was read, or
        a unit failed; :data:`EXIT_VIEWS_STALE` (3) when nothing else went wrong but the
        views file could not be rebuilt after the commits."""
        bad = (self.files_partial or self.files_quarantined or self.failed or self.rejected
               or self.changed)
        return 1 if bad else EXIT_VIEWS_STALE if self.views_error else 0

    def add(self, m: FileManifest) -> None:
        if m.skipped:
            self.files_skipped += 1
            return
        self.files_ok += m.status == "ok"
        self.files_partial += m.status == "partial"
        self.files_quarantined += m.status == "quarantined"
        if m.status == "quarantined":
            self.quarantined.append((m.source_file, m.error or "nothing readable"))
        self.files_duplicate += m.status == "duplicate"
        self.messages_read += m.message_count
        for k, v in m.rows.items():
            self.rows[k] = self.rows.get(k, 0) + v
        _merge(self.rejects, m.rejects_by_reason)
        _merge(self.not_stored, m.not_stored)

    def render(self) -> str:
        """One screen of text for the CLI."""
        lines = [
            f"ingest: {self.files_total} files: {self.files_ok} ok, {self.files_partial} "
            f"partial, {self.files_quarantined} quarantined, {self.files_duplicate} duplicate "
            f"(content ingested under another name), {self.files_skipped} skipped "
            f"(unchanged), {len(self.failed)} failed; {self.messages_read} messages read"
        ]
        if self.window:
            lines.append(f"window: [{self.window[0]}, {self.window[1]}) ns")
        lines.append("rows:    " + _fmt(self.rows))
        lines.append(
            f"rejects: {self.rejected} rows ({_fmt(self.rejects)})" if self.rejected
            else "rejects: none"
        )  # fmt: skip
        if self.not_stored:
            lines.append("valid, not stored (by type): " + _fmt(self.not_stored))
        if self.rejects.get("decoder_missing"):
            lines.append("WARNING: ASTERIX channels not decoded: the ASTERIX decoder is not "
                         "installed; pip install 'surveil-pipeline[asterix]'")  # fmt: skip
        for text in self.overlaps[:10]:
            lines.append(f"WARNING: two sources overlap: {text}")
        if self.overlaps:
            lines.append("  (recorded in source_overlaps: both files are of one site, so "
                         "their rows mix; give each source its own site (MCAP metadata "
                         "`site` or ingest --site) or remove the duplicate file)")
        for text in self.time_warnings[:10]:
            lines.append(f"WARNING: synthetic times: {text}")
        if len(self.time_warnings) > 10:
            lines.append(f"... and {len(self.time_warnings) - 10} more files with synthetic times")
        for path in self.changed[:10]:
            lines.append(f"NOT INGESTED {path}: changed while being read (still being "
                         "written?); read again when the recorder has finished it")
        for path, why in self.not_files[:10]:
            lines.append(f"SKIPPED {path}: {why}")
        if len(self.not_files) > 10:
            lines.append(f"... and {len(self.not_files) - 10} more entries skipped")
        for path, why in self.quarantined[:10]:
            lines.append(f"QUARANTINED {path}: {why}")
        if len(self.quarantined) > 10:
            lines.append(f"... and {len(self.quarantined) - 10} more quarantined files")
        for text in self.place_warnings:
            lines.append(f"WARNING: {text}")
        for path, err in self.failed[:10]:
            lines.append(f"FAILED {path}: {err}")
        if len(self.failed) > 10:
            lines.append(f"... and {len(self.failed) - 10} more failed units")
        if self.views_error:
            lines.append(views_stale_note("ingest", self.views_error))
        lines.append(f"exit code {self.exit_code}")
        # file names come from the archive: a control character in one is shown escaped
        return "\n".join(map(printable, lines))


def _merge(into: dict[str, int], counts: dict[str, int]) -> None:
    for k, v in counts.items():
        into[k] = into.get(k, 0) + v


def _fmt(counts: dict[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
