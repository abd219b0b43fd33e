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
