"""Issue 40 item 2: analysts' SQL is read-only and tampering is detected.

`surveil sql` and the reports reach the warehouse through views over its snapshots
only: no COPY into (or out of) it, no ATTACH, no extension, no file outside it; an
export needs `--allow-write-files DIR` and lands under DIR only. A table file whose size
differs from its Delta log is refused, naming the table and the file (exit 2)."""

from __future__ import annotations

import shutil
from pathlib import Path

import duckdb
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from pipeline.reports import open_warehouse, run_named_report
from pipeline.warehouse.delta import read_table
from pipeline.warehouse.integrity import TableFileError
from tests.jobs.test_cli import surveil


def _track_errors_file(warehouse: Path) -> Path:
    return sorted((warehouse / "tables" / "track_errors").rglob("*.parquet"))[0]


@pytest.fixture
def copy(e2e, tmp_path) -> Path:
    """A copy of the e2e warehouse this test may damage."""
    shutil.copytree(e2e.warehouse, tmp_path / "warehouse")
    return tmp_path / "warehouse"


def _divide_errors_by_ten(path: Path) -> None:
    """The attack of issue 40: the file rewritten with every error divided by 10."""
    t = pq.read_table(path)
    col = "error_m"
    t = t.set_column(t.column_names.index(col), col, pc.divide(t[col], 10.0))
    pq.write_table(t, path)


@pytest.mark.parametrize("statement", [
    "COPY (SELECT 1 AS a) TO '{file}' (FORMAT parquet)",
    "COPY (SELECT 1 AS a) TO '{file}' (FORMAT parquet, USE_TMP_FILE false)",
    "COPY track_errors TO '{warehouse}/tables/track_errors/extra.parquet'",
    "SELECT * FROM read_csv('/etc/passwd', sep = ':')",
    "SELECT * FROM read_text('/etc/hostname')",
    "SELECT * FROM read_parquet('{file}')",
    "SELECT * FROM glob('{warehouse}/*')",
    "ATTACH '{warehouse}/other.duckdb' AS other",
    "INSTALL httpfs",
    "LOAD httpfs",
    "SET allowed_directories = ['/']",
])
def test_the_sql_reaches_no_file_and_no_extension(copy, statement):
    file = _track_errors_file(copy)
    before = file.read_bytes()
    entries = sorted(p.name for p in copy.iterdir())
    con = open_warehouse(copy)
    try:
        with pytest.raises(duckdb.Error):
            con.sql(statement.format(file=file, warehouse=copy))
        # and the views still read the warehouse
        assert con.sql("SELECT count(*) FROM track_errors").fetchall()[0][0] > 0
    finally:
        con.close()
    assert file.read_bytes() == before
    assert sorted(p.name for p in copy.iterdir()) == entries  # no file made beside the tables


def test_surveil_sql_refuses_a_copy_into_the_warehouse_and_keeps_the_figures(copy):
    file = _track_errors_file(copy)
    before = file.read_bytes()
    res = surveil("--warehouse", str(copy), "sql",
                  f"COPY (SELECT * FROM track_errors) TO '{file}' (USE_TMP_FILE false)")
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    assert "--allow-write-files" in res.stderr
    assert file.read_bytes() == before


def test_allow_write_files_exports_under_its_folder_only(copy, tmp_path):
    out = tmp_path / "exports"
    out.mkdir()
    res = surveil("--warehouse", str(copy), "sql", "--allow-write-files", str(out),
                  f"COPY (SELECT count(*) AS n FROM track_errors) TO '{out}/n.csv'")
    assert res.returncode == 0, res.stderr
    assert (out / "n.csv").read_text().splitlines()[0] == "n"
    con = open_warehouse(copy, write_dir=out)
    try:
        for target in (_track_errors_file(copy), out.parent / "beside.csv",
                       out / ".." / "beside.csv"):
            with pytest.raises(duckdb.PermissionException):
                con.sql(f"COPY (SELECT 1) TO '{target}' (USE_TMP_FILE false)")
    finally:
        con.close()
    assert not (out.parent / "beside.csv").exists()
    inside = surveil("--warehouse", str(copy), "sql", "--allow-write-files",
                     str(copy / "tables"), "SELECT 1")
    assert inside.returncode == 2 and "inside the" in inside.stderr, inside.stderr


def test_a_rewritten_table_file_is_refused_naming_table_and_file(copy, cfg):
    file = _track_errors_file(copy)
    _divide_errors_by_ten(file)
    with pytest.raises(TableFileError) as err:
        run_named_report(copy, "accuracy_by_sector", cfg=cfg)
    assert err.value.table == "track_errors" and err.value.path.endswith(file.name)
    with pytest.raises(TableFileError):
        read_table(copy, "track_errors")
    res = surveil("--warehouse", str(copy), "report", "accuracy_by_sector")
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    assert "track_errors" in res.stderr and file.name in res.stderr
    # surveil sql: the other tables stay readable, the damaged one says why
    ok = surveil("--warehouse", str(copy), "sql", "SELECT count(*) AS n FROM system_tracks")
    assert ok.returncode == 0, ok.stderr
    bad = surveil("--warehouse", str(copy), "sql", "SELECT count(*) FROM track_errors")
    assert bad.returncode == 2 and file.name in bad.stderr and "Traceback" not in bad.stderr


def test_a_removed_table_file_is_refused(copy):
    file = _track_errors_file(copy)
    file.unlink()
    with pytest.raises(TableFileError, match="is missing"):
        read_table(copy, "track_errors")


def test_a_rewritten_file_on_s3_is_refused_and_sql_there_is_locked(s3):
    import numpy as np

    from pipeline.warehouse.location import parse_location
    from pipeline.warehouse.staged import TableStager, commit_window
    from tests.warehouse.test_commit_window import T0_NS, truth_rows

    bucket = s3.bucket()
    wh = parse_location(f"s3://{bucket}/wh")
    t = T0_NS + np.arange(0, 60) * 10**9
    st = TableStager(wh / "_staging" / "a", threaded=False)
    st.add("truth", truth_rows(t, speed=1.0))
    commit_window(wh, "truth", st.close(), start_ns=T0_NS, end_ns=T0_NS + 60 * 10**9)
    con = open_warehouse(wh)
    try:
        assert con.sql("SELECT count(*) FROM truth").fetchall() == [(60,)]
        with pytest.raises(duckdb.PermissionException):
            con.sql("SELECT * FROM read_csv('/etc/passwd')")
    finally:
        con.close()
    (key,) = [k for k in s3.keys(bucket, "wh/tables/truth/") if k.endswith(".parquet")]
    s3.client().put_object(Bucket=bucket, Key=key, Body=b"PAR1 not the table PAR1")
    with pytest.raises(TableFileError) as err:
        read_table(wh, "truth")
    assert err.value.table == "truth" and err.value.path.endswith(key.rsplit("/", 1)[1])
    assert err.value.found_bytes == len(b"PAR1 not the table PAR1")
