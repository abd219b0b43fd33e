"""bench/reports_archive.py's 7-day warehouse: every copy of a table holds the day's rows
with times and ``date`` moved by whole days, in the day's row groups."""

from __future__ import annotations

from pathlib import Path

import pyarrow.compute as pc
import pyarrow.parquet as pq
from mcap_fixtures import DAY, T0, hours, truth_rows

# by its module name, not its file: the copy's worker processes import it
from bench.reports_archive import shifted_copy
from pipeline.warehouse.delta import read_table, replace_window, table_snapshot


def test_the_shifted_copy_holds_each_day_once_in_the_days_layout(tmp_path):
    day, week = tmp_path / "day", tmp_path / "week"
    rows = truth_rows(hours(0, 24))
    replace_window(day, "truth", rows, start_ns=T0, end_ns=T0 + DAY)
    written = shifted_copy(day, week, 3, {"truth"})
    assert written == {"truth": 3 * rows.num_rows}
    got = read_table(week, "truth")
    for k in range(3):
        copy = got.filter(pc.and_(pc.greater_equal(got["time_ns"], T0 + k * DAY),
                                  pc.less(got["time_ns"], T0 + (k + 1) * DAY)))
        assert pc.subtract(copy["time_ns"], k * DAY).to_pylist() == rows["time_ns"].to_pylist()
        assert copy["log_time_ns"].to_pylist() == pc.add(rows["log_time_ns"], k * DAY).to_pylist()
        assert copy["mmsi"].to_pylist() == rows["mmsi"].to_pylist()
    assert len(read_table(week, "truth", start_ns=T0 + DAY, end_ns=T0 + 2 * DAY)) == rows.num_rows
    files, _ = table_snapshot(week, "truth")
    assert sorted(Path(f).parent.name for f in files) == [
        "date=2026-01-01", "date=2026-01-02", "date=2026-01-03"]
    (source,), _ = table_snapshot(day, "truth")
    groups = [pq.ParquetFile(f).metadata.num_row_groups for f in files]
    assert groups == [pq.ParquetFile(source).metadata.num_row_groups] * 3
