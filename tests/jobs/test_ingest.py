"""Ingest job end to end (real MCAP files, real Delta warehouse, real DuckDB) and the
executor seam it runs on."""

from __future__ import annotations

import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from mcap_fixtures import (
    AIS_TYPE1,
    T0_NS,
    TYPE5_FRAGMENTS,
    dumps,
    mixed_file,
    radar_messages,
    radar_report,
    write_mcap,
)

import pipeline.ingest.worker
import pipeline.warehouse.staged
from pipeline.decode import json_columns
from pipeline.executors import ExecutorError, UnitQueue, UnitResult, make_executor
from pipeline.families import load_config
from pipeline.ingest.driver import IngestSummary, IngestUsageError, run_ingest
from pipeline.io.mcap_read import read_mcap_batches
from pipeline.threads import HASHER_NICE, SECOND_PARSER_NICE, WRITER_NICE
from pipeline.units import NS
from pipeline.warehouse.delta import read_table, table_version
from pipeline.warehouse.views import VIEWS_FILE, connect_views_file

TABLES = ("radar_tracks", "ais_reports", "ais_static", "truth", "rejects", "ingest_ledger")


@pytest.fixture(scope="module")
def cfg():
    return load_config()


def ingest(paths, cfg, wh, **kw) -> IngestSummary:
    kw.setdefault("executor", make_executor("serial", 1, 1))
    return run_ingest(paths, cfg, wh, **kw)


def versions(wh) -> dict[str, int | None]:
    return {n: table_version(wh, n) for n in TABLES}


def rows_of(wh, name, source) -> list[dict]:
    return [r for r in read_table(wh, name).to_pylist() if r["source_file"] == str(source)]


def test_ingest_directory_then_noop_reingest(tmp_path, cfg):
    arch = tmp_path / "arch"
    (arch / "sub").mkdir(parents=True)
    a = mixed_file(arch / "a.mcap")
    b = write_mcap(arch / "sub" / "b.mcap", radar_messages(50, site="R2"))
    (arch / "notes.txt").write_text("ignored: not *.mcap")
    wh = tmp_path / "wh"
    s = ingest([arch], cfg, wh)
    assert s.exit_code == 0, s.render()
    assert (s.files_total, s.files_ok, s.files_skipped) == (2, 2, 0)
    assert s.rows["radar_tracks"] == 350 and s.rows["truth"] == 30
    assert s.rows["ais_reports"] == 2 and s.rows["ais_static"] == 1 and s.rows["rejects"] == 0
    assert len(rows_of(wh, "radar_tracks", b)) == 50
    ledger = {r["source_file"]: r for r in read_table(wh, "ingest_ledger").to_pylist()}
    assert set(ledger) == {str(a), str(b)} and ledger[str(a)]["status"] == "ok"
    assert ledger[str(a)]["message_count"] == 334
    assert ledger[str(a)]["start_time_ns"] == T0_NS
    assert (wh / VIEWS_FILE).is_file() and not (wh / "_staging").exists()
    text = s.render()
    assert "2 ok" in text and "radar_tracks 350" in text and text.count("\n") < 25

    before = versions(wh)
    again = ingest([arch], cfg, wh)
    assert again.exit_code == 0 and again.files_skipped == 2 and again.files_ok == 0
    assert versions(wh) == before  # nothing committed

    forced = ingest([a], cfg, wh, force=True)
    assert forced.files_ok == 1 and versions(wh)["radar_tracks"] > before["radar_tracks"]
    assert len(rows_of(wh, "radar_tracks", a)) == 300  # replaced, not duplicated


