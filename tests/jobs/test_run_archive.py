"""`surveil run` over what an archive really holds (issue 35 item 7, issue 40 item 1):
raw recordings imported and ingested; the exit codes of `ingest`; files still being
written left until they are finished (or stable for [archive] settle_s); a half-written
file read under another site than its finished one names has its rows moved to the
right site, raw and derived: the warehouse equals a single run over the whole file."""

from __future__ import annotations

import hashlib
import os
import shutil
import time
from dataclasses import replace
from pathlib import Path

import polars as pl
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from jobs.simulate import run_simulate
from pipeline.batch.nightly import run_nightly
from pipeline.families import load_config
from pipeline.ingest.archive import finished_mcap, imported_path
from pipeline.ingest.driver import run_ingest
from pipeline.maritime.config import without_faults
from pipeline.simulate.channel import simulate_channel
from pipeline.tables import table_specs
from pipeline.units import NS
from pipeline.warehouse.delta import read_table
from tests.decode.nmea_builders import tag_block

START_NS = 1_768_435_200 * NS  # 2026-01-15T00:00:00Z
HOUR = 3600 * NS
# bookkeeping columns: wall-clock times of the jobs, not data
VOLATILE = {"ingested_at_ns", "committed_at_ns", "detected_at_ns", "imported_at_ns",
            "window_start_ns", "window_end_ns"}
LEDGERS_OF_RUNS = {"runs"}


def aged(path: Path, seconds: float = 3600.0) -> Path:
    """``path`` as last modified ``seconds`` ago (a finished recording)."""
    t = time.time() - seconds
    os.utime(path, (t, t))
    return path


def tables_of(wh: Path) -> dict[str, pl.DataFrame]:
    """Every table but ``runs``, bookkeeping columns dropped, rows sorted."""
    out = {}
    for name in sorted(set(table_specs()) - LEDGERS_OF_RUNS):
        t = pl.from_arrow(read_table(wh, name))
        t = t.drop([c for c in t.columns if c in VOLATILE])
        out[name] = t.sort(t.columns) if t.height else t
    return out


def assert_same_warehouse(got: Path, want: Path) -> None:
    a, b = tables_of(got), tables_of(want)
    for name in b:
        assert a[name].equals(b[name]), f"table {name} differs"


# --- raw recordings ---------------------------------------------------------------------


def ais_log(path: Path, *, minutes: float = 10.0, bad: int = 1) -> tuple[Path, int]:
    """An NMEA 4 tag-block AIS log of the channel scene (``c:`` receive times), with
    ``bad`` sentences whose checksum is wrong (rejects): (path, good sentences)."""
    sc = simulate_channel(without_faults(load_config()), start_ns=START_NS,
                          duration_s=minutes * 60.0, seed=4)
    ais = sc.ais_sentences
    lines = [tag_block(f"c:{t // NS}") + s for t, s in
             zip(ais["log_time_ns"].to_list(), ais["sentence"].to_list(), strict=True)]
    for i in range(bad):
        body = lines[10 + i]
        lines[10 + i] = body[:-2] + ("00" if body[-2:] != "00" else "11")
    path.write_text("\n".join(lines) + "\n")
    return aged(path), len(lines) - bad


