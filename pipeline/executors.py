"""Executor seam: run the same pure stage function over small picklable work units.

``make_executor(kind, max_workers, threads_per_worker)`` gives an object with
``map_units(fn, units) -> Iterator[UnitResult]``:

- ``serial``: in this process, in order (tests, debugging);
- ``process``: ``concurrent.futures.ProcessPoolExecutor`` (default). Workers are started
  with the ``spawn`` method (no fork of a process that already runs polars/Arrow thread
  pools) and an initializer that caps library threads to ``threads_per_worker``
  (``POLARS_MAX_THREADS``, ``OMP_NUM_THREADS``, BLAS, Arrow's CPU pool), so
  processes × threads do not oversubscribe the cores;
- ``ray``: Ray tasks, only when the optional extra is installed (``surveil[ray]``); Ray
  is imported here and nowhere in stage code. A Ray session already started by the
  caller is used as it is; else ``RAY_ADDRESS`` names an existing cluster to join; else
  a local one with ``max_workers`` CPUs is started (docs/scale.md).

A unit that raises is reported as ``UnitResult(ok=False, error=...)``; nothing raises past
``map_units``, so the caller can list failed units and re-run only those. Results arrive
in completion order (serial: input order).

``units`` may be a :class:`UnitQueue`, to which the caller adds units while it reads the
results (a unit that needs earlier results: a batch unit's finalisation once the units
before it are done); the map takes them after each result it yields and ends when every
unit has its result.

``map_units(fn, units, context=factory)``: ``factory`` (picklable, no arguments) makes a
context manager that each worker enters once and leaves at its end, and ``fn`` is called
as ``fn(unit, value)`` with what it entered to (e.g. the ingest's buffer pool and helper
threads, :class:`pipeline.ingest.IngestContext`). Serial: entered once, in this process,
around the whole map. Process pool: entered by each worker process's initializer (after
the thread caps), left when that process exits. Ray: entered per task.

Every executor is also a context manager: inside ``with executor:`` the process pool
keeps one pool for every ``map_units`` call (workers start and import their libraries
once: the batch's units, then their finalisation); a map given a ``context`` still gets a
pool of its own (its workers enter that context in their initializer).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import multiprocessing
import multiprocessing.util
import os
import pickle
import traceback
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import (
    FIRST_COMPLETED,
    Future,
    ProcessPoolExecutor,
    wait,
)
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

import pyarrow as pa

from pipeline.config import ConfigError
from pipeline.signals import ignore_in_worker

U = TypeVar("U")
V = TypeVar("V")


def _glibc() -> Any:
    """glibc, for ``malloc_trim`` (None elsewhere: musl, macOS)."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
    except OSError:
        return None
    return libc if libc is not None and hasattr(libc, "malloc_trim") else None


_LIBC = _glibc()

THREAD_ENV_VARS = (
    "POLARS_MAX_THREADS",
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "RAYON_NUM_THREADS",
    "SURVEIL_THREADS_PER_WORKER",  # read by stages that open DuckDB (SET threads)
)


class ExecutorError(ConfigError):
    """Unknown executor kind, or an optional engine that is not installed (exit code 2)."""


@dataclass(frozen=True)
class UnitResult(Generic[U, V]):
    """Outcome of one unit: ``value`` when ``ok``, else ``error`` (type, message, where)."""

    unit: U
    ok: bool
    value: V | None = None
    error: str | None = None


class UnitQueue(Generic[U]):
    """Units for ``map_units`` that the caller may add to while it reads the results
    (module docstring). Iterating takes the units in order, those added meanwhile too."""

    def __init__(self, units: Iterable[U] = ()) -> None:
        self._waiting: deque[U] = deque(units)

    def add(self, units: Iterable[U]) -> None:
        self._waiting.extend(units)

    def take(self) -> list[U]:
        """Every unit waiting, removed from the queue."""
        out = list(self._waiting)
        self._waiting.clear()
        return out

    def __iter__(self) -> Iterator[U]:
        while self._waiting:
            yield self._waiting.popleft()


def as_queue(units: Iterable[U]) -> UnitQueue[U]:
    return units if isinstance(units, UnitQueue) else UnitQueue(units)


