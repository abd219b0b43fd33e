"""Every time a recording carries (issue 36), each from its format's published description,
written here from the description (no real recording is copied): USCG N-AIS receiver
fields, Gatehouse $PGHP, NMEA 4 tag blocks, interleaved RMC, base station reports, pcap
packet times, MCAP log times, ASTERIX times of day dated by the file name; the AIS
utc_second refinement; synthetic times warned, never overlapping, never batched; the
class of every message on every import path."""

from __future__ import annotations

import struct
import sys
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from pyais.encode import encode_dict

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "decode"))
from nmea_builders import sentence, tag_block

from pipeline.convert.importer import run_import
from pipeline.convert.legacy import file_name_date, import_file
from pipeline.decode.nmea import decode_nmea
from pipeline.families import load_config
from pipeline.ingest.driver import run_ingest
from pipeline.io.mcap_write import ChannelSpec, write_messages
from pipeline.time_sources import refine_by_utc_second
from pipeline.units import NS
from pipeline.warehouse.delta import read_table


def utc(*args: int, frac_ns: int = 0) -> int:
    return int(datetime(*args, tzinfo=UTC).timestamp()) * NS + frac_ns


def ais(seq_id: int | None = None, **fields) -> list[str]:
    """Our own AIS sentences (pyais's encoder), ITU-R M.1371 fields."""
    return encode_dict(fields, talker_id="AI", sentence_type="VDM", radio_channel="A",
                       seq_id=seq_id)


def pos(mmsi: int = 244000001, second: int = 0, **kw) -> str:
    (s,) = ais(type=1, mmsi=mmsi, lat=52.1, lon=4.2, speed=10.0, course=90.0, second=second,
               **kw)
    return s


def pghp(t: datetime, ms: int) -> str:
    """IALA IWRAP "GH AIS message format": $PGHP,<msg type 1>,<date>,<time>,<country MID>,
    <region>,<PSS MMSI>,<online 1>,<checksum of the AIS sentence>*hh."""
    body = (f"PGHP,1,{t.year},{t.month},{t.day},{t.hour},{t.minute},{t.second},{ms},219,,"
            "2190067,1,00")
    return sentence(body).decode()


def write(tmp: Path, name: str, lines: list[str]) -> Path:
    p = tmp / "in" / name
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text("\n".join(lines) + "\n", encoding="latin-1")
    return p


def ingest(tmp: Path, mcaps: list[Path], tables=("ais_reports",)) -> dict[str, pl.DataFrame]:
    s = run_ingest(mcaps, load_config(), tmp / "wh", executor="serial")
    assert not s.failed, s.render()
    out = {n: pl.from_arrow(read_table(tmp / "wh", n)).sort("time_ns") for n in tables}
    out["_summary"] = s  # type: ignore[assignment]
    return out


def imported(tmp: Path, name: str, lines: list[str], **kw) -> tuple[dict, object]:
    res = import_file(write(tmp, name, lines), tmp / "mcap", **kw)
    return ingest(tmp, [Path(res.output)], ("ais_reports", "ais_static",
                                            "ais_other_messages")), res


# -- USCG N-AIS receiver fields ----------------------------------------------------------


@pytest.mark.parametrize(("trailer", "want_ns", "source"), [
    # t: receiver time of day 05:00:56.00, T: arrival 56.13718694 s into the minute,
    # station r003669946, then the UNIX times (2012-01-01 05:01:00 and 05:00:01)
    (",d-109,S2105,t050056.00,T56.13718694,r003669946,1325394060,1325394001",
     utc(2012, 1, 1, 5, 0, 56, frac_ns=137_186_940), "nais:t"),
    # no t: T in the minute of the UNIX time (08.48347459 s before 01:10:09)
    (",x367022,s32171,d-079,T08.48347459,r003669976,1166058609",
     utc(2006, 12, 14, 1, 10, 8, frac_ns=483_474_590), "nais:T"),
    # the UNIX time alone
    (",s28089,d-103,r08TPHI1,1242958962", utc(2009, 5, 22, 2, 22, 42), "nais:epoch"),
    # t just before midnight, logged just after: the day before the UNIX time's
    (",d-090,t235959.90,T59.90000000,r1,1325376002",
     utc(2011, 12, 31, 23, 59, 59, frac_ns=900_000_000), "nais:t"),
])
def test_nais_receiver_fields(tmp_path, trailer, want_ns, source):
    got, res = imported(tmp_path, "nais.log", [pos() + trailer, pos(mmsi=244000002) + trailer])
    r = got["ais_reports"]
    assert r["time_ns"].to_list() == [want_ns, want_ns]
    assert r["time_source"].to_list() == [source, source]
    assert res.log_time_source["/ais/nmea"] == source and not res.warning


