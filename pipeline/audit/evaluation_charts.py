"""The audit's charts of evaluation without truth (issue 37): a coverage map per radar,
continuity, latency, the error decomposition and the per-target drill-down. Report rows
in, a plotly figure out (``None`` without rows), like :mod:`pipeline.audit.charts`."""

from __future__ import annotations

import math
from itertools import pairwise
from typing import Any

import plotly.graph_objects as go
from plotly.subplots import make_subplots

from pipeline.audit.charts import FUSED, SOURCE_COLOURS, _layout, _limit_line, source_colour
from pipeline.requirements import RequirementsConfig


def _reference_note(rows: list[dict[str, Any]]) -> str:
    kinds = sorted({str(r.get("reference")) for r in rows if r.get("reference")})
    return " vs " + " / ".join(kinds) if kinds else ""


def coverage_maps(rows: list[dict[str, Any]], req: RequirementsConfig) -> go.Figure | None:
    """PD per range/azimuth cell of each radar, as a polar heat map (blind sectors and
    range holes are the pale cells; red outline: below the VTS detection figure)."""
    rows = [r for r in rows if r["expected_scans"]]
    if not rows:
        return None
    radars = sorted({r["radar"] for r in rows})
    fig = make_subplots(rows=1, cols=len(radars), specs=[[{"type": "polar"}] * len(radars)],
                        subplot_titles=[f"radar {s}" for s in radars])
    widths = sorted({r["azimuth_from_deg"] for r in rows})
    az_step = min((b - a for a, b in pairwise(widths) if b > a), default=10.0)
    for j, radar in enumerate(radars, start=1):
        sel = [r for r in rows if r["radar"] == radar]
        rng_step = min((r["range_from_m"] for r in sel if r["range_from_m"] > 0), default=1000.0)
        fig.add_barpolar(
            r=[rng_step / 1000.0] * len(sel),
            base=[r["range_from_m"] / 1000.0 for r in sel],
            theta=[r["azimuth_from_deg"] + az_step / 2 for r in sel],
            width=[az_step] * len(sel),
            marker=dict(color=[r["pd"] for r in sel], colorscale="RdYlGn", cmin=0.0, cmax=1.0,
                        line=dict(color=["#c0392b" if (r["pd"] or 0) < req.vts.radar_detection
                                         else "rgba(0,0,0,0)" for r in sel], width=1.5),
                        colorbar=dict(title="PD", x=1.02) if j == len(radars) else None,
                        showscale=j == len(radars)),
            customdata=[[r["pd"], r["expected_scans"], r["targets"]] for r in sel],
            hovertemplate="%{theta:.0f}°, %{base:.0f}-%{r:.0f} km<br>PD %{customdata[0]}"
                          " of %{customdata[1]} scans, %{customdata[2]} targets<extra>"
                          + radar + "</extra>",
            name=radar, showlegend=False, row=1, col=j)
        fig.update_layout(**{f"polar{j if j > 1 else ''}": dict(
            angularaxis=dict(direction="clockwise", rotation=90),
            radialaxis=dict(title=dict(text="km"), ticksuffix=" km"))})
    return _layout(fig, "Coverage map: probability of detection per range/azimuth cell"
                   + _reference_note(rows), height=460)


