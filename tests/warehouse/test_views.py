"""DuckDB views over the current Delta snapshot (real DuckDB, real Delta tables)."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import duckdb
import pyarrow as pa
import pytest
from mcap_fixtures import DAY, T0, hours, truth_rows

from pipeline.tables import schema, table_specs
from pipeline.warehouse.delta import read_table, replace_window, table_path, table_snapshot
from pipeline.warehouse.views import (
    VIEWS_FILE,
    ViewsEngine,
    connect_views_file,
    rebuild_views_file,
    refresh_views_file,
    register_tables,
    views_stale,
)


def test_view_counts_snapshot_not_glob_after_overwrite(tmp_path):
    replace_window(tmp_path, "truth", truth_rows(hours(0, 30)), start_ns=T0, end_ns=T0 + 2 * DAY)
    replace_window(
        tmp_path, "truth", truth_rows(hours(0, 30), speed=3.0), start_ns=T0, end_ns=T0 + 2 * DAY
    )
    con = duckdb.connect()
    register_tables(con, tmp_path, ["truth"])
    n_delta = read_table(tmp_path, "truth").num_rows
    assert con.execute("SELECT count(*) FROM truth").fetchall()[0][0] == n_delta
    assert con.execute("SELECT DISTINCT speed_mps FROM truth").fetchall() == [(3.0,)]
    glob = str(table_path(tmp_path, "truth") / "**" / "*.parquet")
    n_glob = con.execute("SELECT count(*) FROM read_parquet(?)", [glob]).fetchall()[0][0]
    assert n_glob == 2 * n_delta  # replaced files are still on disk: a glob double-counts


def test_view_types_and_date_partition(tmp_path):
    replace_window(tmp_path, "truth", truth_rows(hours(20, 28)), start_ns=T0, end_ns=T0 + 2 * DAY)
    con = duckdb.connect()
    register_tables(con, tmp_path, ["truth"])
    cols = dict(con.execute("SELECT column_name, column_type FROM (DESCRIBE truth)").fetchall())
    assert cols["date"] == "DATE" and cols["time_ns"] == "BIGINT" and cols["mmsi"] == "BIGINT"
    assert list(cols) == schema("truth").names
    by_day = con.execute("SELECT date, count(*) FROM truth GROUP BY 1 ORDER BY 1").fetchall()
    assert by_day == [(dt.date(2026, 1, 1), 240), (dt.date(2026, 1, 2), 240)]
    # partition pruning by date works through the view
    day2 = [dt.date(2026, 1, 2)]
    assert con.execute("SELECT count(*) FROM truth WHERE date = ?", day2).fetchall() == [(240,)]


def test_a_time_window_opens_only_the_files_that_overlap_it(tmp_path):
    """Each file of a view carries the time range its Delta statistics record: a scan
    filtered on the time column skips the files outside its window unopened (a report
    over one hour of a week-long archive reads that hour's files, not every footer)."""
    replace_window(tmp_path, "truth", truth_rows(hours(0, 72)), start_ns=T0, end_ns=T0 + 3 * DAY)
    files, _ = table_snapshot(tmp_path, "truth")
    first_day = [Path(f) for f in files if "date=2026-01-01" in f]
    assert first_day and len(first_day) < len(files)
    for f in first_day:  # unreadable, its size kept (the views' size check passes)
        f.write_bytes(b"\0" * f.stat().st_size)
    con = duckdb.connect()
    register_tables(con, tmp_path, ["truth"])
    window = "SELECT count(*) FROM truth WHERE time_ns >= ? AND time_ns < ?"
    hour_of_day_3 = [T0 + 2 * DAY + 3_600 * 10**9, T0 + 2 * DAY + 7_200 * 10**9]
    assert con.execute(window, hour_of_day_3).fetchall() == [(60,)]
    with pytest.raises(duckdb.Error):  # a window over the broken files still reads them
        con.execute(window, [T0, T0 + DAY]).fetchall()


def test_empty_tables_get_typed_empty_views(tmp_path):
    con = duckdb.connect()
    names = register_tables(con, tmp_path)
    assert set(names) == set(table_specs())
    for name in names:
        assert con.execute(f'SELECT count(*) FROM "{name}"').fetchall()[0][0] == 0
        got = con.sql(f'SELECT * FROM "{name}"').to_arrow_table()
        assert got.schema.names == schema(name).names
        for f in schema(name):
            want = pa.large_string() if f.type == pa.string() else f.type
            assert got.schema.field(f.name).type in (f.type, want), (name, f.name)


def test_rebuild_views_file_swaps_in_new_views(tmp_path):
    target = rebuild_views_file(tmp_path)
    assert target == tmp_path / VIEWS_FILE
    with connect_views_file(tmp_path) as con:
        assert con.execute("SELECT count(*) FROM truth").fetchall()[0][0] == 0
    replace_window(tmp_path, "truth", truth_rows(hours(0, 1)), start_ns=T0, end_ns=T0 + DAY)
    rebuild_views_file(tmp_path)
    with connect_views_file(tmp_path) as con:
        assert con.execute("SELECT count(*) FROM truth").fetchall()[0][0] == 60
        views = {
            r[0]
            for r in con.execute(
                "SELECT view_name FROM duckdb_views() WHERE NOT internal"
            ).fetchall()
        }
    assert views == set(table_specs())
    assert sorted(p.name for p in tmp_path.iterdir()) == [VIEWS_FILE, "tables"]


def _view_sql(db: Path, schema: str = "main") -> dict[str, str]:
    with connect_views_file(db.parent) as con:
        rows = con.execute("SELECT view_name, sql FROM duckdb_views() WHERE NOT internal "
                           "AND schema_name = ?", [schema])
        return dict(rows.fetchall())


def test_views_update_equals_a_build_from_scratch(tmp_path):
    target = rebuild_views_file(tmp_path)
    replace_window(tmp_path, "truth", truth_rows(hours(0, 1)), start_ns=T0, end_ns=T0 + DAY)
    rebuild_views_file(tmp_path)  # updates the truth view only
    updated = {s: _view_sql(target, s) for s in ("main", "snapshot")}
    target.unlink()
    rebuild_views_file(tmp_path)  # from scratch
    assert updated == {s: _view_sql(target, s) for s in ("main", "snapshot")}
    snapshot = updated["snapshot"]
    assert "read_parquet" in snapshot["truth"] and "read_parquet" not in snapshot["ais_reports"]


def test_views_unchanged_tables_leave_the_file_alone(tmp_path):
    target = rebuild_views_file(tmp_path)
    before = target.stat()
    rebuild_views_file(tmp_path)
    after = target.stat()
    # not rewritten (same file), only touched: it is as new as the tables (views_stale)
    assert (after.st_ino, after.st_size) == (before.st_ino, before.st_size)
    assert after.st_mtime_ns >= before.st_mtime_ns and not views_stale(tmp_path)


def test_a_new_views_file_built_without_warm_up_holds_the_tables_rows(tmp_path):
    """A fresh engine builds the template inside the rebuild (no warm-up): the views
    still go to the file, not to the engine's in-memory database."""
    replace_window(tmp_path, "truth", truth_rows(hours(0, 3)), start_ns=T0, end_ns=T0 + DAY)
    engine = ViewsEngine()
    try:
        engine.rebuild(tmp_path)
    finally:
        engine.close()
    with connect_views_file(tmp_path) as con:
        n = con.execute("SELECT count(*) FROM truth").fetchall()[0][0]
    assert n == read_table(tmp_path, "truth").num_rows > 0


def test_views_stale_when_a_table_commits_after_the_file(tmp_path):
    assert not views_stale(tmp_path)  # no tables, no file
    replace_window(tmp_path, "truth", truth_rows(hours(0, 3)), start_ns=T0, end_ns=T0 + DAY)
    assert views_stale(tmp_path)  # tables, no file
    rebuild_views_file(tmp_path)
    assert not views_stale(tmp_path)
    replace_window(tmp_path, "truth", truth_rows(hours(0, 2)), start_ns=T0, end_ns=T0 + DAY)
    assert views_stale(tmp_path)
    assert refresh_views_file(tmp_path) and not refresh_views_file(tmp_path)
    with connect_views_file(tmp_path) as con:
        n = con.execute("SELECT count(*) FROM truth").fetchall()[0][0]
    assert n == read_table(tmp_path, "truth").num_rows


def test_views_a_view_edited_by_hand_is_rewritten_and_a_gone_table_dropped(tmp_path):
    target = rebuild_views_file(tmp_path)
    with duckdb.connect(str(target)) as con:
        con.execute("CREATE OR REPLACE VIEW truth AS SELECT 1 AS x")
        con.execute("CREATE VIEW old_table AS SELECT 1 AS x")  # as written by an older release
        con.execute("COMMENT ON VIEW old_table IS 'digest of its statement'")
        con.execute("CREATE VIEW my_view AS SELECT 2 AS y")  # an analyst's own, no comment
    rebuild_views_file(tmp_path)
    with connect_views_file(tmp_path) as con:
        assert con.sql("SELECT * FROM truth").columns == schema("truth").names
    assert set(_view_sql(target)) == {*table_specs(), "my_view"}


def test_views_an_unreadable_file_is_built_again(tmp_path):
    target = tmp_path / VIEWS_FILE
    target.write_bytes(b"not a duckdb database" * 100)
    rebuild_views_file(tmp_path)
    assert set(_view_sql(target)) == set(table_specs())
    assert sorted(p.name for p in tmp_path.iterdir()) == [VIEWS_FILE]


def test_empty_views_bind_when_queried_and_views_over_files_when_created(tmp_path):
    from pipeline.warehouse.views import _defer_binding_clause, view_sql

    assert _defer_binding_clause("1.4.2") == "" and _defer_binding_clause("dev") == ""
    assert _defer_binding_clause("2.0.0") == _defer_binding_clause("2.1.0.dev5") != ""
    con = duckdb.connect()
    con.execute(view_sql("truth", []))  # deferred or not, it queries as a typed empty view
    assert con.execute('SELECT count(*) FROM "truth"').fetchall() == [(0,)]
    # a file missing from a snapshot fails when the view is written (the job), not later
    missing = str(tmp_path / "gone.parquet")
    with pytest.raises(duckdb.IOException, match=r"gone\.parquet"):
        con.execute(view_sql("truth", [missing]))


def test_views_file_documents_every_column_with_its_unit(tmp_path):
    """`main.<table>` carries schemas/' docs as comments (duckdb_columns(), the
    describe_table macro); an update that changes only files keeps them."""
    rebuild_views_file(tmp_path)
    replace_window(tmp_path, "truth", truth_rows(hours(0, 1)), start_ns=T0, end_ns=T0 + DAY)
    rebuild_views_file(tmp_path)
    with connect_views_file(tmp_path) as con:
        comments = dict(con.execute(
            "SELECT column_name, comment FROM duckdb_columns() "
            "WHERE schema_name = 'main' AND table_name = 'truth'").fetchall())
        assert comments["lat_deg"] == "[deg] WGS-84 latitude, deg"
        assert comments["speed_mps"].startswith("[m/s] ")
        assert comments["time_ns"].startswith("[ns (UTC, since 1970)] ")
        described = con.execute("FROM describe_table('radar_tracks')").fetchall()
        assert [r[0] for r in described] == schema("radar_tracks").names
        assert described[4] == ("range_m", "DOUBLE", "[m] slant range from the site, m")
        table_doc = con.execute("SELECT comment FROM duckdb_views() "
                                "WHERE schema_name = 'main' AND view_name = 'truth'").fetchone()
        assert table_doc[0].startswith("Simulated ground truth")
        assert con.execute("SELECT count(*) FROM truth").fetchone()[0] == 60


def test_views_update_makes_only_the_statements_of_tables_that_changed(tmp_path, monkeypatch):
    """Each snapshot view's comment names the Delta version it reads (and when that log
    entry was written): a rebuild reads the log of a table whose version moved, not of
    every table (~3 ms each); a table made anew with the same version numbers is read
    again; the comments equal a build from scratch."""
    import shutil

    from pipeline.warehouse import views

    replace_window(tmp_path, "truth", truth_rows(hours(0, 3)), start_ns=T0, end_ns=T0 + DAY)
    target = rebuild_views_file(tmp_path)
    made: list[str] = []
    current_view_sql = views._current_view_sql

    def counted(warehouse, name, *args, **kwargs):
        made.append(name)
        return current_view_sql(warehouse, name, *args, **kwargs)

    monkeypatch.setattr(views, "_current_view_sql", counted)
    rebuild_views_file(tmp_path)
    assert made == []
    replace_window(tmp_path, "truth", truth_rows(hours(0, 2)), start_ns=T0, end_ns=T0 + DAY)
    rebuild_views_file(tmp_path)
    assert made == ["truth"]
    shutil.rmtree(table_path(tmp_path, "truth"))  # anew: versions 0 and 1 again
    replace_window(tmp_path, "truth", truth_rows(hours(0, 5)), start_ns=T0, end_ns=T0 + DAY)
    replace_window(tmp_path, "truth", truth_rows(hours(0, 4)), start_ns=T0, end_ns=T0 + DAY)
    rebuild_views_file(tmp_path)
    assert made == ["truth", "truth"]
    with connect_views_file(tmp_path) as con:
        n = con.execute("SELECT count(*) FROM truth").fetchall()[0][0]
        comments = dict(con.execute("SELECT view_name, comment FROM duckdb_views() "
                                    "WHERE schema_name = 'snapshot'").fetchall())
    assert n == read_table(tmp_path, "truth").num_rows == 240
    target.unlink()
    rebuild_views_file(tmp_path)  # from scratch
    with connect_views_file(tmp_path) as con:
        assert comments == dict(con.execute("SELECT view_name, comment FROM duckdb_views() "
                                            "WHERE schema_name = 'snapshot'").fetchall())