def test_run_imports_raw_recordings_and_exits_like_ingest(tmp_path):
    """A folder holding an AIS text log (no MCAP): `surveil run` imports it into the
    warehouse's imported/ folder, records it in import_ledger, ingests and batches it,
    and exits 1 for its rejected sentence as `ingest` of the same MCAP does (was: run
    took *.mcap only, and exited 0 where ingest exited 1). Unchanged: nothing to do; the
    log grows: imported and ingested again, its rows replaced."""
    cfg = load_config()
    archive = tmp_path / "archive"
    archive.mkdir()
    log, _ = ais_log(archive / "receiver-1.nmea")
    wh = tmp_path / "wh"
    res = run_nightly(cfg, wh, folders=[str(archive)], executor_kind="serial")
    mcap = imported_path(wh, log)
    assert res.imports.imported == {str(log.resolve()): "ok"}
    assert mcap.is_file() and mcap.is_relative_to(wh / "imported")
    ledger = read_table(wh, "import_ledger").to_pylist()
    assert len(ledger) == 1
    row = ledger[0]
    assert row["source_file"] == str(log.resolve()) and row["mcap_file"] == str(mcap)
    assert row["sha256"] == hashlib.sha256(log.read_bytes()).hexdigest()
    assert row["status"] == "ok" and row["format"] == "nmea_text"
    assert res.files == {str(mcap): "ok"}
    rejects = pl.from_arrow(read_table(wh, "rejects"))
    assert rejects.height >= 1
    assert read_table(wh, "ais_reports").num_rows > 1000
    assert pl.from_arrow(read_table(wh, "batch_units"))["family"].to_list().count("maritime")
    # ingest of the same MCAP into another warehouse: the same exit code
    alone = run_ingest([mcap], cfg, tmp_path / "alone", executor="serial")
    assert alone.exit_code == 1 and res.exit_code == alone.exit_code, res.render()
    assert "rejects (ingest)" in res.render()
    again = run_nightly(cfg, wh, folders=[str(archive)], executor_kind="serial")
    assert again.nothing_to_do and again.exit_code == 0 and again.imports.unchanged == 1
    # the receiver's log grows: imported again into the same MCAP, its rows replaced
    ais_log(archive / "receiver-1.nmea", minutes=12.0, bad=0)
    grown = run_nightly(cfg, wh, folders=[str(archive)], executor_kind="serial")
    assert grown.exit_code == 0, grown.render()
    assert read_table(wh, "import_ledger").num_rows == 1
    assert read_table(wh, "ingest_ledger").num_rows == 1
    assert read_table(wh, "rejects").num_rows == 0
    # the same rows as a first run over the grown log
    other = tmp_path / "other"
    other.mkdir()
    shutil.copy2(archive / "receiver-1.nmea", other / "receiver-1.nmea")
    fresh = tmp_path / "fresh"
    assert run_nightly(cfg, fresh, folders=[str(other)], executor_kind="serial").exit_code == 0
    cols = ["time_ns", "mmsi", "lat_deg", "lon_deg", "sog_mps"]
    a, b = (pl.from_arrow(read_table(w, "ais_reports", columns=cols)) for w in (wh, fresh))
    assert a.height > 1000 and a.sort(cols).equals(b.sort(cols))


def test_run_exits_1_for_rejects_of_an_mcap_as_ingest_does(tmp_path):
    """An MCAP with rejected messages in the archive: ingest exits 1; run exited 0."""
    cfg = load_config()
    archive = tmp_path / "archive"
    archive.mkdir()
    log, _ = ais_log(tmp_path / "receiver.nmea")
    from pipeline.convert.importer import run_import

    run_import([log], archive)
    res = run_nightly(cfg, tmp_path / "wh", folders=[str(archive)], executor_kind="serial")
    assert res.ingest is not None and res.ingest.exit_code == 1
    assert res.exit_code == 1, res.render()


# --- files still being written ------------------------------------------------------------


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """A finished 10-minute recording whose site metadata (``surveil.scenario``) comes
    after its messages: a recorder that names the site when it closes the file."""
    root = tmp_path_factory.mktemp("writing")
    (src,) = run_simulate("channel-clean", 600.0, 3, root / "sim", load_config(),
                          start_ns=START_NS)
    out = root / "recorder.mcap"
    with open(src, "rb") as f:
        reader = make_reader(f)
        meta = list(reader.iter_metadata())
        with open(out, "wb") as g:
            w = Writer(g, compression=CompressionType.ZSTD, chunk_size=64 * 1024)
            w.start("", "surveil-test")
            schemas: dict[int, int] = {}
            channels: dict[int, int] = {}
            for schema, channel, message in reader.iter_messages(log_time_order=False):
                if schema is not None and schema.id not in schemas:
                    schemas[schema.id] = w.register_schema(schema.name, schema.encoding,
                                                           schema.data)
                if channel.id not in channels:
                    channels[channel.id] = w.register_channel(
                        channel.topic, channel.message_encoding,
                        schemas.get(channel.schema_id, 0), channel.metadata)
                w.add_message(channels[channel.id], message.log_time, message.data,
                              message.publish_time, message.sequence)
            for m in meta:  # the site, last
                w.add_metadata(m.name, m.metadata)
            w.finish()
    return out