def test_nais_fields_without_a_unix_time_give_no_time(tmp_path):
    """A station and T alone cannot be dated: the file has no time (synthetic, warned)."""
    got, res = imported(tmp_path, "n.log", [pos() + ",s36310,d-081,T59.01777335",
                                            pos() + ",b003660465"])
    assert got["ais_reports"]["time_source"].to_list() == ["none:synthetic"] * 2
    assert "--base-time" in res.warning


# -- Gatehouse $PGHP ---------------------------------------------------------------------


def test_pghp_stamps_the_message_after_it(tmp_path):
    t1 = datetime(2014, 4, 10, 13, 30, 29, tzinfo=UTC)
    t2 = datetime(2014, 4, 10, 13, 30, 31, tzinfo=UTC)
    five = ais(seq_id=1, type=5, mmsi=219000606, shipname="FRIGG", callsign="OWNM",
               imo=8222824, ship_type=61)
    assert len(five) == 2
    lines = [pghp(t1, 165), *five, pghp(t2, 470), pos(219000607, second=31),
             pos(219000608, second=31)]  # the last one has no $PGHP of its own
    got, res = imported(tmp_path, "gh.log", lines)
    (static,) = got["ais_static"].iter_rows(named=True)
    assert static["time_ns"] == utc(2014, 4, 10, 13, 30, 29, frac_ns=165_000_000)
    assert static["time_source"] == "pghp"
    r = {x["mmsi"]: x for x in got["ais_reports"].iter_rows(named=True)}
    assert r[219000607]["time_ns"] == utc(2014, 4, 10, 13, 30, 31, frac_ns=470_000_000)
    assert r[219000607]["time_source"] == "pghp"
    assert r[219000608]["time_source"].startswith("interpolated:pghp")
    assert res.log_time_source["/ais/nmea"] == "pghp"


def test_pghp_carried_across_decode_batches():
    t = datetime(2013, 3, 13, 10, 39, 18, tzinfo=UTC)
    lines = [pghp(t, 375), *ais(seq_id=4, type=5, mmsi=220431000, shipname="X")]
    lines = [ln.encode() for ln in lines]
    log = np.array([1, 2, 3], np.int64) * NS
    whole = decode_nmea(lines, log, source_file="f", topic="/ais/nmea", platform_id="p")
    want = whole.tables["ais_static"]["time_ns"].to_pylist()
    assert want == [utc(2013, 3, 13, 10, 39, 18, frac_ns=375_000_000)]
    for k in range(1, len(lines)):  # every split point: the same row
        a = decode_nmea(lines[:k], log[:k], source_file="f", topic="/ais/nmea",
                        platform_id="p", final=False)
        b = decode_nmea(lines[k:], log[k:], source_file="f", topic="/ais/nmea",
                        platform_id="p", carry=a.carry)
        assert b.tables["ais_static"]["time_ns"].to_pylist() == want, k
        assert b.tables["ais_static"]["time_source"].to_pylist() == ["pghp"]


# -- NMEA 4 tag blocks -------------------------------------------------------------------


