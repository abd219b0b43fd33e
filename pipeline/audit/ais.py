"""The audit's AIS sections (issue 36) and its one channel-fault timeline of every
family: report rows in, figures and HTML out; nothing here reads the warehouse.

- **AIS traffic** (``ais_traffic``): messages per station class and per hour, vessels and
  the share of them with static data;
- **AIS quality** (``ais_quality``): the transponders failing most checks first, the
  checks' counts, and reporting-interval conformance per sector and hour;
- **channel faults** (``channel_fault_episodes``, ``fault_timeline``): every family's
  episodes on one time axis: radars and AIS transponders (maritime integrity), own-ship
  GNSS, airfield channels.
"""

from __future__ import annotations

import html
from datetime import datetime, timedelta
from typing import Any

import plotly.graph_objects as go

from pipeline.audit.charts import AIS, SOURCE_COLOURS, _dt, _layout

CLASS_ORDER = ("A", "B", "base_station", "aton", "sar_aircraft", "other")
CLASS_LABELS = {"A": "class A", "B": "class B", "base_station": "base station",
                "aton": "AtoN", "sar_aircraft": "SAR aircraft", "other": "other messages"}
CLASS_COLOURS = {"A": "#1f4e9c", "B": "#2a9d3a", "base_station": "#8c564b",
                 "aton": "#e07b00", "sar_aircraft": "#c0392b", "other": AIS}
CHECKS = {  # checks_failed code -> what a person reads
    "mmsi_invalid": "MMSI of no ITU-R M.585 pattern",
    "mmsi_kind": "MMSI kind does not fit its messages",
    "imo_check_digit": "IMO check digit wrong",
    "no_static": "no static data",
    "no_dimensions": "no dimensions",
    "no_ship_type": "no ship type",
    "interval": "reporting interval (M.1371 Tables 1-2)",
    "position_jump": "impossible position jump",
    "on_land": "position on land",
    "sog_track": "SOG against the track",
    "cog_track": "COG against the track",
    "two_transponders": "one MMSI, two transponders",
    "clock": "reception vs its own second",
}
WORST_SHOWN = 15
LANES_SHOWN = 32
KIND_COLOURS = {"radar": "#1f4e9c", "ais": "#e07b00", "gnss": "#2a9d3a", "smr": "#8e44ad",
                "mlat": "#c0392b", "vasn": "#17becf"}


KIND_ORDER = ("radar", "ais", "gnss", "smr", "mlat", "vasn")


def _hour_label(key: str) -> str:
    """``2026-01-15T00:00Z`` -> ``2026-01-15 00-01 h``: an hour as a category (a date
    axis draws a single hour as milliseconds around it)."""
    t = datetime.strptime(key, "%Y-%m-%dT%H:00Z")
    return f"{t:%Y-%m-%d} {t.hour:02d}-{t.hour + 1:02d} h"


def traffic_figures(rows: list[dict[str, Any]]) -> list[go.Figure]:
    """Messages per station class (bars, vessels and static share in the hover) and per
    hour (bars one hour wide), each site apart."""
    if not rows:
        return []
    figs = []
    sites = sorted({r["site"] for r in rows})
    fig = go.Figure()
    for site in sites:
        cls = {r["key"]: r for r in rows if r["site"] == site and r["breakdown"] == "class"}
        keys = [k for k in CLASS_ORDER if k in cls]
        fig.add_bar(x=[CLASS_LABELS[k] if len(sites) == 1 else f"{site}: {CLASS_LABELS[k]}"
                       for k in keys],
                    y=[cls[k]["messages"] for k in keys],
                    marker_color=[CLASS_COLOURS[k] for k in keys], name=site,
                    customdata=[[cls[k]["stations"], cls[k]["static_share"],
                                 cls[k]["messages_per_hour"]] for k in keys],
                    hovertemplate="%{x}: %{y} messages from %{customdata[0]} stations, "
                                  "%{customdata[2]}/h; static data from %{customdata[1]} of "
                                  "the vessels<extra></extra>")
    total = {r["site"]: r for r in rows if r["breakdown"] == "total"}
    note = "; ".join(f"{s}: {t['vessels']} vessels, {t['messages']} messages, static data "
                     f"from {_share(t['static_share'])} of the vessels" for s, t in total.items())
    figs.append(_layout(fig, f"AIS messages per station class ({note})", height=360,
                        yaxis_title="messages", showlegend=len(sites) > 1))
    hours = [r for r in rows if r["breakdown"] == "hour"]
    if hours:
        fig = go.Figure()
        for i, site in enumerate(sites):
            sel = [r for r in hours if r["site"] == site]
            fig.add_bar(x=[_hour_label(r["key"]) for r in sel],
                        y=[r["messages"] for r in sel], name=site,
                        marker_color=SOURCE_COLOURS[i % len(SOURCE_COLOURS)],
                        customdata=[[r["vessels"], r["stations"]] for r in sel],
                        hovertemplate="%{x} UTC: %{y} messages, "
                                      "%{customdata[0]} vessels, %{customdata[1]} "
                                      "stations<extra></extra>")
        fig = _layout(fig, "AIS messages per hour (UTC)", height=300, yaxis_title="messages",
                      xaxis_title="hour, UTC", showlegend=len(sites) > 1, barmode="group")
        figs.append(fig)
    return figs


