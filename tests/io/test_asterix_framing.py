"""ASTERIX recording formats with per-record framing (pipeline/convert/asterix_framing.py):
generated files of each framing, written here by hand from the layouts that
CroatiaControl's decoder and jASTERIX read (see the module docstring), detected by their
framing, log times from the record headers, damaged files of each kind."""

from __future__ import annotations

import struct
import sys
from datetime import UTC, date, datetime
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "decode"))
from test_asterix import block, cat010_record

from pipeline.convert.asterix import wrap_asterix
from pipeline.convert.asterix_framing import (
    detect_framing,
    fcs16,
    hdlc_fcs,
    oradis_time_unit,
    walk,
)
from pipeline.convert.importer import run_import
from pipeline.convert.legacy import detect_format
from pipeline.convert.output import REJECTS_TOPIC
from pipeline.families import load_config
from pipeline.ingest.driver import run_ingest
from pipeline.io.mcap_read import read_mcap_batches
from pipeline.units import NS
from pipeline.warehouse.delta import read_table

DAY = date(2026, 3, 1)
DAY_NS = int(datetime(2026, 3, 1, tzinfo=UTC).timestamp()) * NS
TODS = [43_200.0, 43_200.5, 43_201.25, 86_399.5, 0.75]  # the last one after midnight


def blocks() -> list[bytes]:
    return [block(10, cat010_record(tod=t, xy=(10 * k, 20), track=k)) for k, t in
            enumerate(TODS)]  # fmt: skip


def gps_file(blks: list[bytes], tods: list[float]) -> bytes:
    out = b"\x00" * 2200  # the GPS file header (not interpreted)
    for b, t in zip(blks, tods, strict=True):
        post = bytes(6) + round(t * 128).to_bytes(3, "big") + b"\x00"
        out += b + post
    return out


def final_file(blks: list[bytes], tods: list[float], *, seq: bool = False) -> bytes:
    out = b""
    for k, (b, t) in enumerate(zip(blks, tods, strict=True)):
        head = (struct.pack(">I", k) if seq else b"") + bytes([1, 2, 60])
        head += round(t * 100).to_bytes(3, "big")
        n = 2 + len(head) + len(b) + 4
        out += n.to_bytes(2, "big") + head + b + b"\xa5" * 4
    return out


def oradis_file(blks: list[bytes], times: list[int]) -> bytes:
    return b"".join((6 + len(b)).to_bytes(2, "big") + t.to_bytes(4, "big") + b
                    for b, t in zip(blks, times, strict=True))  # fmt: skip


def hdlc_file(blks: list[bytes]) -> bytes:
    out = b""
    for b in blks:
        frame = b"\x01\x03" + b
        out += frame + hdlc_fcs(frame)
    return out


def _messages(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list[tuple[int, bytes]]] = {}
    for b in read_mcap_batches(path):
        out.setdefault(b.topic, []).extend(zip(b.log_time_ns.tolist(), b.payloads, strict=True))
    return out


def _expected_times(tods: list[float]) -> list[int]:
    day = DAY_NS
    out, prev = [], None
    for t in tods:
        if prev is not None and t < prev - 43_200:
            day += 86_400 * NS
        prev = t
        out.append(day + round(t * NS))
    return out


def test_fcs_is_crc16_x25():
    assert fcs16(b"123456789") ^ 0xFFFF == 0x906E  # the CRC-16/X.25 check value
    frame = b"\x01\x03" + blocks()[0]
    assert fcs16(frame + hdlc_fcs(frame)) == 0xF0B8  # the good-frame residue