def test_tag_block_c_seconds_fraction_milliseconds_and_the_first_fragment():
    """IEC 61162-1 tag block c: UNIX time; a multi-sentence message stamped on its first
    fragment only (g: group) takes that time, not the next fragment's log time."""
    one, two = ais(seq_id=6, type=5, mmsi=229000001, shipname="GROUP")
    lines = [
        (tag_block("s:r1,c:1418169601.25") + pos()).encode(),
        (tag_block("c:1418169602500") + pos(244000002)).encode(),
        (tag_block("g:1-2-1604,c:1418169700") + one).encode(),
        (tag_block("g:2-2-1604") + two).encode(),
    ]
    out = decode_nmea(lines, np.array([10, 20, 30, 40], np.int64) * NS, source_file="f",
                      topic="/ais/nmea", platform_id="p")
    r = out.tables["ais_reports"].to_pylist()
    assert [x["time_ns"] for x in r] == [1418169601 * NS + 250_000_000,
                                          1418169602 * NS + 500_000_000]
    assert {x["time_source"] for x in r} == {"tag_block:c"}
    (s,) = out.tables["ais_static"].to_pylist()
    assert (s["time_ns"], s["time_source"]) == (1418169700 * NS, "tag_block:c")


# -- interleaved RMC and the report's own second ------------------------------------------


def test_interpolated_reports_move_to_their_utc_second():
    """Reports between RMC sentences 1 s apart are placed by line number; their own
    utc_second (ITU-R M.1371-5: the second of the fix) then gives the second."""
    t0 = utc(2020, 4, 7, 21, 40, 0)
    lines = [pos(244000001, second=0), pos(244000002, second=0), pos(244000003, second=33)]
    log = np.array([t0 + 250_000_000, t0 + 500_000_000, t0 + 750_000_000], np.int64)
    out = decode_nmea([s.encode() for s in lines], log, source_file="f", topic="/ais/nmea",
                      platform_id="p", fallback_time_source="interpolated:nmea:RMC",
                      refine_gap_s=1.0)
    r = {x["mmsi"]: x for x in out.tables["ais_reports"].to_pylist()}
    assert r[244000001]["time_ns"] == r[244000002]["time_ns"] == t0
    assert r[244000001]["time_source"] == "interpolated:nmea:RMC+utc_second"
    # 33 s: not within the bracket + latency of the interpolated time: kept as it was
    assert r[244000003]["time_ns"] == t0 + 750_000_000
    assert r[244000003]["time_source"] == "interpolated:nmea:RMC"


def test_refinement_needs_a_narrow_bracket():
    t = np.array([utc(2020, 1, 1, 0, 0, 0, frac_ns=400_000_000)], np.int64)
    got, hit = refine_by_utc_second(t, np.array([59]), np.array([True]), gap_s=1.0)
    assert hit.tolist() == [True] and got[0] == utc(2019, 12, 31, 23, 59, 59)  # minute before
    _, hit = refine_by_utc_second(t, np.array([0]), np.array([True]), gap_s=40.0)
    assert hit.tolist() == [False]  # a bracket of 40 s: the minute is ambiguous
    _, hit = refine_by_utc_second(t, np.array([0]), np.array([False]), gap_s=1.0)
    assert hit.tolist() == [False]  # a time of its own is never moved


def test_rmc_interleaved_log_refined_end_to_end(tmp_path):
    rmc = [sentence(f"GPRMC,2140{s:02d}.00,A,5250.5,N,00542.3,E,0.0,,070420,,,A").decode()
           for s in range(3)]
    lines = [rmc[0], pos(244000001, second=0), rmc[1], pos(244000002, second=1), rmc[2]]
    got, _ = imported(tmp_path, "rmc.log", lines)
    r = got["ais_reports"]
    assert r["time_ns"].to_list() == [utc(2020, 4, 7, 21, 40, 0), utc(2020, 4, 7, 21, 40, 1)]
    assert set(r["time_source"]) == {"interpolated:nmea:RMC+utc_second"}


# -- base station reports ------------------------------------------------------------------


