"""What ``surveil run`` brings from its archive folders to the ingest.

Issue 35 item 7 and issue 40 item 1. The folders may hold anything ``surveil import``
reads besides MCAP files (NMEA 0183 text, AIS CSV, ASTERIX raw / framed / pcap, ROS 1
bags): :func:`scan_folders` sorts them, :func:`import_recordings` wraps each new or
changed recording into ``<warehouse>/imported/<key>/<name>.mcap`` (``key``: a digest of
the recording's path, so a changed recording replaces its own MCAP and its rows) and
records it in ``import_ledger`` (path, size, sha256, the MCAP written, status); an
unchanged recording (same size and sha256, its MCAP still there) is not imported again.

Files still being written are left for a later run (:func:`settled`): an MCAP without
its footer and summary (the recorder has not closed it) until it has not changed for
``[archive] settle_s``, and a raw recording modified within ``settle_s``. (A file that
changes while it is read is caught by the ingest worker itself:
``FileManifest.changed_while_read``.) After ``settle_s`` without a change an unfinished
MCAP is read as it is (``partial``: a recorder that died leaves such a file for good).
"""

from __future__ import annotations

import hashlib
import struct
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pyarrow as pa

from pipeline.config import Config
from pipeline.convert.config import import_options
from pipeline.convert.legacy import detect_format, import_file, output_path
from pipeline.errors import UsageError
from pipeline.ingest.plan import folder_files, not_a_file
from pipeline.io.mcap_read import MAGIC
from pipeline.tables import conform, default_site
from pipeline.units import NS
from pipeline.warehouse.delta import read_table, replace_source_file
from pipeline.warehouse.ledger import file_fingerprint

IMPORTED = "imported"  # <warehouse>/imported/: the MCAP files run wrote for raw recordings
IMPORT_LEDGER = "import_ledger"
_OP_FOOTER = 0x02
_FOOTER_BYTES = 1 + 8 + 8 + 8 + 4  # opcode, record length, summary start, offset start, crc


@dataclass
class ArchiveScan:
    """The files of the archive folders, sorted by kind."""

    mcap: list[Path] = field(default_factory=list)
    raw: list[Path] = field(default_factory=list)  # what `surveil import` reads
    other: list[Path] = field(default_factory=list)  # neither: not read
    # entries that are not regular files (FIFO, socket, device, dangling link, link to a
    # folder): never opened, each with why (pipeline.ingest.plan.not_a_file)
    skipped: list[tuple[str, str]] = field(default_factory=list)


def scan_folders(folders: Sequence[Path | str], exclude: Iterable[Path] = ()) -> ArchiveScan:
    """Every file under ``folders`` (recursive; hidden files and anything under
    ``exclude``, the warehouse, left out), sorted into MCAP files, raw recordings
    (``detect_format`` of :mod:`pipeline.convert.legacy`) and others. A symbolic link to
    a file is followed (read as its target); an entry that is not a regular file (a
    FIFO, socket, device, dangling link, link to a folder) is never opened and is listed
    in ``skipped`` with why. A folder that does not exist is a :class:`UsageError`."""
    skip = [Path(p).resolve() for p in exclude]
    scan = ArchiveScan()
    seen: set[Path] = set()
    for raw in folders:
        root = Path(raw).expanduser()
        if not root.exists():
            raise UsageError(f"archive folder does not exist: {root}")
        if root.is_dir():
            listed = folder_files(root, "*", found_skipped := [])
            scan.skipped += [(p, why) for p, why in found_skipped
                             if not _hidden(Path(p), root)
                             and not any(Path(p).is_relative_to(s) for s in skip)]
            files = [q for q in listed if not _hidden(q, root)]
        elif (why := not_a_file(root)) is not None:
            scan.skipped.append((str(root), why))
            files = []
        else:
            files = [root]
        for q in files:
            q = q.resolve()
            if q in seen or any(q.is_relative_to(s) for s in skip):
                continue
            seen.add(q)
            if q.suffix.lower() == ".mcap":
                scan.mcap.append(q)
            elif detect_format(q) != "unknown":
                scan.raw.append(q)
            else:
                scan.other.append(q)
    return scan


def _hidden(path: Path, root: Path) -> bool:
    return any(part.startswith(".") for part in path.relative_to(root).parts)


