"""A damaged table through the real `surveil` command (issue 40, items 3 and 6): every
command that needs it exits 2 with one line naming the table and `surveil doctor` (no
traceback, no SIGABRT: the code before printed deltalake's `Json error: Truncated
record...` from every command, and a batch over a deleted raw file aborted with exit
134); commands that do not need it keep working; `surveil doctor` exits 1 and
`doctor --repair` brings it back. A batch whose views rebuild hits a full disk after its
commit says so and exits 3 (the code before: a traceback, exit 1)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from jobs.common import iso
from jobs.simulate import run_simulate
from pipeline.warehouse.crashpoints import ENV, FAIL_ENV
from pipeline.warehouse.views import views_stale
from tests.warehouse.damage import DAMAGES, rebatched_copy

ROOT = Path(__file__).resolve().parents[2]


def _surveil(warehouse: Path, *args: str, env: dict[str, str] | None = None
             ) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if k not in (ENV, FAIL_ENV)}
    full.update(PYTHONPATH=str(ROOT), **(env or {}))
    return subprocess.run([sys.executable, "-m", "jobs.cli", "--warehouse", str(warehouse),
                           *args], env=full, capture_output=True, text=True, check=False,
                          timeout=600)


@pytest.fixture(scope="module")
def clean(e2e, tmp_path_factory):
    return rebatched_copy(e2e, tmp_path_factory.mktemp("damaged") / "clean")


@pytest.fixture
def warehouse(clean, tmp_path):
    dst = tmp_path / "wh"
    shutil.copytree(clean, dst)
    return dst


def _named_exit_2(res: subprocess.CompletedProcess, table: str) -> None:
    assert res.returncode == 2, (res.returncode, res.stderr[-2000:])
    assert "Traceback" not in res.stderr and "terminate called" not in res.stderr
    last = res.stderr.strip().splitlines()[-1]
    assert f"table {table} is damaged" in last and "surveil doctor" in last, last


@pytest.mark.parametrize("damage", list(DAMAGES))
def test_commands_on_a_damaged_table_exit_2_naming_it(e2e, warehouse, damage):
    table, make, problem = DAMAGES[damage]
    make(warehouse, table)
    window = ["--from", iso(e2e.start_ns), "--to", iso(e2e.end_ns)]
    _named_exit_2(_surveil(warehouse, "batch", *window, "--executor", "serial"), table)
    needs = _surveil(warehouse, "report", "accuracy_by_sector")  # reads track_errors
    if table == "track_errors":
        _named_exit_2(needs, table)
    else:
        assert needs.returncode == 0, needs.stderr
    other = _surveil(warehouse, "report", "ais_traffic")  # reads neither table
    assert other.returncode == 0, other.stderr
    _named_exit_2(_surveil(warehouse, "sql", f"SELECT count(*) FROM {table}"), table)
    assert _surveil(warehouse, "sql", "SELECT count(*) FROM ais_reports").returncode == 0
    doctor = _surveil(warehouse, "doctor")
    assert doctor.returncode == 1, doctor.stderr
    assert table in doctor.stdout and problem in doctor.stdout
    repaired = _surveil(warehouse, "doctor", "--repair", "--executor", "serial")
    assert repaired.returncode == (1 if table == "radar_tracks" else 0), repaired.stdout
    assert "Traceback" not in repaired.stderr
    if table == "radar_tracks":  # the command that brings the raw rows back
        assert "surveil ingest --force" in repaired.stdout
    again = _surveil(warehouse, "batch", *window, "--executor", "serial")
    assert again.returncode == 0, again.stderr[-2000:]


def test_an_unrelated_ingest_works_beside_a_damaged_table(e2e, warehouse, tmp_path):
    DAMAGES["truncated_log"][1](warehouse, "track_errors")
    files = run_simulate("airfield", 120.0, 3, tmp_path / "other", e2e.cfg)
    res = _surveil(warehouse, "ingest", *map(str, files), "--executor", "serial")
    assert res.returncode == 0, res.stderr[-2000:]
    assert "Traceback" not in res.stderr


@pytest.mark.parametrize("command", ["ingest", "reprocess"])
def test_the_archive_replaces_a_lost_raw_file(e2e, warehouse, command):
    """`ingest --force` (or `reprocess`) of the archive that fed a lost raw data file
    goes through and leaves the warehouse healthy, also when the views file must be
    rebuilt first (here: it is gone too; the lock's cleanup rebuilds it, which the code
    before did over the missing file, and failed before any work)."""
    DAMAGES["raw_file_deleted"][1](warehouse, "radar_tracks")
    (warehouse / "surveil.duckdb").unlink()
    args = (["ingest", "--force", *map(str, e2e.archive)] if command == "ingest" else
            ["reprocess", "--from", iso(e2e.start_ns), "--to", iso(e2e.end_ns)])
    res = _surveil(warehouse, *args, "--executor", "serial")
    assert res.returncode == 0, res.stderr[-2000:]
    doctor = _surveil(warehouse, "doctor")
    assert doctor.returncode == 0, doctor.stdout


def test_a_full_disk_at_the_views_rebuild_after_the_commit_is_exit_3(e2e, warehouse):
    window = ["--from", iso(e2e.start_ns), "--to", iso(e2e.end_ns)]
    res = _surveil(warehouse, "batch", *window, "--executor", "serial",
                   env={FAIL_ENV: "views.written"})
    assert res.returncode == 3, (res.returncode, res.stderr[-2000:])
    assert "Traceback" not in res.stderr
    assert "committed" in res.stdout and "stale" in res.stdout
    assert "surveil doctor --repair" in res.stdout
    assert views_stale(warehouse)
    doctor = _surveil(warehouse, "doctor")
    assert doctor.returncode == 1 and "views_stale" in doctor.stdout
    fixed = _surveil(warehouse, "doctor", "--repair")
    assert fixed.returncode == 0, fixed.stdout
    assert not views_stale(warehouse)


def _stale_views_exit_3(res: subprocess.CompletedProcess, job: str, warehouse: Path) -> None:
    assert res.returncode == 3, (res.returncode, res.stderr[-2000:])
    assert "Traceback" not in res.stderr
    assert f"the {job} is committed" in res.stdout and "surveil doctor --repair" in res.stdout
    assert views_stale(warehouse)
    assert _surveil(warehouse, "doctor", "--repair").returncode == 0
    assert not views_stale(warehouse)


def test_a_full_disk_at_the_views_rebuild_after_an_ingest_is_exit_3(e2e, tmp_path):
    """(the code before: a traceback, exit 1, after the commits had been made)"""
    fresh = tmp_path / "fresh"
    res = _surveil(fresh, "ingest", *map(str, e2e.archive), "--executor", "serial",
                   env={FAIL_ENV: "views.written"})
    _stale_views_exit_3(res, "ingest", fresh)


def test_a_full_disk_at_the_views_rebuild_after_a_calibration_is_exit_3(e2e, warehouse):
    window = ["--from", iso(e2e.start_ns), "--to", iso(e2e.end_ns)]
    res = _surveil(warehouse, "calibrate-radars", *window, env={FAIL_ENV: "views.written"})
    _stale_views_exit_3(res, "calibration", warehouse)
    assert "range bias" in res.stdout  # the estimates are printed all the same
