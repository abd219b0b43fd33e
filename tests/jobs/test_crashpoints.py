"""Kill points at every commit boundary (issue 18, item 4): a real ``surveil`` process
SIGKILLs itself (``SURVEIL_CRASH_AT``) after a table's commit, after the ledger or
inside the views rebuild. Readers then see each table exactly old or exactly new, the
reports run, and the next job converges to the clean single-run result, removing the
dead job's staging and rebuilding a views file older than the tables."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import polars as pl
import pytest
from polars.testing import assert_frame_equal

from jobs.common import iso
from pipeline.decode.registry import RAW_TABLES
from pipeline.families import FAMILIES
from pipeline.warehouse import pending
from pipeline.warehouse.crashpoints import ENV
from pipeline.warehouse.delta import read_table, replace_window
from pipeline.warehouse.views import connect_views_file, views_stale

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="SIGKILL")

ROOT = Path(__file__).resolve().parents[2]
DERIVED = [name for fam in FAMILIES for name in fam.outputs]
INGESTED = [*RAW_TABLES, "mcap_index"]


def _surveil(config: Path | None, warehouse: Path, *args: str, crash_at: str | None = None
             ) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != ENV}
    env["PYTHONPATH"] = str(ROOT)
    if crash_at is not None:
        env[ENV] = crash_at
    cmd = [sys.executable, "-m", "jobs.cli", "--warehouse", str(warehouse)]
    if config is not None:
        cmd += ["--config", str(config)]
    return subprocess.run([*cmd, *args], env=env, capture_output=True, text=True,
                          check=False, timeout=900)


def _rows(warehouse: Path, name: str) -> pl.DataFrame:
    t = pl.from_arrow(read_table(warehouse, name))
    return t.sort(t.columns) if t.height else t


def _same(a: pl.DataFrame, b: pl.DataFrame) -> bool:
    return a.height == b.height and (a.height == 0 or a.equals(b))


def _views_count(warehouse: Path, name: str) -> int:
    with connect_views_file(warehouse) as con:
        return con.execute(f'SELECT count(*) FROM "{name}"').fetchall()[0][0]


def _clean_after(warehouse: Path) -> None:
    """What a finished job leaves: no staging, no pending marker, views up to date."""
    assert not (warehouse / "_staging").exists(), list((warehouse / "_staging").iterdir())
    assert pending.markers(warehouse) == []
    assert not views_stale(warehouse)
    assert not list(warehouse.glob(".surveil.duckdb.tmp-*"))  # a killed views rebuild's


def test_the_next_job_removes_dead_jobs_staging(e2e, tmp_path):
    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    dead = wh / "_staging" / "ingest-99999999-1"
    dead.mkdir(parents=True)
    (dead / "x.parquet").write_bytes(b"PAR1")
    batch_dir = wh / "_staging" / f"batch-{e2e.start_ns}-{e2e.end_ns}" / "system_tracks"
    batch_dir.mkdir(parents=True)
    (batch_dir / "y.parquet").write_bytes(b"PAR1")
    res = _surveil(None, wh, "ingest", *map(str, e2e.archive), "--executor", "serial")
    assert res.returncode == 0, res.stderr
    assert not (wh / "_staging").exists()


def test_views_older_than_the_tables_are_rebuilt(e2e, tmp_path):
    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    assert not views_stale(wh)
    before = _views_count(wh, "associations")
    # a commit behind the views' back (as a job killed before its views rebuild)
    half = read_table(wh, "associations").slice(0, 10)
    replace_window(wh, "associations", half, start_ns=e2e.start_ns, end_ns=e2e.end_ns)
    assert views_stale(wh) and before != 10
    res = _surveil(None, wh, "sql", "SELECT count(*) AS n FROM associations", "--format",
                   "csv")
    assert res.returncode == 0, res.stderr
    assert res.stdout.split()[-1] == "10"
    # the next writer job, even one with nothing to commit, rebuilds the views file
    res = _surveil(None, wh, "ingest", *map(str, e2e.archive), "--executor", "serial")
    assert res.returncode == 0, res.stderr
    assert _views_count(wh, "associations") == 10
    assert not views_stale(wh)


@pytest.mark.parametrize("point", ["ingest.radar_tracks", "ingest.mcap_index",
                                   "ingest.ingest_ledger", "views.written"])
def test_ingest_killed_at_a_commit_boundary(e2e, tmp_path, point):
    wh = tmp_path / "wh"
    new = {n: _rows(e2e.warehouse, n) for n in INGESTED}
    args = ("ingest", *map(str, e2e.archive), "--executor", "serial")
    res = _surveil(None, wh, *args, crash_at=point)
    assert res.returncode == -signal.SIGKILL, (res.returncode, res.stderr)
    for name in INGESTED:  # an empty warehouse before: each table empty or whole
        now = _rows(wh, name)
        assert now.height == 0 or _same(now, new[name]), name
    res = _surveil(None, wh, "sql", "SELECT count(*) FROM radar_tracks")
    assert res.returncode == 0, res.stderr
    res = _surveil(None, wh, *args)
    assert res.returncode == 0, res.stderr
    for name in INGESTED:
        assert_frame_equal(_rows(wh, name), new[name])
    _clean_after(wh)
    assert _views_count(wh, "radar_tracks") == new["radar_tracks"].height


@pytest.fixture(scope="module")
def changed(e2e, tmp_path_factory):
    """A config whose batch output differs from the e2e warehouse's, and the warehouse a
    clean single batch run with it leaves."""
    root = tmp_path_factory.mktemp("crash-batch")
    config = root / "changed.toml"
    config.write_text(Path(e2e.cfg.source).read_text()
                      .replace("epoch_period_s = 4.0", "epoch_period_s = 5.0"))
    clean = root / "clean"
    shutil.copytree(e2e.warehouse, clean)
    res = _surveil(config, clean, *_batch_args(e2e))
    assert res.returncode == 0, res.stderr
    return config, clean


def _batch_args(e2e) -> tuple[str, ...]:
    return ("batch", "--from", iso(e2e.start_ns), "--to", iso(e2e.end_ns),
            "--executor", "serial")


@pytest.mark.parametrize("point", [f"batch.{DERIVED[0]}", "batch.batch_units",
                                   "views.written"])
def test_batch_killed_at_a_commit_boundary(e2e, changed, tmp_path, point):
    config, clean = changed
    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    old = {n: _rows(wh, n) for n in DERIVED}
    new = {n: _rows(clean, n) for n in DERIVED}
    assert any(not _same(old[n], new[n]) for n in DERIVED), "config change had no effect"
    res = _surveil(config, wh, *_batch_args(e2e), crash_at=point)
    assert res.returncode == -signal.SIGKILL, (res.returncode, res.stderr)
    now = {n: _rows(wh, n) for n in DERIVED}
    for name in DERIVED:
        assert _same(now[name], old[name]) or _same(now[name], new[name]), name
    if point.startswith("batch."):  # mid-commit: readers still see the old window
        assert all(_same(now[n], old[n]) for n in DERIVED)
    res = _surveil(config, wh, "report", "accuracy_by_sector")
    assert res.returncode == 0, res.stderr
    res = _surveil(config, wh, *_batch_args(e2e))
    assert res.returncode == 0, res.stderr
    for name in DERIVED:
        assert_frame_equal(_rows(wh, name), new[name])
    _clean_after(wh)
    assert _views_count(wh, DERIVED[0]) == new[DERIVED[0]].height
