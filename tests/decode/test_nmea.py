"""NMEA 0183 framing, routing, reject reasons, time rules and batch carry
(pipeline/decode/nmea.py)."""

from __future__ import annotations

import math

import numpy as np
import polars as pl
import pytest
from mcap.writer import Writer
from mcap_fixtures import AIS_TYPE1, TYPE5_FRAGMENTS
from nmea_builders import (
    NS,
    PLATFORM,
    SRC,
    T0_NS,
    TOPIC,
    decode,
    reasons,
    rows,
    sentence,
    tag_block,
    times,
    xor,
)
from polars.testing import assert_frame_equal

from pipeline.config import ValidationConfig
from pipeline.decode.nmea import (
    NMEA_TABLES,
    NmeaLimits,
    decode_nmea,
    decode_nmea_sentences,
    xor_checksums,
)
from pipeline.decode.registry import RAW_TABLES, FileDecoder, decoder_kind
from pipeline.io.mcap_read import read_mcap_batches
from pipeline.tables import schema

GGA = sentence("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,")
RMC = sentence("GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W")
HDT = sentence("HEHDT,274.07,T")


def test_checksums_match_a_one_character_at_a_time_reference():
    texts = ["", "A", "GPGGA,1,2", "x" * 300, "IIHDT,,T", "ü,ß"]
    got = xor_checksums(pl.Series(texts))
    assert got.tolist() == [xor(t) for t in texts]


def test_every_table_present_and_conformed():
    out = decode([GGA, HDT])
    assert set(out) == set(NMEA_TABLES)
    for name, table in out.items():
        assert table.schema == schema(name), name
    assert set(NMEA_TABLES) - {"ais_reports", "ais_static"} <= set(RAW_TABLES)


def test_provenance_and_talker():
    (row,) = rows(decode([HDT]), "nav_heading")
    assert (row["platform_id"], row["topic"], row["source_file"]) == (PLATFORM, TOPIC, SRC)
    assert (row["talker"], row["sentence"], row["raw"]) == ("HE", "HDT", HDT.decode())
    assert row["log_time_ns"] == T0_NS


def test_bad_and_missing_checksum_rejected_with_raw_bytes():
    bad = GGA[:-2] + (b"00" if not GGA.endswith(b"00") else b"01")
    missing = GGA.rsplit(b"*", 1)[0]
    out = decode([bad, missing, GGA])
    assert reasons(out) == ["bad_checksum", "bad_checksum"]
    assert out["rejects"].column("raw").to_pylist() == [bad, missing]
    assert out["nav_gnss"].num_rows == 1


def test_one_digit_lower_case_checksum_accepted_when_its_value_is_right():
    body = "IIHDT,28.5,T"
    short = f"${body}*{xor(body):x}".encode()  # OpenCPN writes e.g. *b
    assert len(short.split(b"*")[1]) <= 2
    out = decode([short])
    assert out["rejects"].num_rows == 0 and out["nav_heading"].num_rows == 1


def test_fused_sentences_are_split_and_both_kept():
    out = decode([GGA + RMC, b"  " + HDT + b"\r\n"])
    assert out["rejects"].num_rows == 0
    assert sorted(r["sentence"] for r in rows(out, "nav_gnss")) == ["GGA", "RMC"]
    assert out["nav_heading"].num_rows == 1


def test_fused_line_cut_mid_sentence_keeps_the_intact_one():
    cut = GGA[:30]  # the logger lost the end of the GGA and its line feed
    out = decode([cut + RMC])
    assert reasons(out) == ["bad_checksum"]
    assert out["rejects"].column("raw").to_pylist() == [cut]
    assert [r["sentence"] for r in rows(out, "nav_gnss")] == ["RMC"]


def test_garbage_empty_and_junk_around_a_sentence():
    out = decode([b"hello world", b"", b"\xff\xfe\x00", b"xx" + HDT])
    rej = rows(out, "rejects")
    assert [r["reason_code"] for r in rej] == ["undecodable"] * 4
    assert [r["raw"] for r in rej] == [b"hello world", b"", b"\xff\xfe\x00", b"xx" + HDT]
    assert out["nav_heading"].num_rows == 1  # the sentence after the junk is kept


