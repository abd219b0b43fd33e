"""ASTERIX decoding (CAT010 first) and the raw/pcap importer.

CAT010 blocks are built by hand by a tiny encoder below that follows EUROCONTROL
ASTERIX Category 010 ed 1.1 (UAP and item layouts), independently of the decoder
under test; round trips compare every column with the encoded value within its LSB.
"""

from __future__ import annotations

import base64
import json
import math
import struct
import sys
from datetime import UTC, date, datetime
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from pipeline.config import ValidationConfig
from pipeline.convert.asterix import wrap_asterix_file
from pipeline.decode.asterix import (
    DAY_NS,
    AsterixChannelDecoder,
    decode_asterix,
    split_blocks,
    tod_to_time_ns,
)
from pipeline.decode.registry import FileDecoder, decoder_kind
from pipeline.families import load_config
from pipeline.io.mcap_read import ChannelBatch, read_mcap_batches
from pipeline.units import NS

T0 = int(datetime(2026, 3, 1, 10, 0, tzinfo=UTC).timestamp()) * NS  # 10:00 UTC
REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "asterix"

# -- a tiny CAT010 ed 1.1 encoder -------------------------------------------------------

ICAO6 = {c: i + 1 for i, c in enumerate("ABCDEFGHIJKLMNOPQRSTUVWXYZ")} | {" ": 32} | {
    str(d): 48 + d for d in range(10)
}


