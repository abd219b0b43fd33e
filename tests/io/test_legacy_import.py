"""``surveil import``: NMEA text logs and AIS CSV tables -> MCAP with honest log times;
format detection, usage errors, the CLI (pipeline/convert/legacy.py,
pipeline/convert/importer.py, jobs/cli.py)."""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.reader import make_reader

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "decode"))
from nmea_builders import sentence, tag_block

from jobs.cli import cli
from jobs.common import UsageError
from pipeline.convert.importer import run_import
from pipeline.convert.legacy import (
    AIS_TOPIC,
    CSV_TOPIC,
    NAV_TOPIC,
    SYNTHETIC_STEP_NS,
    detect_format,
    import_file,
)
from pipeline.io.mcap_read import read_mcap_batches
from pipeline.units import NS

AIS1 = b"!AIVDM,1,1,,A,13RlIW?04F1beOVEFLB9bRvH0L0L,0*6C"
AIS2 = b"!AIVDM,1,1,,A,33P;Tw0tjBQO22:E7dm66DrB20UP,0*2E"
HDT = sentence("HEHDT,274.07,T")


def rmc(hhmmss: str, ddmmyy: str = "010615") -> bytes:
    return sentence(f"GPRMC,{hhmmss},A,4807.038,N,01131.000,E,5.0,84.4,{ddmmyy},,")


