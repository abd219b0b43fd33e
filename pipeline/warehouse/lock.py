"""One writer per warehouse: an advisory lock on ``<warehouse>/.surveil.lock``.

``surveil run``, ``ingest``, ``batch``, ``reprocess``, ``demo``, ``calibrate`` and
``calibrate-radars`` (every command that commits) hold it while they work, so two jobs
started by cron, a systemd timer and an engineer never interleave their commits.
The lock is ``flock(2)`` on an open file: the kernel releases it when the holder exits,
however it exits (SIGKILL included), so a crashed job never leaves a stale lock. The
holder writes its pid, start time and command into the file; a second job either waits
(``--wait``) or exits 2 naming them. Every job that stages or commits holds it, so the
job taking it removes what dead jobs left (:func:`recover`).

**On object storage** (an ``s3://`` warehouse) there is no ``flock``: the lock is the
object ``<warehouse>/.surveil.lock`` held as a *lease* (:class:`ObjectLease`). A job
takes it with a conditional put (``If-None-Match: *``: only one of two jobs creates it),
or takes over a released or expired one with ``If-Match`` on the ETag it read (only
one of two jobs replaces it); a thread renews it every ``LEASE_S / 4`` with ``If-Match``
on its own ETag, and it is released by a conditional overwrite too. Its guarantee,
honestly: mutual exclusion holds while the holder renews within ``LEASE_S`` (60 s). A
holder killed (SIGKILL, a lost node) leaves the lease to expire: the next job waits up to
``LEASE_S`` and takes it over, then cleans up as above (at once when the dead holder ran
on the same host: its pid is gone). A holder that could not renew for
``LEASE_S`` (a paused VM, a network partition) has lost it: its next renewal fails, and
the job is terminated (SIGTERM to itself: exit 143, nothing half committed); by then a
second job may have taken the lease, and the two may overlap for the commit in flight,
which Delta's own conditional put keeps atomic per table (one of two commits of a
version fails; neither is half written). Conditional writes need a store that honours
``If-None-Match`` and ``If-Match`` on PUT (Amazon S3 since 2024, MinIO, R2, Ceph RGW 18+).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import signal
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pipeline.errors import UsageError
from pipeline.units import iso
from pipeline.warehouse.location import Location, as_location

log = logging.getLogger(__name__)

LOCK_FILE = ".surveil.lock"
STAGING_DIR = "_staging"  # ingest-<pid>-<ns>, batch-<start>-<end>, rewrite-<uuid>
LEASE_S = 60.0  # an object-store lock not renewed for this long is free to take over

try:
    import fcntl
except ImportError:  # not POSIX: no lock (documented)
    fcntl = None  # type: ignore[assignment]


class WarehouseLockedError(UsageError):
    """Another job holds the warehouse (exit code 2)."""


def holder(warehouse: Path | Location) -> dict:
    """What the lock file says of its (last) holder: pid, started_at_ns, command, host."""
    try:
        return json.loads((as_location(warehouse) / LOCK_FILE).read_text() or "{}")
    except (OSError, ValueError):
        return {}


def held_by(warehouse: Path | Location) -> dict | None:
    """What :func:`holder` says when a job holds the warehouse now, else None: locally a
    non-blocking ``flock`` tried (and let go at once), on object storage the lease read
    (held unless released or expired). For a reader that must not take the lock
    (``surveil doctor`` without ``--repair``) yet must not call a running job's staging
    a dead one's."""
    loc = as_location(warehouse)
    if not loc.is_local:
        try:
            doc = json.loads((loc / LOCK_FILE).read_text() or "{}")
        except (OSError, ValueError):
            return None
        renewed = doc.get("renewed_at_ns", 0) / 1e9
        expired = time.time() - renewed > doc.get("lease_s", LEASE_S)
        return None if doc.get("released") or expired or _dead_here(doc) else doc
    if fcntl is None:
        return None
    try:
        fd = os.open(loc.path / LOCK_FILE, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return holder(warehouse) or {"pid": "?"}
    finally:
        os.close(fd)  # (releases a lock it got)
    return None


def recover(warehouse: Path | Location) -> None:
    """What a dead job left, cleaned up by the next job holding the lock: everything
    under ``<warehouse>/_staging/`` (every job that stages holds the lock, so none is
    staging now) and temporary views files (``.surveil.duckdb.tmp-*``) removed, and a
    views file older than the tables (killed between its commits and its views rebuild)
    rebuilt."""
    from pipeline.warehouse.views import refresh_views_file

    loc = as_location(warehouse)
    if not loc.is_local:  # no views file on object storage (pipeline.warehouse.views)
        (loc / STAGING_DIR).rmtree()
        return
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


def _busy(warehouse: Path | Location, h: dict) -> WarehouseLockedError:
    since = iso(h["started_at_ns"]) if "started_at_ns" in h else "unknown time"
    return WarehouseLockedError(
        f"warehouse {warehouse} is busy: pid {h.get('pid', '?')} on "
        f"{h.get('host', '?')} has held it since {since} "
        f"({h.get('command', 'unknown command')}); try later or pass --wait")


@contextlib.contextmanager
def warehouse_lock(warehouse: Path | Location, *, command: str, wait: bool = False
                   ) -> Iterator[None]:
    """Hold the warehouse's lock for the block (creating the warehouse folder). Raises
    :class:`WarehouseLockedError` naming the holder when another process holds it and
    ``wait`` is False; with ``wait``, blocks until it is free. On object storage: an
    :class:`ObjectLease` (module docstring)."""
    loc = as_location(warehouse)
    if not loc.is_local:
        with ObjectLease(loc / LOCK_FILE, command=command).held(wait):
            recover(loc)
            yield
        return
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
            raise _busy(warehouse, holder(warehouse)) from None
        me = {"pid": os.getpid(), "host": socket.gethostname(),
              "started_at_ns": time.time_ns(), "command": command}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(me).encode(), 0)
        recover(warehouse)
        yield
    finally:
        os.close(fd)  # releases the lock