def fspec(frns: list[int]) -> bytes:
    """Field specification: bit for FRN k at octet (k-1)//7, FX on all but the last."""
    n = (max(frns) + 6) // 7
    octets = [0] * n
    for k in frns:
        octets[(k - 1) // 7] |= 0x80 >> ((k - 1) % 7)
    for i in range(n - 1):
        octets[i] |= 1
    return bytes(octets)


def callsign6(s: str) -> bytes:
    bits = 0
    for c in s.ljust(8)[:8]:
        bits = (bits << 6) | ICAO6[c]
    return bits.to_bytes(6, "big")


def cat010_record(
    *, sac=1, sic=2, msg_type=1, typ=3, tod=36000.5, rho=None, theta=None, xy=None,
    lat_lon=None, v=None, track=None, address=None, callsign=None, sigma=None,
) -> bytes:  # fmt: skip
    """One CAT010 record (items in FRN order); values in SI/deg, rounded to the LSB."""
    items: dict[int, bytes] = {1: bytes([sac, sic]), 2: bytes([msg_type]),
                               3: bytes([(typ << 5) & 0xE0])}  # fmt: skip
    if tod is not None:
        items[4] = round(tod * 128).to_bytes(3, "big")
    if lat_lon is not None:
        k = 2**31 / 180.0
        items[5] = struct.pack(">ii", round(lat_lon[0] * k), round(lat_lon[1] * k))
    if rho is not None:
        items[6] = struct.pack(">HH", round(rho), round(theta * 65536 / 360.0) % 65536)
    if xy is not None:
        items[7] = struct.pack(">hh", round(xy[0]), round(xy[1]))
    if v is not None:
        items[9] = struct.pack(">hh", round(v[0] * 4), round(v[1] * 4))
    if track is not None:
        items[10] = struct.pack(">H", track & 0x0FFF)
    if address is not None:
        items[13] = address.to_bytes(3, "big")
    if callsign is not None:
        items[14] = b"\x00" + callsign6(callsign)
    if sigma is not None:
        items[22] = struct.pack(">BBh", round(sigma[0] * 4), round(sigma[1] * 4), 0)
    return fspec(sorted(items)) + b"".join(items[k] for k in sorted(items))


def block(cat: int, *records: bytes) -> bytes:
    body = b"".join(records)
    return bytes([cat]) + (len(body) + 3).to_bytes(2, "big") + body


def write_asterix_mcap(path: Path, messages: list[tuple[str, int, bytes]],
                       metadata: dict[str, dict[str, str]] | None = None,
                       chunk_size: int = 1024) -> Path:  # fmt: skip
    """An MCAP file with one ``asterix`` channel (no schema) per topic."""
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        w.start(profile="", library="surveil-tests")
        ids: dict[str, int] = {}
        for topic, t, payload in messages:
            if topic not in ids:
                ids[topic] = w.register_channel(topic, "asterix", 0,
                                                metadata=(metadata or {}).get(topic, {}))
            w.add_message(ids[topic], t, payload, t)
        w.finish()
    return path


def decode(payloads, times, metadata=None):
    return decode_asterix(payloads, np.asarray(times, np.int64), source_file="f.mcap",
                          topic="/asterix/smr", metadata=metadata)  # fmt: skip


# -- CAT010 -----------------------------------------------------------------------------


def test_cat010_round_trip_every_item():
    rng = np.random.default_rng(10)
    n = 40
    tod = np.round(rng.uniform(35_000, 37_000, n) * 128) / 128
    rho = rng.integers(50, 4000, n)
    theta = rng.integers(0, 65536, n) * 360.0 / 65536
    x = rng.integers(-3000, 3000, n)
    y = rng.integers(-3000, 3000, n)
    lat = 50.0 + rng.integers(0, 10**6, n) * 180.0 / 2**31
    lon = 30.0 + rng.integers(0, 10**6, n) * 180.0 / 2**31
    vx = rng.integers(-80, 80, n) / 4
    vy = rng.integers(-80, 80, n) / 4
    sx = rng.integers(1, 60, n) / 4
    sy = rng.integers(1, 60, n) / 4
    recs = [
        cat010_record(sac=7, sic=9 + (i % 2), typ=3 if i % 2 else 1, tod=tod[i], rho=rho[i],
                      theta=theta[i], xy=(x[i], y[i]), lat_lon=(lat[i], lon[i]),
                      v=(vx[i], vy[i]), track=100 + i, address=0xABC000 + i,
                      callsign=f"SAS{i:03d}", sigma=(sx[i], sy[i]))
        for i in range(n)
    ]  # fmt: skip
    # 4 records per block, one block per message
    payloads = [block(10, *recs[i : i + 4]) for i in range(0, n, 4)]
    out = decode(payloads, [T0 + k * NS for k in range(len(payloads))])
    assert out.rejects.num_rows == 0
    rows = sorted(out.obs.to_pylist(), key=lambda r: r["track_number"])
    assert len(rows) == n
    day = T0 - T0 % DAY_NS
    for i, r in enumerate(rows):
        assert r["asterix_category"] == 10
        assert (r["sac"], r["sic"]) == (7, 9 + (i % 2))
        assert r["sensor_id"] == f"7/{9 + (i % 2)}"
        assert r["sensor_kind"] == ("smr" if i % 2 else "mlat")
        assert r["message_type"] == "target report"
        assert r["time_ns"] == day + round(tod[i] * NS)
        assert r["range_m"] == rho[i]
        assert r["azimuth_rad"] == pytest.approx(np.deg2rad(theta[i]), abs=1e-12)
        assert (r["x_m"], r["y_m"]) == (x[i], y[i])
        assert r["lat_deg"] == pytest.approx(lat[i], abs=180 / 2**32)  # half an LSB
        assert r["lon_deg"] == pytest.approx(lon[i], abs=180 / 2**32)
        assert (r["vx_mps"], r["vy_mps"]) == (vx[i], vy[i])
        assert (r["sigma_x_m"], r["sigma_y_m"]) == (sx[i], sy[i])
        assert r["target_address"] == 0xABC000 + i
        assert r["callsign"] == f"SAS{i:03d}"
        assert r["topic"] == "/asterix/smr" and r["source_file"] == "f.mcap"


def test_cat010_metadata_overrides_sensor_and_kind():
    p = [block(10, cat010_record(typ=1, xy=(10, 20)))]
    out = decode(p, [T0], metadata={"sensor_id": "mlat_north", "sensor_kind": "mlat"})
    (r,) = out.obs.to_pylist()
    assert (r["sensor_id"], r["sensor_kind"]) == ("mlat_north", "mlat")


@pytest.mark.parametrize(
    ("msg_type", "name"),
    [(2, "start of update cycle"), (3, "periodic status"), (4, "event-triggered status")],
)
def test_cat010_status_messages_go_to_asterix_service(msg_type, name):
    status = cat010_record(msg_type=msg_type, tod=36000.0)  # no position: not a target
    lost = cat010_record(msg_type=1, tod=36001.0)  # target report without any position
    report = cat010_record(msg_type=1, tod=36002.0, xy=(5, 6))
    out = decode([block(10, status, lost, report)], [T0])
    (r,) = out.service.to_pylist()
    assert (r["message_type"], r["asterix_category"], r["sac"], r["sic"]) == (name, 10, 1, 2)
    assert r["time_ns"] == T0 - T0 % DAY_NS + 36_000 * NS
    (o,) = out.obs.to_pylist()
    assert o["message_type"] == "target report" and (o["x_m"], o["y_m"]) == (5.0, 6.0)
    assert out.rejects["reason_code"].to_pylist() == ["no_position"]
    assert out.rejects["raw"][0].as_py() == block(10, status, lost, report)


@pytest.mark.parametrize(
    ("tod", "log_offset_s", "day_shift"),
    [(86_399.5, 86_400.2, -1), (0.25, -0.4, 1), (36_000.0, 36_000.9, 0), (86_399.0, 0.3, -1)],
)
def test_time_of_day_midnight_rollover(tod, log_offset_s, day_shift):
    midnight = T0 - T0 % DAY_NS
    log_t = midnight + round(log_offset_s * NS)
    t = tod_to_time_ns(np.array([tod]), np.array([log_t]))[0]
    log_day = log_t - log_t % DAY_NS
    assert t == log_day + day_shift * DAY_NS + round(tod * NS)
    assert abs(t - log_t) < DAY_NS // 2


def test_time_of_day_absent_takes_log_time():
    log_t = np.array([T0 + 17, T0 + 18])
    assert tod_to_time_ns(np.array([np.nan, np.nan]), log_t).tolist() == log_t.tolist()
    out = decode([block(10, cat010_record(tod=None, xy=(1, 2)))], [T0 + 17])
    assert out.obs["time_ns"].to_pylist() == [T0 + 17]


def test_several_blocks_in_one_payload_and_framing_damage():
    a = block(10, cat010_record(xy=(1, 1), track=1))
    b = block(10, cat010_record(xy=(2, 2), track=2))
    assert split_blocks(a + b) == ([a, b], b"")
    cut = b[:-3]  # LEN runs past the end of the payload
    out = decode([a + b, a + cut, b"\x0a\x00", b"\x0a\x00\x02zz"], [T0, T0 + 1, T0 + 2, T0 + 3])
    assert sorted(out.obs["track_number"].to_pylist()) == [1, 1, 2]
    rej = out.rejects.to_pylist()
    assert [r["reason_code"] for r in rej] == ["undecodable"] * 3
    assert [r["raw"] for r in rej] == [cut, b"\x0a\x00", b"\x0a\x00\x02zz"]
    assert "LEN" in rej[0]["reason"]


def test_records_not_filling_the_block_are_undecodable():
    rec = cat010_record(xy=(5, 5))
    padded = block(10, rec + b"\x00\x00\x00")  # junk after the last record inside LEN
    bad_fspec = block(10, b"\xff\xff\xff\xff\xff")  # FSPEC announcing items that are absent
    out = decode([padded, bad_fspec], [T0, T0 + 1])
    assert out.obs.num_rows == 0
    assert out.rejects["reason_code"].to_pylist() == ["undecodable", "undecodable"]
    assert out.rejects["raw"].to_pylist() == [padded, bad_fspec]


def test_implausible_record_rejects_its_block():
    good = cat010_record(xy=(1, 1))
    bad_lat = cat010_record(lat_lon=(95.0, 10.0))
    bad_tod = cat010_record(tod=90_000.0, xy=(1, 1))  # 24-bit ToD can exceed one day
    out = decode([block(10, good, bad_lat), block(10, bad_tod)], [T0, T0 + 1])
    assert out.obs.num_rows == 0
    assert out.rejects["reason_code"].to_pylist() == ["out_of_range", "out_of_range"]
    assert "record 2" in out.rejects["reason"][0].as_py()


def test_unsupported_category_is_counted_not_rejected(tmp_path):
    cat001 = bytes([1, 0, 6, 0x80, 1, 2])
    msgs = []
    for k in range(300):  # many chunks (1 KiB chunk size)
        msgs.append(("/a", T0 + k * NS, block(10, cat010_record(xy=(k, k)))))
        msgs.append(("/a", T0 + k * NS + 1, cat001))
    path = write_asterix_mcap(tmp_path / "u.mcap", msgs)
    dec = FileDecoder(source_file=str(path), validation=ValidationConfig())
    scan = read_mcap_batches(path)
    for b in scan:
        dec.feed(b)
    out = dec.finish()
    assert scan.status.chunks_read > 10
    assert out["airfield_obs"].num_rows == 300 and out["rejects"].num_rows == 0
    assert dec.not_stored == {"asterix_cat001": 300}


def test_channel_decoder_accumulates_across_batches():
    dec = AsterixChannelDecoder("f", "/t")
    cat004 = bytes([4, 0, 6, 0x80, 1, 2])
    for k in range(3):
        batch = ChannelBatch(1, "/t", "asterix", "", "", b"", np.array([T0 + k, T0 + k]),
                             [cat004, cat004])  # fmt: skip
        assert dec.feed(batch)["rejects"].num_rows == 0
    assert dec.finish() == {} and dec.not_stored == {"asterix_cat004": 6}


def _service_record(frns: dict[int, bytes]) -> bytes:
    return fspec(sorted(frns)) + b"".join(frns[k] for k in sorted(frns))


@pytest.mark.parametrize(
    ("cat", "frns", "want"),
    [
        # CAT002 north marker: I010, I000 = 1, I030 ToD, I041 antenna period 4 s
        (2, {1: b"\x01\x02", 2: b"\x01", 4: round(3600.5 * 128).to_bytes(3, "big"),
             5: (4 * 128).to_bytes(2, "big")},
         {"message_type": "north marker", "antenna_period_s": 4.0}),
        # CAT019 MLAT periodic status: I010, I000 = 2, I140 ToD, I550 status
        (19, {1: b"\x01\x02", 2: b"\x02", 3: round(3600.5 * 128).to_bytes(3, "big"),
              4: b"\x00"}, {"message_type": "periodic status"}),
        # CAT063 sensor status: I010, I015 service id 7, I030 ToD, I050 sensor SAC/SIC
        (63, {1: b"\x01\x02", 2: b"\x07", 3: round(3600.5 * 128).to_bytes(3, "big"),
              4: b"\x03\x04"}, {"service_id": 7}),
        # CAT247 version number exchange: I010, I015, I140 ToD, I550 (1 x CAT 48 ed 1.21)
        (247, {1: b"\x01\x02", 2: b"\x01", 3: round(3600.5 * 128).to_bytes(3, "big"),
               4: b"\x01\x30\x01\x15"}, {"service_id": 1}),
    ],
)  # fmt: skip
def test_service_categories_go_to_asterix_service(cat, frns, want):
    pytest.importorskip("asterix")
    out = decode([block(cat, _service_record(frns))], [T0])
    assert out.rejects.num_rows == 0 and out.obs.num_rows == 0
    (r,) = out.service.to_pylist()
    assert (r["asterix_category"], r["sac"], r["sic"]) == (cat, 1, 2)
    assert r["time_ns"] == T0 - T0 % DAY_NS + round(3600.5 * NS)
    for k, v in want.items():
        assert r[k] == v, k


def test_without_the_asterix_extra_one_reject_per_channel_and_exit_1(tmp_path, monkeypatch):
    from pipeline.ingest.driver import run_ingest
    from pipeline.warehouse.delta import read_table

    path = write_asterix_mcap(tmp_path / "a.mcap", [
        ("/a", T0 + k * NS, block(10, cat010_record(xy=(k, k)))) for k in range(5)])  # fmt: skip
    monkeypatch.setitem(sys.modules, "asterix", None)  # import asterix -> ImportError
    summary = run_ingest([path], load_config(), tmp_path / "wh", executor="serial")
    assert summary.exit_code == 1 and summary.files_partial == 1
    assert "pip install 'surveil-pipeline[asterix]'" in summary.render()
    (rej,) = read_table(tmp_path / "wh", "rejects").to_pylist()
    assert rej["reason_code"] == "decoder_missing" and rej["reason"].startswith("5 ASTERIX")
    (led,) = read_table(tmp_path / "wh", "ingest_ledger").to_pylist()
    assert led["status"] == "partial" and "decoder not installed" in led["error"]
    monkeypatch.undo()  # installed now: the file is read again
    summary = run_ingest([path], load_config(), tmp_path / "wh", executor="serial")
    assert summary.exit_code == 0 and summary.files_skipped == 0
    assert read_table(tmp_path / "wh", "airfield_obs").num_rows == 5
    assert read_table(tmp_path / "wh", "rejects").num_rows == 0


def test_registry_routes_asterix_channels():
    assert decoder_kind("asterix", "", "") == "asterix"
    assert decoder_kind("asterix", "", "asterix") == "asterix"
    assert decoder_kind("asterix", "jsonschema", "other") is None


def test_ingest_asterix_mcap_into_delta(tmp_path):
    from pipeline.ingest.driver import run_ingest
    from pipeline.warehouse.delta import read_table

    msgs = [("/smr", T0 + k * NS, block(10, cat010_record(tod=36_000 + k, xy=(k, -k),
                                                          track=k)))
            for k in range(50)]  # fmt: skip
    msgs.append(("/smr", T0 + 60 * NS, b"\x0a\xff\xff"))
    path = write_asterix_mcap(tmp_path / "smr.mcap", msgs,
                              metadata={"/smr": {"sensor_id": "smr1"}})  # fmt: skip
    summary = run_ingest([path], load_config(), tmp_path / "wh", executor="serial")
    assert summary.rows["airfield_obs"] == 50
    assert summary.rejects == {"undecodable": 1}
    obs = read_table(tmp_path / "wh", "airfield_obs")
    assert sorted(obs["track_number"].to_pylist()) == list(range(50))
    assert set(obs["sensor_id"].to_pylist()) == {"smr1"}


# -- CAT048 RE field (definition patched at first use) ----------------------------------


def test_cat048_with_reserved_expansion_field_decodes():
    path = REAL / "jasterix_single_records" / "cat048ed1.23.bin"
    if not path.exists():
        pytest.skip(f"real sample absent: {path}")
    out = decode([path.read_bytes()], [T0])
    (r,) = out.obs.to_pylist()  # jASTERIX test_cat048_1.23: one record
    assert (r["sac"], r["sic"], r["track_number"]) == (0, 1, 919)
    assert r["callsign"] == "RYR5XW" and r["target_address"] == 11226301
    assert r["range_m"] == pytest.approx(255.99609375 * 1852)


# -- importer ---------------------------------------------------------------------------


def _udp_frame(payload: bytes, src=(10, 0, 0, 1), dst=(239, 1, 2, 3), sport=4000, dport=8600,
               proto=17) -> bytes:  # fmt: skip
    udp = struct.pack(">HHHH", sport, dport, 8 + len(payload), 0) + payload
    ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), 0, 0x4000, 64, proto, 0,
                     bytes(src), bytes(dst)) + udp  # fmt: skip
    return b"\x01\x00\x5e\x01\x02\x03" + b"\x02" * 6 + b"\x08\x00" + ip


