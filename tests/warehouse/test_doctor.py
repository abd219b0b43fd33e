"""`surveil doctor [--repair]` on a real warehouse from the simulator (issue 40, item 3):
each of the four damages is found; the repair of a broken log or a lost derived file
leaves every derived table row for row as in the undamaged warehouse; a lost raw file
is named with the `surveil ingest --force` command that brings it back, and doctor
keeps naming it until it is ingested again (then every raw table is as before too)."""

from __future__ import annotations

import shutil

import pyarrow as pa
import pyarrow.fs as pafs
import pytest
from deltalake import DeltaTable, write_deltalake

from pipeline.batch.doctor import run_doctor
from pipeline.decode.registry import RAW_TABLES
from pipeline.ingest.driver import run_ingest
from pipeline.warehouse import pending
from pipeline.warehouse.doctor import DOCTOR_DIR, examine
from pipeline.warehouse.location import parse_location
from pipeline.warehouse.views import views_stale
from tests.warehouse.damage import DAMAGES, DERIVED, rebatched_copy, rewrite_data_file, rows


@pytest.fixture(scope="module")
def clean(e2e, tmp_path_factory):
    return rebatched_copy(e2e, tmp_path_factory.mktemp("doctor") / "clean")


@pytest.fixture(scope="module")
def clean_rows(clean):
    return {n: rows(clean, n) for n in [*DERIVED, *RAW_TABLES]}


@pytest.fixture
def warehouse(clean, tmp_path):
    dst = tmp_path / "wh"
    shutil.copytree(clean, dst)
    return dst


def _same(a, b) -> bool:
    return a.height == b.height and (a.height == 0 or a.equals(b))


def test_an_undamaged_warehouse_is_healthy(e2e, clean):
    result = run_doctor(e2e.cfg, clean)
    assert result.exit_code == 0, result.render()
    assert result.before.healthy and "is healthy" in result.render()


@pytest.mark.parametrize("damage", list(DAMAGES))
def test_doctor_finds_each_damage(e2e, warehouse, damage):
    table, make, problem = DAMAGES[damage]
    what = make(warehouse, table)
    result = run_doctor(e2e.cfg, warehouse)
    assert result.exit_code == 1
    found = [(f.table, f.problem) for f in result.before.findings]
    assert (table, problem) in found, found
    assert [f for f in result.before.findings if f.table == table and what in f.detail]
    text = result.render()
    assert table in text and problem in text and "--repair" in text


REWRITTEN = ("track_errors", rewrite_data_file, "file_size")


@pytest.mark.parametrize("damage", ["truncated_log", "garbage_next_version",
                                    "derived_file_deleted", "derived_file_rewritten"])
def test_repair_gives_back_every_derived_row(e2e, warehouse, clean_rows, damage):
    table, make, problem = DAMAGES.get(damage, REWRITTEN)
    what = make(warehouse, table)
    assert (table, problem) in {(f.table, f.problem) for f in examine(warehouse).findings}
    result = run_doctor(e2e.cfg, warehouse, repair=True, executor_kind="serial")
    assert result.exit_code == 0, result.render()
    assert result.after is not None and result.after.healthy, result.render()
    for name in DERIVED:
        assert _same(rows(warehouse, name), clean_rows[name]), name
    if problem == "log_unreadable":  # the broken entry is kept, moved aside
        assert list((warehouse / DOCTOR_DIR).glob(f"*/tables/{table}/_delta_log/{what}"))
        assert result.batches, "the units committed since the good version are re-batched"
    if problem == "file_size":  # the rewritten file too
        assert list((warehouse / DOCTOR_DIR).glob(f"*/tables/{table}/{what}"))