def messages(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    """topic -> [(log_time_ns, payload)] in file order, plus channel metadata."""
    out: dict[str, list[tuple[int, bytes]]] = {}
    for b in read_mcap_batches(path):
        out.setdefault(b.topic, []).extend(zip(b.log_time_ns.tolist(), b.payloads, strict=True))
    return out


def channel_meta(path: Path) -> dict[str, dict[str, str]]:
    return {b.topic: b.metadata for b in read_mcap_batches(path)}


def write(tmp_path: Path, name: str, lines: list[bytes], eol: bytes = b"\n") -> Path:
    p = tmp_path / "in" / name
    p.parent.mkdir(exist_ok=True)
    p.write_bytes(eol.join(lines) + eol)
    return p


def test_rmc_times_interpolated_and_channels_split(tmp_path):
    lines = [b"# Name: test log", b"#", AIS1, rmc("120000"), HDT, AIS2, HDT, rmc("120004"),
             b"", AIS1]  # fmt: skip
    src = write(tmp_path, "ship.log", lines, b"\r\n")
    res = import_file(src, tmp_path / "out")
    assert Path(res.output).name == "ship.log.mcap" and res.skipped == {"comment": 2, "blank": 1}
    msgs = messages(Path(res.output))
    t0 = 1_433_160_000 * NS  # 2015-06-01T12:00:00Z
    assert msgs[NAV_TOPIC] == [(t0, rmc("120000")), (t0 + 1 * NS, HDT), (t0 + 3 * NS, HDT),
                               (t0 + 4 * NS, rmc("120004"))]  # fmt: skip
    # AIS before the first time-bearing line takes its time; after the last, the last's
    assert msgs[AIS_TOPIC] == [(t0, AIS1), (t0 + 2 * NS, AIS2), (t0 + 4 * NS, AIS1)]
    meta = channel_meta(Path(res.output))
    assert meta[NAV_TOPIC]["log_time_source"] == "nmea:RMC"
    assert meta[AIS_TOPIC]["platform_id"] == "ship" and meta[AIS_TOPIC]["source_file"] == "ship.log"
    with open(res.output, "rb") as f:
        (rec,) = [m for m in make_reader(f).iter_metadata() if m.name == "surveil.import"]
    assert rec.metadata["header"] == "# Name: test log\n#" and rec.metadata["lines_total"] == "10"


def test_zda_and_gga_on_the_zda_date_across_midnight(tmp_path):
    gga = sentence("GPGGA,000001.00,4807.038,N,01131.000,E,1,08,0.9,5.4,M,46.9,M,,")
    src = write(tmp_path, "z.log", [sentence("GPZDA,235959.00,31,12,2015,00,00"), HDT, gga])
    msgs = messages(Path(import_file(src, tmp_path / "o").output))[NAV_TOPIC]
    eve = 1_451_606_399 * NS
    assert [t for t, _ in msgs] == [eve, eve + NS, eve + 2 * NS]


def test_tag_block_time_wins_and_lines_without_are_interpolated(tmp_path):
    a = (tag_block("s:rORBCOMM008,c:1418169601") + AIS1.decode()).encode()
    b = (tag_block("s:r1,c:1418169611") + AIS2.decode()).encode()
    bad = b"\\s:x,c:1418160000*00\\" + AIS1  # wrong tag checksum: its c: is not used
    src = write(tmp_path, "t.nmea", [a, bad, rmc("000000", "010199"), b])
    res = import_file(src, tmp_path / "o")
    msgs = messages(Path(res.output))
    assert [t for t, _ in msgs[AIS_TOPIC]] == [1418169601 * NS, 1418169604333333333,
                                               1418169611 * NS]  # fmt: skip
    assert msgs[AIS_TOPIC][0][1] == a  # payload keeps its tag block
    assert [t for t, _ in msgs[NAV_TOPIC]] == [1418169607666666667]
    assert set(res.log_time_source.values()) == {"tag_block:c"}


@pytest.mark.parametrize(
    ("prefix", "want_ns"),
    [
        (b"1418169601.25 ", 1_418_169_601_250_000_000),
        (b"1418169601250;", 1_418_169_601_250_000_000),
        (b"2014-12-10T00:00:01.25Z ", 1_418_169_601_250_000_000),
        (b"[2014-12-10 02:00:01.25+02:00] ", 1_418_169_601_250_000_000),
        (b"2014-12-10T00:00:01.25,", 1_418_169_601_250_000_000),
    ],
)
def test_leading_timestamps(tmp_path, prefix, want_ns):
    src = write(tmp_path, "lead.txt", [prefix + HDT, prefix + AIS1])
    res = import_file(src, tmp_path / "o")
    msgs = messages(Path(res.output))
    assert msgs[NAV_TOPIC] == [(want_ns, HDT)]  # the prefix is not in the payload
    assert msgs[AIS_TOPIC] == [(want_ns, AIS1)]
    assert set(res.log_time_source.values()) == {"leading_timestamp"}


def test_no_time_at_all_synthetic_from_the_base(tmp_path):
    src = write(tmp_path, "gpsd.aivdm", [b"# comment", AIS1, b"# decoded: 237836700", AIS2])
    res = import_file(src, tmp_path / "o", base_time_ns=5 * NS)
    msgs = messages(Path(res.output))[AIS_TOPIC]
    assert msgs == [(5 * NS, AIS1), (5 * NS + SYNTHETIC_STEP_NS, AIS2)]
    meta = channel_meta(Path(res.output))[AIS_TOPIC]
    assert meta["log_time_source"] == "none:synthetic"
    assert meta["synthetic_base_ns"] == str(5 * NS)


def test_time_of_day_without_any_date(tmp_path):
    zda = sentence("GPZDA,235959,,,,00,")
    gll = sentence("GPGLL,6005.071,N,02332.346,E,000001,A,D")
    src = write(tmp_path, "plaka.log", [zda, HDT, gll], b"\r")
    res = import_file(src, tmp_path / "o", base_time_ns=1_437_350_400 * NS)  # 2015-07-20
    times = [t for t, _ in messages(Path(res.output))[NAV_TOPIC]]
    t0 = 1_437_350_400 * NS + 86_399 * NS
    assert times == [t0, t0 + NS, t0 + 2 * NS]  # rolled over to the next day
    meta = channel_meta(Path(res.output))[NAV_TOPIC]
    assert meta["log_time_source"] == "nmea_time_of_day:base_time"
    assert meta["log_date"] == "2015-07-20"


def test_garbage_lines_are_kept_as_messages_for_ingest_to_reject(tmp_path):
    src = write(tmp_path, "g.log", [HDT, b"garbage \x01\x02", b"AIVDM,2,2,1,B,000,2*26"])
    msgs = messages(Path(import_file(src, tmp_path / "o").output))
    assert [p for _, p in msgs[NAV_TOPIC]] == [HDT, b"garbage \x01\x02"]
    assert [p for _, p in msgs[AIS_TOPIC]] == [b"AIVDM,2,2,1,B,000,2*26"]


def test_output_bytes_depend_only_on_the_input(tmp_path):
    src = write(tmp_path, "d.log", [rmc("120000"), AIS1, HDT])
    a = Path(import_file(src, tmp_path / "a").output).read_bytes()
    b = Path(import_file(src, tmp_path / "b").output).read_bytes()
    assert a == b


# -- AIS CSV -----------------------------------------------------------------------------

DMA = """# Timestamp,Type of mobile,MMSI,Latitude,Longitude,Navigational status,ROT,SOG,COG,\
Heading,IMO,Callsign,Name,Ship type,Cargo type,Width,Length,Type of position fixing device,\
Draught,Destination,ETA,Data source type
01/06/2018 00:00:01,Class A,215810000,55.921028,17.320418,Moored,0.0,12.5,255.5,256,\
Unknown,OW2,NAME A,Cargo,,10,90,GPS, ,HAMBURG, ,AIS
01/06/2018 00:00:02,Base Station,2190068,55.0,8.0,Unknown value,,,,,Unknown,,,Undefined,,,,\
Surveyed,,,,AIS
01/06/2018 00:00:03,Class B,219000001,91.0,181.0,Unknown value,,,,,Unknown,,,Undefined,,,,\
Undefined,,,,AIS
"""


def test_dma_csv_rows_become_json_messages_with_sentinels_kept(tmp_path):
    src = tmp_path / "aisdk.csv"
    src.write_text(DMA)
    assert detect_format(src) == "ais_csv"
    res = import_file(src, tmp_path / "o")
    msgs = messages(Path(res.output))[CSV_TOPIC]
    t0 = 1_527_811_200 * NS  # 2018-06-01T00:00:00Z, dd/mm/yyyy
    assert [t for t, _ in msgs] == [t0 + NS, t0 + 2 * NS, t0 + 3 * NS]
    docs = [json.loads(p) for _, p in msgs]
    assert docs[0]["mmsi"] == 215810000 and docs[0]["nav_status"] == 5
    assert docs[0]["shipname"] == "NAME A" and docs[0]["imo"] is None
    assert docs[0]["draught_m"] is None and docs[0]["ais_class"] == "A"
    assert docs[1]["mobile_type"] == "Base Station" and docs[1]["nav_status"] == 15
    assert (docs[2]["lat_deg"], docs[2]["lon_deg"]) == (91.0, 181.0)  # decoder's job
    assert docs[0]["raw"].startswith("01/06/2018 00:00:01,Class A,215810000")
    assert channel_meta(Path(res.output))[CSV_TOPIC]["log_time_source"] == "csv:Timestamp"


# -- dispatch, errors, CLI ---------------------------------------------------------------


def test_detect_format(tmp_path):
    (tmp_path / "a.pcap").write_bytes(b"\xd4\xc3\xb2\xa1" + b"\x00" * 20)
    (tmp_path / "b.bin").write_bytes(bytes([48]) + struct.pack(">H", 6) + b"\x80\x01\x02")
    (tmp_path / "c.txt").write_text("just some notes\nnothing here\n")
    (tmp_path / "d.log").write_bytes(HDT + b"\n")
    (tmp_path / "e.bin").write_bytes(bytes([48]) + struct.pack(">H", 999) + b"\x80")
    kinds = {p.name: detect_format(p) for p in sorted(tmp_path.iterdir())}
    assert kinds == {"a.pcap": "asterix", "b.bin": "asterix", "c.txt": "unknown",
                     "d.log": "nmea_text", "e.bin": "unknown"}  # fmt: skip


def test_asterix_inputs_go_to_the_asterix_wrapper(tmp_path):
    # one CAT048 data block with an empty record: the wrapper accepts or explains
    src = tmp_path / "in" / "cat048.raw"
    src.parent.mkdir()
    src.write_bytes(bytes([48]) + struct.pack(">H", 3))
    summary = run_import([src], tmp_path / "o")
    assert len(summary.imported) + len(summary.failed) == 1
    if summary.imported:
        assert summary.imported[0].format == "asterix:raw"
        assert Path(summary.imported[0].output).name == "cat048.raw.mcap"


def test_usage_errors(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "readme.txt").write_text("hello\n")
    (tmp_path / "x.txt").write_text("hello\n")
    for paths, msg in [
        ([tmp_path / "missing.log"], "does not exist"),
        ([tmp_path / "empty"], "no importable files"),
        ([tmp_path / "notes"], "no importable files"),
        ([tmp_path / "x.txt"], "not an importable file"),
        ([], "no input paths"),
    ]:
        with pytest.raises(UsageError, match=msg):
            run_import(paths, tmp_path / "out")
    a, b = tmp_path / "a", tmp_path / "b"
    for d in (a, b):
        d.mkdir()
        (d / "same.log").write_bytes(HDT + b"\n")
    with pytest.raises(UsageError, match=r"same\.log"):
        run_import([a, b], tmp_path / "out")


def test_directory_import_skips_unknown_files(tmp_path):
    d = tmp_path / "logs"
    d.mkdir()
    (d / "ship.log").write_bytes(HDT + b"\n")
    (d / "notes.txt").write_text("hello\n")
    summary = run_import([d], tmp_path / "out")
    assert [Path(f.output).name for f in summary.imported] == ["ship.log.mcap"]
    assert summary.skipped == [str(d / "notes.txt")] and summary.exit_code == 0


def test_cli_import_then_ingest(tmp_path):
    src = write(tmp_path, "ship.log", [rmc("120000"), HDT, AIS1, b"junk"])
    runner = CliRunner()
    res = runner.invoke(cli, ["import", str(src), "--out", str(tmp_path / "mcap")])
    assert res.exit_code == 0, res.output
    assert "ship.log.mcap" in res.output and "nmea:RMC" in res.output
    wh = tmp_path / "wh"
    res = runner.invoke(cli, ["--warehouse", str(wh), "ingest", str(tmp_path / "mcap"),
                              "--executor", "serial"])  # fmt: skip
    assert res.exit_code == 1, res.output  # the junk line is a rejects row (issue 18)
    for fragment in ("nav_gnss 1", "nav_heading 1", "ais_reports 1", "undecodable 1"):
        assert fragment in res.output
    bad = runner.invoke(cli, ["import", str(tmp_path / "nope"), "--out", str(tmp_path)])
    assert bad.exit_code != 0 and isinstance(bad.exception, UsageError | SystemExit)


def test_cli_usage_error_exit_code_2(tmp_path):
    import subprocess

    exe = Path(sys.executable).parent / "surveil"
    r = subprocess.run([str(exe), "import", str(tmp_path / "nope"), "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 2 and "does not exist" in r.stderr and "Traceback" not in r.stderr
    assert np.isfinite(r.returncode)
