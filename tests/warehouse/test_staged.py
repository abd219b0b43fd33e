"""Staged Parquet files committed to Delta in one transaction: create, swap, no-op, and the
rewrite fallback when a data file mixes source files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from deltalake import DeltaTable
from mcap_fixtures import DAY, T0_NS, truth_rows

from pipeline.warehouse.delta import read_table, replace_source_file, table_path
from pipeline.warehouse.staged import TableStager, commit_staged, read_staged


def stage(folder: Path, source: str, t_ns: np.ndarray, *, rows_per_group: int = 1000):
    st = TableStager(folder, row_group_rows=rows_per_group)
    half = len(t_ns) // 2
    st.add("truth", truth_rows(t_ns[half:], source=source))  # out of order on purpose
    st.add("truth", truth_rows(t_ns[:half], source=source))
    return st.close()


def test_stager_writes_sorted_row_groups_per_day_with_stats(tmp_path):
    t = T0_NS + np.arange(5000, dtype=np.int64) * 10**9 * 30  # crosses a day boundary
    files = stage(tmp_path / "s", "/a.mcap", t, rows_per_group=300)
    # a day's second row group goes to a second file when the first is still being
    # written (MAX_FILES_PER_SLOT): how many files a day gets depends on the machine's load
    days = sorted({f.partition["date"] for f in files})
    assert days == ["2026-01-01", "2026-01-02"]
    assert sum(f.rows for f in files) == 5000
    groups = 0
    for f in files:
        pf = pq.ParquetFile(f.path)
        assert "date" not in pf.schema_arrow.names
        groups += pf.metadata.num_row_groups
        for g in range(pf.metadata.num_row_groups):
            ts = pf.read_row_group(g, columns=["time_ns"])["time_ns"].to_numpy()
            assert np.all(np.diff(ts) > 0)
        stats = json.loads(f.stats_json)
        got = pq.read_table(f.path)["time_ns"].to_numpy()
        assert stats["numRecords"] == f.rows == len(got)
        assert (
            stats["minValues"]["time_ns"] == got.min()
            and stats["maxValues"]["time_ns"] == got.max()
        )
        assert stats["minValues"]["source_file"] == stats["maxValues"]["source_file"] == "/a.mcap"
        assert stats["nullCount"]["mmsi"] == f.rows
    assert groups == 3  # day 1: 380 rows, then 2500; day 2: 2120 rows in one add
    back = read_staged("truth", files)
    assert sorted(back["time_ns"].to_pylist()) == t.tolist()


def test_create_swap_and_noop(tmp_path):
    wh = tmp_path / "wh"
    t = T0_NS + np.arange(300, dtype=np.int64) * 10**9
    assert commit_staged(wh, "truth", [], source_file="/a.mcap") == "noop"
    assert (
        commit_staged(wh, "truth", stage(tmp_path / "1", "/a.mcap", t), source_file="/a.mcap")
        == "create"
    )
    assert (
        commit_staged(wh, "truth", stage(tmp_path / "2", "/b.mcap", t + DAY), source_file="/b.mcap")
        == "swap"
    )
    v = DeltaTable(str(table_path(wh, "truth"))).version()
    # a changed /a.mcap: its rows are replaced, /b.mcap's stay
    how = commit_staged(
        wh, "truth", stage(tmp_path / "3", "/a.mcap", t[:100]), source_file="/a.mcap"
    )
    assert how == "swap" and DeltaTable(str(table_path(wh, "truth"))).version() == v + 1
    got = read_table(wh, "truth")
    per_file = dict(
        zip(
            *np.unique(got["source_file"].to_numpy(zero_copy_only=False), return_counts=True),
            strict=True,
        )
    )
    assert per_file == {"/a.mcap": 100, "/b.mcap": 300}
    # a file that now has no rows for the table: removed in one commit; then nothing to do
    assert commit_staged(wh, "truth", [], source_file="/a.mcap") == "swap"
    assert commit_staged(wh, "truth", [], source_file="/a.mcap") == "noop"
    assert set(read_table(wh, "truth")["source_file"].to_pylist()) == {"/b.mcap"}
    # the old version still reads the old rows (time travel: nothing was overwritten)
    old = DeltaTable(str(table_path(wh, "truth")), version=v).to_pyarrow_dataset().to_table()
    assert old.num_rows == 600


def test_mixed_source_files_fall_back_to_a_rewrite(tmp_path):
    wh = tmp_path / "wh"
    t = T0_NS + np.arange(50, dtype=np.int64) * 10**9
    both = pa.concat_tables([truth_rows(t, source="/a.mcap"), truth_rows(t + 1, source="/c.mcap")])
    replace_source_file(wh, "truth", both.slice(0, 0), source_file="/none")  # create the table
    from deltalake import write_deltalake

    write_deltalake(str(table_path(wh, "truth")), both, mode="append", partition_by=["date"])
    how = commit_staged(
        wh, "truth", stage(tmp_path / "s", "/a.mcap", t[:10]), source_file="/a.mcap"
    )
    assert how == "rewrite"
    got = read_table(wh, "truth")
    assert got.filter(pa.compute.equal(got["source_file"], "/a.mcap")).num_rows == 10
    assert got.filter(pa.compute.equal(got["source_file"], "/c.mcap")).num_rows == 50


def test_stats_of_every_column_match_the_written_rows(tmp_path):
    """Delta statistics from the Parquet footer (strings, ints) and from the rows (floats)
    equal min / max / null count of what the file holds; a NaN or a string too long for
    Parquet's statistics leaves that column without min/max; raw bytes have none."""
    t = T0_NS + np.arange(600, dtype=np.int64) * 10**9
    rows = truth_rows(t, source="/a.mcap")
    speed = rows["speed_mps"].to_numpy().copy()
    speed[407] = np.nan
    topics = [f"/truth/{i % 11}" for i in range(600)]
    topics[3] = "/" + "x" * 5000
    rows = rows.set_column(rows.schema.get_field_index("speed_mps"), "speed_mps", pa.array(speed))
    rows = rows.set_column(rows.schema.get_field_index("topic"), "topic", pa.array(topics))
    st = TableStager(tmp_path / "s", row_group_rows=250, threaded=False)  # one file
    for a in range(0, 600, 100):  # row groups of three chunks each
        st.add("truth", rows.slice(a, 100))
    (f,) = st.close()
    stats = json.loads(f.stats_json)
    back = pq.read_table(f.path)
    assert stats["numRecords"] == back.num_rows == 600
    for name in back.column_names:
        col = back[name]
        assert stats["nullCount"][name] == col.null_count, name
        if name in ("speed_mps", "topic") or col.null_count == len(col):
            assert name not in stats["minValues"] and name not in stats["maxValues"], name
            continue
        mm = pa.compute.min_max(col).as_py()
        assert (stats["minValues"][name], stats["maxValues"][name]) == (mm["min"], mm["max"])
    assert set(stats["minValues"]) == {
        "time_ns", "site", "vessel_id", "lat_deg", "lon_deg", "course_rad", "source_file",
        "log_time_ns"
    }  # fmt: skip

    rej = TableStager(tmp_path / "r")
    raw = [b"\x00\xff", None, b"abc"]
    rej.add(
        "rejects",
        pa.table(
            {
                "log_time_ns": pa.array([T0_NS] * 3, pa.int64()),
                "source_file": ["/a.mcap"] * 3,
                "topic": ["/t", None, "/s"],
                "stage": ["ingest"] * 3,
                "reason_code": ["undecodable", "truncated", "bad_checksum"],
                "reason": ["r"] * 3,
                "raw": pa.array(raw, pa.binary()),
            }
        ),
    )
    (r,) = rej.close()
    rstats = json.loads(r.stats_json)
    assert "raw" not in rstats["nullCount"] and "raw" not in rstats["minValues"]
    assert rstats["nullCount"]["topic"] == 1 and rstats["minValues"]["topic"] == "/s"
    assert rstats["minValues"]["reason_code"] == "bad_checksum"
    assert rstats["maxValues"]["reason_code"] == "undecodable"
    assert not pq.read_metadata(r.path).row_group(0).column(7).is_stats_set