def half_of(recording: Path, dest: Path) -> Path:
    dest.parent.mkdir(parents=True, exist_ok=True)
    data = recording.read_bytes()
    dest.write_bytes(data[: len(data) // 2])
    return dest


def whole(recording: Path, dest: Path) -> Path:
    shutil.copyfile(recording, dest)
    return aged(dest, 1.0)


def test_a_file_still_being_written_waits_for_its_end(tmp_path, recording):
    """The recorder's current file (no footer yet, just modified): run leaves it for a
    later run and says so (was: its first half ingested as partial under site
    `default`, batched, "run ok"); once finished it is read whole: the warehouse
    equals a single run over the finished file."""
    cfg = load_config()
    archive = tmp_path / "archive"
    f = half_of(recording, archive / "recorder.mcap")
    assert not finished_mcap(f)
    wh = tmp_path / "wh"
    first = run_nightly(cfg, wh, folders=[str(archive)], executor_kind="serial")
    assert first.exit_code == 0 and first.nothing_to_do, first.render()
    assert [p for p, _ in first.deferred] == [str(f.resolve())]
    assert "still being written" in first.render()
    assert read_table(wh, "ingest_ledger").num_rows == 0
    whole(recording, f)
    second = run_nightly(cfg, wh, folders=[str(archive)], executor_kind="serial")
    assert second.exit_code == 0, second.render()
    single = tmp_path / "single"
    assert run_nightly(cfg, single, folders=[str(archive)],
                       executor_kind="serial").exit_code == 0
    assert_same_warehouse(wh, single)
    # an unfinished file that stopped changing (a recorder that died) is read as it is
    dead = half_of(recording, tmp_path / "dead" / "recorder.mcap")
    res = run_nightly(cfg, tmp_path / "wh-dead", folders=[str(dead.parent)],
                      executor_kind="serial", now_ns=time.time_ns() + 301 * NS)
    assert res.files == {str(dead.resolve()): "partial"} and res.exit_code == 1


def test_a_half_file_read_under_another_site_moves_to_its_own(tmp_path, recording):
    """With no settle time, the half file is read (partial: exit 1, as ingest) before
    its site metadata exists: under `default`, and batched. Read whole, it names its
    site: its raw rows are replaced under that site and the `default` site's derived
    rows and units of its span removed. The warehouse then equals a single run over
    the whole file, with no `default` row in any table."""
    cfg = replace(load_config(), archive_settle_s=0.0)
    archive = tmp_path / "archive"
    f = half_of(recording, archive / "recorder.mcap")
    wh = tmp_path / "wh"
    first = run_nightly(cfg, wh, folders=[str(archive)], executor_kind="serial")
    assert first.files == {str(f.resolve()): "partial"}
    assert first.exit_code == 1, first.render()  # as ingest of the same file
    assert set(pl.from_arrow(read_table(wh, "batch_units"))["site"]) == {"default"}
    assert read_table(wh, "system_tracks").num_rows > 0
    whole(recording, f)
    second = run_nightly(cfg, wh, folders=[str(archive)], executor_kind="serial")
    assert second.exit_code == 0, second.render()
    assert any("now names 'channel-clean'" in m for m in second.moved)
    for name in table_specs():
        if name in LEDGERS_OF_RUNS or "site" not in table_specs()[name].schema.names:
            continue
        sites = set(pl.from_arrow(read_table(wh, name, columns=["site"]))["site"])
        assert "default" not in sites, name
    single = tmp_path / "single"
    assert run_nightly(cfg, single, folders=[str(archive)],
                       executor_kind="serial").exit_code == 0
    assert_same_warehouse(wh, single)


def test_the_operations_guide_agrees_with_run_help():
    """docs/operations.md said `run` has no --site while --help showed one: every option
    of `surveil run --help` is in the guide's section on the nightly job, and the guide
    does not deny one."""
    import re

    from click.testing import CliRunner

    from jobs.cli import cli

    text = CliRunner().invoke(cli, ["run", "--help"]).output
    options = set(re.findall(r"^\s+(--[a-z-]+)", text, flags=re.M)) - {"--help"}
    guide = (Path(__file__).resolve().parents[2] / "docs" / "operations.md").read_text()
    section = guide[guide.index("## The nightly job"):guide.index("## Reprocess is exact")]
    assert {"--site", "--ignore-place", "--wait"} <= options
    missing = {o for o in options - {"--config", "--warehouse", "--executor"}
               if o not in section}
    assert not missing, missing
    for o in options:
        assert f"has no `{o}`" not in guide, o