def test_unused_and_proprietary_sentences_are_counted_not_rejected():
    gsv = sentence("GPGSV,1,1,00")
    pashr = sentence("PASHR,204132.000,010.51,T,+00.39,-00.79,-00.84,0.151,0.075,0.555,1,0")
    out = decode_nmea([gsv, gsv, pashr, sentence("WIMWV,214.8,R,0.1,K,A"), HDT],
                      times(5), source_file=SRC, topic=TOPIC, platform_id=PLATFORM)  # fmt: skip
    assert out.tables["rejects"].num_rows == 0 and out.tables["nav_heading"].num_rows == 1
    assert out.not_stored == {"nmea_GSV": 2, "nmea_PASHR": 1, "nmea_MWV": 1}


@pytest.mark.parametrize("talker", ["04", "24", "II", "A1", "U0"])
def test_any_two_character_talker_including_digits(talker):
    """NMEA 2000 gateways write numeric talkers ($04HDM, $24HDG); CRLF, no time."""
    lines = [sentence(f"{talker}HDM,123.4,M") + b"\r\n", sentence(f"{talker}HDG,101.1,,,3.0,E")]
    out = decode(lines)
    assert reasons(out) == []
    hdg = rows(out, "nav_heading")
    assert [r["talker"] for r in hdg] == [talker, talker]
    assert [r["sentence"] for r in hdg] == ["HDM", "HDG"]


def test_address_of_five_digits_or_a_lower_case_formatter_is_undecodable():
    out = decode([sentence("12345,1"), sentence("04hdm,1.0,M")])
    assert reasons(out) == ["undecodable", "undecodable"]


def test_bad_address_field_undecodable():
    out = decode([sentence("GP,1,2"), sentence("gpgga,1")])
    assert reasons(out) == ["undecodable", "undecodable"]


def test_latitude_123_and_longitude_200_out_of_range():
    lat = sentence("GPGGA,123519,12300.000,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,")
    lon = sentence("GPGLL,4807.038,N,20000.000,W,123519,A")
    out = decode([lat, lon, GGA])
    rej = rows(out, "rejects")
    assert [r["reason_code"] for r in rej] == ["out_of_range", "out_of_range"]
    assert "lat_deg=123" in rej[0]["reason"] and "lon_deg=-200" in rej[1]["reason"]
    assert out["nav_gnss"].num_rows == 1


def test_900_knots_out_of_range_everywhere_a_speed_is():
    lines = [
        sentence("GPRMC,123519,A,4807.038,N,01131.000,E,900.0,084.4,230394,,"),
        sentence("GPVTG,084.4,T,,M,900.0,N,1666.8,K,A"),
        sentence("VWVHW,,T,,M,900.0,N,,K"),
        sentence("VDVBW,900.0,0.1,A,10.0,0.1,A"),
        sentence("RATTM,01,2.5,45.0,T,900.0,90.0,T,0.5,3.0,N,,T,,123519.00,A"),
        sentence("RAOSD,90.0,A,90.0,B,900.0,B,,,N"),
        sentence("GPVTG,084.4,T,,M,12.0,N,22.2,K,A"),
    ]
    out = decode(lines)
    assert reasons(out) == ["out_of_range"] * 6
    assert all("900" in r for r in out["rejects"].column("reason").to_pylist())
    assert out["nav_gnss"].num_rows == 1


def test_speed_limit_follows_the_limits():
    vtg = sentence("GPVTG,084.4,T,,M,50.0,N,,K,A")  # 25.7 m/s
    strict = decode_nmea_sentences(
        [vtg],
        times(1),
        source_file=SRC,
        topic=TOPIC,
        platform_id=PLATFORM,
        limits=NmeaLimits(max_speed_mps=20.0),
    )
    assert reasons(strict) == ["out_of_range"] and reasons(decode([vtg])) == []


def test_time_going_backwards_rejected_per_talker_and_formatter():
    def gga(hhmmss: str, talker: str = "GP") -> bytes:
        return sentence(f"{talker}GGA,{hhmmss},4807.038,N,01131.000,E,1,08,0.9,5.4,M,46.9,M,,")

    lines = [gga("100000"), gga("100001"), gga("095900"), gga("100002"), gga("095000", "GN")]
    out = decode(lines)
    rej = rows(out, "rejects")
    assert [r["reason_code"] for r in rej] == ["out_of_range"]
    assert "backwards by 61.0 s" in rej[0]["reason"] and rej[0]["raw"] == lines[2]
    assert out["nav_gnss"].num_rows == 4  # another talker has its own clock


