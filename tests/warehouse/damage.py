"""The four ways a warehouse table is damaged in the doctor's tests (issue 40, item 3):
its newest log entry cut in half, a garbage next-version file, a data file its snapshot
lists deleted (a raw table's or a derived table's)."""

from __future__ import annotations

import shutil
from pathlib import Path
from urllib.parse import unquote

import polars as pl
from deltalake import DeltaTable

from jobs.batch import run_batch
from pipeline.families import FAMILIES
from pipeline.warehouse.delta import read_table

DERIVED = [name for fam in FAMILIES for name in fam.outputs]


def rows(warehouse: Path, name: str) -> pl.DataFrame:
    """A table's rows in one order, without the wall-clock columns (``*_at_ns``)."""
    t = pl.from_arrow(read_table(warehouse, name))
    t = t.drop([c for c in t.columns if c.endswith("_at_ns")])
    return t.sort(t.columns) if t.height else t


def rebatched_copy(e2e, dst: Path) -> Path:
    """The e2e warehouse copied to ``dst`` and its window batched once more, so that
    every derived table has a version before its newest."""
    shutil.copytree(e2e.warehouse, dst)
    again = run_batch(e2e.cfg, dst, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                      executor_kind="serial")
    assert again.exit_code == 0, again.render()
    return dst


def _log(warehouse: Path, name: str) -> Path:
    return warehouse / "tables" / name / "_delta_log"


def newest_entry(warehouse: Path, name: str) -> Path:
    return max(_log(warehouse, name).glob("*.json"), key=lambda p: int(p.stem))


def truncate_newest(warehouse: Path, name: str) -> str:
    """Cut the newest log entry of ``name`` in half (a full disk mid-write)."""
    entry = newest_entry(warehouse, name)
    data = entry.read_bytes()
    entry.write_bytes(data[: len(data) // 2])
    return entry.name


def garbage_next(warehouse: Path, name: str) -> str:
    """A garbage file where ``name``'s next version goes."""
    nxt = _log(warehouse, name) / f"{int(newest_entry(warehouse, name).stem) + 1:020d}.json"
    nxt.write_text("garbage{\n")
    return nxt.name


def delete_data_file(warehouse: Path, name: str) -> str:
    """Delete the first data file ``name``'s snapshot lists; returns its relative path."""
    table = warehouse / "tables" / name
    rel = unquote(DeltaTable(str(table)).get_add_actions(flatten=True).column("path")[0].as_py())
    (table / rel).unlink()
    return rel


def rewrite_data_file(warehouse: Path, name: str) -> str:
    """Append bytes to the first data file ``name``'s snapshot lists (its size no longer
    the one the log records); returns its relative path."""
    table = warehouse / "tables" / name
    rel = unquote(DeltaTable(str(table)).get_add_actions(flatten=True).column("path")[0].as_py())
    with open(table / rel, "ab") as f:
        f.write(b"tampered")
    return rel


DAMAGES = {  # id -> (table, damage, what doctor calls it)
    "truncated_log": ("track_errors", truncate_newest, "log_unreadable"),
    "garbage_next_version": ("track_errors", garbage_next, "log_unreadable"),
    "raw_file_deleted": ("radar_tracks", delete_data_file, "file_missing"),
    "derived_file_deleted": ("track_errors", delete_data_file, "file_missing"),
}