def detection_bars(rows: list[dict[str, Any]], req: RequirementsConfig) -> go.Figure | None:
    """PD per radar and sector (all classes)."""
    rows = [r for r in rows if r["target_class"] == "(all classes)" and r["pd"] is not None]
    if not rows:
        return None
    radars = sorted({r["radar"] for r in rows})
    fig = go.Figure()
    for radar in radars:
        sel = [r for r in rows if r["radar"] == radar]
        fig.add_bar(x=[r["sector"] for r in sel], y=[r["pd"] for r in sel], name=radar,
                    marker_color=source_colour(radar, radars),
                    customdata=[[r["expected_scans"], r["missed_scans"]] for r in sel],
                    hovertemplate="%{x}: PD %{y} (%{customdata[1]} of %{customdata[0]} "
                                  "scans missed)<extra>" + radar + "</extra>")
    _limit_line(fig, req.vts.radar_detection,
                f"IMO MSC.192(79): 5 of 10 scans (PD ≥ {req.vts.radar_detection:g})")
    low = min(r["pd"] for r in rows)
    fig = _layout(fig, "Probability of detection per radar from update intervals"
                  + _reference_note(rows), barmode="group", yaxis_title="PD per scan")
    fig.update_yaxes(range=[max(0.0, min(low, req.vts.radar_detection) - 0.05), 1.0])
    return fig


def continuity_bars(rows: list[dict[str, Any]], req: RequirementsConfig) -> go.Figure | None:
    """Track number changes per hour, gap probability, extra-track share and swaps."""
    if not rows:
        return None
    fig = make_subplots(rows=1, cols=4, subplot_titles=[
        "track number changes per hour", "gap probability (per target epoch)",
        "extra-track share", "track swaps (IALA G1111: 0)"])
    sectors = [r["sector"] for r in rows]
    for col, key in enumerate(("changes_per_h", "gap_probability", "extra_track_share",
                               "track_swaps"), start=1):
        fig.add_bar(x=sectors, y=[r[key] for r in rows], showlegend=False,
                    marker_color=[SOURCE_COLOURS[i % len(SOURCE_COLOURS)]
                                  for i in range(len(rows))],
                    customdata=[[r["targets"], r["target_hours"]] for r in rows],
                    hovertemplate="%{x}: %{y}<br>%{customdata[0]} targets, %{customdata[1]} "
                                  "target hours<extra></extra>", row=1, col=col)
    _limit_line(fig, float(req.vts.max_track_swaps), "limit", row=1, col=4)
    return _layout(fig, "Track continuity of the fused picture" + _reference_note(rows),
                   height=360)


def latency_bars(rows: list[dict[str, Any]]) -> go.Figure | None:
    """Latency per source with its 95 % interval."""
    rows = [r for r in rows if r["latency_s"] is not None]
    if not rows:
        return None
    order = sorted({r["source"] for r in rows}, key=lambda s: (s != "fused", s))
    fig = go.Figure()
    fig.add_bar(x=[r["source"] for r in rows], y=[r["latency_s"] for r in rows],
                marker_color=[source_colour(r["source"], order) for r in rows],
                error_y=dict(type="data", symmetric=False,
                             array=[r["latency_ci_high_s"] - r["latency_s"] for r in rows],
                             arrayminus=[r["latency_s"] - r["latency_ci_low_s"] for r in rows]),
                customdata=[r["samples"] for r in rows], showlegend=False,
                hovertemplate="%{x}: %{y} s (%{customdata} moving points)<extra></extra>")
    fig.add_hline(y=0.0, line=dict(color="#999", width=1))
    return _layout(fig, "Latency: −along-track error ÷ speed, with 95% intervals"
                   + _reference_note(rows), yaxis_title="latency, s (> 0: positions late)",
                   height=340)