@pytest.mark.parametrize(
    ("framing", "data", "source"),
    [
        ("gps", lambda b: gps_file(b, TODS), "gps_header:time_of_day"),
        ("final", lambda b: final_file(b, TODS), "final_header:time_of_day"),
        ("ioss_seq", lambda b: final_file(b, TODS, seq=True), "ioss_seq_header:time_of_day"),
        ("oradis", lambda b: oradis_file(b, [round(t * 1000) for t in TODS]),
         "oradis_header:ms_of_day"),
    ],
)  # fmt: skip
def test_framed_recordings_use_their_header_times(tmp_path, framing, data, source):
    blks = blocks()
    src = tmp_path / f"rec.{framing}"
    src.write_bytes(data(blks))
    assert detect_framing(src.read_bytes()) == framing and detect_format(src) == "asterix"
    w = wrap_asterix(src, tmp_path / "out", day=DAY)
    assert w.kind == framing and w.log_time_source == {f"/asterix/{framing}": source}
    msgs = _messages(w.output)[f"/asterix/{framing}"]
    assert [p for _, p in msgs] == blks
    assert [t for t, _ in msgs] == _expected_times(TODS)


def test_header_times_win_over_the_records_own(tmp_path):
    """FINAL header times 2 s after the records' I140: the log time is the header's."""
    blks = blocks()
    src = tmp_path / "rec.final"
    src.write_bytes(final_file(blks, [t + 2.0 for t in TODS[:3]] + TODS[3:]))
    w = wrap_asterix(src, tmp_path / "out", day=DAY)
    times = [t for t, _ in _messages(w.output)["/asterix/final"]]
    assert times[:3] == [DAY_NS + round((t + 2.0) * NS) for t in TODS[:3]]


def test_hdlc_frames_take_the_records_time_of_day(tmp_path):
    pytest.importorskip("asterix")
    blks = blocks()
    src = tmp_path / "rec.hdlc"
    src.write_bytes(hdlc_file(blks))
    assert detect_framing(src.read_bytes()) == "hdlc"
    w = wrap_asterix(src, tmp_path / "out", day=DAY)
    msgs = _messages(w.output)["/asterix/hdlc"]
    assert [p for _, p in msgs] == blks and [t for t, _ in msgs] == _expected_times(TODS)


def test_hdlc_skips_a_frame_with_a_bad_fcs_and_resynchronises(tmp_path):
    pytest.importorskip("asterix")
    blks = blocks()
    data = bytearray(hdlc_file(blks))
    bad_at = len(hdlc_file(blks[:2])) + 10  # inside the third frame
    data[bad_at] ^= 0xFF
    src = tmp_path / "bad.hdlc"
    src.write_bytes(bytes(data))
    w = wrap_asterix(src, tmp_path / "out", day=DAY)
    msgs = _messages(w.output)
    assert [p for _, p in msgs["/asterix/hdlc"]] == blks[:2] + blks[3:]
    assert len(msgs[REJECTS_TOPIC]) == 1


