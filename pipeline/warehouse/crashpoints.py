"""Named kill points at the warehouse's commit boundaries, for crash tests.

``SURVEIL_CRASH_AT=<point>`` makes the process SIGKILL itself when it reaches that point
(as if the machine died there): ``ingest.<table>`` after an ingest's commit of a table
(its raw tables, ``mcap_index``, ``ingest_ledger`` last), ``batch.<table>`` after a
batch's commit of a table (each derived table, ``rejects``, ``batch_units``),
``batch.continuation`` after a batch's window committed, before the units after it are
batched again (``pipeline.batch.continuation``: the trailing-edge chain),
``views.written`` inside the views rebuild (the new file written, not yet swapped in)
and ``views.replaced`` (swapped in). The variable is read once, at import: unset, a point costs one
comparison.
"""

from __future__ import annotations

import os
import signal

ENV = "SURVEIL_CRASH_AT"
_AT = os.environ.get(ENV) or None


def crash_point(name: str) -> None:
    """SIGKILL this process when ``SURVEIL_CRASH_AT`` names ``name``."""
    if name == _AT:
        os.kill(os.getpid(), signal.SIGKILL)
