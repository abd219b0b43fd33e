"""Every MCAP writer entry point with extreme times: year 1, year 9999, negative, > 2^64 ns.

The io writers refuse them with a clear :class:`LogTimeError` before writing anything; the
converters (``surveil import``) divert the piece to ``/import/rejects`` and ingest turns it
into a ``rejects`` row with its reason: rejected per message, never a traceback."""

from __future__ import annotations

import json
import sys
from datetime import date
from pathlib import Path

import polars as pl
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "decode"))
from nmea_builders import sentence, tag_block

from jobs.common import UsageError
from pipeline.convert.asterix import wrap_asterix_file
from pipeline.convert.importer import run_import
from pipeline.convert.legacy import import_file
from pipeline.convert.output import REJECTS_TOPIC, Message, write_converted
from pipeline.families import load_config
from pipeline.ingest.driver import run_ingest
from pipeline.io.mcap_read import read_mcap_batches
from pipeline.io.mcap_write import ChannelSpec, LogTimeError, write_mcap_file, write_messages
from pipeline.units import NS, TIME_MAX_NS
from pipeline.warehouse.delta import read_table

YEAR_1_NS = -62_135_596_800 * NS  # 0001-01-01T00:00:00Z
YEAR_9999_NS = 253_370_764_800 * NS  # 9999-01-01T00:00:00Z
EXTREME = {
    "year_1": YEAR_1_NS,
    "year_9999": YEAR_9999_NS,
    "negative": -1,
    "int64_max_plus_1": TIME_MAX_NS + 1,
    "beyond_uint64": 2**64 + 5,
}
GOOD_NS = 1_767_225_600 * NS  # 2026-01-01


def _topics(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list[tuple[int, bytes]]] = {}
    for b in read_mcap_batches(path):
        out.setdefault(b.topic, []).extend(zip(b.log_time_ns.tolist(), b.payloads, strict=True))
    return out


def _ingest_rejects(tmp_path: Path, mcap: Path) -> list[dict]:
    summary = run_ingest([mcap], load_config(), tmp_path / "wh", executor="serial")
    rejects = read_table(tmp_path / "wh", "rejects").to_pylist()
    assert summary.exit_code == (1 if rejects else 0), summary.render()  # issue 18
    return rejects


# -- io writers: refuse, nothing written ---------------------------------------------------


@pytest.mark.parametrize("name", list(EXTREME))
def test_write_mcap_file_refuses_with_a_clear_error(tmp_path, name):
    times = pl.Series("log_time_ns", [GOOD_NS, EXTREME[name]], dtype=pl.Int128)
    df = pl.DataFrame({"log_time_ns": times, "channel": [0, 0], "payload": [b"{}", b"{}"]})
    out = tmp_path / "sim.mcap"
    with pytest.raises(LogTimeError, match=r"message 1: log time .* outside the representable"):
        write_mcap_file(out, [("/x", "json", None)], {}, {}, df)
    assert list(tmp_path.iterdir()) == []  # no file, no temporary left behind


@pytest.mark.parametrize("name", list(EXTREME))
def test_write_messages_refuses_with_a_clear_error(tmp_path, name):
    with pytest.raises(LogTimeError, match="outside the representable range"):
        write_messages(tmp_path / "m.mcap", [ChannelSpec("/x", "json")], [0, 0],
                       [GOOD_NS, EXTREME[name]], [b"a", b"b"])  # fmt: skip
    assert list(tmp_path.iterdir()) == []


def test_write_messages_accepts_the_range_ends(tmp_path):
    counts = write_messages(tmp_path / "m.mcap", [ChannelSpec("/x", "json")], [0, 0],
                            [0, TIME_MAX_NS], [b"a", b"b"])  # fmt: skip
    assert counts == {"/x": 2}
    assert _topics(tmp_path / "m.mcap")["/x"] == [(0, b"a"), (TIME_MAX_NS, b"b")]


# -- converters: divert per message, ingest records the reason -----------------------------


@pytest.mark.parametrize("name", list(EXTREME))
def test_write_converted_diverts_to_rejects(tmp_path, name):
    msgs = [Message("/x", GOOD_NS, b"a"), Message("/x", EXTREME[name], b"bad"),
            Message("/x", GOOD_NS + 1, b"c")]  # fmt: skip
    out = tmp_path / "c.mcap"
    counts = write_converted(out, [ChannelSpec("/x", "nmea0183")], msgs, metadata={})
    assert counts == {"/x": 2, REJECTS_TOPIC: 1}
    topics = _topics(out)
    (t, payload), = topics[REJECTS_TOPIC]  # fmt: skip
    doc = json.loads(payload)
    assert t == GOOD_NS and doc["topic"] == "/x" and doc["reason_code"] == "out_of_range"
    assert str(EXTREME[name]) in doc["reason"]


def test_nmea_text_leading_timestamps_out_of_range(tmp_path):
    hdt = sentence("HEHDT,274.07,T").decode()
    lines = [f"2026-01-01T00:00:00Z {hdt}", f"0001-01-01T00:00:00Z {hdt}",
             f"9999-12-31T23:59:59Z {hdt}", f"9999999999.5 {hdt}", f"2026-01-01T00:00:02Z {hdt}"]
    src = tmp_path / "in" / "lead.log"
    src.parent.mkdir()
    src.write_text("\n".join(lines) + "\n")
    res = import_file(src, tmp_path / "out")
    assert res.messages == {"/nav/nmea": 2, REJECTS_TOPIC: 3}
    rej = _ingest_rejects(tmp_path, Path(res.output))
    assert [r["reason_code"] for r in rej] == ["out_of_range"] * 3
    assert {r["stage"] for r in rej} == {"import"} and {r["topic"] for r in rej} == {"/nav/nmea"}
    assert sorted(r["raw"] for r in rej) == sorted(ln.split(" ")[1].encode() for ln in lines[1:4])
    assert "'0001-01-01T00:00:00Z'" in " ".join(r["reason"] for r in rej)


