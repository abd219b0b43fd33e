"""Ingest ledger: fingerprints, entries, the unchanged-file rule."""

from __future__ import annotations

import hashlib
import json

import pytest

from pipeline.tables import schema
from pipeline.warehouse.delta import read_table, table_version
from pipeline.warehouse.ledger import (
    file_fingerprint,
    is_unchanged,
    ledger_entry,
    lookup,
    write_entry,
)


def entry(path: str, sha: str, status: str = "ok", size: int = 10):
    return ledger_entry(
        path,
        size_bytes=size,
        sha256=sha,
        status=status,
        error=None if status == "ok" else "chunk lost",
        message_count=5,
        rows={"radar_tracks": 4, "truth": 1},
        rejects_count=0,
        start_time_ns=1,
        end_time_ns=2,
        ingested_at_ns=123,
    )


def test_fingerprint(tmp_path):
    p = tmp_path / "f.bin"
    data = bytes(range(256)) * 9000  # > 1 MiB: several blocks
    p.write_bytes(data)
    assert file_fingerprint(p) == (len(data), hashlib.sha256(data).hexdigest())


def test_entry_is_conformed():
    e = entry("/a.mcap", "abc")
    assert e.schema == schema("ingest_ledger") and e.num_rows == 1
    assert json.loads(e["rows_json"][0].as_py()) == {"radar_tracks": 4, "truth": 1}
    with pytest.raises(ValueError):
        entry("/a.mcap", "abc", status="weird")


def test_is_unchanged_rules(tmp_path):
    assert not is_unchanged(tmp_path, "/a.mcap", 10, "abc")
    write_entry(tmp_path, entry("/a.mcap", "abc"))
    write_entry(tmp_path, entry("/b.mcap", "bbb", status="partial"))
    write_entry(tmp_path, entry("/c.mcap", "ccc", status="quarantined"))
    assert is_unchanged(tmp_path, "/a.mcap", 10, "abc")
    assert not is_unchanged(tmp_path, "/a.mcap", 10, "abd")  # content changed
    assert not is_unchanged(tmp_path, "/a.mcap", 11, "abc")  # size changed
    assert is_unchanged(tmp_path, "/b.mcap", 10, "bbb")  # partial: re-reading won't help
    assert not is_unchanged(tmp_path, "/c.mcap", 10, "ccc")  # quarantined files are retried
    v = table_version(tmp_path, "ingest_ledger")
    write_entry(tmp_path, entry("/a.mcap", "new"))  # replaces, never duplicates
    assert table_version(tmp_path, "ingest_ledger") == v + 1
    assert read_table(tmp_path, "ingest_ledger").num_rows == 3
    assert lookup(tmp_path, "/a.mcap")["sha256"] == "new"


def test_not_stored_column_is_added_to_a_ledger_written_before_it(tmp_path):
    """A warehouse whose ledger predates ``not_stored_json``: reads give null for the old
    rows, and the next entry adds the column (schema merge) instead of failing."""
    from deltalake import write_deltalake

    from pipeline.warehouse.delta import table_path

    old = entry("/a.mcap", "aa").drop_columns(["not_stored_json"])
    write_deltalake(str(table_path(tmp_path, "ingest_ledger")), old)
    (row,) = read_table(tmp_path, "ingest_ledger").to_pylist()
    assert row["source_file"] == "/a.mcap" and row["not_stored_json"] is None
    new = ledger_entry("/b.mcap", size_bytes=1, sha256="bb", status="ok", error=None,
                       message_count=3, rows={}, rejects_count=0, start_time_ns=1,
                       end_time_ns=2, not_stored={"nmea_GSV": 2})  # fmt: skip
    write_entry(tmp_path, new)
    rows = {r["source_file"]: r for r in read_table(tmp_path, "ingest_ledger").to_pylist()}
    assert rows["/a.mcap"]["not_stored_json"] is None
    assert json.loads(rows["/b.mcap"]["not_stored_json"]) == {"nmea_GSV": 2}