def test_base_station_reports_date_a_log_without_any_other_time(tmp_path):
    """Messages 4 carry the base station's UTC date and time (ITU-R M.1371-5 Annex 8):
    a log of bare !AIVDM lines is no longer synthetic."""
    (b1,) = ais(type=4, mmsi=2442000, year=2021, month=11, day=1, hour=1, minute=58,
                second=0, lat=52.0, lon=4.0)
    (b2,) = ais(type=4, mmsi=2442000, year=2021, month=11, day=1, hour=1, minute=58,
                second=10, lat=52.0, lon=4.0)
    got, res = imported(tmp_path, "bare.log", [b1, pos(second=3), pos(second=6), b2])
    assert res.log_time_source["/ais/nmea"] == "ais:base_station" and not res.warning
    r = got["ais_reports"]
    assert r["time_ns"].to_list() == [utc(2021, 11, 1, 1, 58, 3), utc(2021, 11, 1, 1, 58, 6)]
    assert set(r["time_source"]) == {"interpolated:ais:base_station+utc_second"}
    base = got["ais_other_messages"]
    assert base["station_utc_ns"].to_list() == [utc(2021, 11, 1, 1, 58, 0),
                                                utc(2021, 11, 1, 1, 58, 10)]
    assert set(base["ais_class"]) == {"base_station"}


# -- pcap / pcapng packet times -------------------------------------------------------------


def _udp_frame(payload: bytes, sport: int = 4001) -> bytes:
    udp = struct.pack(">HHHH", sport, 10110, 8 + len(payload), 0) + payload
    ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), 0, 0x4000, 64, 17, 0,
                     bytes((10, 0, 0, 9)), bytes((255, 255, 255, 255))) + udp  # fmt: skip
    return b"\xff" * 6 + b"\x02" * 6 + b"\x08\x00" + ip


def test_nmea_over_udp_in_a_pcap_takes_the_packet_times(tmp_path):
    """An AIS receiver's !AIVDM lines over UDP (port 10110), captured with libpcap
    (magic a1b2c3d4, µs): each line's time is its packet's capture time; a tag block in a
    line still wins."""
    t1 = utc(2024, 5, 1, 12, 0, 0, frac_ns=123_456_000)
    t2 = utc(2024, 5, 1, 12, 0, 2, frac_ns=500_000)
    frames = [(t1, _udp_frame(f"{pos(second=0)}\r\n{pos(244000002, second=0)}\r\n".encode())),
              (t2, _udp_frame((tag_block("c:1714564900") + pos(244000003)).encode() + b"\r\n"))]
    out = struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1)
    for t_ns, frame in frames:
        out += struct.pack("<IIII", t_ns // NS, (t_ns % NS) // 1000, len(frame), len(frame))
        out += frame
    src = tmp_path / "ais_udp.pcap"
    src.write_bytes(out)
    res = import_file(src, tmp_path / "mcap")
    got = ingest(tmp_path, [Path(res.output)])
    r = got["ais_reports"]
    assert r["time_ns"].to_list() == [t1, t1, 1714564900 * NS]
    assert r["time_source"].to_list() == ["pcap", "pcap", "tag_block:c"]


# -- MCAP log times ---------------------------------------------------------------------


def test_a_native_mcap_recording_keeps_its_log_times(tmp_path):
    t = utc(2026, 1, 15, 0, 0, 1)
    path = tmp_path / "native.mcap"
    write_messages(path, [ChannelSpec("/ais", "nmea0183")], [0], [t], [pos().encode()])
    r = ingest(tmp_path, [path])["ais_reports"]
    assert r["time_ns"].to_list() == [t] and r["time_source"].to_list() == ["mcap_log_time"]


# -- ASTERIX times of day ------------------------------------------------------------------


def test_file_name_dates():
    assert str(file_name_date("smr_20240131.raw")) == "2024-01-31"
    assert str(file_name_date("2024-01-31_capture.ast")) == "2024-01-31"
    assert str(file_name_date("rec_2023_12_05_1200.ast")) == "2023-12-05"
    assert file_name_date("cat048.raw") is None
    assert file_name_date("log_20241331.raw") is None  # month 13
    assert file_name_date("serial_123420240131.raw") is None  # inside a longer number


@pytest.fixture()
def asterix_records():
    from pipeline.decode.asterix import decoder_available

    if not decoder_available():
        pytest.skip("the ASTERIX decoder (asterix_decoder, extra [asterix]) is not installed")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "decode"))
    from test_asterix import block, cat010_record

    return b"".join(block(10, cat010_record(tod=t, xy=(1, 1), track=1)) for t in
                    (28_800.0, 28_801.0))