@pytest.mark.parametrize(
    ("unit", "values"),
    [("ms_of_day", [round(t * 1000) for t in TODS]),
     ("1/128s_of_day", [round(t * 128) for t in TODS]),
     ("10ms_of_day", [round(t * 100) for t in TODS]),
     ("unix_s", [DAY_NS // NS + round(t) for t in TODS[:3]] * 1 + [0, 0])],
)  # fmt: skip
def test_oradis_time_unit_is_calibrated_against_the_records(unit, values):
    if unit == "unix_s":
        values = [DAY_NS // NS + round(t) for t in TODS[:3]]
        assert oradis_time_unit(values, TODS[:3]) == unit
        assert oradis_time_unit(values, [None] * 3) == unit  # no records: plausible Unix s
        return
    assert oradis_time_unit(values, TODS) == unit


def test_oradis_with_unix_seconds_gives_absolute_log_times(tmp_path):
    blks = blocks()[:3]
    secs = [DAY_NS // NS + 43_200 + k for k in range(3)]
    src = tmp_path / "rec.oradis"
    src.write_bytes(oradis_file(blks, secs))
    w = wrap_asterix(src, tmp_path / "out", day=date(1970, 1, 1))
    assert [t for t, _ in _messages(w.output)["/asterix/oradis"]] == [s * NS for s in secs]


@pytest.mark.parametrize(
    ("framing", "make"),
    [("gps", lambda b: gps_file(b, TODS)), ("final", lambda b: final_file(b, TODS)),
     ("ioss_seq", lambda b: final_file(b, TODS, seq=True)),
     ("oradis", lambda b: oradis_file(b, [round(t * 1000) for t in TODS]))],
)  # fmt: skip
def test_truncated_recordings_keep_their_records_and_reject_the_tail(tmp_path, framing, make):
    blks = blocks()
    data = make(blks)[:-7]  # the last record cut off
    src = tmp_path / f"cut.{framing}"
    src.write_bytes(data)
    assert detect_framing(data) == framing
    records, tail = walk(data, framing)
    assert [r.content for r in records] == blks[:-1] and "past the end" in tail.reason
    summary = run_import([src], tmp_path / "out", base_time_ns=DAY_NS)
    assert summary.exit_code == 1, summary.render()  # partial: the tail is rejected
    (f,) = summary.imported
    assert f.messages == {f"/asterix/{framing}": 4, REJECTS_TOPIC: 1}
    ingest = run_ingest([f.output], load_config(), tmp_path / "wh", executor="serial")
    assert ingest.exit_code == 1  # one rejects row
    (rej,) = read_table(tmp_path / "wh", "rejects").to_pylist()
    assert rej["reason_code"] == "undecodable" and rej["stage"] == "import"
    assert "past the end" in rej["reason"]
    if pytest.importorskip("asterix"):
        obs = read_table(tmp_path / "wh", "airfield_obs")
        assert obs.num_rows == 4


def test_random_binary_and_text_are_not_framings():
    import random

    rng = random.Random(7)
    noise = bytes(rng.randrange(256) for _ in range(5000))
    assert detect_framing(noise) is None
    text = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4*47\r\n" * 100
    assert detect_framing(text) is None


def test_oradis_packets_inside_a_pcap_are_unwrapped(tmp_path):
    from test_asterix import _udp_frame, write_pcap

    blks = blocks()[:2]
    payload = oradis_file(blks, [1, 2])
    t = DAY_NS + 43_200 * NS
    path = write_pcap(tmp_path / "o.pcap", [(t, _udp_frame(payload))])
    w = wrap_asterix(path, tmp_path / "out")
    (msgs,) = _messages(w.output).values()
    assert msgs == [(t, blks[0]), (t, blks[1])]


def test_final_padding_is_not_required_to_be_a5(tmp_path):
    blks = blocks()
    data = final_file(blks, TODS).replace(b"\xa5" * 4, b"\x00" * 4)
    assert detect_framing(data) == "final"
    records, tail = walk(data, "final")
    assert [r.content for r in records] == blks and tail is None


def test_config_editions_reach_the_channel_metadata(tmp_path):
    src = tmp_path / "rec.final"
    src.write_bytes(final_file(blocks(), TODS))
    w = wrap_asterix(src, tmp_path / "out", day=DAY, editions={10: "0.24", 62: "0.17"})
    (b,) = list(read_mcap_batches(w.output))
    assert b.metadata["asterix_editions"] == "010=0.24,062=0.17"


def test_raw_asterix_without_the_decoder_is_refused_with_exit_1(tmp_path, monkeypatch):
    src = tmp_path / "x.ast"
    src.write_bytes(b"".join(blocks()))
    monkeypatch.setitem(sys.modules, "asterix", None)
    summary = run_import([src], tmp_path / "out")
    assert summary.exit_code == 1
    ((_, err),) = summary.failed
    assert "pip install 'surveil-pipeline[asterix]'" in err
    final = tmp_path / "rec.final"  # header times: no decoder needed to import
    final.write_bytes(final_file(blocks(), TODS))
    assert run_import([final], tmp_path / "out2").exit_code == 0
