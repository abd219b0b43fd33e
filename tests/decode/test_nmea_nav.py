"""Field decoding of every navigation / ARPA sentence type (pipeline/decode/nav_nmea.py):
values and SI units recomputed inline from the NMEA 0183 field definitions."""

from __future__ import annotations

import math

import numpy as np
import pytest
from nmea_builders import NS, T0_NS, decode, reasons, rows, sentence

from pipeline.decode.nav_nmea import DECODERS, days_from_civil

KN = 1852.0 / 3600.0
R = math.radians
TOD_123519 = (12 * 3600 + 35 * 60 + 19) * NS


NOON_NS = T0_NS + 12 * 3600 * NS  # log time: 2026-01-01T12:00:00Z


def one(body: str, table: str) -> dict:
    out = decode([sentence(body)], np.asarray([NOON_NS], np.int64))
    assert reasons(out) == [], out["rejects"].to_pylist()
    (row,) = rows(out, table)
    return row


def test_every_declared_formatter_is_tested_here():
    tested = {"GGA", "RMC", "VTG", "GSA", "GLL", "ZDA", "HDT", "HDM", "HDG", "THS", "ROT",
              "VHW", "VBW", "TTM", "TLL", "OSD"}  # fmt: skip
    assert set(DECODERS) == tested


def test_days_from_civil_against_numpy_dates():
    y, m, d = (
        np.array([1970, 2000, 2016, 1969, 2100]),
        np.array([1, 2, 2, 12, 3]),
        np.array([1, 29, 29, 31, 1]),
    )
    want = [
        (np.datetime64(f"{a:04d}-{b:02d}-{c:02d}") - np.datetime64("1970-01-01")).astype(int)
        for a, b, c in zip(y, m, d, strict=True)
    ]
    assert days_from_civil(y, m, d).tolist() == want


def test_gga_southern_western_fix_quality_and_time():
    r = one("GNGGA,132819.60,4134.49795459,S,09345.03431408,W,4,10,0.9,278.161,M,-31.4,M,6.6,0133",
            "nav_gnss")  # fmt: skip
    assert r["lat_deg"] == pytest.approx(-(41 + 34.49795459 / 60), abs=1e-12)
    assert r["lon_deg"] == pytest.approx(-(93 + 45.03431408 / 60), abs=1e-12)
    assert (r["talker"], r["fix_quality"], r["n_satellites"]) == ("GN", 4, 10)
    assert r["hdop"] == 0.9 and r["altitude_m"] == 278.161
    assert r["time_ns"] == T0_NS + (13 * 3600 + 28 * 60 + 19.6) * NS


def test_gga_without_fix_keeps_quality_zero():
    r = one("GPGGA,123519,,,,,0,00,,,M,,M,,", "nav_gnss")
    assert r["fix_quality"] == 0 and r["lat_deg"] is None and r["n_satellites"] == 0


def test_rmc_status_speed_course_and_date():
    r = one("GPRMC,225446,V,4916.45,N,12311.12,W,000.5,054.7,191194,020.3,E", "nav_gnss")
    assert r["fix_valid"] is False and r["sog_mps"] == pytest.approx(0.5 * KN)
    assert r["cog_rad"] == pytest.approx(R(54.7))
    assert r["time_ns"] == 785_285_686 * NS  # 1994-11-19T22:54:46Z


def test_vtg_knots_else_kmh():
    r = one("GPVTG,054.7,T,034.4,M,005.5,N,010.2,K,A", "nav_gnss")
    assert r["sog_mps"] == pytest.approx(5.5 * KN) and r["cog_rad"] == pytest.approx(R(54.7))
    r = one("GPVTG,,T,,M,,N,36.0,K,A", "nav_gnss")
    assert r["sog_mps"] == pytest.approx(10.0) and r["cog_rad"] is None


def test_gsa_satellites_listed_and_hdop():
    r = one("GPGSA,A,3,11,32,14,28,22,03,10,08,17,,,,2.02,1.03,1.74", "nav_gnss")
    assert (r["n_satellites"], r["hdop"], r["sentence"]) == (9, 1.03, "GSA")


def test_gll_position_status_time():
    r = one("GPGLL,5012.790800,N,00806.879600,W,130711,A,D", "nav_gnss")
    assert r["lat_deg"] == pytest.approx(50 + 12.7908 / 60)
    assert r["lon_deg"] == pytest.approx(-(8 + 6.8796 / 60))
    assert r["fix_valid"] is True
    assert r["time_ns"] == T0_NS + (13 * 3600 + 7 * 60 + 11) * NS


def test_zda_is_a_row_with_its_own_date():
    r = one("GPZDA,130711,01,06,2011,01,00", "nav_gnss")
    assert r["time_ns"] == 1_306_933_631 * NS  # 2011-06-01T13:07:11Z
    assert r["lat_deg"] is None and r["sentence"] == "ZDA"


def test_zda_without_date_uses_the_log_date():
    r = one("GPZDA,095559,,,,00,", "nav_gnss")
    assert r["time_ns"] == T0_NS + (9 * 3600 + 55 * 60 + 59) * NS


def test_hdt_hdm():
    r = one("HEHDT,274.07,T", "nav_heading")
    assert r["heading_rad"] == pytest.approx(R(274.07)) and r["is_magnetic"] is False
    r = one("HCHDM,12.5,M", "nav_heading")
    assert r["heading_rad"] == pytest.approx(R(12.5)) and r["is_magnetic"] is True


