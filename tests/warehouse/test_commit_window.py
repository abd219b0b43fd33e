"""commit_window: a time window of a table replaced by staged files in one commit."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
from deltalake import DeltaTable
from mcap_fixtures import T0_NS, truth_rows

from pipeline.warehouse.delta import read_table, replace_rows, table_path
from pipeline.warehouse.staged import TableStager, commit_window

S = 10**9


def _stage(folder, t_ns, speed):
    st = TableStager(folder, threaded=False)
    st.add("truth", truth_rows(t_ns, speed=speed))
    return st.close()


def _rows(wh):
    t = read_table(wh, "truth")
    return t["time_ns"].to_numpy(), t["speed_mps"].to_numpy()


def test_create_replace_inside_partial_and_empty(tmp_path):
    wh = tmp_path / "wh"
    t = T0_NS + np.arange(0, 100) * S
    assert commit_window(wh, "truth", _stage(tmp_path / "a", t, 1.0),
                         start_ns=T0_NS, end_ns=T0_NS + 100 * S) == "create"
    # a sub-window: the first file holds rows outside it and is rewritten without them
    sub = T0_NS + np.arange(20, 50) * S
    assert commit_window(wh, "truth", _stage(tmp_path / "b", sub, 2.0),
                         start_ns=T0_NS + 20 * S, end_ns=T0_NS + 50 * S) == "swap"
    tt, v = _rows(wh)
    np.testing.assert_array_equal(tt, t)
    np.testing.assert_array_equal(v, np.where((tt >= sub[0]) & (tt <= sub[-1]), 2.0, 1.0))
    # the same sub-window again: its file lies wholly inside, removed, nothing rewritten
    version = DeltaTable(str(table_path(wh, "truth"))).version()
    assert commit_window(wh, "truth", _stage(tmp_path / "c", sub, 3.0),
                         start_ns=T0_NS + 20 * S, end_ns=T0_NS + 50 * S) == "swap"
    assert DeltaTable(str(table_path(wh, "truth"))).version() == version + 1
    tt, v = _rows(wh)
    assert tt.size == 100 and set(v[(tt >= sub[0]) & (tt <= sub[-1])]) == {3.0}
    # nothing staged: the window is emptied; outside untouched
    commit_window(wh, "truth", [], start_ns=T0_NS, end_ns=T0_NS + 30 * S)
    tt, v = _rows(wh)
    np.testing.assert_array_equal(tt, t[30:])
    # nothing staged and nothing in the window: no commit
    version = DeltaTable(str(table_path(wh, "truth"))).version()
    assert commit_window(wh, "truth", [], start_ns=T0_NS - 100 * S, end_ns=T0_NS) == "noop"
    assert DeltaTable(str(table_path(wh, "truth"))).version() == version


def test_window_across_midnight(tmp_path):
    wh = tmp_path / "wh"
    day = 86_400 * S
    t = T0_NS + day - 50 * S + np.arange(100) * S  # crosses into the next day
    commit_window(wh, "truth", _stage(tmp_path / "a", t, 1.0), start_ns=t[0], end_ns=t[-1] + S)
    commit_window(wh, "truth", _stage(tmp_path / "b", t[40:60], 5.0), start_ns=t[40],
                  end_ns=t[60])
    tt, v = _rows(wh)
    np.testing.assert_array_equal(tt, t)
    assert (v[40:60] == 5.0).all() and (v[:40] == 1.0).all() and (v[60:] == 1.0).all()


def test_a_site_replaces_only_its_rows(tmp_path):
    """``site=``: another site's file is left as it is (same path: the same bytes); a file
    holding two sites is rewritten without this site's rows of the window."""
    wh = tmp_path / "wh"
    t = T0_NS + np.arange(0, 100) * S
    st = TableStager(tmp_path / "a", threaded=False)
    st.add("truth", truth_rows(t, speed=1.0, site="north"))
    commit_window(wh, "truth", st.close(), start_ns=T0_NS, end_ns=T0_NS + 100 * S)
    st = TableStager(tmp_path / "b", threaded=False)
    st.add("truth", truth_rows(t, speed=1.0, site="south"))
    commit_window(wh, "truth", st.close(), start_ns=T0_NS, end_ns=T0_NS + 100 * S,
                  site="south")
    before = set(DeltaTable(str(table_path(wh, "truth"))).file_uris())
    assert len(before) == 2  # one file per site
    st = TableStager(tmp_path / "c", threaded=False)
    st.add("truth", truth_rows(t[20:50], speed=2.0, site="south"))
    commit_window(wh, "truth", st.close(), start_ns=T0_NS + 20 * S, end_ns=T0_NS + 50 * S,
                  site="south")
    north = read_table(wh, "truth", site="north")
    assert north.num_rows == 100 and set(north["speed_mps"].to_pylist()) == {1.0}
    south = read_table(wh, "truth", site="south")
    v = dict(zip(south["time_ns"].to_pylist(), south["speed_mps"].to_pylist(), strict=True))
    assert len(v) == 100 and {v[x] for x in t[20:50].tolist()} == {2.0}
    after = set(DeltaTable(str(table_path(wh, "truth"))).file_uris())
    assert len(before & after) == 1  # north's file untouched; south's rewritten
    # one file holding both sites (a replace_rows of mixed rows): rewritten without south's
    both = pa.concat_tables([truth_rows(t, speed=7.0, site="north"),
                             truth_rows(t, speed=7.0, site="south")])
    replace_rows(wh, "truth", both, predicate_sql="true")
    st = TableStager(tmp_path / "d", threaded=False)
    st.add("truth", truth_rows(t[:10], speed=9.0, site="south"))
    commit_window(wh, "truth", st.close(), start_ns=T0_NS, end_ns=T0_NS + 10 * S,
                  site="south")
    north = read_table(wh, "truth", site="north")
    assert north.num_rows == 100 and set(north["speed_mps"].to_pylist()) == {7.0}
    south = read_table(wh, "truth", site="south")
    assert south.num_rows == 100
    assert sorted(set(south["speed_mps"].to_pylist())) == [7.0, 9.0]


