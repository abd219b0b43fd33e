"""The units of an ingest run: one :class:`~pipeline.ingest.worker.IngestUnit` per file."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterable
from pathlib import Path

from pipeline.config import ValidationConfig
from pipeline.errors import UsageError
from pipeline.ingest.worker import IngestUnit
from pipeline.io.mcap_site import SiteConflictError, declared_site
from pipeline.tables import is_site_name
from pipeline.warehouse.location import Location, as_location, parse_location


class IngestUsageError(UsageError):
    """Bad input paths (missing path, directory without MCAP files) or window: exit 2."""


def not_a_file(path: Path) -> str | None:
    """Why ``path`` is not read as a recording (None: a regular file, or a symbolic link
    to one, which is followed): a FIFO, socket or device (never opened: a FIFO would
    block the reader for ever), a dangling link, a link to a folder (not followed). From
    ``lstat``/``stat`` alone."""
    try:
        st = path.lstat()
    except FileNotFoundError:
        return "gone while the folder was listed"
    if stat.S_ISLNK(st.st_mode):
        try:
            target = path.stat()
        except OSError:
            return f"a dangling symbolic link (to {os.readlink(path)}): nothing to read"
        if stat.S_ISDIR(target.st_mode):
            return "a symbolic link to a folder: not followed"
        st = target
    if stat.S_ISREG(st.st_mode):
        return None
    for test, what in ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device")):
        if test(st.st_mode):
            return f"{what}: not a regular file, never opened"
    return None if stat.S_ISDIR(st.st_mode) else "not a regular file, never opened"


def folder_files(root: Path, pattern: str, skipped: list[tuple[str, str]]) -> list[Path]:
    """The regular files (and links to them) under ``root`` matching ``pattern``
    (recursive, sorted); every other entry but a folder (a FIFO, socket, device,
    dangling link, link to a folder) is appended to ``skipped`` as ``(path, why)``
    (:func:`not_a_file`)."""
    found = []
    for q in sorted(root.rglob(pattern)):
        why = not_a_file(q)
        if why is None:
            if not q.is_dir():
                found.append(q)
        else:
            skipped.append((str(q), why))
    return found


def expand_paths(paths: Iterable[Path | str], where: Path | Location | None = None,
                 skipped: list[tuple[str, str]] | None = None) -> list[Path | str]:
    """Absolute file paths: directories expand to their ``*.mcap`` files (recursive,
    sorted; a symbolic link to a file is followed and read as its target; any other
    entry that is not a regular file is left out and appended to ``skipped`` with why:
    :func:`folder_files`); an explicit file is taken as given. An ``s3://`` URI is a
    prefix (its ``*.mcap`` objects) or an object, listed with ``where``'s storage
    options (the warehouse's) and returned as URIs. Raises :class:`IngestUsageError`
    for a missing path, an explicit path that is not a regular file (a FIFO: never
    opened), a directory or prefix without MCAP files, or no paths at all."""
    out: list[Path | str] = []
    base = as_location(where) if where is not None else Location(".")
    skipped = [] if skipped is None else skipped
    for raw in paths:
        if "://" in str(raw):
            out.extend(_objects(base, str(raw)))
            continue
        p = Path(raw).expanduser()
        if not p.exists() and not p.is_symlink():
            raise IngestUsageError(f"input path does not exist: {p}")
        why = not_a_file(p)
        if why is not None:
            raise IngestUsageError(f"input path {p} is {why}")
        if p.is_dir():
            found = folder_files(p, "*.mcap", skipped)
            if not found:
                raise IngestUsageError(f"no *.mcap files under directory: {p}" + "".join(
                    f"; {q} is {w}" for q, w in skipped[:5]))
            out.extend(found)
        else:
            out.append(p)
    if not out:
        raise IngestUsageError("no input paths given")
    return list(dict.fromkeys(q if isinstance(q, str) else q.resolve() for q in out))


def _objects(base: Location, uri: str) -> list[str]:
    """The ``*.mcap`` objects of an archive prefix (or the one object) on object storage."""
    import pyarrow.fs as pafs

    try:
        loc = base.at(parse_location(uri).uri)
    except UsageError as exc:
        raise IngestUsageError(f"input {uri!r}: {exc}") from None
    info = loc.fs.get_file_info(loc.fs_path)
    if info.type == pafs.FileType.File:
        return [loc.uri]
    found = loc.fs.get_file_info(pafs.FileSelector(loc.fs_path, recursive=True,
                                                   allow_not_found=True))
    files = sorted(f"s3://{i.path}" for i in found
                   if i.type == pafs.FileType.File and i.path.endswith(".mcap"))
    if not files:
        raise IngestUsageError(f"no *.mcap objects under {loc.uri}" + (
            "" if info.type != pafs.FileType.NotFound else " (nothing there)"))
    return files


def plan_units(
    paths: Iterable[Path | str],
    *,
    warehouse: Path | Location,
    staging: Path | Location,
    validation: ValidationConfig,
    start_ns: int | None = None,
    end_ns: int | None = None,
    force: bool = False,
    asterix_editions: tuple[tuple[int, str], ...] = (),
    site: str | None = None,
    skipped: list[tuple[str, str]] | None = None,
) -> list[IngestUnit]:
    """One unit per file of ``paths`` (:func:`expand_paths`, which appends the folders'
    entries it leaves out to ``skipped``), in path order, staging under ``staging``.
    ``[start_ns, end_ns)``: both bounds or neither, a non-empty window;
    :class:`IngestUsageError` otherwise."""
    if (start_ns is None) != (end_ns is None):
        raise IngestUsageError("give both start and end of the window, or neither")
    if start_ns is not None and end_ns <= start_ns:  # type: ignore[operator]
        raise IngestUsageError(f"empty window [{start_ns}, {end_ns})")
    wh = as_location(warehouse)
    stage = wh.at(staging)
    return [
        IngestUnit(str(f), wh, stage, validation, start_ns, end_ns, force, asterix_editions,
                   site)
        for f in expand_paths(paths, wh, skipped)
    ]


def check_sites(units: list[IngestUnit]) -> None:
    """:class:`IngestUsageError` when ``--site`` contradicts the site a file's metadata
    names (refused before any work: a file is never stamped with a site it denies)."""
    bad = []
    for u in units:
        if u.site is None:
            continue
        try:
            source = as_location(u.warehouse).at(u.path)
            if source.is_local:
                named = declared_site(u.path)
            else:  # its metadata read in place (the footer and summary: ranged reads)
                with source.open_input() as f:
                    named = declared_site(f)
        except SiteConflictError as exc:
            bad.append(str(exc))
            continue
        if named is not None and named != u.site and is_site_name(named):  # (an invalid
            # name: that file alone is refused by its worker, pipeline.ingest.worker)
            bad.append(f"{u.path} names site {named!r} in its metadata")
    if bad:
        raise IngestUsageError(
            f"--site {units[0].site!r} contradicts the files' own metadata: "
            + "; ".join(bad[:5]) + (f" (and {len(bad) - 5} more)" if len(bad) > 5 else "")
            + ". Leave --site out (each file keeps its site) or ingest those files apart")
