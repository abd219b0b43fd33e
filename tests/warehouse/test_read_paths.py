"""read_table under warehouse paths with characters a URI encodes (issue 18): the
snapshot's file list comes percent-encoded; the reader decodes it."""

from __future__ import annotations

import pyarrow as pa
import pytest

from pipeline.units import NS
from pipeline.warehouse.delta import read_table, replace_window

T0 = 1_767_225_600 * NS


@pytest.mark.parametrize("name", ["a b", "a#b", "a%b", "a?b", "a+b", "aéb"])
def test_read_table_under_odd_paths(tmp_path, name):
    wh = tmp_path / name
    rows = pa.table({"time_ns": [T0, T0 + NS], "vessel_id": [1, 1], "mmsi": [2, 2],
                     "lat_deg": [46.0, 46.1], "lon_deg": [30.0, 30.1],
                     "course_rad": [0.0, 0.0], "speed_mps": [1.0, 1.0],
                     "source_file": ["/f", "/f"], "topic": ["/t", "/t"],
                     "log_time_ns": [T0, T0 + NS]})  # fmt: skip
    replace_window(wh, "truth", rows, start_ns=T0, end_ns=T0 + 2 * NS)
    assert read_table(wh, "truth").num_rows == 2
    assert read_table(wh, "truth", start_ns=T0 + NS, end_ns=T0 + 2 * NS).num_rows == 1


@pytest.mark.parametrize("name", ["a b", "a#b", "a%b"])
def test_snapshot_files_exist_under_odd_paths(tmp_path, name):
    """The DuckDB views read ``table_snapshot``'s files: they must be real paths."""
    from pathlib import Path

    from pipeline.warehouse.delta import table_snapshot

    test_read_table_under_odd_paths(tmp_path, name)
    files, _ = table_snapshot(tmp_path / name, "truth")
    assert files and all(Path(f).is_file() for f in files)