def test_chart_plotter_stream_with_zda_two_digit_year_and_bad_tag_times(tmp_path):
    """AIS + navigation interleaved, times from the sentences; a ZDA with a two-digit year,
    one with year 9999 and a tag block c: beyond 2262 are rejected per sentence."""
    ais = b"!AIVDM,1,1,,A,13RlIW?04F1beOVEFLB9bRvH0L0L,0*6C"
    rmc = sentence("GPRMC,120000,A,4807.038,N,01131.000,E,5.0,84.4,010626,,")
    rmc2 = sentence("GPRMC,120004,A,4807.038,N,01131.000,E,5.0,84.4,010626,,")
    zda24 = sentence("GPZDA,120001.00,01,06,24,00,00")
    zda9999 = sentence("GPZDA,120002.00,01,06,9999,00,00")
    tag = tag_block("c:99999999999999").encode() + sentence("HEHDT,274.07,T")
    src = tmp_path / "in" / "wifi.log"
    src.parent.mkdir()
    src.write_bytes(b"\r\n".join([rmc, ais, zda24, ais, zda9999, tag, rmc2]) + b"\r\n")
    res = import_file(src, tmp_path / "out")
    assert res.log_time_source["/nav/nmea"] == "nmea:RMC,ZDA"
    times = [t for t, _ in _topics(Path(res.output))["/nav/nmea"]]
    t0 = 1_780_315_200 * NS  # 2026-06-01T12:00:00Z
    assert times[0] == t0 and times[-1] == t0 + 4 * NS and all(t0 <= t <= t0 + 4 * NS
                                                               for t in times)  # fmt: skip
    rej = _ingest_rejects(tmp_path, Path(res.output))
    got = sorted((r["reason_code"], r["raw"]) for r in rej)
    assert got == sorted([("out_of_range", zda24), ("out_of_range", zda9999),
                          ("out_of_range", tag)])  # fmt: skip
    assert any("ZDA year 24" in r["reason"] for r in rej)


@pytest.mark.parametrize(
    "cell", ["0001-01-01 00:00:00", "9999-12-31 23:59:59", "99999999999", "1e30"]
)
def test_ais_csv_row_times_out_of_range(tmp_path, cell):
    src = tmp_path / "in" / "t.csv"
    src.parent.mkdir()
    src.write_text("MMSI,Timestamp,Latitude,Longitude,SOG,COG\n"
                   "244660000,2026-01-01 00:00:00,52.1,4.2,10.0,90.0\n"
                   f"244660000,{cell},52.1,4.2,10.0,90.0\n"
                   "244660000,2026-01-01 00:00:02,52.1,4.2,10.0,90.0\n")  # fmt: skip
    res = import_file(src, tmp_path / "out")
    rej = _ingest_rejects(tmp_path, Path(res.output))
    assert len(rej) == 1 and cell in rej[0]["raw"].decode()
    assert rej[0]["reason_code"] in ("out_of_range", "undecodable")  # 1e30: not a time
    assert read_table(tmp_path / "wh", "ais_reports").num_rows == 2


@pytest.mark.parametrize("day", [date(1, 1, 1), date(9999, 12, 31)])
def test_raw_asterix_with_an_extreme_day(tmp_path, day):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "decode"))
    from test_asterix import block, cat010_record

    pytest.importorskip("asterix")
    src = tmp_path / "x.ast"
    src.write_bytes(block(10, cat010_record(tod=3600.0, xy=(1, 1))))
    out = wrap_asterix_file(src, tmp_path / "out", day=day)
    topics = _topics(out)
    assert list(topics) == [REJECTS_TOPIC]
    doc = json.loads(topics[REJECTS_TOPIC][0][1])
    assert doc["topic"] == "/asterix/raw" and doc["reason_code"] == "out_of_range"


@pytest.mark.parametrize("ticks", [2**64 - 1, 2**63])
def test_pcapng_ticks_beyond_int64(tmp_path, ticks):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "decode"))
    from test_asterix import _udp_frame, block, cat010_record, write_pcapng

    a = block(10, cat010_record(xy=(1, 1)))
    path = write_pcapng(tmp_path / "cap.pcapng", [(GOOD_NS, _udp_frame(a)),
                                                  (ticks, _udp_frame(a))])  # fmt: skip
    out = wrap_asterix_file(path, tmp_path / "out")
    topics = _topics(out)
    flow = "/asterix/10.0.0.1:4000/239.1.2.3:8600"
    assert len(topics[REJECTS_TOPIC]) == 1 and len(topics[flow]) == 1


@pytest.mark.parametrize("base", [YEAR_9999_NS, -1, 2**64 + 5])
def test_import_base_time_out_of_range_is_a_usage_error(tmp_path, base):
    src = tmp_path / "in.log"
    src.write_bytes(sentence("HEHDT,274.07,T") + b"\n")
    with pytest.raises(UsageError, match="outside 1970-01-01"):
        run_import([src], tmp_path / "out", base_time_ns=base)
    with pytest.raises(ValueError, match="outside 1970-01-01"):
        import_file(src, tmp_path / "out", base_time_ns=base)