def test_changed_file_replaces_its_rows(tmp_path, cfg):
    wh = tmp_path / "wh"
    p = mixed_file(tmp_path / "f.mcap", n_radar=200)
    other = write_mcap(tmp_path / "other.mcap", radar_messages(10, site="R2"))
    ingest([p, other], cfg, wh)
    assert len(rows_of(wh, "radar_tracks", p)) == 200
    assert len(rows_of(wh, "ais_static", p)) == 1
    # the file is rewritten: fewer radar reports, no AIS at all, one bad report
    msgs = radar_messages(80)
    msgs.append(("/radar/R1/tracks", T0_NS + 500 * NS, dumps(radar_report(1, range_m=-3.0))))
    write_mcap(p, msgs)
    s = ingest([p, other], cfg, wh)
    assert s.files_ok == 1 and s.files_skipped == 1
    assert len(rows_of(wh, "radar_tracks", p)) == 80
    assert rows_of(wh, "ais_reports", p) == [] and rows_of(wh, "ais_static", p) == []
    assert rows_of(wh, "truth", p) == []
    assert [r["reason_code"] for r in rows_of(wh, "rejects", p)] == ["out_of_range"]
    assert len(rows_of(wh, "radar_tracks", other)) == 10  # other file untouched
    con = connect_views_file(wh)
    n_view = con.execute("SELECT count(*) FROM radar_tracks").fetchall()[0][0]
    con.close()
    assert n_view == read_table(wh, "radar_tracks").num_rows == 90


def test_not_mcap_quarantined_and_run_continues(tmp_path, cfg):
    arch = tmp_path / "arch"
    arch.mkdir()
    good = write_mcap(arch / "good.mcap", radar_messages(30))
    junk = arch / "junk.mcap"
    junk.write_bytes(b"PK\x03\x04 this is a zip file")
    wh = tmp_path / "wh"
    s = ingest([arch], cfg, wh)
    assert s.exit_code == 1 and s.files_quarantined == 1 and s.files_ok == 1
    assert s.rejects == {"not_mcap": 1}
    (rej,) = rows_of(wh, "rejects", junk)
    assert rej["reason_code"] == "not_mcap" and rej["topic"] is None
    assert rej["raw"] == junk.read_bytes()[:64] and rej["log_time_ns"] == 0
    ledger = {Path(r["source_file"]).name: r for r in read_table(wh, "ingest_ledger").to_pylist()}
    assert ledger["junk.mcap"]["status"] == "quarantined" and ledger["junk.mcap"]["error"]
    assert len(rows_of(wh, "radar_tracks", good)) == 30
    # a quarantined file is retried on the next run (and still quarantined)
    again = ingest([arch], cfg, wh)
    assert again.files_quarantined == 1 and again.files_skipped == 1
    assert len(rows_of(wh, "rejects", junk)) == 1


def test_damaged_file_is_partial_with_rejects(tmp_path, cfg):
    p = mixed_file(tmp_path / "d.mcap", n_radar=400)
    data = bytearray(p.read_bytes())
    scan = read_mcap_batches(p)
    list(scan)
    assert scan.status.chunks_read > 5
    with open(p, "rb") as f:
        from mcap.reader import make_reader

        ci = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)[
            3
        ]
    data[ci.chunk_start_offset + ci.chunk_length // 2] ^= 0x55
    p.write_bytes(bytes(data))
    wh = tmp_path / "wh"
    s = ingest([p], cfg, wh)
    assert s.exit_code == 1 and s.files_partial == 1 and s.rejects == {"corrupt_chunk": 1}
    (rej,) = rows_of(wh, "rejects", p)
    assert "messages lost" in rej["reason"] and rej["log_time_ns"] == ci.message_start_time
    (led,) = read_table(wh, "ingest_ledger").to_pylist()
    assert led["status"] == "partial" and "corrupt_chunk" in led["error"]
    # partial -> read again next time (issue 18: the README's promise), same result
    again = ingest([p], cfg, wh)
    assert again.files_skipped == 0 and again.files_partial == 1 and again.exit_code == 1
    assert len(rows_of(wh, "rejects", p)) == 1


def test_bad_paths_are_usage_errors(tmp_path, cfg):
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "readme.txt").write_text("no mcap here")
    with pytest.raises(IngestUsageError, match=r"no \*\.mcap files"):
        ingest([empty], cfg, tmp_path / "wh")
    with pytest.raises(IngestUsageError, match="does not exist"):
        ingest([tmp_path / "nope.mcap"], cfg, tmp_path / "wh")
    with pytest.raises(IngestUsageError):
        ingest([], cfg, tmp_path / "wh")
    with pytest.raises(IngestUsageError, match="window"):
        ingest([empty], cfg, tmp_path / "wh", start_ns=5)
    assert IngestUsageError.__mro__[1].__name__ == "UsageError"  # exit code 2 at the CLI
    assert not (tmp_path / "wh").exists()


