"""`surveil run`, the nightly job (issue 17, item 1): ingest what is new, batch exactly the
windows it touches, record the run; an unchanged archive does nothing; a lock keeps two
jobs apart; what a crashed or failed run left is picked up by the next."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import polars as pl

from jobs.simulate import run_simulate
from pipeline.batch.nightly import run_nightly
from pipeline.batch.pending import pending_windows
from pipeline.ingest.driver import run_ingest
from pipeline.units import NS
from pipeline.warehouse.delta import read_table

REPO = Path(__file__).resolve().parents[2]
HOUR = 3600 * NS


def _archive(e2e, tmp_path: Path) -> Path:
    archive = tmp_path / "archive"
    archive.mkdir()
    for f in e2e.archive:
        shutil.copy(f, archive / f.name)
    return archive


def test_run_twice_then_a_new_file(e2e, tmp_path):
    archive, wh = _archive(e2e, tmp_path), tmp_path / "wh"
    first = run_nightly(e2e.cfg, wh, folders=[str(archive)], executor_kind="serial")
    assert first.exit_code == 0, first.render()
    assert len(first.files) == 2 and first.files_skipped == 0
    hour0 = e2e.start_ns // HOUR * HOUR  # 00:00; the data is 00:50 - 01:10
    assert first.windows == [(hour0, hour0 + 2 * HOUR)]
    runs = pl.from_arrow(read_table(wh, "runs"))
    assert runs.height == 1 and runs["status"][0] == "ok"
    row = runs.row(0, named=True)
    assert json.loads(row["windows_json"]) == [[hour0, hour0 + 2 * HOUR]]
    assert json.loads(row["rows_json"])["system_tracks"] > 0
    assert len(row["config_sha256"]) == 64 and row["code_version"]
    assert sorted(json.loads(row["files_json"])) == sorted(str(f.resolve())
                                                          for f in archive.iterdir())
    tracks = read_table(wh, "system_tracks")

    second = run_nightly(e2e.cfg, wh, folders=[str(archive)], executor_kind="serial")
    assert second.nothing_to_do and second.exit_code == 0
    assert "nothing to do" in second.render()
    assert read_table(wh, "runs").num_rows == 1  # nothing written
    assert read_table(wh, "system_tracks").equals(tracks)

    # the archive grows: ten minutes of another hour; only that hour is batched
    later = run_simulate("channel", 600.0, 8, archive / "later", e2e.cfg,
                         start_ns=hour0 + 3 * HOUR)
    third = run_nightly(e2e.cfg, wh, folders=[str(archive)], executor_kind="serial")
    assert third.exit_code == 0, third.render()
    assert list(third.files) == [str(later[0].resolve())] and third.files_skipped == 2
    assert third.windows == [(hour0 + 3 * HOUR, hour0 + 4 * HOUR)]
    assert read_table(wh, "runs").num_rows == 2
    assert pending_windows(wh) == []


def test_a_window_left_by_a_crash_is_batched_by_the_next_run(e2e, tmp_path):
    """Files ingested by a run that died before its batch: the ledger says they are
    unchanged, but no unit committed after them covers them, so the next run batches
    their hours (and only those)."""
    archive, wh = _archive(e2e, tmp_path), tmp_path / "wh"
    ingest = run_ingest([archive], e2e.cfg, wh, executor="serial")
    assert ingest.exit_code == 0
    hour0 = e2e.start_ns // HOUR * HOUR
    assert pending_windows(wh) == [(hour0, hour0 + 2 * HOUR)]
    res = run_nightly(e2e.cfg, wh, folders=[str(archive)], executor_kind="serial")
    assert res.files == {} and res.files_skipped == 2
    assert res.windows == [(hour0, hour0 + 2 * HOUR)] and res.exit_code == 0
    assert read_table(wh, "system_tracks").num_rows > 0
    assert pending_windows(wh) == []


def test_a_second_job_on_a_locked_warehouse_exits_2_naming_the_holder(e2e, tmp_path):
    archive, wh = _archive(e2e, tmp_path), tmp_path / "wh"
    (wh / "tables").mkdir(parents=True)  # an (empty) warehouse, so that batch gets as far
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time\n"
         "from pathlib import Path\n"
         "from pipeline.warehouse.lock import warehouse_lock\n"
         f"with warehouse_lock(Path({str(wh)!r}), command='surveil run (holder)'):\n"
         "    print('held', flush=True)\n"
         "    time.sleep(120)\n"],
        cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        for args in (("run", str(archive)), ("ingest", str(archive)),
                     ("batch", "--from", str(e2e.start_ns), "--to", str(e2e.end_ns))):
            res = subprocess.run([sys.executable, "-m", "jobs.cli", "--warehouse", str(wh),
                                  *args], cwd=REPO, capture_output=True, text=True,
                                 check=False)
            assert res.returncode == 2, (args, res.stdout, res.stderr)
            assert f"pid {holder.pid}" in res.stderr and "surveil run (holder)" in res.stderr
            assert "Traceback" not in res.stderr
        assert list((wh / "tables").iterdir()) == []  # nothing was written
    finally:
        holder.kill()
        holder.wait()
    # the kernel released the lock with the killed holder: a run goes through (without
    # --wait the lock is never waited for, LOCK_NB: one still held would be exit 2 above)
    res = subprocess.run([sys.executable, "-m", "jobs.cli", "--warehouse", str(wh), "run",
                          str(archive), "--executor", "serial"], cwd=REPO,
                         capture_output=True, text=True, check=False,
                         env={**os.environ, "PYTHONPATH": str(REPO)})
    assert res.returncode == 0, res.stderr
    assert "2 file(s) ingested" in res.stdout, res.stdout
