"""A portable, readable warehouse (issue 17, item 5): a copied or moved warehouse reads
its own files, and ``surveil.duckdb`` opens in the DuckDB 1.x command line."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import duckdb
import pytest

from pipeline.warehouse.delta import read_table
from pipeline.warehouse.views import (
    STORAGE_VERSION,
    VIEWS_FILE,
    connect_views_file,
    rebuild_views_file,
)

TABLES = ("radar_tracks", "ais_reports", "truth", "system_tracks", "siap_by_sector")
CLI_SPEC = "duckdb-cli<2"  # the DuckDB 1.x command line, as a wheel on PyPI


def _counts(con: duckdb.DuckDBPyConnection) -> dict[str, int]:
    return {t: con.execute(f"SELECT count(*) FROM {t}").fetchall()[0][0] for t in TABLES}


def _moved_copy(e2e, tmp_path: Path) -> tuple[Path, dict[str, int]]:
    """The end-to-end warehouse copied, its views file written there, then the copy moved
    (renamed) and the first location deleted: only the moved folder exists."""
    first = tmp_path / "first"
    shutil.copytree(e2e.warehouse, first)
    rebuild_views_file(first)
    want = {t: read_table(first, t).num_rows for t in TABLES}
    moved = tmp_path / "elsewhere" / "moved"
    moved.parent.mkdir()
    first.rename(moved)
    assert not first.exists()
    return moved, want


def test_a_moved_warehouse_reads_itself(e2e, tmp_path):
    moved, want = _moved_copy(e2e, tmp_path)
    assert all(want.values()), want
    with connect_views_file(moved) as con:  # from anywhere: file_search_path
        assert _counts(con) == want
        sql = con.execute("SELECT sql FROM duckdb_views() WHERE schema_name = 'snapshot' "
                          "AND view_name = 'radar_tracks'").fetchall()[0][0]
    assert "'tables/radar_tracks/" in sql and str(tmp_path) not in sql
    assert str(e2e.warehouse) not in sql
    # plain DuckDB, opened from inside the warehouse (relative paths: the working folder)
    code = ("import duckdb, json; con = duckdb.connect('surveil.duckdb', read_only=True); "
            f"print(json.dumps({{t: con.execute(f'SELECT count(*) FROM {{t}}').fetchall()[0][0]"
            f" for t in {list(TABLES)!r}}}))")
    res = subprocess.run([sys.executable, "-c", code], cwd=moved, capture_output=True,
                         text=True, check=False)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == str(want).replace("'", '"')


def test_the_views_file_is_in_a_storage_format_duckdb_1x_reads(tmp_path):
    target = rebuild_views_file(tmp_path)
    con = duckdb.connect()
    con.execute(f"ATTACH '{target}' AS w (READ_ONLY)")
    tag = con.execute("SELECT tags['storage_version'] FROM duckdb_databases() "
                      "WHERE database_name = 'w'").fetchall()[0][0]
    con.close()
    assert tag.rstrip("+") == STORAGE_VERSION


def test_a_views_file_in_another_storage_format_is_built_anew(tmp_path):
    """A file written by an earlier release (DuckDB 2.x's default format) is replaced by
    one in the 1.x format, with the same views."""
    target = tmp_path / VIEWS_FILE
    with duckdb.connect(str(target)) as con:
        con.execute("CREATE VIEW truth AS SELECT 1 AS x")
        latest = con.execute("SELECT tags['storage_version'] FROM duckdb_databases() "
                             "WHERE database_name = current_database()").fetchall()[0][0]
    if latest.rstrip("+") == STORAGE_VERSION:
        pytest.skip(f"this DuckDB ({duckdb.__version__}) writes {STORAGE_VERSION} already")
    rebuild_views_file(tmp_path)
    with connect_views_file(tmp_path) as con:
        assert con.execute("SELECT count(*) FROM truth").fetchall() == [(0,)]
        tag = con.execute("SELECT tags['storage_version'] FROM duckdb_databases() "
                          "WHERE database_name = current_database()").fetchall()[0][0]
    assert tag.rstrip("+") == STORAGE_VERSION


def _duckdb_1x_cli() -> Path:
    """The ``duckdb`` binary of PyPI's ``duckdb-cli`` 1.x wheel, installed once into a
    cache folder; skip with the reason when it cannot be installed (offline)."""
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "surveil-tests"
    target = cache / "duckdb-cli-1x"
    binary = target / "duckdb_cli" / "duckdb"
    if not binary.is_file():
        res = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet",
                              "--disable-pip-version-check", "--target", str(target),
                              CLI_SPEC], capture_output=True, text=True, check=False,
                             timeout=600)
        if res.returncode != 0 or not binary.is_file():
            pytest.skip(f"cannot install {CLI_SPEC!r} from PyPI (offline?): "
                        f"{res.stderr.strip()[-300:]}")
    return binary


def test_the_duckdb_1x_command_line_opens_a_moved_warehouse(e2e, tmp_path):
    """Was: "Trying to read a database file with version number 69, but we can only read
    versions between 64 and 68" (DuckDB 1.x CLI on a file written by DuckDB 2.x)."""
    cli = _duckdb_1x_cli()
    version = subprocess.run([str(cli), "--version"], capture_output=True, text=True,
                             check=True).stdout
    assert version.startswith("v1."), version
    moved, want = _moved_copy(e2e, tmp_path)
    queries = [f"SELECT '{t}', count(*) FROM {t};" for t in TABLES]
    queries.append("SELECT 'comment', comment FROM duckdb_columns() WHERE schema_name = "
                   "'main' AND table_name = 'truth' AND column_name = 'lat_deg';")
    res = subprocess.run([str(cli), "-readonly", "-csv", "-noheader", VIEWS_FILE,
                          "-c", " ".join(queries)], cwd=moved, capture_output=True,
                         text=True, check=False)
    assert res.returncode == 0, res.stderr
    got = dict(line.split(",", 1) for line in res.stdout.splitlines() if line)
    assert {t: int(got[t]) for t in TABLES} == want, (version, res.stdout)
    assert got["comment"].strip('"') == "[deg] WGS-84 latitude, deg"