def test_asterix_time_of_day_dated_by_the_file_name(tmp_path, asterix_records):
    src = tmp_path / "smr_20240131.ast"
    src.write_bytes(asterix_records)
    res = import_file(src, tmp_path / "mcap")
    assert not res.warning
    got = ingest(tmp_path, [Path(res.output)], ("airfield_obs",))["airfield_obs"]
    assert got["time_ns"].to_list() == [utc(2024, 1, 31, 8, 0, 0), utc(2024, 1, 31, 8, 0, 1)]
    assert set(got["time_source"]) == {"asterix_tod+file_name"}


def test_undated_asterix_is_warned_and_overlaps_nothing(tmp_path, asterix_records):
    a, b = tmp_path / "a.ast", tmp_path / "b.ast"
    a.write_bytes(asterix_records)
    b.write_bytes(asterix_records + b"\x0a\x00\x03")  # different content, same topic and times
    summary = run_import([a, b], tmp_path / "mcap")
    assert all("--base-time" in f.warning for f in summary.imported)
    assert "WARNING" in summary.render()
    got = ingest(tmp_path, sorted((tmp_path / "mcap").glob("*.mcap")), ("airfield_obs",))
    s = got["_summary"]
    assert s.overlaps == [] and len(s.time_warnings) == 2
    assert set(got["airfield_obs"]["time_source"]) == {"asterix_tod:undated"}  # no batch input


# -- synthetic times ---------------------------------------------------------------------


def test_synthetic_files_are_warned_and_never_overlap(tmp_path):
    """Two logs without any time both lie at 1970-01-01 + 1 ms per line: before issue 36
    that was "two sources overlap" between unrelated files."""
    one = write(tmp_path, "one.log", [pos(), pos(244000002)])
    two = write(tmp_path, "two.log", [pos(244000003), pos(244000004), pos(244000005)])
    summary = run_import([one, two], tmp_path / "mcap")
    assert summary.render().count("WARNING") == 2
    got = ingest(tmp_path, sorted((tmp_path / "mcap").glob("*.mcap")))
    s = got["_summary"]
    assert s.overlaps == [], s.overlaps
    assert len(s.time_warnings) == 2 and "--base-time" in s.render()
    assert set(got["ais_reports"]["time_source"]) == {"none:synthetic"}


def test_synthetic_rows_are_no_batch_input(tmp_path):
    from pipeline.batch.worker import read_inputs
    from pipeline.families import family
    from pipeline.family import Window

    cfg = load_config()
    real = write(tmp_path, "real.log", [(tag_block("c:20") + pos()).encode().decode()])
    none = write(tmp_path, "none.log", [pos(244000002)])
    summary = run_import([real, none], tmp_path / "mcap")
    ingest(tmp_path, sorted(Path(f.output) for f in summary.imported))
    inputs = read_inputs(family("maritime"), tmp_path / "wh", cfg, Window(0, 3600 * NS))
    assert inputs["ais_reports"]["mmsi"].to_list() == [244000001]  # the timed one only


def test_a_window_before_1980_says_why_it_is_empty(tmp_path):
    from pipeline.batch.window import bounded_window

    none = write(tmp_path, "none.log", [pos()])
    summary = run_import([none], tmp_path / "mcap")
    ingest(tmp_path, [Path(summary.imported[0].output)])
    w = bounded_window(load_config(), tmp_path / "wh", 0, 3600 * NS)
    assert "before 1980" in w.note and "--base-time" in w.note


# -- the class of every message, on every import path --------------------------------------