def test_heading_outside_360_and_no_data():
    out = decode([sentence("HEHDT,400.0,T"), sentence("IIHDT,,T"), sentence("IIHDM,,M")])
    assert reasons(out) == ["out_of_range", "no_data", "no_data"]


def test_non_numeric_field_undecodable():
    out = decode(
        [sentence("HEHDT,12x.4,T"), sentence("GPGGA,12:35:19,4807.038,N,01131.000,E,1,,,,,,,,")]
    )
    assert reasons(out) == ["undecodable", "undecodable"]


# -- time --------------------------------------------------------------------------------


def test_time_of_day_on_the_log_date_without_any_date_sentence():
    log = np.asarray([T0_NS + 13 * 3600 * NS], np.int64)  # 2026-01-01 13:00
    (row,) = rows(decode([GGA], log), "nav_gnss")
    assert row["time_ns"] == T0_NS + (12 * 3600 + 35 * 60 + 19) * NS
    assert row["log_time_ns"] == int(log[0])


def test_rmc_and_zda_dates_win_over_the_log_date():
    zda = sentence("GPZDA,235959.50,31,12,2015,00,00")
    after = sentence("GPGLL,4807.038,N,01131.000,E,000001.00,A")
    out = decode([zda, after], times(2, start_ns=T0_NS))  # logged in 2026
    got = sorted(r["time_ns"] for r in rows(out, "nav_gnss"))
    eve = 1_451_606_399_500_000_000  # 2015-12-31T23:59:59.5Z
    assert got == [eve, eve + 1_500_000_000]  # the GLL rolled over midnight into 2016


def test_midnight_rollover_backwards_against_the_log_date():
    # logged just after midnight, sentence time just before: the previous day
    log = np.asarray([T0_NS + 2 * NS], np.int64)
    gga = sentence("GPGGA,235959.00,4807.038,N,01131.000,E,1,08,0.9,5.4,M,46.9,M,,")
    (row,) = rows(decode([gga], log), "nav_gnss")
    assert row["time_ns"] == T0_NS - NS


def test_rmc_two_digit_year_pivot():
    r94 = sentence("GPRMC,000000,A,4807.038,N,01131.000,E,0.0,0.0,010194,,")
    r09 = sentence("GPRMC,000000,A,4807.038,N,01131.000,E,0.0,0.0,010109,,")
    got = [r["time_ns"] for r in rows(decode([r94]), "nav_gnss")]
    got += [r["time_ns"] for r in rows(decode([r09]), "nav_gnss")]
    assert got == [757_382_400 * NS, 1_230_768_000 * NS]


def test_sentences_without_time_take_the_log_time():
    log = times(2, start_ns=T0_NS + 123)
    out = decode([HDT, sentence("GPVTG,084.4,T,,M,5.0,N,,K,A")], log)
    assert [r["time_ns"] for r in rows(out, "nav_heading")] == [T0_NS + 123]
    assert [r["time_ns"] for r in rows(out, "nav_gnss")] == [T0_NS + 123 + NS]


def test_tag_block_time_for_ais_and_untimed_nav_sentences():
    c_s = 1_635_731_889
    tagged_ais = (tag_block(f"s:42809,c:{c_s}") + AIS_TYPE1.decode()).encode()
    tagged_hdt = (tag_block(f"c:{c_s + 5}000") + HDT.decode()).encode()  # milliseconds
    out = decode([tagged_ais, tagged_hdt])
    assert out["rejects"].num_rows == 0
    (ais,) = rows(out, "ais_reports")
    assert ais["time_ns"] == c_s * NS and ais["log_time_ns"] == T0_NS
    assert ais["nmea"].startswith("\\s:42809")  # the tag block stays in the raw text
    assert rows(out, "nav_heading")[0]["time_ns"] == (c_s + 5) * NS


def test_bad_tag_block_checksum_rejects_the_sentence():
    bad = b"\\s:42809,c:1635731889*00\\" + AIS_TYPE1
    out = decode([bad])
    assert reasons(out) == ["bad_checksum"] and out["ais_reports"].num_rows == 0


