"""One window, one commit for readers (issue 17, item 3): a batch stopped between its
table commits leaves every table reading as before it, in the reports and in the views
file too; families reading another family's output read this run's."""

from __future__ import annotations

import itertools
import shutil

import numpy as np
import polars as pl
from polars.testing import assert_frame_equal

from pipeline.batch import run_batch
from pipeline.batch.plan import family_waves
from pipeline.families import FAMILIES
from pipeline.reports import run_named_report
from pipeline.warehouse import pending
from pipeline.warehouse.delta import read_table, replace_rows, replace_window
from pipeline.warehouse.views import connect_views_file, rebuild_views_file

DERIVED = [name for fam in FAMILIES for name in fam.outputs]


def _rows(wh, name):
    t = pl.from_arrow(read_table(wh, name))
    return t.sort(t.columns) if t.height else t


def test_a_batch_stopped_between_tables_is_invisible_until_a_batch_covers_it(e2e, tmp_path):
    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    old = {n: _rows(wh, n) for n in DERIVED}
    siap_old = run_named_report(wh, "siap_by_sector")
    # what _commit does first, then the process dies: the marker, then one table changed
    pending.begin(wh, [*DERIVED, "rejects", "batch_units"], job="batch",
                  window=[e2e.start_ns, e2e.end_ns])
    half = read_table(wh, "associations").slice(0, 10)
    replace_window(wh, "associations", half, start_ns=e2e.start_ns, end_ns=e2e.end_ns)
    rebuild_views_file(wh)  # e.g. by the next job
    # the Delta table holds the new (10 rows) version; every reader sees the old one
    assert pending.latest_version(wh, "associations") > pending.pinned_versions(wh)[
        "associations"]
    for name in DERIVED:
        assert_frame_equal(_rows(wh, name), old[name])
    with connect_views_file(wh) as con:
        n = con.execute("SELECT count(*) FROM associations").fetchall()[0][0]
    assert n == old["associations"].height
    assert run_named_report(wh, "siap_by_sector").equals(siap_old)

    # a batch over the window re-does the work: the crashed marker goes with its own
    res = run_batch(e2e.cfg, wh, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                    executor_kind="serial")
    assert res.exit_code == 0, res.render()
    assert pending.markers(wh) == [] and pending.pinned_versions(wh) == {}
    for name in DERIVED:
        assert_frame_equal(_rows(wh, name), old[name])  # the same rows, now committed
    assert not (wh / pending.PENDING_DIR).exists()


def test_a_marker_of_another_window_keeps_its_pins(e2e, tmp_path):
    """A batch of a window that does not cover the crashed one leaves its marker (the
    crashed window's tables keep reading as before the crash)."""
    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    marker = pending.begin(wh, ["associations"], job="batch",
                           window=[e2e.end_ns + 1, e2e.end_ns + 2])
    res = run_batch(e2e.cfg, wh, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                    executor_kind="serial")
    assert res.exit_code == 0
    assert [p for p, _ in pending.markers(wh)] == [marker]


def test_gaps_runs_after_maritime_on_its_system_tracks(cfg):
    waves = [[f.name for f in wave] for wave in family_waves(FAMILIES, cfg)]
    assert waves.index(next(w for w in waves if "gaps" in w)) > waves.index(
        next(w for w in waves if "maritime" in w))


def test_a_later_wave_reads_this_batchs_rows_inside_the_window(e2e, tmp_path):
    """gaps' system_tracks input, inside the batch window, comes from this batch's joined
    rows (the override), outside it from the warehouse: here the warehouse has none
    inside (as on a first batch) and the unit still gets every row."""
    import pyarrow.parquet as pq

    from pipeline.batch import read_inputs
    from pipeline.families import family
    from pipeline.family import Window
    from pipeline.units import NS
    from pipeline.warehouse.delta import table_path

    wh = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, wh)
    tracks = read_table(wh, "system_tracks")
    assert tracks.num_rows > 0
    joined = tmp_path / "system_tracks.parquet"
    pq.write_table(tracks, joined)
    mid = e2e.start_ns + 600 * NS
    outside = tracks.filter(pl.from_arrow(tracks)["time_ns"].to_numpy() < mid)
    shutil.rmtree(table_path(wh, "system_tracks"))
    replace_window(wh, "system_tracks", outside, start_ns=e2e.start_ns, end_ns=mid)
    gaps = family("gaps")
    window = Window(mid, e2e.end_ns)
    got = read_inputs(gaps, wh, e2e.cfg, window, {"system_tracks": (str(joined),)},
                      (mid, e2e.end_ns))["system_tracks"]
    spec = next(i for i in gaps.inputs(e2e.cfg) if i.table == "system_tracks")
    lo, hi = spec.span_ns(window)
    want = pl.from_arrow(tracks).filter((pl.col("time_ns") >= lo) & (pl.col("time_ns") < hi))
    assert got.height == want.height > 0
    assert_frame_equal(got.sort(got.columns), want.select(got.columns).sort(got.columns))


