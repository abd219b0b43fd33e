"""The audit's AIS sections and its one channel-fault timeline of every family (issue 36),
from literal report rows: what a person reads is there, worst transponders first."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import duckdb
import polars as pl

from pipeline.audit import ais as ais_audit
from pipeline.audit.data import AUDIT_REPORTS, AuditData
from pipeline.audit.page import render, sections
from pipeline.families import load_config
from pipeline.reports import load_report, run_report
from pipeline.tables import empty, table_specs

NS = 1_000_000_000
T0 = 1_768_435_200 * NS  # 2026-01-15 00:00 UTC


def traffic_rows() -> list[dict]:
    base = {"site": "port", "name": None, "static_share": None, "synthetic_messages": 0,
            "first_utc": None, "last_utc": None, "messages_per_hour": 10.0}
    return [
        {**base, "breakdown": "total", "key": "all", "vessels": 3, "stations": 5,
         "messages": 120, "static_share": 0.667},
        {**base, "breakdown": "class", "key": "A", "vessels": 2, "stations": 2, "messages": 90},
        {**base, "breakdown": "class", "key": "B", "vessels": 1, "stations": 1, "messages": 20},
        {**base, "breakdown": "class", "key": "base_station", "vessels": 0, "stations": 1,
         "messages": 8},
        {**base, "breakdown": "class", "key": "aton", "vessels": 0, "stations": 1, "messages": 2},
        {**base, "breakdown": "hour", "key": "2026-01-15T00:00Z", "vessels": 3, "stations": 5,
         "messages": 120},
    ]


def quality_rows() -> list[dict]:
    cols = [f.name for f in _columns("ais_quality")]
    empty = dict.fromkeys(cols)

    def tp(mmsi: int, failed: str, name: str) -> dict:
        n = len(failed.split(",")) if failed else 0
        return {**empty, "site": "port", "level": "transponder", "mmsi": mmsi, "name": name,
                "mmsi_kind": "ship", "ais_class": "A", "problems": n, "checks_failed": failed,
                "position_reports": 10, "interval_conformance": 0.5, "position_jumps": 1,
                "land_checked": 10, "positions_on_land": 0, "median_clock_offset_s": 0.4,
                "late_reports": 0}

    return [
        {**empty, "site": "port", "level": "site", "transponders": 3},
        {**empty, "site": "port", "level": "sector_hour", "sector": "bay",
         "hour_utc": "2026-01-15T00:00Z", "interval_conformance": 0.8, "intervals_checked": 50,
         "position_jumps": 1, "late_reports": 0},
        tp(244000001, "position_jump,two_transponders,clock", "<TWIN>"),
        tp(244000002, "interval", "SLOW"),
        tp(244000003, "", "FINE"),
    ]


def _columns(report: str):
    return _empty(report).schema


def episodes() -> list[dict]:
    def ep(family: str, kind: str, channel: str, start_s: float, dur: float) -> dict:
        return {"site": "port", "family": family, "sector": "bay", "sensor_kind": kind,
                "channel": channel, "start_ns": T0 + round(start_s * NS),
                "duration_s": dur, "checks": "nis"}

    return [ep("maritime", "radar", "R1", 600, 120), ep("maritime", "ais", "244000001", 900, 60),
            ep("nav", "gnss", "ownship", 1200, 30), ep("airfield", "mlat", "MLAT1", 1500, 40)]


def test_traffic_figures_name_every_station_class():
    figs = ais_audit.traffic_figures(traffic_rows())
    assert len(figs) == 2
    assert list(figs[0].data[0].x) == ["class A", "class B", "base station", "AtoN"]
    assert "3 vessels, 120 messages, static data from 67% of the vessels" in \
        figs[0].layout.title.text
    assert list(figs[1].data[0].x) == ["2026-01-15 00-01 h"]


def test_quality_lists_the_worst_transponders_first():
    rows = quality_rows()
    table = ais_audit.worst_table(rows)
    assert table.index("244000001") < table.index("244000002")
    assert "244000003" not in table  # no failed check: not listed
    assert "&lt;TWIN&gt;" in table and "<TWIN>" not in table
    assert "one MMSI, two transponders" in table
    bars, conformance = ais_audit.quality_figures(rows)
    counts = dict(zip(bars.data[0].y, bars.data[0].x, strict=True))
    assert counts["impossible position jump"] == 1 and counts["no static data"] == 0
    assert list(conformance.data[0].y) == [0.8]


def test_one_timeline_for_every_family():
    outages = [{"site": "port", "lane": "GNSS ownship", "kind": "gnss outage (emergency)",
                "start_utc": datetime(2026, 1, 15, 0, 30), "end_utc": None, "duration_s": 60.0}]
    fig = ais_audit.episode_timeline(episodes(), outages, T0, T0 + 3600 * NS)
    lanes = list(fig.layout.yaxis.categoryarray)[::-1]  # top to bottom
    assert lanes == ["RADAR R1", "AIS 244000001", "GNSS ownship", "MLAT MLAT1"]
    kinds = {t.name for t in fig.data}
    assert kinds == {"radar", "ais", "gnss", "mlat"}


def test_the_page_has_the_ais_sections_and_the_timeline(tmp_path):
    data = AuditData(
        cfg=load_config(), warehouse=Path(tmp_path), start_ns=T0, end_ns=T0 + 3600 * NS,
        sector=None, empty_reasons={}, verdicts=(),
        reports={**{n: _empty(n) for n in AUDIT_REPORTS},
                 "ais_traffic": pl.DataFrame(traffic_rows()).to_arrow(),
                 "ais_quality": pl.DataFrame(quality_rows(), infer_schema_length=None).to_arrow(),
                 "channel_fault_episodes": pl.DataFrame(episodes()).to_arrow()},
    )
    secs = {s.anchor: s for s in sections(data)}
    assert len(secs["ais-traffic"].figures) == 2
    assert len(secs["ais-quality"].figures) == 2 and "244000001" in secs["ais-quality"].html
    assert secs["faults"].reports[0] == "channel_fault_episodes"
    assert len(secs["faults"].figures) == 1
    page = render(data)
    assert "id='ais-traffic'" in page and "id='ais-quality'" in page
    assert page.index("id='ais-quality'") < page.index("id='faults'")


def _empty(name: str):
    """Report ``name`` on an empty warehouse: its columns, no rows."""
    con = duckdb.connect()
    for t in table_specs():
        con.register(t, empty(t))
    return run_report(con, load_report(name), start_ns=0, end_ns=1,
                      params={"step_s": 20.0} if name == "map_tracks" else None)
