"""ais_traffic and ais_quality (issue 36) on built AIS tables whose answers are known:
every check has a transponder built to fail it and one built to pass it."""

from __future__ import annotations

import math

import duckdb
import polars as pl
import pytest

from pipeline.reports import SiteGeometry, run_report
from pipeline.tables import conform, empty

NS = 1_000_000_000
T0 = 1_768_435_200 * NS  # 2026-01-15 00:00 UTC
KN = 1852 / 3600
LAT0, LON0 = 46.0, 31.0
M_PER_DEG_LAT = 111_132.0


def north(m: float) -> float:
    return m / M_PER_DEG_LAT


def east(m: float) -> float:
    return m / (M_PER_DEG_LAT * math.cos(math.radians(LAT0)))


def track(mmsi: int, n: int, step_s: float, sog_kn: float, *, cog_deg: float = 0.0,
          msg_type: int = 1, ais_class: str = "A", start_s: float = 0.0, status: int = 0,
          lat: float = LAT0, lon: float = LON0, time_source: str = "tag_block:c",
          reported_sog_kn: float | None = None, reported_cog_deg: float | None = None,
          utc_offset_s: float = 0.0) -> list[dict]:
    """A straight track at ``sog_kn`` towards ``cog_deg``, one report every ``step_s``;
    each report's utc_second is its time's second minus ``utc_offset_s`` (a late one)."""
    rows = []
    for i in range(n):
        t_s = start_s + i * step_s
        d = sog_kn * KN * t_s
        t_ns = T0 + round(t_s * NS)
        rows.append({
            "time_ns": t_ns, "mmsi": mmsi, "msg_type": msg_type, "ais_class": ais_class,
            "lat_deg": lat + north(d * math.cos(math.radians(cog_deg))),
            "lon_deg": lon + east(d * math.sin(math.radians(cog_deg))),
            "sog_mps": (sog_kn if reported_sog_kn is None else reported_sog_kn) * KN,
            "cog_rad": math.radians(cog_deg if reported_cog_deg is None else reported_cog_deg),
            "nav_status": status if msg_type in (1, 2, 3) else None,
            "utc_second": int(((t_ns - round(utc_offset_s * NS)) // NS) % 60),
            "nmea": "", "source_file": "f.mcap", "topic": "/ais/nmea", "log_time_ns": t_ns,
            "time_source": time_source, "site": "harbour",
        })
    return rows


def static(mmsi: int, *, imo: int | None = None, name: str = "SHIP", length: float | None = 100,
           ship_type: int | None = 70, msg_type: int = 5) -> dict:
    return {"time_ns": T0 + NS, "mmsi": mmsi, "msg_type": msg_type, "ais_class": "A",
            "imo": imo, "shipname": name, "ship_type": ship_type, "length_m": length,
            "width_m": 20.0 if length else None, "nmea": "", "source_file": "f.mcap",
            "topic": "/ais/nmea", "log_time_ns": T0 + NS, "time_source": "tag_block:c",
            "site": "harbour"}


def other(mmsi: int, msg_type: int, ais_class: str | None, *, lat: float | None = LAT0,
          n: int = 1) -> list[dict]:
    return [{"time_ns": T0 + i * 10 * NS, "mmsi": mmsi, "msg_type": msg_type,
             "ais_class": ais_class, "lat_deg": lat, "lon_deg": LON0 if lat else None,
             "nmea": "", "source_file": "f.mcap", "topic": "/ais/nmea",
             "log_time_ns": T0 + i * 10 * NS, "time_source": "tag_block:c", "site": "harbour"}
            for i in range(n)]


def connect(reports: list[dict], statics: list[dict], others: list[dict]):
    c = duckdb.connect()
    for name, rows in (("ais_reports", reports), ("ais_static", statics),
                       ("ais_other_messages", others)):
        table = conform(name, pl.DataFrame(rows, infer_schema_length=None).to_arrow()) \
            if rows else empty(name)
        c.register(name, table)
    return c


ISLAND = ((LAT0 + north(20_000), LON0 - east(1000)), (LAT0 + north(20_000), LON0 + east(1000)),
          (LAT0 + north(22_000), LON0 + east(1000)), (LAT0 + north(22_000), LON0 - east(1000)))
SECTOR = ((LAT0 - 1, LON0 - 1), (LAT0 - 1, LON0 + 1), (LAT0 + 1, LON0 + 1), (LAT0 + 1, LON0 - 1))
GEOMETRY = SiteGeometry((("sector", "bay", SECTOR), ("land", "isle", ISLAND)))


def quality(con, geometry=GEOMETRY, **params) -> dict[int, dict]:
    t = pl.from_arrow(run_report(con, "ais_quality", start_ns=T0, end_ns=T0 + 3600 * NS,
                                 geometry=geometry, params=params))
    return {r["mmsi"]: r for r in t.filter(pl.col("level") == "transponder").iter_rows(named=True)}


OK_SHIP = 211000001  # 12 kn every 10 s: conforming, static complete, valid IMO


def base_case() -> tuple[list[dict], list[dict], list[dict]]:
    reports = track(OK_SHIP, 30, 10.0, 12.0)
    statics = [static(OK_SHIP, imo=9074729)]
    return reports, statics, []


def test_a_clean_transponder_fails_no_check():
    r, s, o = base_case()
    q = quality(connect(r, s, o))[OK_SHIP]
    assert q["problems"] == 0 and q["checks_failed"] == "", q
    assert q["interval_conformance"] == 1.0 and q["intervals_checked"] == 29
    assert q["imo_valid"] is True and q["mmsi_kind"] == "ship"
    assert q["position_jumps"] == 0 and q["positions_on_land"] == 0 and q["land_checked"] == 30
    assert q["sog_mismatch"] == 0 and q["sog_checked"] == 29
    assert q["cog_mismatch"] == 0 and q["cog_checked"] > 0
    assert q["clock_checked"] == 30 and q["median_clock_offset_s"] == 0.0


@pytest.mark.parametrize(("step_s", "sog_kn", "status", "cls", "msg", "ok"), [
    (10.0, 12.0, 0, "A", 1, True),     # Table 1: 0-14 kn, 10 s
    (30.0, 12.0, 0, "A", 1, False),    # ... every 30 s: too slow
    (6.0, 18.0, 0, "A", 1, True),      # 14-23 kn: 6 s
    (10.0, 18.0, 0, "A", 1, False),    # ... every 10 s: too slow
    (2.0, 30.0, 0, "A", 1, True),      # > 23 kn: 2 s
    (180.0, 0.0, 1, "A", 1, True),     # at anchor, <= 3 kn: 3 min
    (180.0, 0.0, 0, "A", 1, False),    # not at anchor, 0 kn: 10 s
    (30.0, 6.0, 0, "B", 18, True),     # Table 2, class B "CS" > 2 kn: 30 s
    (60.0, 6.0, 0, "B", 18, False),
    (180.0, 1.0, 0, "B", 18, True),    # class B <= 2 kn: 3 min
])
def test_reporting_interval_against_itu_r_m1371_tables(step_s, sog_kn, status, cls, msg, ok):
    mmsi = 211000009
    rows = track(mmsi, 6, step_s, sog_kn, status=status, ais_class=cls, msg_type=msg)
    q = quality(connect(rows, [static(mmsi, imo=9074729)], []), gap_s=600.0)[mmsi]
    assert q["intervals_checked"] == 5
    assert (q["interval_conformance"] == 1.0) is ok
    assert ("interval" in q["checks_failed"]) is (not ok)


def test_changing_course_shortens_the_interval():
    """Table 1: 0-14 kn changing course, 3 1/3 s: a turning ship at 10 s is too slow."""
    mmsi = 211000010
    rows = []
    for i in range(8):  # COG turns 10 deg between reports 10 s apart
        rows += track(mmsi, 1, 10.0, 10.0, start_s=10.0 * i, cog_deg=10.0 * i,
                      lat=LAT0 + north(50.0 * i))
    q = quality(connect(rows, [static(mmsi, imo=9074729)], []), cog_tol_deg=180.0)[mmsi]
    assert q["interval_conformance"] < 0.5 and "interval" in q["checks_failed"]


@pytest.mark.parametrize(("mmsi", "msg", "kind", "valid", "mismatch"), [
    (211000001, 1, "ship", True, False),
    (2442000, 4, "coast_station", True, False),     # 00MIDXXXX base station sending 4
    (992441234, 21, "aton", True, False),           # 99MIDXXXX AtoN sending 21
    (111244123, 9, "sar_aircraft", True, False),    # 111MIDXXX SAR aircraft sending 9
    (244123456, 4, "ship", True, True),             # a ship MMSI sending base station reports
    (2442000, 1, "coast_station", True, True),      # a base station MMSI sending positions
    (123, 1, "invalid", False, False),              # not 9 digits of any pattern
    (191000000, 1, "invalid", False, False),        # MID 191: not maritime (201-775)
    (1193046, 1, "invalid", False, False),          # pyais's test MMSI
])
def test_mmsi_validity_and_kind_itu_r_m585(mmsi, msg, kind, valid, mismatch):
    if msg in (1,):
        r, o = track(mmsi, 3, 10.0, 5.0), []
    else:
        r, o = [], other(mmsi, msg, {4: "base_station", 21: "aton", 9: "sar_aircraft"}[msg])
    q = quality(connect(r, [], o))[mmsi]
    assert q["mmsi_kind"] == kind
    assert ("mmsi_invalid" in q["checks_failed"]) is (not valid)
    assert ("mmsi_kind" in q["checks_failed"].split(",")) is mismatch


@pytest.mark.parametrize(("imo", "valid"), [(9074729, True), (9074728, False),
                                            (1234567, True), (123456, False)])
def test_imo_check_digit(imo, valid):
    # 1234567: 7+12+15+16+15+12 = 77 -> 7 (valid); 123456: not 7 digits
    r = track(OK_SHIP, 3, 10.0, 5.0)
    q = quality(connect(r, [static(OK_SHIP, imo=imo)], []))[OK_SHIP]
    assert q["imo_valid"] is valid and ("imo_check_digit" in q["checks_failed"]) is not valid


def test_static_data_missing_dimensions_and_ship_type():
    a, b, c = 211000021, 211000022, 211000023
    r = track(a, 3, 10.0, 5.0) + track(b, 3, 10.0, 5.0) + track(c, 3, 10.0, 5.0)
    s = [static(b, length=None, ship_type=None)]
    q = quality(connect(r, s, []))
    assert "no_static" in q[a]["checks_failed"]
    assert {"no_dimensions", "no_ship_type"} <= set(q[b]["checks_failed"].split(","))
    assert q[c]["checks_failed"] == "no_static"


def test_a_position_jump_with_an_impossible_speed():
    r = track(OK_SHIP, 10, 10.0, 12.0)
    r[5] = {**r[5], "lat_deg": r[5]["lat_deg"] + north(5000)}  # 5 km off, then back
    q = quality(connect(r, [static(OK_SHIP, imo=9074729)], []))[OK_SHIP]
    assert q["position_jumps"] == 2 and q["max_jump_kn"] > 900
    assert "position_jump" in q["checks_failed"]
    assert q["jump_returns"] == 1 and q["two_transponders"] == 0  # one bad fix, not two units


def test_one_mmsi_from_two_transponders():
    """Two ships 30 km apart transmit one MMSI: every report jumps and comes back."""
    a = track(OK_SHIP, 12, 20.0, 10.0)
    b = track(OK_SHIP, 12, 20.0, 10.0, start_s=10.0, lat=LAT0 + north(30_000))
    q = quality(connect(a + b, [static(OK_SHIP, imo=9074729)], []))[OK_SHIP]
    assert q["jump_returns"] >= 20 and q["two_transponders"] == 1
    assert "two_transponders" in q["checks_failed"]


def test_positions_on_land_where_the_site_has_a_coastline():
    r = track(OK_SHIP, 3, 10.0, 0.0, lat=LAT0 + north(21_000), status=5)
    q = quality(connect(r, [static(OK_SHIP, imo=9074729)], []))[OK_SHIP]
    assert q["positions_on_land"] == 3 and "on_land" in q["checks_failed"]
    q = quality(connect(r, [static(OK_SHIP, imo=9074729)], []),
                geometry=SiteGeometry((("sector", "bay", SECTOR),)))[OK_SHIP]
    assert q["land_checked"] == 0 and q["positions_on_land"] == 0  # no coastline: no check


def test_sog_and_cog_against_the_track():
    fast = track(211000031, 20, 10.0, 10.0, reported_sog_kn=30.0)  # says 30 kn, makes 10
    skew = track(211000032, 20, 20.0, 10.0, reported_cog_deg=90.0)  # heads north, says east
    s = [static(211000031, imo=9074729), static(211000032, imo=9074729)]
    q = quality(connect(fast + skew, s, []))
    assert q[211000031]["sog_mismatch"] == q[211000031]["sog_checked"] == 19
    assert q[211000031]["cog_mismatch"] == 0
    assert q[211000032]["cog_mismatch"] == q[211000032]["cog_checked"] > 0
    assert q[211000032]["sog_mismatch"] == 0


def test_clock_offset_and_late_reports():
    late = track(211000041, 10, 10.0, 5.0, utc_offset_s=8.0)  # received 8 s after its second
    interp = track(211000042, 10, 10.0, 5.0, utc_offset_s=8.0,
                   time_source="interpolated:nmea:RMC")  # no reception time of its own
    s = [static(211000041, imo=9074729), static(211000042, imo=9074729)]
    q = quality(connect(late + interp, s, []))
    assert q[211000041]["late_reports"] == 10 and q[211000041]["median_clock_offset_s"] == 8.0
    assert "clock" in q[211000041]["checks_failed"]
    assert q[211000042]["clock_checked"] == 0 and "clock" not in q[211000042]["checks_failed"]


def test_synthetic_and_interpolated_times_are_not_checked_in_time():
    r = track(OK_SHIP, 10, 30.0, 12.0, time_source="none:synthetic")
    q = quality(connect(r, [static(OK_SHIP, imo=9074729)], []))[OK_SHIP]
    assert q["intervals_checked"] == 0 and q["clock_checked"] == 0 and q["sog_checked"] == 0
    # interpolated by line number: not good to a second, unless moved to its utc_second
    r = track(OK_SHIP, 10, 30.0, 12.0, time_source="interpolated:ais:base_station")
    q = quality(connect(r, [static(OK_SHIP, imo=9074729)], []))[OK_SHIP]
    assert q["intervals_checked"] == 0 and q["sog_checked"] == 0
    r = track(OK_SHIP, 10, 30.0, 12.0, time_source="interpolated:ais:base_station+utc_second")
    q = quality(connect(r, [static(OK_SHIP, imo=9074729)], []))[OK_SHIP]
    assert q["intervals_checked"] == 9 and q["interval_conformance"] == 0.0
    assert q["clock_checked"] == 0  # its reception time is not its own


def test_summary_per_site_sector_and_hour():
    r, s, o = base_case()
    r += track(123, 3, 10.0, 5.0)
    t = pl.from_arrow(run_report(connect(r, s, o), "ais_quality", start_ns=T0,
                                 end_ns=T0 + 3600 * NS, geometry=GEOMETRY))
    site = t.filter(pl.col("level") == "site").row(0, named=True)
    assert (site["transponders"], site["invalid_mmsi"], site["position_reports"]) == (2, 1, 33)
    assert site["transponders_with_problems"] == 1
    (hour,) = t.filter(pl.col("level") == "sector_hour").iter_rows(named=True)
    assert (hour["sector"], hour["hour_utc"]) == ("bay", "2026-01-15T00:00Z")
    assert t["level"].to_list()[:2] == ["site", "sector_hour"]  # summaries first
    worst = t.filter(pl.col("level") == "transponder")["mmsi"].to_list()
    assert worst == [123, OK_SHIP]  # worst transponders first


# -- ais_traffic -------------------------------------------------------------------------


def traffic(con, **kw) -> dict[tuple[str, str], dict]:
    t = pl.from_arrow(run_report(con, "ais_traffic", start_ns=T0, end_ns=T0 + 3600 * NS,
                                 geometry=GEOMETRY, **kw))
    return {(r["breakdown"], r["key"]): r for r in t.iter_rows(named=True)}


def test_traffic_per_class_type_hour_sector_and_busiest():
    r = track(OK_SHIP, 30, 10.0, 12.0) + track(244000002, 10, 30.0, 6.0, msg_type=18,
                                                ais_class="B", lon=LON0 + 2)
    s = [static(OK_SHIP, imo=9074729)]
    o = (other(2442000, 4, "base_station", n=6) + other(992441234, 21, "aton")
         + other(111244123, 9, "sar_aircraft") + other(244000002, 8, None, lat=None))
    t = traffic(connect(r, s, o))
    assert t[("total", "all")]["messages"] == 30 + 10 + 1 + 6 + 1 + 1 + 1
    assert t[("total", "all")]["vessels"] == 2 and t[("total", "all")]["static_share"] == 0.5
    assert {k: t[("class", k)]["messages"] for k in
            ("A", "B", "base_station", "aton", "sar_aircraft", "other")} == {
        "A": 31, "B": 10, "base_station": 6, "aton": 1, "sar_aircraft": 1, "other": 1}
    assert t[("msg_type", "18")]["messages"] == 10 and t[("msg_type", "05")]["messages"] == 1
    assert t[("class", "A")]["messages_per_hour"] == pytest.approx(31 / (290 / 3600), rel=1e-3)
    assert t[("hour", "2026-01-15T00:00Z")]["messages"] == 50
    assert t[("sector", "bay")]["vessels"] == 1  # the class B ship is 2 deg east of it
    assert t[("sector", "(outside sectors)")]["vessels"] == 1
    busiest = [k for (b, k) in t if b == "vessel"]
    assert busiest == [str(OK_SHIP), "244000002"] and t[("vessel", str(OK_SHIP))]["name"] == "SHIP"
    only_bay = traffic(connect(r, s, o), sector="bay")
    assert only_bay[("total", "all")]["vessels"] == 1


def test_traffic_top_n_and_synthetic_times():
    r = track(OK_SHIP, 5, 10.0, 12.0, time_source="none:synthetic") + track(
        244000003, 3, 10.0, 5.0)
    t = traffic(connect(r, [], []), params={"top_n": 1})
    assert [k for (b, k) in t if b == "vessel"] == [str(OK_SHIP)]
    assert t[("total", "all")]["synthetic_messages"] == 5
    assert t[("time_source", "none:synthetic")]["messages_per_hour"] is None
    assert t[("hour", "2026-01-15T00:00Z")]["messages"] == 3  # synthetic rows have no hour