def test_an_override_read_is_in_time_order_whatever_the_order_of_its_files(e2e, tmp_path):
    """A later wave's read of this batch's rows (one file per unit) comes out sorted by
    the table's key: as it is when the units' files are given in time order (no sort,
    no copy of the rows), and sorted when they are not."""
    import pyarrow.parquet as pq

    from pipeline.batch.worker import is_sorted_by, read_inputs
    from pipeline.families import family
    from pipeline.family import Window

    tracks = pl.from_arrow(read_table(e2e.warehouse, "system_tracks"))
    cuts = np.linspace(e2e.start_ns, e2e.end_ns, 4).astype(np.int64)
    files = []
    for i, (lo, hi) in enumerate(itertools.pairwise(cuts)):
        part = tracks.filter((pl.col("time_ns") >= lo) & (pl.col("time_ns") < hi))
        files.append(str(tmp_path / f"unit{i}.parquet"))
        pq.write_table(part.to_arrow(), files[-1])
    gaps = family("gaps")
    window = Window(int(cuts[1]), int(cuts[2]))
    reads = [read_inputs(gaps, e2e.warehouse, e2e.cfg, window, {"system_tracks": order},
                         (e2e.start_ns, e2e.end_ns))["system_tracks"]
             for order in (tuple(files), tuple(reversed(files)))]
    assert reads[0].height > 0
    for got in reads:
        assert got["time_ns"].is_sorted()
        assert_frame_equal(got.sort(got.columns), reads[0].sort(got.columns))
    frame = pl.DataFrame({"t": [1, 1, 2, 2], "i": [1, 3, 0, 2]})
    assert is_sorted_by(frame, ["t", "i"]) and is_sorted_by(frame, ["t"])
    assert not is_sorted_by(frame.reverse(), ["t"])
    assert not is_sorted_by(pl.DataFrame({"t": [1, 1], "i": [2, 1]}), ["t", "i"])
    assert not is_sorted_by(pl.DataFrame({"t": [1, None]}), ["t"])


def test_a_batch_replaces_its_rejects_and_commits_none_when_none_change(tmp_path):
    """The window's batch rejects of its site are replaced (the ingest's, other sites'
    and other times' kept); with none new and none to replace (by the files' statistics)
    the rejects table gets no commit (a predicate overwrite, ~12 ms of CPU, per batch)."""
    from pipeline import tables
    from pipeline.batch.commit import commit_batch
    from pipeline.batch.summary import BatchSummary
    from pipeline.warehouse.delta import table_version

    t0 = 1_768_435_200 * 10**9  # 2026-01-15
    rows = pl.DataFrame({
        "log_time_ns": [t0 + 10, t0 + 20, t0 + 30, t0 + 4_000 * 10**9],
        "source_file": ["/a.mcap"] * 4, "stage": ["ingest", "batch", "batch", "batch"],
        "reason_code": ["x"] * 4, "reason": ["r"] * 4,
        "site": ["quay", "quay", "harbour", "quay"]})
    for i in range(rows.height):  # a file each (as jobs write them: the ingest's, a batch's)
        replace_rows(tmp_path, "rejects", tables.conform("rejects", rows.slice(i, 1)),
                     predicate_sql=f"log_time_ns = {rows['log_time_ns'][i]}")
    window = BatchSummary(start_ns=t0, end_ns=t0 + 3_600 * 10**9, site="quay")
    commit_batch(tmp_path, [], window, (), None)
    left = _rows(tmp_path, "rejects").select("log_time_ns", "stage", "site")
    assert left.rows() == [(t0 + 10, "ingest", "quay"), (t0 + 30, "batch", "harbour"),
                           (t0 + 4_000 * 10**9, "batch", "quay")]
    version = table_version(tmp_path, "rejects")
    commit_batch(tmp_path, [], BatchSummary(start_ns=t0, end_ns=t0 + 3_600 * 10**9,
                                            site="quay"), (), None)
    assert table_version(tmp_path, "rejects") == version
    assert _rows(tmp_path, "rejects").select("log_time_ns", "stage", "site").equals(left)
