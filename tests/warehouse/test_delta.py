"""Delta warehouse: idempotent overwrites, window replaces, Delta's own predicate check,
safe literals, snapshot reads with pruning, and readers that never see a mix."""

from __future__ import annotations

import datetime as dt
import threading

import numpy as np
import pyarrow as pa
import pyarrow.dataset as pds
import pytest
from deltalake import DeltaTable
from mcap_fixtures import DAY, T0, hours, truth_rows

from pipeline.tables import schema
from pipeline.units import NS
from pipeline.warehouse.damage import DamagedTableError
from pipeline.warehouse.delta import (
    may_hold_rows,
    read_table,
    replace_rows,
    replace_source_file,
    replace_window,
    shared_handles,
    sql_literal,
    table_files,
    table_path,
    table_version,
    window_predicate,
)


def test_missing_table_reads_empty_with_canonical_schema(tmp_path):
    t = read_table(tmp_path, "radar_tracks", start_ns=T0, end_ns=T0 + DAY)
    assert t.num_rows == 0 and t.schema == schema("radar_tracks")
    t = read_table(tmp_path, "truth", columns=["time_ns", "mmsi"])
    assert t.schema.names == ["time_ns", "mmsi"]
    assert table_files(tmp_path, "truth") == [] and table_version(tmp_path, "truth") is None


def test_overwrite_twice_gives_same_rows(tmp_path):
    rows = truth_rows(hours(0, 30))  # spans two days
    for _ in range(2):
        replace_window(tmp_path, "truth", rows, start_ns=T0, end_ns=T0 + 2 * DAY)
    got = read_table(tmp_path, "truth")
    assert got.num_rows == rows.num_rows and got.equals(rows)
    assert got.schema == schema("truth")
    parts = {p.split("/date=")[1].split("/")[0] for p in table_files(tmp_path, "truth")}
    assert parts == {"2026-01-01", "2026-01-02"}


def test_window_replace_leaves_other_windows_untouched(tmp_path):
    replace_window(tmp_path, "truth", truth_rows(hours(0, 30)), start_ns=T0, end_ns=T0 + 2 * DAY)
    start, end = T0 + 10 * 3600 * NS, T0 + 12 * 3600 * NS
    new = truth_rows(hours(10, 12, step_s=30), speed=9.0)
    files_day2 = {f for f in table_files(tmp_path, "truth") if "date=2026-01-02" in f}
    replace_window(tmp_path, "truth", new, start_ns=start, end_ns=end)
    got = read_table(tmp_path, "truth")
    t, speed = got["time_ns"].to_numpy(), got["speed_mps"].to_numpy()
    inside = (t >= start) & (t < end)
    assert np.all(speed[inside] == 9.0) and inside.sum() == new.num_rows
    assert np.all(speed[~inside] == 5.0) and (~inside).sum() == len(hours(0, 30)) - 120
    # the other day's files were not rewritten
    assert files_day2 <= set(table_files(tmp_path, "truth"))
    # reading the window returns exactly the new rows
    assert read_table(tmp_path, "truth", start_ns=start, end_ns=end).equals(new)


def test_rows_outside_predicate_are_rejected_by_delta(tmp_path):
    replace_window(tmp_path, "truth", truth_rows(hours(0, 2)), start_ns=T0, end_ns=T0 + DAY)
    v = table_version(tmp_path, "truth")
    outside = truth_rows(hours(5, 6))
    with pytest.raises(Exception, match="failed validation"):
        replace_window(tmp_path, "truth", outside, start_ns=T0, end_ns=T0 + 3600 * NS)
    assert table_version(tmp_path, "truth") == v
    assert read_table(tmp_path, "truth").num_rows == len(hours(0, 2))


def test_empty_replace_deletes_matching_rows(tmp_path):
    replace_window(tmp_path, "truth", truth_rows(hours(0, 4)), start_ns=T0, end_ns=T0 + DAY)
    replace_window(
        tmp_path, "truth", schema("truth").empty_table(), start_ns=T0, end_ns=T0 + 3600 * NS
    )
    got = read_table(tmp_path, "truth")
    assert got.num_rows == len(hours(1, 4)) and got["time_ns"].to_numpy().min() >= T0 + 3600 * NS


def test_source_file_replace_with_quotes_in_path(tmp_path):
    weird = "/archive/it's a \\ file; DROP TABLE x --.mcap"
    replace_source_file(tmp_path, "truth", truth_rows(hours(0, 1), source=weird), source_file=weird)
    replace_source_file(
        tmp_path, "truth", truth_rows(hours(0, 1), source="/b.mcap"), source_file="/b.mcap"
    )
    replace_source_file(
        tmp_path, "truth", truth_rows(hours(0, 2), speed=7.0, source=weird), source_file=weird
    )
    got = read_table(tmp_path, "truth", predicate=pds.field("source_file") == weird)
    assert got.num_rows == len(hours(0, 2)) and set(got["speed_mps"].to_pylist()) == {7.0}
    assert read_table(tmp_path, "truth").num_rows == len(hours(0, 2)) + len(hours(0, 1))


