"""What a job takes of the machine: its helper threads (niceness per thread on Linux, and
pools built with it) and the memory it may size itself to.

A kernel with no dependencies, used by the decoders, the stager, the ingest job, the
batch's window planning and the reports.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

# Niceness added to a job's helper threads (initializers of their pools). On two cores the
# chunk fetch thread (read + zstd, one chunk after another) is the critical path of an
# ingest: CFS shares the cores equally among runnable threads, so while the Parquet
# writer, the file hasher and the second JSON parser run, it gets a fraction of a core
# and the parsers then wait for chunks. The writer and the hasher have slack until the
# end of the file (the writer is at most two row groups behind, so memory stays bounded);
# the second parser is needed at the end of each group, hence a smaller value. Measured
# on the 1 M-report bench file in alternated fresh processes (docs/ingest_speed.md,
# session 8): 0.06-0.10 s less per ingest (medians of 8-14 pairs, five experiments); it
# works through the stager's second file per slot (with one file: no gain).
WRITER_NICE = 10
HASHER_NICE = 10
SECOND_PARSER_NICE = 5


def lower_thread_priority(nice: int) -> None:
    """Thread-pool initializer: add ``nice`` to the calling thread's niceness (at most
    19). Linux only (a thread is a task with its own nice value there); elsewhere, or
    where the system refuses, nothing changes. Raising one's own niceness needs no
    privilege, but it cannot be undone: call it only in threads of a pool."""
    if sys.platform != "linux" or nice <= 0:
        return
    tid = threading.get_native_id()
    with contextlib.suppress(OSError):
        current = os.getpriority(os.PRIO_PROCESS, tid)
        os.setpriority(os.PRIO_PROCESS, tid, min(19, current + nice))


def helper_pool(workers: int, name: str, nice: int) -> ThreadPoolExecutor:
    """A thread pool whose threads run ``nice`` steps nicer than the thread creating them
    (:func:`lower_thread_priority` as their initializer)."""
    return ThreadPoolExecutor(workers, name, initializer=lower_thread_priority, initargs=(nice,))


def machine_memory_bytes() -> int:
    """The machine's physical memory, or the container's cgroup (v2) limit when lower;
    0 where neither can be read."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        total = 0
    try:
        limit = int(Path("/sys/fs/cgroup/memory.max").read_text())  # "max": no limit
    except (OSError, ValueError):
        limit = 0
    return min(total, limit) if total and limit else total or limit