ContextFactory = Callable[[], AbstractContextManager[Any]]
"""Makes the context a worker enters once (see the module docstring)."""


class Executor(Protocol):
    def map_units(
        self, fn: Callable[..., V], units: Iterable[U], *, context: ContextFactory | None = None
    ) -> Iterator[UnitResult]: ...


def thread_env(threads_per_worker: int) -> dict[str, str]:
    """Environment variables that cap library thread pools to ``threads_per_worker``."""
    return dict.fromkeys(THREAD_ENV_VARS, str(threads_per_worker))


def limit_threads(threads_per_worker: int) -> None:
    """Worker initializer: cap thread pools before the stage imports polars/Arrow."""
    os.environ.update(thread_env(threads_per_worker))
    try:
        import pyarrow

        pyarrow.set_cpu_count(threads_per_worker)
    except ImportError:  # pragma: no cover - pyarrow is a dependency
        pass


# what the context factory of map_units entered to, in a pool worker process (set by its
# initializer, _start_worker; never in the driver's process)
_worker_context: Any = None


def _start_worker(threads_per_worker: int, context: bytes | None) -> None:
    """Pool worker initializer: cap the thread pools, then enter the pickled context
    factory's context (unpickled only now: it may import polars); it is left when the
    worker process exits."""
    global _worker_context
    ignore_in_worker()
    limit_threads(threads_per_worker)
    if context is None:
        return
    manager = pickle.loads(context)()
    _worker_context = manager.__enter__()
    multiprocessing.util.Finalize(
        None, manager.__exit__, args=(None, None, None), exitpriority=10
    )


def _call_in_worker(fn: Callable[..., V], unit: Any) -> V:
    try:
        return fn(unit, _worker_context)
    finally:
        release_memory()


def _call_released(fn: Callable[..., V], unit: Any) -> V:
    try:
        return fn(unit)
    finally:
        release_memory()


def release_memory() -> None:
    """Hand the pages a unit's frames freed back to the OS: glibc's heap and Arrow's
    pool keep them, so a pool worker carried its largest unit's memory into every later
    one (a region day's worker: ~1.0 GB between maritime units, 0.66 GB with this)."""
    pa.default_memory_pool().release_unused()
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


def _call_with_own_context(fn: Callable[..., V], context: ContextFactory, unit: Any) -> V:
    with context() as value:
        return fn(unit, value)


def _describe(exc: BaseException) -> str:
    tb = traceback.extract_tb(exc.__traceback__)
    where = f" (at {tb[-1].filename}:{tb[-1].lineno})" if tb else ""
    return f"{type(exc).__name__}: {exc}{where}"


@dataclass(frozen=True)
class SerialExecutor:
    """Runs units one after the other in this process."""

    def __enter__(self) -> SerialExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def map_units(
        self, fn: Callable[..., V], units: Iterable[U], *, context: ContextFactory | None = None
    ) -> Iterator[UnitResult]:
        with context() if context is not None else contextlib.nullcontext() as ctx:
            for unit in units:
                try:
                    value = fn(unit) if context is None else fn(unit, ctx)
                except Exception as exc:  # reported per unit, never raised past the map
                    yield UnitResult(unit, False, error=_describe(exc))
                else:
                    yield UnitResult(unit, True, value=value)