def test_source_file_replace_in_window_keeps_rows_outside(tmp_path):
    replace_source_file(tmp_path, "truth", truth_rows(hours(0, 4)), source_file="/a.mcap")
    start, end = T0 + 3600 * NS, T0 + 2 * 3600 * NS
    replace_source_file(
        tmp_path,
        "truth",
        truth_rows(hours(1, 2), speed=1.0),
        source_file="/a.mcap",
        start_ns=start,
        end_ns=end,
    )
    got = read_table(tmp_path, "truth")
    assert got.num_rows == len(hours(0, 4))
    assert sorted(set(got["speed_mps"].to_pylist())) == [1.0, 5.0]


def test_sql_literal():
    assert sql_literal("it's") == "'it''s'"
    assert sql_literal(5) == "5" and sql_literal(-(2**63)) == str(-(2**63))
    assert sql_literal(dt.date(2026, 1, 2)) == "DATE '2026-01-02'"
    assert sql_literal(None) == "NULL" and sql_literal(True) == "TRUE"
    for bad in (float("nan"), b"x", object(), "a\x00b"):
        with pytest.raises(TypeError):
            sql_literal(bad)


def test_window_predicate_has_date_range():
    pred = window_predicate("truth", T0 + 3600 * NS, T0 + DAY + 1)
    assert f"time_ns >= {T0 + 3600 * NS}" in pred
    assert "date >= DATE '2026-01-01'" in pred and "date <= DATE '2026-01-02'" in pred
    # end exactly at midnight: the next day is not included
    assert "date <= DATE '2026-01-01'" in window_predicate("truth", T0, T0 + DAY)
    with pytest.raises(ValueError):
        window_predicate("ingest_ledger", T0, T0 + 1)


def test_read_window_prunes_partitions(tmp_path):
    replace_window(tmp_path, "truth", truth_rows(hours(0, 72)), start_ns=T0, end_ns=T0 + 3 * DAY)
    ds = DeltaTable(str(table_path(tmp_path, "truth"))).to_pyarrow_dataset()
    from pipeline.warehouse.delta import window_filter

    expr = window_filter("truth", T0 + DAY + 60 * NS, T0 + DAY + 3600 * NS)
    frags = list(ds.get_fragments(filter=expr))
    assert len(frags) == 1 and "date=2026-01-02" in frags[0].path
    got = read_table(tmp_path, "truth", start_ns=T0 + DAY + 60 * NS, end_ns=T0 + DAY + 3600 * NS)
    assert got.num_rows == 59


def test_replace_rows_validates_schema(tmp_path):
    bad = pa.table({"time_ns": [T0]})  # missing required columns
    with pytest.raises(KeyError):
        replace_rows(tmp_path, "truth", bad, predicate_sql="time_ns >= 0")


def test_concurrent_reader_sees_old_or_new_never_a_mix(tmp_path):
    start, end = T0, T0 + 2 * DAY
    versions = {
        1.0: truth_rows(hours(0, 30, step_s=20), speed=1.0),
        2.0: truth_rows(hours(0, 30, step_s=45), speed=2.0),
    }
    replace_window(tmp_path, "truth", versions[1.0], start_ns=start, end_ns=end)
    seen: list[tuple[int, set]] = []
    stop = threading.Event()
    errors: list[BaseException] = []

    def reader() -> None:
        try:
            while not stop.is_set():
                t = read_table(tmp_path, "truth")
                seen.append((t.num_rows, set(t["speed_mps"].to_pylist())))
        except BaseException as exc:  # surfaced in the main thread
            errors.append(exc)

    th = threading.Thread(target=reader)
    th.start()
    try:
        for k in range(6):
            speed = 2.0 if k % 2 == 0 else 1.0
            replace_window(tmp_path, "truth", versions[speed], start_ns=start, end_ns=end)
    finally:
        stop.set()
        th.join()
    assert not errors
    allowed = {(v.num_rows, frozenset({s})) for s, v in versions.items()}
    assert len(seen) > 3
    for n, speeds in seen:
        assert (n, frozenset(speeds)) in allowed


