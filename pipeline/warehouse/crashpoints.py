"""Named kill points at the warehouse's commit boundaries, for crash tests.

``SURVEIL_CRASH_AT=<point>`` makes the process SIGKILL itself when it reaches that point
(as if the machine died there): ``ingest.<table>`` after an ingest's commit of a table
(its raw tables, ``mcap_index``, ``ingest_ledger`` last), ``batch.<table>`` after a
batch's commit of a table (each derived table, ``rejects``, ``batch_units``),
``batch.continuation`` after a batch's window committed, before the units after it are
batched again (``pipeline.batch.continuation``: the trailing-edge chain),
``views.written`` inside the views rebuild (the new file written, not yet swapped in)
and ``views.replaced`` (swapped in). ``SURVEIL_FAIL_AT=<point>`` makes the same point
raise ``OSError(ENOSPC)`` instead, as a full disk does there (the job goes on to handle
it). The variables are read once, at import: unset, a point costs one comparison each.
"""

from __future__ import annotations

import errno
import os
import signal

ENV = "SURVEIL_CRASH_AT"
FAIL_ENV = "SURVEIL_FAIL_AT"
_AT = os.environ.get(ENV) or None
_FAIL_AT = os.environ.get(FAIL_ENV) or None


def crash_point(name: str) -> None:
    """SIGKILL this process when ``SURVEIL_CRASH_AT`` names ``name``; raise a full disk's
    ``OSError`` when ``SURVEIL_FAIL_AT`` does."""
    if name == _AT:
        os.kill(os.getpid(), signal.SIGKILL)
    if name == _FAIL_AT:
        raise OSError(errno.ENOSPC, f"No space left on device ({FAIL_ENV}={name})")