def test_constant_string_read_off_the_buffers():
    from pipeline.warehouse.staged import _constant_string

    def col(*chunks):
        return pa.chunked_array([pa.array(c, pa.string()) for c in chunks], pa.string())

    path = "/archive/2026/01/radar_R1.mcap"
    assert _constant_string(col([path] * 1000, [path] * 3)) == path
    assert _constant_string(col([""] * 5)) == ""
    assert _constant_string(col(["x"])) == "x"
    assert _constant_string(col(["ab", "ab", "ba"])) is None  # same lengths, other bytes
    assert _constant_string(col(["ab", "ab", "a", "bab"])) is None  # same bytes, other cuts
    assert _constant_string(col(["abcdefghij"] * 9 + ["abcdefghiJ"])) is None  # last byte
    assert _constant_string(col([path] * 4, [path + "x"] * 4)) is None  # chunk by chunk
    assert _constant_string(col([path, None, path])) is None
    sliced = pa.chunked_array([pa.array(["a", "bb", "bb", "bb", "c"]).slice(1, 3)])
    assert _constant_string(sliced) == "bb"
    assert _constant_string(pa.chunked_array([pa.array([1, 1])])) is None


def test_dictionary_columns_written_as_strings(tmp_path):
    """String columns constant in a file's first row group go to Parquet as dictionaries
    (no hashing per row); later groups where they vary are still right, readers see
    plain strings, and the statistics hold."""
    t = T0_NS + np.arange(900, dtype=np.int64) * 10**9
    rows = truth_rows(t, source="/a.mcap")
    topics = ["/truth/vessels"] * 300 + [f"/truth/{i % 7}" for i in range(600)]
    rows = rows.set_column(rows.schema.get_field_index("topic"), "topic", pa.array(topics))
    st = TableStager(tmp_path / "s", row_group_rows=300, threaded=False)
    for a in range(0, 900, 300):
        st.add("truth", rows.slice(a, 300))
    (f,) = st.close()
    pf = pq.ParquetFile(f.path)
    assert pf.metadata.num_row_groups == 3
    back = pf.read()
    assert back.schema.field("topic").type == pa.string()
    assert (
        back["topic"].to_pylist() == topics and back["source_file"].to_pylist() == ["/a.mcap"] * 900
    )
    for g in range(3):
        enc = pf.metadata.row_group(g).column(back.schema.get_field_index("source_file")).encodings
        assert "RLE_DICTIONARY" in enc or "PLAIN_DICTIONARY" in enc, enc
    stats = json.loads(f.stats_json)
    assert (
        stats["minValues"]["topic"] == "/truth/0"
        and stats["maxValues"]["topic"] == "/truth/vessels"
    )
    assert stats["minValues"]["source_file"] == stats["maxValues"]["source_file"] == "/a.mcap"