def test_receiver_fields_after_the_checksum_are_tolerated():
    uscg = AIS_TYPE1 + b",s36310,d-081,T59.01777335,x147521,r08TPHI1,1242958962"
    out = decode([uscg])
    assert out["rejects"].num_rows == 0 and out["ais_reports"].num_rows == 1


# -- AIS routing and batches -------------------------------------------------------------


def test_ais_interleaved_with_nav_and_multipart_across_nav_lines():
    f1, f2 = TYPE5_FRAGMENTS
    out = decode([f1, GGA, HDT, f2, AIS_TYPE1])
    assert out["rejects"].num_rows == 0
    assert out["ais_static"].num_rows == 1 and out["ais_reports"].num_rows == 1
    assert out["nav_gnss"].num_rows == 1 and out["nav_heading"].num_rows == 1
    assert out["ais_static"]["time_ns"][0].as_py() == T0_NS + 3 * NS


@pytest.mark.parametrize("split", range(1, 9))
def test_carry_between_batches_equals_one_batch(split):
    f1, f2 = TYPE5_FRAGMENTS
    zda = sentence("GPZDA,235959.00,31,12,2015,00,00")
    lines = [
        zda,
        GGA,
        f1,
        sentence("GPGLL,4807.038,N,01131.000,E,000002.00,A"),
        f2,
        AIS_TYPE1,
        sentence("GPGLL,4807.038,N,01131.000,E,000001.00,A"),
        HDT,
        RMC,
    ]
    t = times(len(lines))
    whole = decode(lines, t)
    kw = {"source_file": SRC, "topic": TOPIC, "platform_id": PLATFORM}
    a = decode_nmea(lines[:split], t[:split], final=False, **kw)
    b = decode_nmea(lines[split:], t[split:], carry=a.carry, final=True, **kw)
    for name in NMEA_TABLES:
        joined = pl.concat([pl.from_arrow(a.tables[name]), pl.from_arrow(b.tables[name])])
        want = pl.from_arrow(whole[name])
        keys = [c for c in ("log_time_ns", "raw", "nmea", "reason") if c in want.columns]
        assert_frame_equal(joined.sort(keys), want.sort(keys), check_exact=False)
    assert reasons(whole) == ["out_of_range"]  # the GLL at 00:00:01 after 00:00:02


def _nmea_mcap(path, channels: dict[str, dict], msgs: list[tuple[str, int, bytes]]):
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        ids = {t: w.register_channel(t, "nmea0183", 0, metadata=m) for t, m in channels.items()}
        for topic, t, payload in msgs:
            w.add_message(ids[topic], t, payload, t)
        w.finish()
    return path


def test_registry_routes_nmea_channels_with_platform_id(tmp_path):
    assert decoder_kind("nmea0183", "", "") == "nmea"
    msgs = [("/nav/nmea", T0_NS + i, s) for i, s in enumerate([GGA, HDT, b"junk", RMC])]
    msgs.append(("/ais/nmea", T0_NS + 9, AIS_TYPE1))
    chans = {"/nav/nmea": {"platform_id": "MV Test"}, "/ais/nmea": {}}
    path = _nmea_mcap(tmp_path / "n.mcap", chans, msgs)
    dec = FileDecoder(source_file=str(path), validation=ValidationConfig())
    for batch in read_mcap_batches(path):
        dec.feed(batch)
    out = dec.finish()
    assert out["nav_gnss"].num_rows == 2 and out["nav_heading"].num_rows == 1
    assert out["ais_reports"].num_rows == 1 and reasons(out) == ["undecodable"]
    assert set(out["nav_gnss"].column("platform_id").to_pylist()) == {"MV Test"}
    assert out["rejects"].column("topic").to_pylist() == ["/nav/nmea"]


def test_units_of_a_gga_rmc_pair():
    out = decode([GGA, RMC])
    gga, rmc = sorted(rows(out, "nav_gnss"), key=lambda r: r["sentence"])
    assert gga["lat_deg"] == pytest.approx(48 + 7.038 / 60)
    assert gga["lon_deg"] == pytest.approx(11 + 31.0 / 60)
    assert (gga["fix_quality"], gga["n_satellites"], gga["hdop"]) == (1, 8, 0.9)
    assert gga["altitude_m"] == 545.4
    assert rmc["sog_mps"] == pytest.approx(22.4 * 1852 / 3600)
    assert rmc["cog_rad"] == pytest.approx(math.radians(84.4)) and rmc["fix_valid"] is True
