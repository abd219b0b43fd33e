"""Interrupts as exceptions, and sections they must not cut.

The CLI (:func:`install_handlers`) turns SIGTERM into :class:`Terminated`, as Python
turns SIGINT into ``KeyboardInterrupt``: both unwind the driver through its ``finally``
blocks (staging removed, pool workers stopped: :mod:`pipeline.executors`) and the CLI
exits 130 / 143 without a traceback. :func:`deferred_interrupts` holds both signals
while a commit runs, so that a file's or a window's commit is done whole or not started;
the interrupt is raised right after the section.

Pool workers ignore SIGINT (:func:`ignore_in_worker`): Ctrl-C reaches the whole process
group, and the driver alone decides (it terminates its workers).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType

EXIT_INTERRUPTED = 130  # 128 + SIGINT
EXIT_TERMINATED = 143  # 128 + SIGTERM


class Terminated(BaseException):
    """SIGTERM received (a ``BaseException``: ``except Exception`` does not catch it)."""


def _raise_terminated(signum: int, frame: FrameType | None) -> None:
    raise Terminated(f"signal {signum}")


def install_handlers() -> None:
    """SIGTERM -> :class:`Terminated` in this (main) thread; SIGINT stays
    ``KeyboardInterrupt``."""
    signal.signal(signal.SIGTERM, _raise_terminated)
    signal.signal(signal.SIGINT, signal.default_int_handler)


def ignore_in_worker() -> None:
    """In a pool worker: SIGINT ignored (the driver stops the workers), SIGTERM default."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


@contextlib.contextmanager
def deferred_interrupts() -> Iterator[None]:
    """Hold SIGINT and SIGTERM inside the block; raise the first one received
    (``KeyboardInterrupt`` / :class:`Terminated`) once it is done. A no-op outside the
    main thread (Python delivers signals there only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []
    signums = (signal.SIGINT, signal.SIGTERM)
    old = {s: signal.getsignal(s) for s in signums}
    for s in signums:
        signal.signal(s, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)
    if received:
        if received[0] == signal.SIGINT:
            raise KeyboardInterrupt
        raise Terminated(f"signal {received[0]}")
