"""Progress bars with ETA on stderr (rich), only when stderr is a terminal: ingest in
bytes (advanced as each file is committed), batch in work units. A job takes an optional
``progress`` and calls its hooks; ``None`` (tests, cron, pipes) shows nothing."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

from rich import filesize
from rich.console import Console
from rich.progress import (
    BarColumn,
    DownloadColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)


class TerminalProgress:
    """The bars of one command: ``ingest`` (bytes of the files) and ``batch`` (units)."""

    def __init__(self) -> None:
        self._bars = Progress(
            TextColumn("{task.description:<8}"), BarColumn(), TextColumn("{task.fields[done]}"),
            TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
            console=Console(stderr=True), transient=False,
        )
        self._ingest: TaskID | None = None
        self._batch: TaskID | None = None

    def __enter__(self) -> TerminalProgress:
        self._bars.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._bars.stop()

    def ingest_total(self, paths: list[Path | str]) -> None:
        total = sum(_size(p) for p in paths)
        self._ingest = self._bars.add_task(
            "ingest", total=total, done=f"0/{filesize.decimal(total)} in {len(paths)} file(s)")
        self._bytes = DownloadColumn()

    def ingest_result(self, res: Any) -> None:
        if self._ingest is None:
            return
        size = _size(res.unit.path)
        self._bars.advance(self._ingest, size)
        task = self._bars.tasks[self._ingest]
        self._bars.update(self._ingest, done=self._bytes.render(task).plain)

    def batch_units(self, n: int) -> None:
        self._batch = self._bars.add_task("batch", total=n, done=f"0/{n} units")
        self._units = MofNCompleteColumn()

    def batch_result(self, res: Any) -> None:
        if self._batch is None:
            return
        self._bars.advance(self._batch, 1)
        task = self._bars.tasks[self._batch]
        self._bars.update(self._batch, done=self._units.render(task).plain + " units")


def terminal_progress() -> TerminalProgress | None:
    """Bars when stderr is a terminal, else None."""
    return TerminalProgress() if sys.stderr.isatty() else None


def _size(path: Path | str) -> int:
    """A file's size (an object's, on object storage; 0 when it cannot be had)."""
    if "://" not in str(path):
        return os.path.getsize(path) if os.path.exists(path) else 0
    from pipeline.warehouse.location import as_location

    try:
        return as_location(str(path)).stat()[0]
    except (OSError, ValueError):
        return 0