def test_a_derived_table_whose_every_log_entry_is_broken_is_batched_anew(e2e, warehouse,
                                                                          clean_rows):
    """No version of track_errors' log reads (its first entry cut, the later ones and
    checkpoints garbage): was "rebuild it from the archive"; the batch writes the table,
    so the repair sets the log aside and batches every unit again."""
    log = warehouse / "tables" / "track_errors" / "_delta_log"
    for entry in log.iterdir():
        if entry.is_file():
            entry.write_bytes(entry.read_bytes()[: entry.stat().st_size // 2])
    assert examine(warehouse).damaged["track_errors"].good_version is None
    result = run_doctor(e2e.cfg, warehouse, repair=True, executor_kind="serial")
    assert result.exit_code == 0, result.render()
    assert result.after is not None and result.after.healthy, result.render()
    for name in DERIVED:
        assert _same(rows(warehouse, name), clean_rows[name]), name
    assert list((warehouse / DOCTOR_DIR).glob("*/tables/track_errors/_delta_log/*.json"))


def test_a_layout_other_than_schemas_is_found_and_left_alone(e2e, warehouse):
    """A table whose columns are not those ``schemas/`` declares, and a folder of a table
    it does not declare, are named; --repair leaves them (a rebuild's job)."""
    odd = pa.table({"start_ns": pa.array(["a"], pa.string()), "extra": [1]})
    shutil.rmtree(warehouse / "tables" / "fault_truth", ignore_errors=True)
    write_deltalake(str(warehouse / "tables" / "fault_truth"), odd)
    write_deltalake(str(warehouse / "tables" / "not_a_table"), odd)
    result = run_doctor(e2e.cfg, warehouse)
    details = {(f.table, f.problem, f.detail) for f in result.before.findings}
    assert ("not_a_table", "unknown_table") in {(t, p) for t, p, _ in details}
    schema = sorted(d for t, p, d in details if t == "fault_truth" and p == "schema")
    assert "column extra is not in schemas/" in schema
    assert any(d.startswith("column start_ns is string, schemas/ declares") for d in schema)
    assert any("not null) is missing" in d for d in schema)
    repaired = run_doctor(e2e.cfg, warehouse, repair=True, executor_kind="serial")
    assert repaired.exit_code == 1 and repaired.after is not None
    assert {f.problem for f in repaired.after.findings} == {"unknown_table", "schema"}


def test_a_lost_raw_file_is_named_until_ingested_again(e2e, warehouse, clean_rows):
    make = DAMAGES["raw_file_deleted"][1]
    make(warehouse, "radar_tracks")
    result = run_doctor(e2e.cfg, warehouse, repair=True, executor_kind="serial")
    assert result.exit_code == 1  # something is left to the operator
    commands = [line for line in result.todo if "surveil ingest --force" in line]
    assert len(commands) == 1, result.todo
    fed = [str(f) for f in e2e.archive if f"surveil ingest --force {f}" in commands[0]]
    assert len(fed) == 1, commands
    assert result.after is not None
    assert [f.problem for f in result.after.findings] == ["raw_rows_lost"]
    again = run_doctor(e2e.cfg, warehouse)  # a later doctor still names it
    assert again.exit_code == 1 and fed[0] in again.render()
    ingest = run_ingest(fed, e2e.cfg, warehouse, force=True, executor="serial")
    assert ingest.exit_code == 0, ingest.render()
    for name in RAW_TABLES:
        assert _same(rows(warehouse, name), clean_rows[name]), name
    assert run_doctor(e2e.cfg, warehouse).exit_code == 0


def test_leftovers_of_a_dead_job_are_found_and_removed(e2e, warehouse):
    (warehouse / "_staging" / "batch-x-1-2").mkdir(parents=True)
    marker = pending.begin(warehouse, ["track_errors"], job="batch",
                           window=[e2e.start_ns, e2e.end_ns], site="channel-clean")
    (warehouse / "tables" / "track_errors" / "_delta_log").touch()  # (mtime: views stale)
    newest = max((warehouse / "tables" / "track_errors" / "_delta_log").glob("*.json"))
    newest.touch()
    found = {f.problem for f in examine(warehouse).findings}
    assert found == {"orphan_staging", "pending_marker", "views_stale"}
    result = run_doctor(e2e.cfg, warehouse, repair=True, executor_kind="serial")
    assert result.exit_code == 0, result.render()
    assert not (warehouse / "_staging").exists()
    assert pending.markers(warehouse) == [] and not marker.exists()
    assert not views_stale(warehouse)


def test_doctor_on_object_storage_finds_and_repairs(e2e, clean, clean_rows, s3):
    """The same checks and repairs on an ``s3://`` warehouse (moto's server): a truncated
    log entry and a deleted raw data file are found through the warehouse's storage
    options; the repair moves the entry aside there and forgets the file (FSCK); the
    units of the restored table are batched only after the raw rows are ingested again
    (their inputs lack rows until then), so no derived row is lost meanwhile."""
    wh = parse_location(f"s3://{s3.bucket()}/wh")
    pafs.copy_files(str(clean / "tables"), f"{wh.fs_path}/tables", destination_filesystem=wh.fs)
    bucket = wh.fs_path.split("/")[0]
    entry = max(k for k in s3.keys(bucket, "wh/tables/track_errors/_delta_log/")
                if k.endswith(".json"))
    data = wh.fs.open_input_stream(f"{bucket}/{entry}").read()
    with wh.fs.open_output_stream(f"{bucket}/{entry}") as f:
        f.write(data[: len(data) // 2])
    raw = wh / "tables" / "radar_tracks"
    rel = DeltaTable(raw.uri, storage_options=raw.storage_options).get_add_actions(
        flatten=True).column("path")[0].as_py()
    wh.fs.delete_file(f"{raw.fs_path}/{rel}")
    found = {(f.table, f.problem) for f in examine(wh).findings}
    assert found == {("track_errors", "log_unreadable"), ("radar_tracks", "file_missing")}
    result = run_doctor(e2e.cfg, wh, repair=True, executor_kind="serial")
    assert result.exit_code == 1  # the raw file's rows are left to an ingest
    assert result.after is not None
    assert [f.problem for f in result.after.findings] == ["raw_rows_lost"], result.render()
    assert not result.batches and any("after the ingest" in t for t in result.todo)
    for name in DERIVED:
        assert _same(rows(wh, name), clean_rows[name]), name