def _share(v: float | None) -> str:
    return "–" if v is None else f"{v:.0%}"


def quality_figures(rows: list[dict[str, Any]]) -> list[go.Figure]:
    """Transponders failing each check (bars) and interval conformance per sector and
    hour (lines)."""
    tps = [r for r in rows if r["level"] == "transponder"]
    if not tps:
        return []
    counts = {c: sum(1 for r in tps if c in (r["checks_failed"] or "").split(","))
              for c in CHECKS}
    fig = go.Figure()
    fig.add_bar(y=[CHECKS[c] for c in CHECKS][::-1], x=[counts[c] for c in CHECKS][::-1],
                orientation="h", marker_color="#c0392b",
                hovertemplate="%{y}: %{x} transponders<extra></extra>")
    fig = _layout(fig, f"Transponders failing each check (of {len(tps)})",
                  height=120 + 26 * len(CHECKS), xaxis_title="transponders")
    fig.update_xaxes(tickformat="d", dtick=1 if max(counts.values()) <= 10 else None)
    figs = [fig]
    hours = [r for r in rows if r["level"] == "sector_hour" and r["hour_utc"]
             and r["interval_conformance"] is not None]
    if hours:
        fig = go.Figure()
        sectors = sorted({r["sector"] for r in hours})
        for i, sector in enumerate(sectors):
            sel = sorted((r for r in hours if r["sector"] == sector), key=lambda r: r["hour_utc"])
            fig.add_bar(x=[_hour_label(r["hour_utc"]) for r in sel],
                        y=[r["interval_conformance"] for r in sel], name=sector,
                        marker_color=SOURCE_COLOURS[i % len(SOURCE_COLOURS)],
                        customdata=[[r["intervals_checked"], r["position_jumps"],
                                     r["late_reports"]] for r in sel],
                        hovertemplate=f"{html.escape(sector)}: %{{y:.1%}} of "
                                      "%{customdata[0]} intervals; %{customdata[1]} jumps, "
                                      "%{customdata[2]} late<extra></extra>")
        fig = _layout(fig, "Reporting-interval conformance per sector and hour "
                           "(ITU-R M.1371-5 Annex 1 Tables 1-2)", height=320, barmode="group",
                      xaxis_title="hour, UTC", yaxis_title="within the nominal interval")
        fig.update_yaxes(range=[0, 1.02], tickformat=".0%")
        figs.append(fig)
    return figs


def worst_table(rows: list[dict[str, Any]], n: int = WORST_SHOWN) -> str:
    """The ``n`` transponders failing most checks (the report's order: worst first)."""
    tps = [r for r in rows if r["level"] == "transponder" and (r["problems"] or 0) > 0][:n]
    if not tps:
        return ""
    def num(v: Any, fmt: str = "{}") -> str:
        return "–" if v is None else fmt.format(v)

    head = ("<tr><th>site</th><th>MMSI</th><th>name</th><th>kind</th><th>class</th>"
            "<th>reports</th><th>interval ok</th><th>jumps</th><th>on land</th>"
            "<th>clock offset, s</th><th>late</th><th>checks failed</th></tr>")
    body = []
    for r in tps:
        failed = ", ".join(CHECKS.get(c, c) for c in (r["checks_failed"] or "").split(",") if c)
        body.append(
            "<tr>"
            f"<td>{html.escape(r['site'])}</td><td class='num'>{r['mmsi']}</td>"
            f"<td>{html.escape(r['name'] or '')}</td><td>{html.escape(r['mmsi_kind'] or '')}</td>"
            f"<td>{html.escape(r['ais_class'] or '')}</td>"
            f"<td class='num'>{r['position_reports']}</td>"
            f"<td class='num'>{num(r['interval_conformance'], '{:.0%}')}</td>"
            f"<td class='num'>{r['position_jumps']}</td>"
            f"<td class='num'>{num(r['positions_on_land'] if r['land_checked'] else None)}</td>"
            f"<td class='num'>{num(r['median_clock_offset_s'])}</td>"
            f"<td class='num'>{r['late_reports']}</td>"
            f"<td><span class='badge fail'>{r['problems']}</span> {html.escape(failed)}</td>"
            "</tr>")
    more = sum(1 for r in rows if r["level"] == "transponder" and (r["problems"] or 0) > 0)
    caption = (f"<p class='caption'>Worst transponders first: {len(tps)} of {more} with a "
               "failed check (<code>surveil report ais_quality</code> lists every one).</p>")
    return (caption + "<table class='verdicts'><thead>" + head + "</thead><tbody>"
            + "".join(body) + "</tbody></table>")


