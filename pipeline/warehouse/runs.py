"""The ``runs`` table: one row per nightly run that had work (what it read, wrote, failed)."""

from __future__ import annotations

import hashlib
import json
import os
from importlib import metadata
from pathlib import Path
from typing import Any

import polars as pl

from pipeline import tables
from pipeline.config import Config
from pipeline.warehouse.delta import replace_window


def record_run(warehouse: Path, cfg: Config, s: Any) -> None:
    """One ``runs`` row (one commit) for ``s``, a run's summary
    (``pipeline.batch.nightly.RunSummary``)."""
    row = {
        "started_at_ns": s.started_at_ns, "ended_at_ns": s.ended_at_ns,
        "run_id": f"{s.started_at_ns}-{os.getpid()}", "command": s.command,
        "status": s.status, "files_json": json.dumps(s.files, sort_keys=True),
        "files_skipped": s.files_skipped,
        "windows_json": json.dumps([[int(a), int(b)] for a, b in s.windows]),
        "rows_json": json.dumps(s.rows(), sort_keys=True),
        "failures_json": json.dumps(s.failures), "config_sha256": config_sha256(cfg),
        "code_version": code_version(),
    }
    frame = tables.conform("runs", pl.DataFrame([row]))
    replace_window(warehouse, "runs", frame, start_ns=s.started_at_ns,
                   end_ns=s.started_at_ns + 1)


def config_sha256(cfg: Config) -> str:
    """sha256 of the config file (of its repr for a config built in memory)."""
    try:
        data = Path(cfg.source).read_bytes()
    except OSError:
        data = repr(cfg).encode()
    return hashlib.sha256(data).hexdigest()


def code_version() -> str:
    try:
        return metadata.version("surveil-pipeline")
    except metadata.PackageNotFoundError:
        return "unknown"