def _sorted_rows(wh):
    import polars as pl

    return pl.from_arrow(read_table(wh, "truth")).sort("source_file", "time_ns", "speed_mps")


def test_source_window_equals_replace_source_file(tmp_path):
    """commit_source_window (the windowed re-ingest) leaves the rows replace_source_file
    leaves: other sources in the window kept, the source's rows outside it kept, files
    written by delta-rs (its own, possibly truncated string statistics) and by the stager,
    sources whose names share a long prefix."""
    import pyarrow as pa
    from polars.testing import assert_frame_equal

    from pipeline.warehouse.delta import replace_rows, replace_source_file
    from pipeline.warehouse.staged import commit_source_window

    long = "/archive/" + "x" * 60
    a, b, c = f"{long}/region_a.mcap", f"{long}/region_b.mcap", "/z.mcap"
    t = T0_NS + np.arange(0, 100) * S
    lo, hi = T0_NS + 30 * S, T0_NS + 60 * S
    new = t[(t >= lo) & (t < hi)]
    whs = []
    for k, how in enumerate(("staged", "reference")):
        wh = tmp_path / f"wh{k}"
        # a: staged whole-file (our statistics); b: through delta-rs; c: a file mixing a/c
        commit_source_window(wh, "truth", _stage_src(tmp_path / f"a{k}", t, 1.0, a),
                             source_file=a, start_ns=T0_NS, end_ns=T0_NS + 100 * S)
        replace_rows(wh, "truth", truth_rows(t[::2], speed=2.0, source=b),
                     predicate_sql="speed_mps = 2.0")
        mixed = pa.concat_tables([truth_rows(t[1::7], speed=3.0, source=a),
                                  truth_rows(t[::5], speed=4.0, source=c)])
        replace_rows(wh, "truth", mixed, predicate_sql="speed_mps > 2.5 AND speed_mps < 4.5")
        if how == "staged":
            got = commit_source_window(wh, "truth", _stage_src(tmp_path / f"n{k}", new, 9.0, a),
                                       source_file=a, start_ns=lo, end_ns=hi)
            assert got == "swap"
        else:
            replace_source_file(wh, "truth", truth_rows(new, speed=9.0, source=a),
                                source_file=a, start_ns=lo, end_ns=hi)
        whs.append(wh)
    ref = _sorted_rows(whs[1])
    assert ref.height > 100
    assert_frame_equal(_sorted_rows(whs[0]), ref, check_exact=True)