def episode_timeline(episodes: list[dict[str, Any]], outages: list[dict[str, Any]],
                     start_ns: int, end_ns: int) -> go.Figure | None:
    """Every family's channel-fault episodes on one time axis: radars and AIS
    transponders (``channel_fault_episodes``, maritime), own-ship GNSS (its exclusions
    and ``fault_timeline``'s outages), airfield channels. One lane per channel, coloured
    by sensor kind; the longest-faulted lanes when there are more than
    :data:`LANES_SHOWN`."""
    bars = [(f"{e['sensor_kind'].upper()} {e['channel']}", e["sensor_kind"],
             f"{e['family']} {e['sensor_kind']} excluded ({e['checks'] or 'integrity'})",
             _dt(e["start_ns"]), e["duration_s"], e["sector"]) for e in episodes]
    bars += [(o["lane"], "gnss", o["kind"], o["start_utc"], o["duration_s"], "")
             for o in outages if o["lane"].startswith("GNSS")]
    if not bars:
        return None
    per_lane: dict[str, float] = {}
    for lane, *_rest, dur, _sec in bars:
        per_lane[lane] = per_lane.get(lane, 0.0) + dur
    # every radar, GNSS and airfield channel; the AIS transponders longest excluded first
    kind_of = {b[0]: b[1] for b in bars}
    fixed = [k for k in per_lane if kind_of[k] != "ais"]
    ais = sorted((k for k in per_lane if kind_of[k] == "ais"), key=lambda k: (-per_lane[k], k))
    lanes = fixed + ais[:max(0, LANES_SHOWN - len(fixed))]
    fig = go.Figure()
    for kind in sorted({b[1] for b in bars}):
        sel = [b for b in bars if b[1] == kind and b[0] in lanes]
        if not sel:
            continue
        fig.add_bar(y=[b[0] for b in sel], x=[max(b[4], 5.0) * 1000 for b in sel],
                    base=[b[3] for b in sel], orientation="h", name=kind,
                    marker_color=KIND_COLOURS.get(kind, AIS),
                    customdata=[[b[2], f"{b[3]:%H:%M:%S}", b[4], b[5]] for b in sel],
                    hovertemplate="%{y}: %{customdata[0]} from %{customdata[1]} UTC for "
                                  "%{customdata[2]} s %{customdata[3]}<extra></extra>")
    hidden = len(per_lane) - len(lanes)
    title = "Channel faults of every family: radar, AIS, GNSS, airfield" + (
        f" ({hidden} more channels in channel_fault_episodes)" if hidden else "")
    fig = _layout(fig, title, height=160 + 26 * len(lanes), barmode="overlay",
                  xaxis_title="time, UTC")
    fig.update_xaxes(type="date", range=_span(bars, start_ns, end_ns))
    rank = {k: i for i, k in enumerate(KIND_ORDER)}
    order = sorted(lanes, key=lambda k: (rank.get(kind_of[k], len(rank)), -per_lane[k], k))
    fig.update_yaxes(categoryorder="array", categoryarray=order[::-1], automargin=True)
    return fig


def _span(bars: list[tuple], start_ns: int, end_ns: int) -> list[datetime]:
    """The window, or the stretch of it the episodes cover (5 % margin, >= 30 s) when
    they fill less than a tenth of it: a minute of faults in an hour stays readable."""
    lo, hi = _dt(start_ns), _dt(end_ns)
    first = min(b[3] for b in bars)
    last = max(b[3] + timedelta(seconds=max(b[4], 5.0)) for b in bars)
    if (last - first) * 10 >= hi - lo:
        return [lo, hi]
    pad = max((last - first) * 0.05, timedelta(seconds=30))
    return [max(lo, first - pad), min(hi, last + pad)]