def test_a_table_written_before_its_schema_gained_a_column(tmp_path):
    """A warehouse written by an earlier release (here: truth without ``mmsi``): reads give
    nulls for the new column, views bind, and the next window replace adds the column."""
    import duckdb
    from deltalake import write_deltalake

    from pipeline.tables import conform
    from pipeline.warehouse.views import register_tables

    rows = truth_rows(hours(0, 2))
    old = conform("truth", rows).drop_columns(["mmsi"])
    write_deltalake(str(table_path(tmp_path, "truth")), old, partition_by=["date"])
    got = read_table(tmp_path, "truth")
    assert got.schema == schema("truth") and got["mmsi"].null_count == got.num_rows
    con = duckdb.connect()
    register_tables(con, tmp_path, ["truth"])
    assert con.execute("SELECT count(*), count(mmsi) FROM truth").fetchall() == [(rows.num_rows, 0)]
    replace_window(tmp_path, "truth", rows, start_ns=T0, end_ns=T0 + DAY)
    assert "mmsi" in DeltaTable(str(table_path(tmp_path, "truth"))).schema().to_arrow().names
    assert read_table(tmp_path, "truth").equals(read_table(tmp_path, "truth").cast(schema("truth")))
    register_tables(con, tmp_path, ["truth"])
    assert con.execute("SELECT count(*) FROM truth").fetchall() == [(rows.num_rows,)]


def test_a_column_doc_edited_since_the_table_was_written(tmp_path):
    """A column's doc changed in schemas/ after the table was created (main's rejects.stage):
    delta-rs refuses a write whose column metadata differs; the write keeps the table's."""
    from deltalake import write_deltalake

    from pipeline.tables import conform

    rows = conform("truth", truth_rows(hours(0, 2)))
    old = pa.schema([f.with_metadata({"doc": "an older doc"}) for f in rows.schema])
    write_deltalake(str(table_path(tmp_path, "truth")), rows.cast(old), partition_by=["date"])
    replace_window(tmp_path, "truth", rows, start_ns=T0, end_ns=T0 + DAY)
    assert read_table(tmp_path, "truth").num_rows == rows.num_rows


def test_shared_handles_read_a_log_once_and_see_every_commit(tmp_path, monkeypatch):
    """Inside ``shared_handles`` a table's log is read once per version (an open costs
    ~4.5 ms of CPU; a batch made ~50); a commit, the pipeline's or another writer's, is
    seen by the next read, and a garbage next log entry still stops it."""
    from deltalake import write_deltalake

    replace_window(tmp_path, "truth", truth_rows(hours(0, 2)), start_ns=T0, end_ns=T0 + DAY)
    opened: list[str] = []
    real = DeltaTable.__init__

    def counting(self, uri, *args, **kwargs):
        opened.append(str(uri))
        real(self, uri, *args, **kwargs)

    monkeypatch.setattr(DeltaTable, "__init__", counting)
    n0 = read_table(tmp_path, "truth").num_rows
    read_table(tmp_path, "truth")
    assert len(opened) == 2  # outside: every read opens the log
    with shared_handles():
        assert read_table(tmp_path, "truth").num_rows == n0
        assert table_files(tmp_path, "truth") and read_table(tmp_path, "truth").num_rows == n0
        assert len(opened) == 3
        # the pipeline's commit brings the shared table up to date: no open
        replace_window(tmp_path, "truth", truth_rows(hours(0, 1, step_s=120)), start_ns=T0,
                       end_ns=T0 + 3600 * NS)
        assert read_table(tmp_path, "truth").num_rows == n0 - 30
        assert len(opened) == 3
        # another writer's commit: seen
        write_deltalake(str(table_path(tmp_path, "truth")), truth_rows(hours(3, 4)),
                        mode="append", partition_by=["date"])
        assert read_table(tmp_path, "truth").num_rows == n0 + 30
        version = table_version(tmp_path, "truth")
        log = table_path(tmp_path, "truth") / "_delta_log"
        (log / f"{version + 1:020d}.json").write_text("{not json\n")
        with pytest.raises(DamagedTableError):
            read_table(tmp_path, "truth")


def test_may_hold_rows_from_the_files_statistics(tmp_path):
    """The files' min/max statistics of the time column and the given columns decide
    (the batch's rejects: no commit when none are new and none may be replaced)."""
    assert not may_hold_rows(tmp_path, "truth", T0, T0 + DAY, {"site": "harbour"})  # no table
    replace_window(tmp_path, "truth", truth_rows(hours(0, 2), site="harbour"), start_ns=T0,
                   end_ns=T0 + DAY)
    long = "/archive/" + "x" * 80 + ".mcap"
    replace_window(tmp_path, "truth", truth_rows(hours(5, 6), source=long, site="quay"),
                   start_ns=T0 + 5 * 3600 * NS, end_ns=T0 + 6 * 3600 * NS)
    h = 3600 * NS
    assert may_hold_rows(tmp_path, "truth", T0, T0 + h, {"site": "harbour"})
    assert not may_hold_rows(tmp_path, "truth", T0, T0 + h, {"site": "quay"})
    assert not may_hold_rows(tmp_path, "truth", T0 + 2 * h, T0 + 5 * h, {})
    assert may_hold_rows(tmp_path, "truth", T0 + 5 * h, T0 + 6 * h, {"source_file": long})
    assert not may_hold_rows(tmp_path, "truth", T0 + 5 * h, T0 + 6 * h,
                             {"source_file": "/a.mcap"})