def _stage_src(folder, t_ns, speed, source):
    st = TableStager(folder, threaded=False)
    st.add("truth", truth_rows(t_ns, speed=speed, source=source))
    return st.close()


def test_a_checkpoint_every_ten_versions_same_rows(tmp_path):
    """commit_window and replace_rows write a Delta checkpoint at versions 10, 20, ...
    (opening a table replays only the entries after it); the rows are unchanged and an
    older version still reads as it was."""
    from pipeline.warehouse.delta import CHECKPOINT_EVERY, replace_rows

    wh = tmp_path / "wh"
    t = T0_NS + np.arange(0, 100) * S
    commit_window(wh, "truth", _stage(tmp_path / "a", t, 1.0), start_ns=T0_NS,
                  end_ns=T0_NS + 100 * S)
    for v in range(1, 2 * CHECKPOINT_EVERY + 3):
        lo = T0_NS + (v % 10) * 10 * S
        sub = lo + np.arange(10) * S
        if v % 2:
            commit_window(wh, "truth", _stage(tmp_path / f"s{v}", sub, float(v)), start_ns=lo,
                          end_ns=lo + 10 * S)
        else:
            replace_rows(wh, "truth", truth_rows(sub, speed=float(v)),
                         predicate_sql=f"time_ns >= {lo} AND time_ns < {lo + 10 * S}")
        if v == 5:
            at5 = read_table(wh, "truth")
    log = table_path(wh, "truth") / "_delta_log"
    assert sorted(p.name for p in log.glob("*.checkpoint.parquet")) == [
        f"{v:020d}.checkpoint.parquet" for v in (CHECKPOINT_EVERY, 2 * CHECKPOINT_EVERY)]
    tt, v = _rows(wh)
    np.testing.assert_array_equal(tt, t)
    last = {(i % 10): i for i in range(1, 2 * CHECKPOINT_EVERY + 3)}
    np.testing.assert_array_equal(v, [float(last[k]) for k in np.repeat(np.arange(10), 10)])
    old = DeltaTable(str(table_path(wh, "truth")), version=5).to_pyarrow_table()
    assert sorted(old["speed_mps"].to_pylist()) == sorted(at5["speed_mps"].to_pylist())


def test_a_nullable_column_added_to_the_schema_joins_the_table(tmp_path):
    """A table written before its canonical schema gained a nullable column (``mmsi`` of
    ``truth`` stands for one: ``sensor_registration.range_gain`` was added so) takes the
    column at the next window commit: the new rows carry it, the older read null. A
    commit of add actions keeps the table's schema, so before ``add_new_columns`` the
    staged column was never read."""
    from deltalake import write_deltalake

    from pipeline.tables import conform
    from pipeline.warehouse.staged import add_new_columns

    wh = tmp_path / "wh"
    t = T0_NS + np.arange(0, 100) * S
    old = conform("truth", truth_rows(t[:50], speed=1.0)).drop(["mmsi"])
    write_deltalake(str(table_path(wh, "truth")), old, partition_by=["date"])
    assert "mmsi" not in DeltaTable(str(table_path(wh, "truth"))).schema().to_arrow().names
    new = truth_rows(t[50:], speed=2.0)
    new = new.set_column(new.schema.get_field_index("mmsi"), "mmsi",
                         pa.array(np.full(50, 273_000_001), pa.int64()))
    st = TableStager(tmp_path / "a", threaded=False)
    st.add("truth", new)
    assert commit_window(wh, "truth", st.close(), start_ns=int(t[50]),
                         end_ns=int(t[-1]) + S) == "swap"
    got = read_table(wh, "truth")
    assert "mmsi" in got.column_names and got.num_rows == 100
    mmsi = got.sort_by("time_ns")["mmsi"]
    assert mmsi[:50].null_count == 50 and mmsi[50:].null_count == 0
    # nothing more to add
    assert add_new_columns(DeltaTable(str(table_path(wh, "truth"))), "truth") == []
