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

METADATA_KEY = "site"
RECORD_PREFIX = "surveil"


class SiteConflictError(ValueError):
    """Two ``surveil`` metadata records of one file name different sites."""


def declared_site(path: Path | str | BinaryIO) -> str | None:
    """The site ``path``'s metadata names, or None (none named, or no readable summary:
    a damaged file's problems are the ingest reader's to report). ``path`` may be an open
    seekable binary file (an object-store file)."""
    names: set[str] = set()
    try:
        with (open(path, "rb") if not hasattr(path, "read")
              else contextlib.nullcontext(path)) as f:
            for record in make_reader(f).iter_metadata():
                if record.name == RECORD_PREFIX or record.name.startswith(RECORD_PREFIX + "."):
                    value = record.metadata.get(METADATA_KEY)
                    if value:
                        names.add(value)
    except Exception:  # untrusted bytes: the ingest reader reports the damage, not us
        return None
    if len(names) > 1:
        raise SiteConflictError(f"{path}: its metadata names sites {sorted(names)}")
    return names.pop() if names else None