def _dead_here(doc: dict) -> bool:
    """The lease's holder ran on this host and its process is gone (killed): no need to
    wait for the lease to expire. (A pid reused since only makes the next job wait.)"""
    if doc.get("host") != socket.gethostname() or not isinstance(doc.get("pid"), int):
        return False
    try:
        os.kill(doc["pid"], 0)
    except ProcessLookupError:
        return True
    except OSError:  # alive, another user's
        return False
    return False


class ObjectLease:
    """The writer lock of a warehouse on object storage: a lease object taken and renewed
    with conditional puts (obstore), its guarantee in the module docstring. ``lease_s``:
    how long a holder that stopped renewing keeps it."""

    def __init__(self, obj: Location, *, command: str, lease_s: float = LEASE_S) -> None:
        self.obj, self.command, self.lease_s = obj, command, lease_s
        self._etag: str | None = None
        self._stop = threading.Event()

    def _store(self) -> tuple[Any, str]:
        from obstore.store import S3Store

        bucket, _, key = self.obj.uri.split("://", 1)[1].partition("/")
        o = self.obj.storage_options
        config = {k: v for k, v in o.items() if k.startswith("aws_") and k not in (
            "aws_allow_http", "aws_s3_locking_provider", "aws_s3_allow_unsafe_rename")}
        http = o.get("aws_allow_http", "").lower() in ("1", "true", "yes")
        return S3Store.from_url(f"s3://{bucket}", config=config,
                                client_options={"allow_http": http}), key

    def _doc(self, released: bool = False) -> bytes:
        now = time.time_ns()
        return json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                           "started_at_ns": self._started, "renewed_at_ns": now,
                           "lease_s": self.lease_s, "command": self.command,
                           "released": released}).encode()

    def acquire(self, wait: bool) -> None:
        import obstore
        from obstore.exceptions import AlreadyExistsError, PreconditionError

        store, key = self._store()
        self._started = time.time_ns()
        while True:
            try:
                self._etag = obstore.put(store, key, self._doc(), mode="create")["e_tag"]
                return
            except AlreadyExistsError:
                pass
            try:
                got = obstore.get(store, key)
            except FileNotFoundError:  # released by a delete between the two calls
                continue
            doc = json.loads(bytes(got.bytes()) or b"{}")
            renewed = doc.get("renewed_at_ns", 0) / 1e9
            expired = time.time() - renewed > doc.get("lease_s", self.lease_s)
            if doc.get("released") or expired or _dead_here(doc):
                try:  # free or expired: only one of two jobs replaces the ETag it read
                    self._etag = obstore.put(store, key, self._doc(),
                                             mode={"e_tag": got.meta["e_tag"]})["e_tag"]
                    if not doc.get("released"):
                        log.warning("took over the lock of %s: its holder (pid %s on %s) "
                                    "had not renewed it for %.0f s", self.obj.parent,
                                    doc.get("pid"), doc.get("host"), time.time() - renewed)
                    return
                except PreconditionError:
                    continue
            if not wait:
                raise _busy(self.obj.parent, doc)
            time.sleep(min(2.0, self.lease_s / 10))

    def _renew(self) -> None:
        import obstore
        from obstore.exceptions import PreconditionError

        store, key = self._store()
        while not self._stop.wait(self.lease_s / 4):
            try:
                self._etag = obstore.put(store, key, self._doc(),
                                         mode={"e_tag": self._etag})["e_tag"]
            except PreconditionError:
                log.error("lost the lock of %s (not renewed within %.0f s; another job "
                          "holds it now): stopping", self.obj.parent, self.lease_s)
                os.kill(os.getpid(), signal.SIGTERM)
                return
            except Exception as exc:  # the store unreachable: try again until the lease ends
                log.warning("could not renew the lock of %s: %s", self.obj.parent, exc)

    def release(self) -> None:
        import obstore

        self._stop.set()
        if self._etag is None:
            return
        store, key = self._store()
        with contextlib.suppress(Exception):  # (lost meanwhile: it is another's now)
            obstore.put(store, key, self._doc(released=True), mode={"e_tag": self._etag})
        self._etag = None

    @contextlib.contextmanager
    def held(self, wait: bool) -> Iterator[None]:
        self.acquire(wait)
        renewer = threading.Thread(target=self._renew, name="surveil-lease", daemon=True)
        renewer.start()
        try:
            yield
        finally:
            self.release()
            renewer.join(timeout=5)