def test_class_from_the_message_type_in_nmea():
    lines = [pos(),
             *ais(type=18, mmsi=244000010, lat=52.0, lon=4.0, speed=5.0, course=10.0),
             *ais(type=19, mmsi=244000011, lat=52.0, lon=4.0, speed=5.0, course=10.0,
                  shipname="NINETEEN"),
             *ais(type=24, mmsi=244000012, partno=0, shipname="PART A"),
             *ais(type=4, mmsi=2442000, year=2024, month=1, day=1, hour=0, minute=0, second=0,
                  lat=52.0, lon=4.0),
             as_type_11(*ais(type=4, mmsi=2442001, year=2024, month=1, day=1, hour=0,
                             minute=0, second=0, lat=52.0, lon=4.0)),
             *ais(type=21, mmsi=992441234, name="BUOY 1", lat=52.0, lon=4.0),
             *ais(type=9, mmsi=111244123, lat=52.0, lon=4.0, speed=120, alt=300)]
    out = decode_nmea([s.encode() for s in lines], np.arange(len(lines), dtype=np.int64) * NS,
                      source_file="f", topic="/ais/nmea", platform_id="p")
    reports = {r["msg_type"]: r["ais_class"] for r in out.tables["ais_reports"].to_pylist()}
    assert reports == {1: "A", 18: "B", 19: "B"}
    statics = {r["msg_type"]: r["ais_class"] for r in out.tables["ais_static"].to_pylist()}
    assert statics == {19: "B", 24: "B"}
    other = {r["msg_type"]: r for r in out.tables["ais_other_messages"].to_pylist()}
    assert {k: v["ais_class"] for k, v in other.items()} == {
        4: "base_station", 11: "base_station", 21: "aton", 9: "sar_aircraft"}
    assert other[21]["name"] == "BUOY 1" and other[9]["altitude_m"] == 300.0
    assert other[9]["sog_mps"] == pytest.approx(120 * 1852 / 3600)


def as_type_11(line: str) -> str:
    """Message 11 (UTC/date response) has message 4's layout (ITU-R M.1371-5 Annex 8
    §3.3): the same payload with message id 11 (';' in the 6-bit armour). pyais's encoder
    writes id 4 for both."""
    head, payload, tail = line.split(",", 5)[:5], line.split(",")[5], line.split(",")[6]
    body = ",".join([*head, ";" + payload[1:], tail.split("*")[0]])[1:]
    return sentence(body, "!").decode()


CSV_DIALECTS = {
    # Stone Soup's demo table: no class, no message type -> class A
    "stonesoup.csv": ("Time,MMSI,Latitude_degrees,Longitude_degrees,COG_degrees,SOG_knots\n"
                      "2016-01-12 13:02:11.218,235000001,50.8,-1.3,90.0,10.0\n",
                      {235000001: ("ais_reports", "A")}),
    # NOAA MarineCadastre: TransceiverClass A/B
    "noaa.csv": ("MMSI,BaseDateTime,LAT,LON,SOG,COG,Heading,VesselName,IMO,CallSign,"
                 "VesselType,Status,Length,Width,Draft,Cargo,TransceiverClass\n"
                 "367000001,2023-01-11T00:00:00,30.0,-90.0,1.0,10.0,511,A ONE,IMO9074729,"
                 "WAB1,70,0,100,20,5,70,A\n"
                 "367000002,2023-01-11T00:00:10,30.1,-90.1,1.0,10.0,511,B TWO,,WAB2,37,,10,"
                 "3,,,B\n",
                 {367000001: ("ais_reports", "A"), 367000002: ("ais_reports", "B")}),
    # DMA aisdk: Type of mobile, including stations that are not vessels
    "dma.csv": ("# Timestamp,Type of mobile,MMSI,Latitude,Longitude,Navigational status,ROT,"
                "SOG,COG,Heading,IMO,Callsign,Name,Ship type,Cargo type,Width,Length,"
                "Type of position fixing device,Draught,Destination,ETA,Data source type\n"
                "01/06/2018 00:00:00,Class A,219000001,55.0,12.0,Under way using engine,0,"
                "10,90,90,Unknown,OXAA,SHIP A,Cargo,,20,100,GPS,5,X,,AIS\n"
                "01/06/2018 00:00:00,Class B,219000002,55.0,12.0,Unknown value,,5,90,,"
                "Unknown,,,Pleasure,,3,10,GPS,,,,AIS\n"
                "01/06/2018 00:00:00,Base Station,2190047,55.0,12.0,Unknown value,,,,,"
                "Unknown,,,Undefined,,,,GPS,,,,AIS\n"
                "01/06/2018 00:00:00,AtoN,992191000,55.0,12.0,Unknown value,,,,,"
                "Unknown,,BUOY,Undefined,,,,GPS,,,,AIS\n"
                "01/06/2018 00:00:00,SAR Airborne,111219500,55.0,12.0,Unknown value,,120,"
                "90,,Unknown,,,Undefined,,,,GPS,,,,AIS\n",
                {219000001: ("ais_reports", "A"), 219000002: ("ais_reports", "B"),
                 2190047: ("ais_other_messages", "base_station"),
                 992191000: ("ais_other_messages", "aton"),
                 111219500: ("ais_other_messages", "sar_aircraft")}),
    # a wide message-level export whose class column says A for class B message types
    "wide.csv": ("msg_type,mmsi,timestamp,lat,lon,speed,course,name,class\n"
                 "18,244000020,2024-01-31T12:00:00Z,52.0,4.0,5,10,,A\n"
                 "19,244000021,2024-01-31T12:00:01Z,52.0,4.0,5,10,SOMEONE,A\n"
                 "24,244000022,2024-01-31T12:00:02Z,,,,,PART A,A\n"
                 "9,111244001,2024-01-31T12:00:03Z,52.0,4.0,120,10,,\n",
                 {244000020: ("ais_reports", "B"), 244000021: ("ais_reports", "B"),
                  244000022: ("ais_static", "B"),
                  111244001: ("ais_other_messages", "sar_aircraft")}),
}


