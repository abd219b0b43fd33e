"""The site (deployment) an MCAP file declares in its metadata.

A file names its site with the key ``site`` of a metadata record named ``surveil`` or
``surveil.<anything>`` (``surveil simulate`` writes it in ``surveil.scenario``,
``surveil import --site`` in ``surveil.import``; any other tool may write a ``surveil``
record ``{"site": "harbour-north"}``). Read from the summary's metadata index: no chunk
is read. Ingest stamps it on every row of the file (``schemas/tables.toml [site]``).
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import BinaryIO

from mcap.reader import make_reader
from mcap.records import DataEnd, Footer, Metadata
from mcap.stream_reader import StreamReader

METADATA_KEY = "site"
RECORD_PREFIX = "surveil"


class SiteConflictError(ValueError):
    """Two ``surveil`` metadata records of one file name different sites."""


def declared_site(path: Path | str | BinaryIO) -> str | None:
    """The site ``path``'s metadata names, or None (none named, or nothing readable: a
    damaged file's problems are the ingest reader's to report). Read from the summary's
    metadata index; a file without a summary (still being written, or cut off) is
    scanned for its metadata records instead (:func:`_scanned_metadata`: a writer puts
    them ahead of the messages, so a half-written file names its site too). ``path`` may
    be an open seekable binary file (an object-store file)."""
    names: set[str] = set()
    try:
        with (open(path, "rb") if not hasattr(path, "read")
              else contextlib.nullcontext(path)) as f:
            records = list(make_reader(f).iter_metadata())
    except Exception:  # untrusted bytes: the ingest reader reports the damage, not us
        records = []
    if not records and not hasattr(path, "read"):
        records = _scanned_metadata(Path(path))
    for record in records:
        if record.name == RECORD_PREFIX or record.name.startswith(RECORD_PREFIX + "."):
            value = record.metadata.get(METADATA_KEY)
            if value:
                names.add(value)
    if len(names) > 1:
        raise SiteConflictError(f"{path}: its metadata names sites {sorted(names)}")
    return names.pop() if names else None


def _scanned_metadata(path: Path) -> list[Metadata]:
    """The metadata records of a file's data section, read record by record without
    decompressing a chunk (a file without a summary: the metadata index is in the
    summary); as many as are readable before any damage or the cut-off end."""
    found: list[Metadata] = []
    try:
        with open(path, "rb") as f:
            for record in StreamReader(f, skip_magic=False, emit_chunks=True).records:
                if isinstance(record, Metadata):
                    found.append(record)
                elif isinstance(record, DataEnd | Footer):
                    break
    except Exception:  # the cut-off end of a file being written, or damage: stop there
        pass
    return found
