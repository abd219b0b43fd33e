"""One self-contained HTML page per audit: verdicts first, then a section per question,
each chart from a named report (``surveil report NAME`` prints the same rows).

plotly.js is embedded once in the page's head, so the file opens without a network; the
page records script errors in ``data-js-errors`` on ``<html>`` and the number of charts
drawn in ``data-charts-drawn`` (the browser test reads both).
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from typing import Any

import plotly.graph_objects as go
from plotly.offline import get_plotlyjs

from pipeline.audit import ais as ais_audit
from pipeline.audit import charts
from pipeline.audit import evaluation_charts as ev
from pipeline.audit.data import AuditData
from pipeline.requirements import (
    FAIL,
    NOT_APPLICABLE,
    NOT_ENOUGH,
    PASS,
    Verdict,
    requirements_config,
)


@dataclass(frozen=True)
class Section:
    """One question of the audit: its charts (from reports) or why there are none."""

    anchor: str
    title: str
    caption: str
    reports: tuple[str, ...]
    figures: tuple[go.Figure, ...]
    empty_note: str = ""
    html: str = ""
    """A table (or other HTML) shown after the figures."""


def _iso(t_ns: int) -> str:
    return datetime.fromtimestamp(t_ns / 1e9, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def sections(data: AuditData) -> list[Section]:
    """Every section of the page, in reading order."""
    req = requirements_config(data.cfg)
    rows = data.rows
    out: list[Section] = []

    def add(anchor: str, title: str, caption: str, reports: tuple[str, ...],
            *figs: go.Figure | None, table: str = "") -> None:
        kept = tuple(f for f in figs if f is not None)
        note = "" if kept or table else "; ".join(
            f"{r}: {data.empty_reasons[r]}" for r in reports if r in data.empty_reasons
        ) or "no rows to draw"
        out.append(Section(anchor, title, caption, reports, kept, note, table))

    add("map", "Map of the window",
        "Fused system tracks, each radar's synchronised tracks (click them in the legend), AIS "
        "positions and airfield surface tracks over the configured sectors, fairway legs, "
        "coastline ([gaps] admissible area and islands) and airfield areas; red circles are "
        "the 90% regions of the data-gap forecasts.",
        ("map_tracks", "gap_forecasts"),
        charts.maritime_map(data.cfg, rows("map_tracks"), rows("gap_forecasts"))
        if data.reports["map_tracks"].num_rows or data.reports["gap_forecasts"].num_rows
        else None)
    add("accuracy", "Position accuracy per sector",
        "95th percentile of the horizontal error against the reference (simulated truth, "
        "else the reconstructed reference: each AIS vessel's smoothed trajectory; hover for "
        "the reference's own 95% error), per sector, fused and per radar.",
        ("accuracy_by_sector",), charts.accuracy_bars(rows("accuracy_by_sector"), req))
    add("error-time", "Error over time", "95th percentile of the error per minute.",
        ("accuracy_over_time",), charts.error_over_time(rows("accuracy_over_time"), req))
    add("identification", "Identification",
        "Share of fused track time with the right MMSI, a wrong one or none, per sector and "
        "class of vessel.", ("identification_by_sector",),
        charts.identification_bars(rows("identification_by_sector"), req))
    _ais_sections(add, rows)
    add("siap", "SIAP", "Single Integrated Air Picture measures of the fused tracks against "
        "truth (simulated logs), else against the reconstructed references of the vessels "
        "carrying AIS, per sector and for all sectors.", ("siap_by_sector",),
        charts.siap_bars(rows("siap_by_sector"), req))
    add("cross-track", "Cross-track error along the fairway",
        "Multi-radar paper, figures 1-2: the 60-s RMS error of the cross-track deviation along "
        "each leg, each radar's own (partial) track against the fused one.",
        ("cross_track_along_leg", "cross_track_by_leg"),
        charts.cross_track_along(rows("cross_track_along_leg"), req))
    add("coverage", "Detection and coverage map per radar",
        "Probability of detection from update intervals (OpenATS COMPASS's definition): scans "
        "expected while a referenced target was in the radar's range, and those with an update; "
        "per radar and sector, and per range/azimuth cell (blind sectors and range holes are "
        "the red cells). Against simulated truth, else the reconstructed references of the "
        "vessels carrying AIS.", ("detection_by_sector", "radar_coverage"),
        ev.detection_bars(rows("detection_by_sector"), req),
        ev.coverage_maps(rows("radar_coverage"), req))
    add("continuity", "Track continuity",
        "Gaps in each referenced target's fused track, track number changes (breaks) per hour, "
        "extra tracks on one target, swaps of two targets' tracks (IALA G1111: none); "
        "tracks without any reference (false, or ships without AIS) and reference-free "
        "dubious tracks are in the reports false_tracks and dubious_tracks.",
        ("track_continuity", "false_tracks", "dubious_tracks"),
        ev.continuity_bars(rows("track_continuity"), req))
    add("latency", "Latency",
        "How late each radar's (and the fused) positions are: −along-track error ÷ speed "
        "(a clock offset, a late time stamp or a slow tracker), with 95% intervals.",
        ("latency_by_sensor",), ev.latency_bars(rows("latency_by_sensor")))
    add("decomposition", "Error decomposition",
        "Position error along and across the reference's course, and each radar's range and "
        "azimuth error from its site, beside the IMO MSC.192(79) figures (95% of ranges "
        "within 50 m or 1% of range, bearings within 2°).", ("error_decomposition",),
        ev.decomposition_bars(rows("error_decomposition"), req))
    add("drilldown", "Per-target drill-down",
        "The referenced targets that cost the accuracy and detection verdicts most, worst "
        "first (target_drilldown), and the worst five on the map: reference track and fused "
        "points coloured by their error.", ("target_drilldown", "target_points"),
        ev.drilldown_map(rows("target_points")), table=ev.drilldown_table(
            rows("target_drilldown")))
    add("bias", "Radar registration bias",
        "Range bias, range gain, azimuth bias and time offset of each site estimated from AIS, "
        "with 95% intervals.",
        ("radar_bias_by_site",), charts.radar_bias(rows("radar_bias_by_site")))
    add("registration", "Online registration and estimated accuracy",
        "Each radar's range bias, azimuth bias, clock offset and range gain as the batch "
        "estimated them "
        "from AIS ships and radar overlap (95% interval as a band; large markers: the minutes "
        "the estimate was removed from the reports before fusion), the factors its stated "
        "range, azimuth and speed or course variances were found too small by for minutes "
        "on end and tracked "
        "on (1: as stated) and the variance scale on top of them (1: the stated or so scaled "
        "sigmas). Where a site's sectors differ, "
        "each sector registered on its own has a dashed line of the site's colour.",
        ("registration_over_time", "sensor_registration"),
        charts.registration_over_time(rows("registration_over_time"), data.start_ns,
                                      data.end_ns))
    add("airfield", "Airfield surface accuracy (ED-87)",
        "95th percentile of each channel's and the fused tracks' error per ED-87 area class, "
        "with the area's limit (red bars) and the sensor level (dashed).",
        ("surface_accuracy_by_area", "map_tracks"),
        charts.surface_accuracy_bars(rows("surface_accuracy_by_area"), req),
        charts.airfield_map(data.cfg, rows("map_tracks")))
    add("faults", "Channel faults",
        "Every family's channel-fault episodes on one timeline: radars and AIS transponders "
        "excluded by the maritime integrity checks, own-ship GNSS exclusions and outages, "
        "airfield channels excluded (at least half of their targets).",
        ("channel_fault_episodes", "fault_timeline", "channel_faults_by_sector"),
        ais_audit.episode_timeline(rows("channel_fault_episodes"), rows("fault_timeline"),
                                   data.start_ns, data.end_ns))
    add("heading", "Own-ship heading error",
        "Gyro/GNSS/log paper: the gyrocompass alone against the integrated solution.",
        ("nav_heading_error", "nav_quality"), charts.heading_error(rows("nav_heading_error")))
    add("gaps", "Data-gap forecasts",
        "Particle-filter forecasts of silent ships: error of the forecast mean against the "
        "reference and the radius of the 90% region (regions on the map).",
        ("gap_forecasts", "gap_forecast_calibration"), charts.gap_errors(rows("gap_forecasts")))
    return out


def _ais_sections(add: Any, rows: Any) -> None:
    """The AIS traffic and quality sections (:mod:`pipeline.audit.ais`)."""
    add("ais-traffic", "AIS traffic",
        "Vessels, messages and message rate per station class (from the message type: class "
        "A, class B, base station, AtoN, SAR aircraft) and per hour; the share of vessels "
        "that sent static data.", ("ais_traffic",),
        *ais_audit.traffic_figures(rows("ais_traffic")))
    quality = rows("ais_quality")
    add("ais-quality", "AIS quality",
        "Each transponder's checks (reporting interval against ITU-R M.1371-5 Annex 1 "
        "Tables 1-2, MMSI and IMO validity, static data, position jumps, positions on land, "
        "SOG/COG against the track, one MMSI from two transponders, clock offset and late "
        "reports), worst transponders first.", ("ais_quality",),
        *ais_audit.quality_figures(quality), table=ais_audit.worst_table(quality))


_CSS = """
body { font-family: 'DejaVu Sans', Arial, sans-serif; margin: 0 auto; max-width: 1280px;
       padding: 0 24px 40px; color: #222; }
h1 { font-size: 22px; margin: 20px 0 4px; } h2 { font-size: 18px; margin: 28px 0 4px;
     border-bottom: 1px solid #ddd; padding-bottom: 4px; }
.meta { color: #555; font-size: 13px; }
.caption { color: #444; font-size: 13px; margin: 4px 0 8px; }
.src { color: #777; font-size: 12px; } code { background: #f4f4f4; padding: 0 3px; }
.empty { background: #fff8e5; border: 1px solid #f0d48a; padding: 10px 12px; font-size: 13px; }
table.verdicts { border-collapse: collapse; font-size: 13px; width: 100%; }
table.verdicts th, table.verdicts td { border-bottom: 1px solid #e5e5e5; padding: 4px 8px;
     text-align: left; vertical-align: top; }
table.verdicts td.num { text-align: right; font-variant-numeric: tabular-nums;
     white-space: nowrap; }
.badge { display: inline-block; padding: 1px 8px; border-radius: 10px; font-weight: bold;
         font-size: 12px; white-space: nowrap; }
.pass { background: #d9f2dd; color: #1d6b2a; } .fail { background: #f8d7d3; color: #9b2316; }
.nes { background: #eee; color: #555; }
.why { color: #666; font-size: 11px; max-width: 280px; margin-top: 2px; }
.summary span { margin-right: 14px; } nav a { margin-right: 10px; font-size: 13px; }
.chart { margin: 6px 0 14px; break-inside: avoid; }
@page { size: A4; margin: 12mm; }
@media print { body { max-width: none; padding: 0; } nav, .modebar { display: none !important; }
               h2, .caption { break-after: avoid; } tr { break-inside: avoid; } }
"""

_ERRORS_JS = """
window.__auditErrors = [];
function __recordError(msg) {
  window.__auditErrors.push(String(msg));
  document.documentElement.setAttribute('data-js-errors', JSON.stringify(window.__auditErrors));
}
window.addEventListener('error', function (e) { __recordError(e.message || e); });
window.addEventListener('unhandledrejection', function (e) { __recordError(e.reason); });
"""

_DRAWN_JS = """
Promise.all(Array.from(document.querySelectorAll('.chart > div')).map(function (d) {
  return new Promise(function (resolve) {
    if (d.querySelector('.main-svg')) { resolve(); return; }
    d.on ? d.on('plotly_afterplot', resolve) : resolve();
    setTimeout(resolve, 8000);
  });
})).then(function () {
  var n = document.querySelectorAll('.chart .main-svg').length ? Array.from(
    document.querySelectorAll('.chart > div')).filter(function (d) {
      return d.querySelector('.main-svg'); }).length : 0;
  document.documentElement.setAttribute('data-charts-drawn', String(n));
});
"""


def _badge(status: str, outcome: str | None = None) -> str:
    cls = {PASS: "pass", FAIL: "fail", NOT_ENOUGH: "nes", NOT_APPLICABLE: "nes"}[outcome or status]
    return f'<span class="badge {cls}">{html.escape(status)}</span>'


def _verdict_cell(v: Verdict) -> str:
    """The verdict's badge, its reason (after "status: ") below it in small text: a
    sentence in a badge that does not wrap squeezed the table's other columns."""
    label, _, why = v.status.partition(": ")
    why_html = f'<div class="why">{html.escape(why)}</div>' if why else ""
    return _badge(label, v.outcome) + why_html


def _fmt(v: float | None, unit: str) -> str:
    if v is None:
        return "–"
    text = f"{v:.4f}".rstrip("0").rstrip(".") if abs(v) < 10 else f"{v:.1f}"
    return f"{text} {unit}".strip()


def verdict_table(verdicts: list[Verdict] | tuple[Verdict, ...]) -> str:
    counts = {s: sum(v.outcome == s for v in verdicts)
              for s in (PASS, FAIL, NOT_ENOUGH, NOT_APPLICABLE)}
    head = ('<p class="summary">' + "".join(f"<span>{_badge(s)} {n}</span>"
                                           for s, n in counts.items()) + "</p>")
    body = []
    order = {FAIL: 0, PASS: 1, NOT_ENOUGH: 2, NOT_APPLICABLE: 3}
    for v in sorted(verdicts, key=lambda v: order[v.outcome]):
        body.append(
            "<tr>"
            f"<td>{_verdict_cell(v)}</td><td>{html.escape(v.requirement)}</td>"
            f"<td>{html.escape(v.scope)}</td>"
            f'<td class="num">{_fmt(v.value, v.unit)}</td>'
            f'<td class="num">{html.escape(v.comparison)} {_fmt(v.limit, v.unit)}</td>'
            f'<td class="num">{v.samples:,} (min {v.min_samples:,})</td>'
            f'<td><code>{html.escape(v.report)}</code>.{html.escape(v.metric)}</td>'
            "</tr>")
    return (head + '<table class="verdicts"><thead><tr><th>verdict</th><th>requirement</th>'
            "<th>scope</th><th>value</th><th>limit</th><th>samples</th><th>from report</th>"
            "</tr></thead><tbody>" + "".join(body) + "</tbody></table>")


def render(data: AuditData, *, title: str = "") -> str:
    """The whole page as one HTML string (plotly.js inlined)."""
    secs = sections(data)
    try:
        pkg_version = version("surveil-pipeline")
    except PackageNotFoundError:
        pkg_version = "dev"
    window = f"[{_iso(data.start_ns)}, {_iso(data.end_ns)})"
    title = title or f"surveil audit {window}"
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title>",
        f"<script>{_ERRORS_JS}</script>",
        f"<script>{get_plotlyjs()}</script>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        f'<p class="meta">window {window}, sector {html.escape(data.sector or "all")} · '
        f"config <code>{html.escape(data.cfg.source or '(built in)')}</code> · warehouse "
        f"<code>{html.escape(str(data.warehouse))}</code> · surveil {pkg_version} · written "
        f"{datetime.now(UTC):%Y-%m-%d %H:%M} UTC</p>",
        *(f'<p class="meta provenance">{html.escape(line)}</p>' for line in data.provenance),
        *(f'<div class="empty provenance-warning">Warning: {html.escape(line)}</div>'
          for line in data.provenance_warnings),
        "<nav>" + "".join(f'<a href="#{s.anchor}">{html.escape(s.title)}</a>' for s in secs)
        + "</nav>",
        "<h2 id='verdicts'>Requirements</h2>",
        '<p class="caption">Each requirement of the config\'s <code>[requirements]</code> on '
        "every row it applies to; fewer samples than the minimum gives no pass or fail.</p>",
        verdict_table(data.verdicts),
    ]
    n = 0
    for s in secs:
        parts.append(f"<h2 id='{s.anchor}'>{html.escape(s.title)}</h2>")
        parts.append(f'<p class="caption">{html.escape(s.caption)} '
                     f'<span class="src">From: {", ".join(f"<code>{r}</code>" for r in s.reports)}'
                     "</span></p>")
        if not s.figures and not s.html:
            parts.append(f'<div class="empty">No data to draw. {html.escape(s.empty_note)}</div>')
        for fig in s.figures:
            n += 1
            div = fig.to_html(full_html=False, include_plotlyjs=False, div_id=f"chart-{n}",
                              config={"displaylogo": False, "responsive": True})
            parts.append(f'<div class="chart" data-chart="{s.anchor}">{div}</div>')
        if s.html:
            parts.append(s.html)
    parts.append(f"<script>{_DRAWN_JS}</script>")
    parts.append(f"<script type='application/json' id='audit-meta'>"
                 f"{script_json({'charts': n, 'window': window, 'sector': data.sector})}"
                 "</script></body></html>")
    return "\n".join(parts)


def script_json(value: object) -> str:
    """``value`` as JSON that stays inside a ``<script>`` element: ``<``, ``>`` and ``&``
    as ``\\u`` escapes (a sector named ``</script><script>...`` is text, not markup);
    ``json.loads`` reads it back unchanged."""
    text = json.dumps(value)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def chart_count(page: str) -> int:
    """Charts a rendered page holds (from its metadata block)."""
    start = page.index("id='audit-meta'>") + len("id='audit-meta'>")
    return int(json.loads(page[start:page.index("</script>", start)])["charts"])