def finished_mcap(path: Path) -> bool:
    """The file ends with an MCAP footer and the closing magic: its writer closed it
    (the summary, with its metadata index, is written just before)."""
    try:
        with open(path, "rb") as f:
            size = f.seek(0, 2)
            tail = len(MAGIC) + _FOOTER_BYTES
            if size < len(MAGIC) + tail:
                return False
            f.seek(size - tail)
            end = f.read(tail)
    except OSError:
        return False
    return end[-len(MAGIC):] == MAGIC and end[0] == _OP_FOOTER and struct.unpack_from(
        "<Q", end, 1)[0] == _FOOTER_BYTES - 9


def settled(paths: Iterable[Path], settle_s: float, now_ns: int | None = None,
            *, raw: bool = False) -> tuple[list[Path], list[tuple[Path, str]]]:
    """(ready, [(deferred, why)]): an MCAP file is ready when its writer closed it
    (:func:`finished_mcap`) or when it has not changed for ``settle_s`` (read as it is);
    a raw recording (``raw``) when it has not changed for ``settle_s``."""
    now = time.time_ns() if now_ns is None else now_ns
    ready, deferred = [], []
    for p in paths:
        if not raw and finished_mcap(p):
            ready.append(p)
            continue
        age_s = (now - p.stat().st_mtime_ns) / NS
        if age_s >= settle_s:
            ready.append(p)
            continue
        what = "changed" if raw else "has no footer/summary yet and changed"
        deferred.append((p, f"{what} {age_s:.0f} s ago: still being written? read once "
                            f"unchanged for [archive] settle_s = {settle_s:g} s"))
    return ready, deferred


@dataclass
class ImportResult:
    """What :func:`import_recordings` did: the MCAP files to ingest (new and unchanged
    imports), per recording its status, and failures."""

    mcap: list[Path] = field(default_factory=list)
    imported: dict[str, str] = field(default_factory=dict)  # recording -> ok | partial
    unchanged: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)
    rejected: int = 0  # pieces written to /import/rejects

    @property
    def exit_code(self) -> int:
        """As ``surveil import``'s: 1 when a recording failed or was partial."""
        return 1 if self.failed or "partial" in self.imported.values() else 0


def imported_path(warehouse: Path, recording: Path) -> Path:
    """Where run writes the MCAP of ``recording``: one folder per recording path."""
    key = hashlib.sha256(str(recording.resolve()).encode()).hexdigest()[:16]
    return output_path(recording, warehouse / IMPORTED / key)


def import_recordings(recordings: Sequence[Path], warehouse: Path, cfg: Config,
                      site: str | None = None) -> ImportResult:
    """Wrap each new or changed recording into its MCAP under ``<warehouse>/imported/``
    (``site`` in its metadata, as ``surveil import --site``) and record it in
    ``import_ledger``; an unchanged one (size, sha256, its MCAP there) is listed as it
    is. A recording that fails is recorded as ``failed`` (tried again once changed)."""
    out = ImportResult()
    if not recordings:
        return out
    known = {r["source_file"]: r for r in read_table(warehouse, IMPORT_LEDGER).to_pylist()}
    options = import_options(cfg)
    for rec in recordings:
        size, sha = file_fingerprint(rec)
        mcap = imported_path(warehouse, rec)
        prior = known.get(str(rec))
        if (prior is not None and prior["sha256"] == sha and prior["size_bytes"] == size
                and (prior["status"] == "failed" or mcap.is_file())):
            out.unchanged += 1
            if prior["status"] != "failed":
                out.mcap.append(mcap)
            continue
        mcap.parent.mkdir(parents=True, exist_ok=True)
        row = {"source_file": str(rec), "size_bytes": size, "sha256": sha,
               "format": detect_format(rec), "imported_at_ns": time.time_ns()}
        try:
            done = import_file(rec, mcap.parent, options=options, site=site)
        except ValueError as exc:  # damaged or unrecognised content found while wrapping
            out.failed.append((str(rec), str(exc)))
            row.update(mcap_file=None, status="failed", error=str(exc))
        else:
            out.mcap.append(Path(done.output))
            out.imported[str(rec)] = done.status
            out.rejected += done.rejected
            row.update(mcap_file=done.output, status=done.status, format=done.format,
                       error=f"{done.rejected} pieces rejected" if done.rejected else None)
        replace_source_file(warehouse, IMPORT_LEDGER,
                            conform(IMPORT_LEDGER, pa.Table.from_pylist([row]),
                                    site=site or default_site()),
                            source_file=str(rec))
    return out
