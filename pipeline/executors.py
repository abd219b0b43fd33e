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
"""

from __future__ import annotations

import multiprocessing
import os
import traceback
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import (
    FIRST_COMPLETED,
    Future,
    ProcessPoolExecutor,
    wait,
)
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

from pipeline.config import ConfigError

U = TypeVar("U")
V = TypeVar("V")

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


class Executor(Protocol):
    def map_units(self, fn: Callable[[U], V], units: Iterable[U]) -> Iterator[UnitResult]: ...


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

    def map_units(self, fn: Callable[[U], V], units: Iterable[U]) -> Iterator[UnitResult]:
        for unit in units:
            try:
                value = fn(unit)
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

    def _new_pool(self, n: int) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=max(1, min(self.max_workers, n)),
            mp_context=multiprocessing.get_context("spawn"),
            initializer=limit_threads,
            initargs=(self.threads_per_worker,),
        )

    def __enter__(self) -> ProcessExecutor:
        self._pool = self._new_pool(self.max_workers)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def map_units(self, fn: Callable[[U], V], units: Iterable[U]) -> Iterator[UnitResult]:
        units = list(units)
        if not units:
            return
        if self._pool is not None:
            yield from self._map(self._pool, fn, units)
            return
        with self._new_pool(len(units)) as pool:
            yield from self._map(pool, fn, units)

    @staticmethod
    def _map(pool: ProcessPoolExecutor, fn: Callable[[U], V], units: list[U]
             ) -> Iterator[UnitResult]:
        futures: dict[Future, Any] = {pool.submit(fn, u): u for u in units}
        pending = set(futures)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                yield _result(futures[fut], fut)


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

    def map_units(self, fn: Callable[[U], V], units: Iterable[U]) -> Iterator[UnitResult]:
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
        )(fn)
        refs = {remote.remote(u): u for u in units}
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                try:
                    yield UnitResult(refs[ref], True, value=ray.get(ref))
                except Exception as exc:  # RayTaskError wraps the unit's exception
                    yield UnitResult(refs[ref], False, error=_describe(exc))


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