def decomposition_bars(rows: list[dict[str, Any]], req: RequirementsConfig
                       ) -> go.Figure | None:
    """Along/across-track RMS per source and sector; range and azimuth p95 per radar."""
    if not rows:
        return None
    order = sorted({r["source"] for r in rows}, key=lambda s: (s != "fused", s))
    fig = make_subplots(rows=1, cols=3, subplot_titles=[
        "along / across track RMS, m", "range error 95%, m (radars)",
        "azimuth error 95%, deg (radars)"])
    for src in order:
        sel = [r for r in rows if r["source"] == src]
        x = [r["sector"] for r in sel]
        colour = source_colour(src, order)
        fig.add_bar(x=x, y=[r["along_rms_m"] for r in sel], name=f"{src} along",
                    marker_color=colour, row=1, col=1)
        fig.add_bar(x=x, y=[r["across_rms_m"] for r in sel], name=f"{src} across",
                    marker_color=colour, marker_pattern_shape="/", row=1, col=1)
        if src != "fused":
            fig.add_bar(x=x, y=[r["range_p95_m"] for r in sel], name=f"{src} range",
                        marker_color=colour, showlegend=False, row=1, col=2)
            fig.add_bar(x=x, y=[r["azimuth_p95_deg"] for r in sel], name=f"{src} azimuth",
                        marker_color=colour, showlegend=False, row=1, col=3)
    _limit_line(fig, req.vts.radar_range_p95_m,
                f"IMO: {req.vts.radar_range_p95_m:g} m (or 1% of range)", row=1, col=2)
    _limit_line(fig, req.vts.radar_bearing_p95_deg,
                f"IMO: {req.vts.radar_bearing_p95_deg:g}°", row=1, col=3)
    return _layout(fig, "Error decomposition" + _reference_note(rows), barmode="group",
                   height=400)


def drilldown_map(points: list[dict[str, Any]]) -> go.Figure | None:
    """The worst targets' reference tracks (solid) and their fused points (dots coloured
    by error), regional ENU in km."""
    if not points:
        return None
    fig = go.Figure()
    ranks = sorted({r["rank"] for r in points})
    for rank in ranks:
        sel = [r for r in points if r["rank"] == rank]
        colour = SOURCE_COLOURS[(rank - 1) % len(SOURCE_COLOURS)]
        name = f"#{rank} target {sel[0]['reference_id']}"
        fig.add_scatter(x=[r["reference_x_m"] / 1000 for r in sel],
                        y=[r["reference_y_m"] / 1000 for r in sel], mode="lines",
                        line=dict(color=colour, width=2), name=name, legendgroup=name)
        fig.add_scatter(x=[r["fused_x_m"] / 1000 for r in sel],
                        y=[r["fused_y_m"] / 1000 for r in sel], mode="markers",
                        marker=dict(size=5, color=[r["error_m"] for r in sel],
                                    colorscale="Reds", line=dict(width=0.5, color=colour)),
                        name=f"{name}: fused", legendgroup=name, showlegend=False,
                        customdata=[r["error_m"] for r in sel],
                        hovertemplate="error %{customdata:.1f} m<extra>" + name + "</extra>")
    fig = _layout(fig, "Drill-down: the worst targets' reference (lines) and fused points "
                  "(dots, darker = larger error)", height=520, xaxis_title="east, km",
                  yaxis_title="north, km")
    fig.update_yaxes(scaleanchor="x", scaleratio=1)
    return fig


def drilldown_table(rows: list[dict[str, Any]]) -> str:
    """The worst targets as an HTML table (worst first)."""
    if not rows:
        return ""
    cols = (("rank", "#"), ("reference_id", "target"), ("sector", "sector"),
            ("fused_points", "fused points"), ("rms_error_m", "RMS m"),
            ("p95_error_m", "p95 m"), ("max_error_m", "max m"), ("missed_scans", "missed scans"),
            ("pd", "PD"), ("extra_track_numbers", "extra track numbers"))
    head = "".join(f"<th>{label}</th>" for _, label in cols)
    body = "".join("<tr>" + "".join(
        f'<td class="num">{_cell(r.get(k))}</td>' for k, _ in cols) + "</tr>" for r in rows)
    return (f'<table class="verdicts"><thead><tr>{head}</tr></thead><tbody>{body}'
            "</tbody></table>")


def _cell(v: Any) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    return f"{v:.4g}" if isinstance(v, float) else str(v)


__all__ = ["FUSED", "continuity_bars", "coverage_maps", "decomposition_bars", "detection_bars",
           "drilldown_map", "drilldown_table", "latency_bars"]
