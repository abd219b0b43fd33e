"""Issue 18, item 2: concatenated MCAP files are read as their parts; identical content
under another name is a ``duplicate`` in the ledger, not ingested twice; a partial file
is read again on re-run."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from mcap_fixtures import T0_NS, mixed_file, radar_messages, write_mcap

from pipeline.families import load_config
from pipeline.ingest.driver import run_ingest
from pipeline.io.mcap_read import read_mcap_batches
from pipeline.warehouse.delta import read_table


def _ledger(wh: Path) -> dict[str, dict]:
    return {Path(r["source_file"]).name: r for r in read_table(wh, "ingest_ledger").to_pylist()}


def test_concatenated_mcap_is_read_as_its_parts(tmp_path):
    a = mixed_file(tmp_path / "a.mcap", 300)
    b = write_mcap(tmp_path / "b.mcap", radar_messages(500, site="R2", t0_ns=T0_NS + 10**12))
    c = tmp_path / "in" / "c.mcap"
    c.parent.mkdir()
    c.write_bytes(a.read_bytes() + b.read_bytes())
    scan = read_mcap_batches(c)
    topics: dict[str, int] = {}
    for batch in scan:
        topics[batch.topic] = topics.get(batch.topic, 0) + len(batch)
    assert scan.status.parts == 2 and scan.status.status == "ok"
    assert topics["/radar/R2/tracks"] == 500 and topics["/radar/R1/tracks"] == 300
    s = run_ingest([c], load_config(), tmp_path / "wh", executor="serial")
    assert s.exit_code == 0, s.render()
    assert s.rows["radar_tracks"] == 800
    index = read_table(tmp_path / "wh", "mcap_index").to_pylist()
    assert {r["topic"] for r in index} >= {"/radar/R1/tracks", "/radar/R2/tracks"}


def test_same_content_under_two_names_is_ingested_once(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    mixed_file(src / "first.mcap", 200)
    shutil.copy(src / "first.mcap", src / "copy.mcap")
    wh = tmp_path / "wh"
    s = run_ingest([src], load_config(), wh, executor="serial")
    assert s.files_duplicate == 1 and "1 duplicate" in s.render()
    assert s.exit_code == 0, s.render()  # nothing lost: the content is in the warehouse
    assert read_table(wh, "radar_tracks").num_rows == 200
    ledger = _ledger(wh)
    dup = [r for r in ledger.values() if r["status"] == "duplicate"]
    assert len(dup) == 1 and "same content" in dup[0]["error"]
    assert dup[0]["sha256"] == ledger["first.mcap"]["sha256"]
    # a later run with a third copy: recognised from the ledger
    shutil.copy(src / "first.mcap", src / "third.mcap")
    again = run_ingest([src / "third.mcap"], load_config(), wh, executor="serial")
    assert again.files_duplicate == 1
    assert read_table(wh, "radar_tracks").num_rows == 200
    # and an unchanged duplicate is skipped
    assert run_ingest([src], load_config(), wh, executor="serial").files_skipped == 3


def test_partial_file_is_read_again(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    data = mixed_file(tmp_path / "whole.mcap", 300).read_bytes()
    (src / "cut.mcap").write_bytes(data[: len(data) * 2 // 3])
    wh = tmp_path / "wh"
    first = run_ingest([src], load_config(), wh, executor="serial")
    assert first.files_partial == 1 and first.exit_code == 1
    again = run_ingest([src], load_config(), wh, executor="serial")
    assert again.files_skipped == 0 and again.files_partial == 1 and again.exit_code == 1
    (src / "cut.mcap").write_bytes(data)  # the rest arrived: read whole now
    whole = run_ingest([src], load_config(), wh, executor="serial")
    assert whole.files_ok == 1 and whole.exit_code == 0
    assert read_table(wh, "radar_tracks").num_rows == 300
