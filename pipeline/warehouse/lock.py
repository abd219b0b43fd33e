"""One writer per warehouse: an advisory lock on ``<warehouse>/.surveil.lock``.

``surveil run``, ``ingest``, ``batch``, ``reprocess``, ``demo``, ``calibrate`` and
``calibrate-radars`` (every command that commits) hold it while they work, so two jobs
started by cron, a systemd timer and an engineer never interleave their commits.
The lock is ``flock(2)`` on an open file: the kernel releases it when the holder exits,
however it exits (SIGKILL included), so a crashed job never leaves a stale lock. The
holder writes its pid, start time and command into the file; a second job either waits
(``--wait``) or exits 2 naming them. Every job that stages or commits holds it, so the
job taking it removes what dead jobs left (:func:`recover`).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import time
from collections.abc import Iterator
from pathlib import Path

from pipeline.errors import UsageError
from pipeline.units import iso

LOCK_FILE = ".surveil.lock"
STAGING_DIR = "_staging"  # ingest-<pid>-<ns>, batch-<start>-<end>, rewrite-<uuid>

try:
    import fcntl
except ImportError:  # not POSIX: no lock (documented)
    fcntl = None  # type: ignore[assignment]


class WarehouseLockedError(UsageError):
    """Another job holds the warehouse (exit code 2)."""


def holder(warehouse: Path) -> dict:
    """What the lock file says of its (last) holder: pid, started_at_ns, command, host."""
    try:
        return json.loads((Path(warehouse) / LOCK_FILE).read_text() or "{}")
    except (OSError, ValueError):
        return {}


def recover(warehouse: Path) -> None:
    """What a dead job left, cleaned up by the next job holding the lock: everything
    under ``<warehouse>/_staging/`` (every job that stages holds the lock, so none is
    staging now) and temporary views files (``.surveil.duckdb.tmp-*``) removed, and a
    views file older than the tables (killed between its commits and its views rebuild)
    rebuilt."""
    from pipeline.warehouse.views import refresh_views_file

    staging = Path(warehouse) / STAGING_DIR
    for tmp in Path(warehouse).glob(".surveil.duckdb.tmp-*"):  # a killed views rebuild
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    with contextlib.suppress(FileNotFoundError):
        for entry in os.scandir(staging):
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path, ignore_errors=True)
            else:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(entry.path)
    with contextlib.suppress(OSError):
        staging.rmdir()
    refresh_views_file(warehouse)


@contextlib.contextmanager
def warehouse_lock(warehouse: Path, *, command: str, wait: bool = False) -> Iterator[None]:
    """Hold the warehouse's lock for the block (creating the warehouse folder). Raises
    :class:`WarehouseLockedError` naming the holder when another process holds it and
    ``wait`` is False; with ``wait``, blocks until it is free."""
    warehouse = Path(warehouse)
    warehouse.mkdir(parents=True, exist_ok=True)
    if fcntl is None:
        yield
        return
    fd = os.open(warehouse / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            h = holder(warehouse)
            since = iso(h["started_at_ns"]) if "started_at_ns" in h else "unknown time"
            raise WarehouseLockedError(
                f"warehouse {warehouse} is busy: pid {h.get('pid', '?')} on "
                f"{h.get('host', '?')} has held it since {since} "
                f"({h.get('command', 'unknown command')}); try later or pass --wait"
            ) from None
        me = {"pid": os.getpid(), "host": socket.gethostname(),
              "started_at_ns": time.time_ns(), "command": command}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(me).encode(), 0)
        recover(warehouse)
        yield
    finally:
        os.close(fd)  # releases the lock