@dataclass
class ProcessExecutor:
    """A local process pool (``spawn``), library threads capped per worker.

    Used as a context manager (``with executor: ...``), one pool serves every
    ``map_units`` call inside the block (workers are started, and import their libraries,
    once); otherwise each call starts and stops its own pool."""

    max_workers: int
    threads_per_worker: int = 1
    _pool: ProcessPoolExecutor | None = None

    def _new_pool(self, n: int, context: bytes | None = None) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=max(1, min(self.max_workers, n)),
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_start_worker,
            initargs=(self.threads_per_worker, context),
        )

    def __enter__(self) -> ProcessExecutor:
        self._pool = self._new_pool(self.max_workers)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            if exc[0] is not None:  # an interrupt or an error: do not wait for the units
                _stop_pool(self._pool)
            else:
                self._pool.shutdown(wait=True)
            self._pool = None

    def map_units(
        self, fn: Callable[..., V], units: Iterable[U], *, context: ContextFactory | None = None
    ) -> Iterator[UnitResult]:
        queue = as_queue(units)
        first = queue.take()
        if not first:
            return
        if self._pool is not None and context is None:
            try:
                yield from self._map(self._pool, fn, first, queue, None)
            except BaseException:  # interrupted: the shared pool's workers go too
                _stop_pool(self._pool)
                self._pool = None
                raise
            return
        # a context is entered by each worker's initializer: a pool of its own
        blob = None if context is None else pickle.dumps(context)
        pool = self._new_pool(len(first), blob)
        try:
            yield from self._map(pool, fn, first, queue, blob)
        except BaseException:  # interrupt, or the caller stopped early: no worker left
            _stop_pool(pool)
            raise
        pool.shutdown(wait=True)

    @staticmethod
    def _map(pool: ProcessPoolExecutor, fn: Callable[..., V], units: list[U],
             queue: UnitQueue[U], blob: bytes | None) -> Iterator[UnitResult]:
        futures: dict[Future, Any] = {}

        def submit(more: list[U]) -> None:
            for u in more:
                call = _call_released if blob is None else _call_in_worker
                futures[pool.submit(call, fn, u)] = u

        submit(units)
        while futures:
            done, _ = wait(futures, return_when=FIRST_COMPLETED)
            for fut in done:
                yield _result(futures.pop(fut), fut)
                submit(queue.take())  # what the caller added on reading that result


def _stop_pool(pool: ProcessPoolExecutor, grace_s: float = 5.0) -> None:
    """Terminate the pool's workers now (their units are abandoned: nothing of theirs is
    committed, the driver commits), then reap them; SIGKILL after ``grace_s``."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(grace_s)
            if p.is_alive():
                p.kill()
                p.join(1.0)


def _result(unit: Any, fut: Future) -> UnitResult:
    try:
        return UnitResult(unit, True, value=fut.result())
    except Exception as exc:  # includes BrokenProcessPool when a worker dies
        return UnitResult(unit, False, error=_describe(exc))


@dataclass(frozen=True)
class RayExecutor:
    """Ray tasks (optional extra). ``ray.init`` is called if Ray is not running yet."""

    max_workers: int
    threads_per_worker: int = 1
    max_retries: int = 0

    def __enter__(self) -> RayExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def map_units(
        self, fn: Callable[..., V], units: Iterable[U], *, context: ContextFactory | None = None
    ) -> Iterator[UnitResult]:
        import ray

        if not ray.is_initialized():
            if os.environ.get("RAY_ADDRESS"):  # an existing cluster: it has its own CPUs
                ray.init(address=os.environ["RAY_ADDRESS"])
            else:
                ray.init(num_cpus=self.max_workers, include_dashboard=False)
        remote = ray.remote(
            num_cpus=1,
            max_retries=self.max_retries,
            runtime_env={"env_vars": thread_env(self.threads_per_worker)},
        )(_call_released if context is None else _call_with_own_context)
        queue = as_queue(units)
        refs: dict[Any, Any] = {}

        def submit(more: list[U]) -> None:
            for u in more:
                refs[remote.remote(fn, u) if context is None
                     else remote.remote(fn, context, u)] = u

        submit(queue.take())
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            for ref in done:
                unit = refs.pop(ref)
                try:
                    yield UnitResult(unit, True, value=ray.get(ref))
                except Exception as exc:  # RayTaskError wraps the unit's exception
                    yield UnitResult(unit, False, error=_describe(exc))
                submit(queue.take())


def make_executor(kind: str, max_workers: int, threads_per_worker: int) -> Executor:
    """``serial`` | ``process`` | ``ray`` executor; raises ``ExecutorError`` otherwise.

    ``max_workers`` and ``threads_per_worker`` below 1 are taken as 1."""
    max_workers, threads_per_worker = max(1, max_workers), max(1, threads_per_worker)
    if kind == "serial":
        return SerialExecutor()
    if kind == "process":
        return ProcessExecutor(max_workers, threads_per_worker)
    if kind == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            raise ExecutorError(
                "executor 'ray' needs the optional extra: pip install 'surveil-pipeline[ray]'"
            ) from None
        return RayExecutor(max_workers, threads_per_worker)
    raise ExecutorError(f"unknown executor {kind!r}: use serial, process or ray")