def test_window_replaces_only_the_window(tmp_path, cfg):
    p = mixed_file(tmp_path / "w.mcap", n_radar=300)
    wh = tmp_path / "wh"
    ingest([p], cfg, wh)
    before = read_table(wh, "radar_tracks")
    start, end = T0_NS + 100 * NS, T0_NS + 200 * NS
    # rewrite the file with the reports inside the window changed (speed 7)
    msgs = []
    for i in range(300):
        t = T0_NS + i * NS
        speed = 7.0 if start <= t < end else 5.0
        msgs.append(("/radar/R1/tracks", t, dumps(radar_report(i, t_ns=t, speed_mps=speed))))
    msgs.append(("/radar/R1/tracks", T0_NS + 150 * NS + 1, b"not json"))
    write_mcap(p, msgs)
    s = ingest([p], cfg, wh, start_ns=start, end_ns=end)
    assert s.rows["radar_tracks"] == 100 and s.rejects == {"undecodable": 1}
    after = read_table(wh, "radar_tracks")
    assert after.num_rows == before.num_rows == 300
    t = after["time_ns"].to_pylist()
    speeds = after["speed_mps"].to_pylist()
    assert all((sp == 7.0) == (start <= ti < end) for ti, sp in zip(t, speeds, strict=True))
    # rows of other tables outside the window are kept (AIS at t0+5 s, truth everywhere)
    assert len(rows_of(wh, "ais_reports", p)) == 2
    truth_t = [r["time_ns"] for r in rows_of(wh, "truth", p)]
    assert truth_t and not any(start <= x < end for x in truth_t)
    # windowed runs neither skip by nor write the ledger
    (led,) = read_table(wh, "ingest_ledger").to_pylist()
    assert led["message_count"] == 334
    again = ingest([p], cfg, wh, start_ns=start, end_ns=end)
    assert again.files_skipped == 0 and read_table(wh, "radar_tracks").equals(after)


def test_window_report_logged_outside_window_is_kept(tmp_path, cfg):
    # report time inside the window, logged 2 s after its end: still ingested
    start, end = T0_NS, T0_NS + 10 * NS
    rep = dumps(radar_report(0, t_ns=end - NS))
    p = write_mcap(tmp_path / "late.mcap", [("/radar/R1/tracks", end + 2 * NS, rep)])
    s = ingest([p], cfg, tmp_path / "wh", start_ns=start, end_ns=end)
    assert s.rows["radar_tracks"] == 1


def test_ais_multipart_across_chunks_end_to_end(tmp_path, cfg):
    msgs = [("/ais/nmea", T0_NS + i, AIS_TYPE1) for i in range(40)]
    msgs += [("/ais/nmea", T0_NS + 100 + k, f) for k, f in enumerate(TYPE5_FRAGMENTS)]
    p = write_mcap(tmp_path / "a.mcap", msgs, chunk_size=150)
    s = ingest([p], cfg, tmp_path / "wh")
    assert s.rows["ais_static"] == 1 and s.rows["ais_reports"] == 40 and not s.rejects


def test_process_executor_end_to_end(tmp_path, cfg):
    arch = tmp_path / "arch"
    arch.mkdir()
    for k in range(3):
        write_mcap(arch / f"f{k}.mcap", radar_messages(40, t0_ns=T0_NS + k * 3600 * NS))
    s = run_ingest([arch], cfg, tmp_path / "wh", executor="process")
    assert s.exit_code == 0 and s.files_ok == 3 and s.rows["radar_tracks"] == 120


def test_failed_commit_is_reported_not_raised(tmp_path, cfg, monkeypatch):
    import pipeline.ingest.commit as commit

    p = write_mcap(tmp_path / "x.mcap", radar_messages(5))

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(commit, "replace_source_file", boom)
    s = ingest([p], cfg, tmp_path / "wh")
    assert s.exit_code == 1 and s.failed and "disk full" in s.failed[0][1]
    assert read_table(tmp_path / "wh", "ingest_ledger").num_rows == 0