def test_hdg_deviation_and_variation():
    r = one("SDHDG,229.8,1.0,W,1.3,E", "nav_heading")
    assert r["heading_rad"] == pytest.approx(R(229.8 - 1.0 + 1.3))  # true heading
    assert r["deviation_rad"] == pytest.approx(R(-1.0))
    assert r["variation_rad"] == pytest.approx(R(1.3)) and r["is_magnetic"] is False
    r = one("IIHDG,359.5,1.0,E,,", "nav_heading")  # no variation: magnetic, wraps past 360
    assert r["heading_rad"] == pytest.approx(R(0.5)) and r["is_magnetic"] is True


def test_ths_and_rot():
    r = one("INTHS,77.52,A", "nav_heading")
    assert r["heading_rad"] == pytest.approx(R(77.52)) and r["mode"] == "A"
    r = one("HEROT,-3.0,A", "nav_heading")
    assert r["rate_of_turn_radps"] == pytest.approx(R(-3.0) / 60.0) and r["mode"] == "A"


def test_vhw_speed_and_heading():
    r = one("IIVHW,245.1,T,242.0,M,5.9,N,10.9,K", "nav_speed_log")
    assert r["speed_water_mps"] == pytest.approx(5.9 * KN)
    assert r["heading_rad"] == pytest.approx(R(245.1))
    r = one("SDVHW,,T,,M,,N,18.0,K", "nav_speed_log")
    assert r["speed_water_mps"] == pytest.approx(5.0)


def test_vbw_water_ground_and_validity():
    r = one("VDVBW,10.1,-0.2,A,9.8,0.3,V", "nav_speed_log")
    assert r["speed_water_mps"] == pytest.approx(10.1 * KN)
    assert r["transverse_speed_water_mps"] == pytest.approx(-0.2 * KN)
    assert r["speed_ground_mps"] == pytest.approx(9.8 * KN)
    assert r["transverse_speed_ground_mps"] == pytest.approx(0.3 * KN)
    assert r["valid"] is False


def test_ttm_real_sentence_units_and_radar_clock():
    ttm = b"$RATTM,11,11.4,13.6,T,7.0,20.0,T,0.0,0.0,N,,Q,,154125.82,A,*17"
    out = decode([ttm], np.asarray([NOON_NS], np.int64))
    assert reasons(out) == []
    (r,) = rows(out, "arpa_targets")
    assert (r["target_number"], r["target_status"], r["acquisition"]) == (11, "Q", "A")
    assert r["range_m"] == pytest.approx(11.4 * 1852) and r["bearing_rad"] == pytest.approx(R(13.6))
    assert r["speed_mps"] == pytest.approx(7.0 * KN) and r["course_rad"] == pytest.approx(R(20))
    assert r["bearing_is_relative"] is False and r["tcpa_s"] == 0.0
    assert r["time_ns"] == T0_NS + round((15 * 3600 + 41 * 60 + 25.82) * NS)


def test_ttm_kilometres_relative_bearing_and_tcpa():
    r = one("RATTM,02,3.0,350.0,R,36.0,10.0,R,0.5,-2.5,K,TGT2,T,R,,M", "arpa_targets")
    assert r["range_m"] == pytest.approx(3000.0) and r["speed_mps"] == pytest.approx(10.0)
    assert r["cpa_m"] == pytest.approx(500.0) and r["tcpa_s"] == pytest.approx(-150.0)
    assert (r["bearing_is_relative"], r["course_is_relative"], r["is_reference"]) == (
        True, True, True)  # fmt: skip
    assert (r["target_name"], r["acquisition"]) == ("TGT2", "M")


def test_tll_position_and_time():
    r = one("RATLL,07,5759.097,N,01144.345,E,FERRY,092212.5,T,", "arpa_targets")
    assert r["lat_deg"] == pytest.approx(57 + 59.097 / 60)
    assert r["lon_deg"] == pytest.approx(11 + 44.345 / 60)
    assert (r["target_number"], r["target_name"], r["target_status"]) == (7, "FERRY", "T")
    assert r["time_ns"] == T0_NS + round((9 * 3600 + 22 * 60 + 12.5) * NS)


def test_osd_own_ship():
    r = one("RAOSD,35.1,A,36.0,P,10.0,P,15.3,0.2,N", "arpa_own_ship")
    assert r["heading_rad"] == pytest.approx(R(35.1)) and r["heading_valid"] is True
    assert r["course_rad"] == pytest.approx(R(36.0)) and r["course_reference"] == "P"
    assert r["speed_mps"] == pytest.approx(10.0 * KN) and r["speed_reference"] == "P"
    assert r["set_rad"] == pytest.approx(R(15.3)) and r["drift_mps"] == pytest.approx(0.2 * KN)


@pytest.mark.parametrize(
    "body",
    [
        "GPGGA,123519,4807.038,X,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",  # hemisphere
        "GPGGA,123519,4875.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",  # 75 minutes
        "GPGGA,256000,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",  # hour 25
        "GPRMC,123519,A,4807.038,N,01131.000,E,1.0,84.4,23o394,,",  # date
        "GPZDA,130711,32,13,2011,00,00",  # day 32, month 13
        "RATTM,02,3.0,350.0,T,36.0,10.0,T,0.5,-2.5,X,,T,,,A",  # units
    ],
)
def test_malformed_fields_undecodable(body):
    assert reasons(decode([sentence(body)])) == ["undecodable"]