def write_pcap(path: Path, frames: list[tuple[int, bytes]]) -> Path:
    out = struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1)
    for t_ns, frame in frames:
        out += struct.pack("<IIII", t_ns // NS, (t_ns % NS) // 1000, len(frame), len(frame))
        out += frame
    path.write_bytes(out)
    return path


def write_pcapng(path: Path, frames: list[tuple[int, bytes]]) -> Path:
    def blk(btype: int, body: bytes) -> bytes:
        body += b"\x00" * (-len(body) % 4)
        n = len(body) + 12
        return struct.pack("<II", btype, n) + body + struct.pack("<I", n)

    out = blk(0x0A0D0D0A, struct.pack("<IHHq", 0x1A2B3C4D, 1, 0, -1))
    tsresol = struct.pack("<HHB3x", 9, 1, 9) + struct.pack("<HH", 0, 0)  # ns units
    out += blk(1, struct.pack("<HHI", 1, 0, 65535) + tsresol)
    for t_ns, frame in frames:
        out += blk(6, struct.pack("<IIIII", 0, t_ns >> 32, t_ns & 0xFFFFFFFF, len(frame),
                                  len(frame)) + frame)  # fmt: skip
    path.write_bytes(out)
    return path


def _messages(path: Path) -> list[tuple[str, int, bytes, dict]]:
    with open(path, "rb") as f:
        r = make_reader(f)
        return [(c.topic, m.log_time, m.data, dict(c.metadata)) for _, c, m in r.iter_messages()]


@pytest.mark.parametrize("writer", [write_pcap, write_pcapng])
def test_wrap_capture_splits_blocks_and_keeps_capture_times(tmp_path, writer):
    a = block(10, cat010_record(xy=(1, 1)))
    b = block(34, bytes([0x80, 1, 2]))  # any category: the importer only frames
    t1, t2 = T0 + 123_456_000, T0 + 2 * NS + 789_000
    frames = [
        (t1, _udp_frame(a + b)),
        (t1 + 5, _udp_frame(a, proto=6)),  # TCP: skipped and counted
        (t2, _udp_frame(a, src=(10, 0, 0, 2), sport=4001)),
    ]
    path = writer(tmp_path / "cap.bin", frames)
    out = wrap_asterix_file(path, tmp_path / "out")
    msgs = _messages(out)
    assert [(m[0], m[1], m[2]) for m in msgs] == [
        ("/asterix/10.0.0.1:4000/239.1.2.3:8600", t1, a),
        ("/asterix/10.0.0.1:4000/239.1.2.3:8600", t1, b),
        ("/asterix/10.0.0.2:4001/239.1.2.3:8600", t2, a),
    ]
    assert msgs[0][3]["log_time_source"] == "pcap" and msgs[0][3]["dst_port"] == "8600"
    with open(out, "rb") as f:
        (meta,) = [m.metadata for m in make_reader(f).iter_metadata()]
    assert meta["packets_skipped_not_udp"] == "1"


def test_wrap_raw_derives_times_and_crosses_midnight(tmp_path):
    recs = [(86_399.0, 1), (86_399.875, 2), (0.5, 3), (10.0, 4)]
    data = b"".join(block(10, cat010_record(tod=t, xy=(1, 1), track=k)) for t, k in recs)
    data += b"\x0a\x00\x50\x00"  # a cut-off tail: an /import/rejects message with its offset
    (tmp_path / "x.ast").write_bytes(data)
    out = wrap_asterix_file(tmp_path / "x.ast", tmp_path / "out", day=date(2026, 3, 1))
    assert out == tmp_path / "out" / "x.ast.mcap"
    msgs = _messages(out)
    day = int(datetime(2026, 3, 1, tzinfo=UTC).timestamp()) * NS
    expected = [day + round(86_399.0 * NS), day + round(86_399.875 * NS),
                day + DAY_NS + round(0.5 * NS), day + DAY_NS + 10 * NS]  # fmt: skip
    assert [m[1] for m in msgs] == [*expected, expected[-1]]
    tail = json.loads(msgs[-1][2])
    assert msgs[-1][0] == "/import/rejects" and tail["topic"] == "/asterix/raw"
    assert base64.b64decode(tail["raw_base64"]) == b"\x0a\x00\x50\x00"
    assert f"at octet {len(data) - 4}" in tail["reason"]
    assert msgs[0][3] == {"log_time_source": "asterix_time_of_day", "log_date": "2026-03-01",
                          "log_date_source": "given"}
    payloads = [m[2] for m in msgs[:-1]]
    res = decode_asterix(payloads, np.array([m[1] for m in msgs[:-1]]), source_file="x",
                         topic="/asterix/raw")  # fmt: skip
    assert res.obs["time_ns"].to_pylist() == expected
    assert res.rejects.num_rows == 0


@pytest.mark.parametrize(
    ("content", "match"),
    [(b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n" * 400, "text"),
     (b"\x0a\xff\xff\x00\x01", "do not frame"), (b"", "empty")],
)  # fmt: skip
def test_wrap_rejects_files_that_are_not_asterix(tmp_path, content, match):
    path = tmp_path / "f.raw"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=match):
        wrap_asterix_file(path, tmp_path / "out")
    assert not (tmp_path / "out" / "f.raw.mcap").exists()


@pytest.mark.slow
def test_cat010_decode_rate():
    """Throughput of decode_asterix (asterix_decoder + extraction + table), printed with
    ``-s``; 20,000 records, 1 and 20 records per data block."""
    import time

    recs = [cat010_record(tod=36_000 + i / 128, rho=100 + i % 3000, theta=float(i % 360),
                          xy=(i % 1000, -(i % 900)), v=(1.0, 2.0), track=i % 4000,
                          sigma=(2.5, 3.0)) for i in range(20_000)]  # fmt: skip
    for per in (1, 20):
        payloads = [block(10, *recs[i : i + per]) for i in range(0, len(recs), per)]
        times = T0 + np.arange(len(payloads), dtype=np.int64) * NS
        t = time.perf_counter()
        out = decode(payloads, times)
        dt = time.perf_counter() - t
        assert out.obs.num_rows == len(recs)
        print(f"\nCAT010 {per:2d} record(s)/block: {len(recs) / dt:,.0f} records/s ({dt:.2f} s)")
        assert len(recs) / dt > 2_000


def test_airfield_simulator_encoder_round_trips():
    """The airfield issue's CAT010 encoder (pipeline/decode/asterix_encode.py) decodes here to
    the values it quantised: both sides follow CAT010 ed 1.1."""
    enc = pytest.importorskip("pipeline.decode.asterix_encode")
    n = 6
    t = T0 + np.arange(n, dtype=np.int64) * NS // 2
    common = {"time_ns": t, "track_number": np.arange(n) + 100,
              "sigma_x_m": np.full(n, 2.5), "sigma_y_m": np.full(n, 3.25),
              "cov_xy_m2": np.zeros(n), "last": np.zeros(n, bool)}  # fmt: skip
    smr = enc.Cat010Reports(kind="smr", sac=3, sic=1, range_m=np.linspace(100, 900, n),
                            azimuth_rad=np.linspace(0.1, 6.0, n), speed_mps=np.full(n, 8.0),
                            course_rad=np.full(n, 1.0), **common)  # fmt: skip
    mlat = enc.Cat010Reports(kind="mlat", sac=3, sic=2, x_m=np.linspace(-50, 50, n),
                             y_m=np.linspace(20, 80, n), vx_mps=np.full(n, 1.25),
                             vy_mps=np.full(n, -2.5), target_address=np.arange(n) + 0x4000,
                             callsign=np.array(["SAS1", "DLH22", "CAR7", "V1", "V2", "V3"]),
                             target_type=np.array(["aircraft"] * 3 + ["vehicle"] * 3),
                             **common)  # fmt: skip
    for rep in (smr, mlat):
        keys, blocks = enc.encode_blocks(rep, rep.time_ns)
        out = decode(blocks, keys.astype(np.int64))
        assert out.rejects.num_rows == 0
        rows = out.obs.to_pylist()
        assert [r["time_ns"] for r in rows] == t.tolist()  # whole 1/128 s steps
        assert [r["track_number"] for r in rows] == (np.arange(n) + 100).tolist()
        assert {(r["sigma_x_m"], r["sigma_y_m"]) for r in rows} == {(2.5, 3.25)}
        if rep.kind == "smr":
            assert {r["sensor_kind"] for r in rows} == {"smr"}
            q = enc.quantise_azimuth(rep.azimuth_rad)
            assert [r["azimuth_rad"] for r in rows] == pytest.approx(q, abs=1e-12)
            assert [r["range_m"] for r in rows] == pytest.approx(rep.range_m, abs=0.5)
            speed = [math.hypot(r["vx_mps"], r["vy_mps"]) for r in rows]
            assert speed == pytest.approx([8.0] * n, abs=enc.GS_LSB_MPS)
        else:
            assert {r["sensor_kind"] for r in rows} == {"mlat"}
            assert [r["x_m"] for r in rows] == np.round(rep.x_m).tolist()
            assert {(r["vx_mps"], r["vy_mps"]) for r in rows} == {(1.25, -2.5)}
            assert [r["callsign"] for r in rows] == rep.callsign.tolist()
            assert [r["target_address"] for r in rows] == rep.target_address.tolist()