# -- executors ---------------------------------------------------------------------------


def _square_or_fail(x: int) -> int:
    if x == 3:
        raise ValueError("three is bad")
    return x * x


def _thread_env(_: int) -> str:
    import polars as pl

    env = os.environ.get("OMP_NUM_THREADS", "")
    return f"{pl.thread_pool_size()}/{env}"


@pytest.mark.parametrize("kind", ["serial", "process"])
def test_executor_reports_failures_per_unit(kind):
    ex = make_executor(kind, 2, 1)
    results = list(ex.map_units(_square_or_fail, [1, 2, 3, 4]))
    assert all(isinstance(r, UnitResult) for r in results)
    by_unit = {r.unit: r for r in results}
    assert {u: r.value for u, r in by_unit.items() if r.ok} == {1: 1, 2: 4, 4: 16}
    assert not by_unit[3].ok and "ValueError: three is bad" in by_unit[3].error


@pytest.mark.parametrize("kind", ["serial", "process"])
def test_units_added_while_the_results_are_read_run_in_the_same_map(kind):
    queue = UnitQueue([1, 2, 3])
    results = []
    with make_executor(kind, 2, 1) as ex:
        for r in ex.map_units(_square_or_fail, queue):
            results.append(r)
            if r.ok and r.value < 10:
                queue.add([r.unit + 10])  # a follow-up of each first unit
    assert sorted(r.unit for r in results) == [1, 2, 3, 11, 12]
    assert {r.unit: r.value for r in results if r.ok} == {1: 1, 2: 4, 11: 121, 12: 144}
    assert [r.unit for r in results if not r.ok] == [3]


def test_process_executor_caps_threads():
    results = list(make_executor("process", 2, 3).map_units(_thread_env, [1, 2]))
    assert {r.value for r in results} == {"3/3"}


def test_executor_kinds():
    with pytest.raises(ExecutorError, match="unknown executor"):
        make_executor("spark", 2, 1)
    try:
        import ray  # noqa: F401
    except ImportError:
        with pytest.raises(ExecutorError, match="surveil-pipeline\\[ray\\]"):
            make_executor("ray", 2, 1)
    assert list(make_executor("process", 2, 1).map_units(_square_or_fail, [])) == []


def _niceness() -> int:
    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())


def _can_renice() -> bool:
    def probe() -> bool:
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), min(19, _niceness() + 1))
        except OSError:
            return False
        return True

    with ThreadPoolExecutor(1) as pool:
        return pool.submit(probe).result()


@pytest.mark.skipif(sys.platform != "linux", reason="per-thread niceness is Linux's")
def test_helper_threads_yield_the_cores_to_the_fetch_thread(tmp_path, cfg, monkeypatch):
    """The Parquet writer, the file hasher and the second JSON parser run niced; the
    calling thread (and so the chunk fetch thread it starts) keeps its priority."""
    if not _can_renice():
        pytest.skip("this system refuses setpriority (lower_thread_priority does nothing)")
    base, seen = _niceness(), {}
    write = pipeline.warehouse.staged._write_group
    fingerprint = pipeline.ingest.worker.file_fingerprint

    def noted_write(f, group):
        seen["writer"] = _niceness()
        return write(f, group)

    def noted_fingerprint(path):
        seen["hasher"] = _niceness()
        return fingerprint(path)

    monkeypatch.setattr(pipeline.warehouse.staged, "_write_group", noted_write)
    monkeypatch.setattr(pipeline.ingest.worker, "file_fingerprint", noted_fingerprint)
    src = write_mcap(tmp_path / "a.mcap", radar_messages(50))
    assert ingest([src], cfg, tmp_path / "wh").exit_code == 0
    assert seen == {"writer": min(19, base + WRITER_NICE), "hasher": min(19, base + HASHER_NICE)}
    with json_columns.parser_pool() as pool:
        parser = pool.submit(_niceness).result()
    assert parser == min(19, base + SECOND_PARSER_NICE)
    assert _niceness() == base