@pytest.mark.parametrize("name", sorted(CSV_DIALECTS))
def test_class_on_every_csv_dialect(tmp_path, name):
    text, want = CSV_DIALECTS[name]
    src = tmp_path / "in" / name
    src.parent.mkdir()
    src.write_text(text)
    res = import_file(src, tmp_path / "mcap")
    got = ingest(tmp_path, [Path(res.output)], ("ais_reports", "ais_static",
                                                "ais_other_messages"))
    seen = {}
    for table in ("ais_static", "ais_reports", "ais_other_messages"):
        for r in got[table].iter_rows(named=True):
            seen[r["mmsi"]] = (table, r["ais_class"])
            assert r["time_source"].startswith("csv:")
    assert seen == want
    if name == "noaa.csv":  # dimensions of the CSV in ais_static
        s = got["ais_static"].filter(pl.col("mmsi") == 367000001).row(0, named=True)
        assert (s["length_m"], s["width_m"]) == (100.0, 20.0)


# -- logger timestamps in CSV rows ----------------------------------------------------------


@pytest.mark.parametrize("quoted", [False, True])
def test_vdr_csv_log_takes_the_row_times(tmp_path, quoted):
    """OpenCPN's VDR log format (CSV, RFC 4180): a ``#`` comment block, a header
    ``received_at,protocol,msg_type,source,raw_data``, then one row per sentence whose
    first cell is the ISO 8601 reception time; the sentence cell quoted or not (the
    specification's own example writes it bare, LogAIS quotes it)."""
    a, b = pos(244000001, second=8), pos(244000002, second=8)
    cell = (lambda s: f'"{s}"') if quoted else (lambda s: s)
    lines = ["# VDR Log File", "# Created: 2025-06-09T02:57:03.588Z",
             "received_at,protocol,msg_type,source,raw_data",
             f'2025-06-09T02:57:08.053Z,NMEA0183,AIVDM,"UDP port:6039",{cell(a)}',
             f'2025-06-09T02:57:08.591Z,NMEA0183,AIVDM,"UDP port:6039",{cell(b)}']
    got, res = imported(tmp_path, "vdr.csv", lines)
    assert res.log_time_source["/ais/nmea"] == "leading_timestamp" and not res.warning
    r = got["ais_reports"]
    assert r["time_ns"].to_list() == [utc(2025, 6, 9, 2, 57, 8, frac_ns=53_000_000),
                                      utc(2025, 6, 9, 2, 57, 8, frac_ns=591_000_000)]
    assert set(r["time_source"]) == {"leading_timestamp"}
    assert got["_summary"].rejected == 0  # the header is no message, the quotes no junk
