"""The audit's charts: one function per chart, report rows in, a plotly figure out
(``None`` when the report has no rows). Nothing here reads the warehouse.

Maps are drawn without online tiles: longitude/latitude axes at the region's scale
(``scaleratio`` = 1 / cos(latitude): a metre is as long east as north), the config's
admissible area ([gaps], the water) and islands as the coastline, sectors, fairway legs,
radar sites and the airfield's ED-87 areas over it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from datetime import UTC, datetime
from typing import Any

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from pipeline.config import Config
from pipeline.frames import enu_to_geodetic, geodetic_to_enu
from pipeline.requirements import RequirementsConfig

FUSED = "#1f4e9c"
SOURCE_COLOURS = ["#e07b00", "#2a9d3a", "#c0392b", "#8c564b", "#17becf", "#bcbd22"]
AIS = "#6b6b6b"
AIRFIELD = "#8e44ad"
WATER = "#d6e6f5"
LAND = "#efe9dc"
LIMIT = "#c0392b"
AREA_COLOURS = {"manoeuvring": "#9ecae1", "apron_taxiway": "#fdd0a2", "stand": "#c7e9c0"}
FONT = dict(family="DejaVu Sans, Arial, sans-serif", size=12)


def source_colour(source: str, order: Sequence[str]) -> str:
    """fused: dark blue; each radar (or channel) its own colour, stable by ``order``."""
    if source == "fused":
        return FUSED
    others = [s for s in order if s != "fused"]
    i = others.index(source) if source in others else len(others)
    return SOURCE_COLOURS[i % len(SOURCE_COLOURS)]


def _layout(fig: go.Figure, title: str, height: int = 380, **kw: Any) -> go.Figure:
    fig.update_layout(title=dict(text=title, x=0.01, y=0.98, yanchor="top", font=dict(size=15)),
                      height=height, margin=dict(l=60, r=20, t=80, b=50), font=FONT,
                      plot_bgcolor="white", paper_bgcolor="white",
                      legend=dict(orientation="h", yanchor="bottom", y=1.06, x=1,
                                  xanchor="right"),
                      **kw)
    fig.update_xaxes(showline=True, linecolor="#999", gridcolor="#eee", zeroline=False)
    fig.update_yaxes(showline=True, linecolor="#999", gridcolor="#eee", zeroline=False)
    return fig


def _sources(rows: Iterable[Mapping[str, Any]], key: str = "source") -> list[str]:
    seen: list[str] = []
    for r in rows:
        if r[key] not in seen:
            seen.append(r[key])
    return sorted(seen, key=lambda s: (s != "fused", s))


def _limit_line(fig: go.Figure, y: float, text: str, **kw: Any) -> None:
    fig.add_hline(y=y, line=dict(color=LIMIT, dash="dash", width=2), annotation_text=text,
                  annotation_position="top right", annotation_font_color=LIMIT,
                  annotation_bgcolor="rgba(255,255,255,0.85)", **kw)


# --- maritime ----------------------------------------------------------------------------


def accuracy_bars(rows: list[dict[str, Any]], req: RequirementsConfig) -> go.Figure | None:
    """95th-percentile error per sector and source, with our maritime target."""
    if not rows:
        return None
    order = _sources(rows)
    fig = go.Figure()
    for src in order:
        sel = [r for r in rows if r["source"] == src]
        fig.add_bar(x=[r["sector"] for r in sel], y=[r["p95_error_m"] for r in sel], name=src,
                    marker_color=source_colour(src, order),
                    customdata=[[r["samples"], r["rms_error_m"], r["reference"]] for r in sel],
                    hovertemplate="%{x}<br>p95 %{y} m<br>RMS %{customdata[1]} m<br>"
                                  "%{customdata[0]} samples vs %{customdata[2]}<extra>"
                                  + src + "</extra>")
    _limit_line(fig, req.maritime_position_p95_m,
                f"target: fused 95% ≤ {req.maritime_position_p95_m:g} m")
    return _layout(fig, "Position error, 95th percentile, per sector", barmode="group",
                   yaxis_title="error, m (95th percentile)")


def error_over_time(rows: list[dict[str, Any]], req: RequirementsConfig) -> go.Figure | None:
    """Per-minute 95th-percentile error of the fused picture and of each radar."""
    if not rows:
        return None
    order = _sources(rows)
    fig = go.Figure()
    for src in order:
        sel = [r for r in rows if r["source"] == src]
        fig.add_scatter(x=[r["minute_utc"] for r in sel], y=[r["p95_error_m"] for r in sel],
                        name=src, mode="lines", line=dict(color=source_colour(src, order),
                                                          width=3 if src == "fused" else 1.5),
                        customdata=[r["samples"] for r in sel],
                        hovertemplate="%{x|%H:%M} UTC<br>p95 %{y} m, %{customdata} samples"
                                      "<extra>" + src + "</extra>")
    _limit_line(fig, req.maritime_position_p95_m, "target (fused)")
    return _layout(fig, "Position error over time (95th percentile per minute)",
                   yaxis_title="error, m", xaxis_title="time, UTC")


def identification_bars(rows: list[dict[str, Any]], req: RequirementsConfig
                        ) -> go.Figure | None:
    """Share of fused track time with the correct, a wrong or no MMSI."""
    if not rows:
        return None
    labels = [f"{r['sector']}<br>{r['vessel_class']}" for r in rows]
    fig = go.Figure()
    for key, name, colour in (("correct_share", "correct", "#2a9d3a"),
                              ("wrong_share", "wrong MMSI", "#c0392b"),
                              ("none_share", "no MMSI", "#f0ad4e")):
        vals = [r[key] for r in rows]
        fig.add_bar(x=labels, y=vals, name=name, marker_color=colour,
                    text=[f"{v:.2%}" if key == "correct_share" else "" for v in vals],
                    textposition="inside", insidetextanchor="start",
                    customdata=[r["samples"] for r in rows],
                    hovertemplate="%{x}<br>" + name + " %{y:.2%} of %{customdata} points"
                                  "<extra></extra>")
    low = min(r["correct_share"] for r in rows)
    bottom = max(0.0, math.floor((min(low, req.maritime_identification_share) - 0.01) * 100)
                 / 100)
    _limit_line(fig, req.maritime_identification_share,
                f"target: ≥ {req.maritime_identification_share:g} correct (ships with AIS)")
    fig = _layout(fig, f"Identification: share of fused track time by MMSI verdict (axis from "
                       f"{bottom:.0%})", barmode="stack", yaxis_title="share of track time")
    # ticks of a few-percent axis are tenths of a percent: ".0%" printed 100%, 100%, 99%
    fig.update_yaxes(range=[bottom, 1.0], tickformat=".1%" if bottom > 0.95 else ".0%")
    return fig


SIAP_MEASURES = (("completeness", "completeness (→1)"), ("ambiguity", "ambiguity (→1)"),
                 ("spuriousness", "spuriousness (→0)"), ("longest_segment", "longest segment (→1)"),
                 ("id_completeness", "ID completeness (→1)"),
                 ("id_correctness", "ID correctness (→1)"))


def siap_bars(rows: list[dict[str, Any]], req: RequirementsConfig) -> go.Figure | None:
    """SIAP measures per sector (0..1 scale; ambiguity can exceed 1)."""
    if not rows:
        return None
    fig = go.Figure()
    for i, r in enumerate(rows):
        fig.add_bar(x=[label for _, label in SIAP_MEASURES],
                    y=[r[k] for k, _ in SIAP_MEASURES], name=r["sector"],
                    marker_color=SOURCE_COLOURS[i % len(SOURCE_COLOURS)]
                    if r["sector"] != "(all sectors)" else "#444",
                    customdata=[[r["position_accuracy_m"], r["changes_per_h"], r["track_swaps"]]]
                    * len(SIAP_MEASURES),
                    hovertemplate="%{x}: %{y}<br>PA %{customdata[0]} m, R %{customdata[1]}/h, "
                                  "swaps %{customdata[2]}<extra>" + r["sector"] + "</extra>")
    _limit_line(fig, req.maritime_siap_completeness,
                f"target completeness ≥ {req.maritime_siap_completeness:g}")
    refs = sorted({str(r.get("reference") or "truth") for r in rows})
    return _layout(fig, f"SIAP measures of the fused picture (against {' / '.join(refs)})",
                   barmode="group",
                   yaxis_title="measure")


def cross_track_along(rows: list[dict[str, Any]], req: RequirementsConfig
                      ) -> go.Figure | None:
    """Mean 60-s RMS cross-track error along each leg, fused against each radar."""
    if not rows:
        return None
    legs = sorted({r["leg_id"] for r in rows})
    order = _sources(rows)
    fig = make_subplots(rows=1, cols=len(legs), subplot_titles=[f"leg {leg}" for leg in legs],
                        shared_yaxes=True, horizontal_spacing=0.04)
    for j, leg in enumerate(legs, start=1):
        for src in order:
            sel = [r for r in rows if r["leg_id"] == leg and r["source"] == src
                   and r["samples"] >= 5]
            if not sel:
                continue
            fig.add_scatter(x=[r["along_track_km"] for r in sel],
                            y=[r["mean_rms_60s_m"] for r in sel], mode="lines+markers",
                            name=src, legendgroup=src, showlegend=j == 1,
                            line=dict(color=source_colour(src, order),
                                      width=3 if src == "fused" else 1.5),
                            marker=dict(size=4),
                            customdata=[[r["samples"], r["mean_aspect_deg"]] for r in sel],
                            hovertemplate="%{x} km: %{y} m (%{customdata[0]} pts, aspect "
                                          "%{customdata[1]}°)<extra>" + src + "</extra>",
                            row=1, col=j)
        fig.update_xaxes(title_text="km along the leg", row=1, col=j)
    _limit_line(fig, req.maritime_cross_track_rms_60s_p95_m, "target (fused, 95%)",
                row="all", col="all")
    fig.update_yaxes(title_text="60-s RMS cross-track error, m", row=1, col=1)
    return _layout(fig, "Cross-track error along each fairway leg: partial (each radar) vs fused",
                   height=400)


def radar_bias(rows: list[dict[str, Any]]) -> go.Figure | None:
    """Range bias, range gain, azimuth bias and time offset per site with their 95%
    intervals (a row estimated before the gain was has no gain bar)."""
    if not rows:
        return None
    panels = (("range bias, m", "range_bias_m", "range_ci_low_m", "range_ci_high_m"),
              ("range gain, m per km", "range_gain_m_per_km", "range_gain_ci_low_m_per_km",
               "range_gain_ci_high_m_per_km"),
              ("azimuth bias, deg", "azimuth_bias_deg", "azimuth_ci_low_deg",
               "azimuth_ci_high_deg"),
              ("time offset, s", "time_offset_s", "time_ci_low_s", "time_ci_high_s"))
    fig = make_subplots(rows=1, cols=len(panels), subplot_titles=[p[0] for p in panels])
    sites = [f"{r['site_id']}<br>{r['window_start_utc']:%H:%M}" for r in rows]
    for col, (_, v, lo, hi) in enumerate(panels, start=1):
        vals = [r.get(v) for r in rows]
        fig.add_bar(x=sites, y=vals, showlegend=False, marker_color=FUSED,
                    error_y=dict(type="data", symmetric=False,
                                 array=[None if r.get(v) is None else r[hi] - r[v]
                                        for r in rows],
                                 arrayminus=[None if r.get(v) is None else r[v] - r[lo]
                                             for r in rows]),
                    row=1, col=col)
    return _layout(fig, "Radar registration bias with 95% intervals (reported − true)",
                   height=330)


_REGISTRATION_PANELS = (
    ("range bias, m", "range_bias_m", "range_ci_low_m", "range_ci_high_m"),
    ("azimuth bias, deg", "azimuth_bias_deg", "azimuth_ci_low_deg", "azimuth_ci_high_deg"),
    ("clock offset, s", "time_offset_s", "time_ci_low_s", "time_ci_high_s"),
    ("range gain, m per km", "range_gain_m_per_km", "range_gain_ci_low_m_per_km",
     "range_gain_ci_high_m_per_km"),
    ("stated range variance scale", "stated_range_scale_max", None, None),
    ("stated azimuth variance scale", "stated_azimuth_scale_max", None, None),
    ("stated speed / course variance scale (the larger)", "stated_velocity_scale_max", None,
     None),
    ("variance scale (largest sector)", "variance_scale_max", None, None),
)


def registration_over_time(rows: list[dict[str, Any]], start_ns: int, end_ns: int
                           ) -> go.Figure | None:
    """Each radar's online registration per minute (range, azimuth, clock, gain; the 95 %
    interval as a band, markers where the estimate was applied) and its variance scale;
    a sector registered on its own (the site's sectors differ) as a dashed or dotted line
    of the site's colour, its interval in the hover (a sector with few tracks has a wide
    one: as a band it would hide every other line)."""
    if not rows:
        return None
    fig = make_subplots(rows=len(_REGISTRATION_PANELS), cols=1, shared_xaxes=True,
                        vertical_spacing=0.05,
                        subplot_titles=[p[0] for p in _REGISTRATION_PANELS])
    sites = sorted({r["site_id"] for r in rows})
    series = sorted({(r["site_id"], r.get("registered_sector")) for r in rows},
                    key=lambda s: (s[0], s[1] is not None, s[1] or ""))
    dashes = ("dash", "dot", "dashdot", "longdash", "longdashdot")
    for site_id, sector in series:
        sel = [r for r in rows
               if r["site_id"] == site_id and r.get("registered_sector") == sector]
        colour = SOURCE_COLOURS[sites.index(site_id) % len(SOURCE_COLOURS)]
        own = sorted({s for i, s in series if i == site_id and s is not None})
        dash = "solid" if sector is None else dashes[own.index(sector) % len(dashes)]
        name = site_id if sector is None else f"{site_id} · {sector}"
        t = [r["minute_utc"] for r in sel]
        applied = [r["registration_applied_share"] > 0 for r in sel]
        for row, (_, v, lo, hi) in enumerate(_REGISTRATION_PANELS, start=1):
            if lo is not None and sector is None:  # the interval as a band under it
                fig.add_scatter(x=t + t[::-1], y=[r[hi] for r in sel] + [r[lo] for r in sel][::-1],
                                fill="toself", fillcolor=colour, opacity=0.18, mode="none",
                                hoverinfo="skip", showlegend=False, row=row, col=1)
            interval = [[r[lo], r[hi]] if lo is not None else [None, None] for r in sel]
            fig.add_scatter(
                x=t, y=[r[v] for r in sel], name=name, legendgroup=name, showlegend=row == 1,
                mode="lines+markers", line=dict(color=colour, width=1.5, dash=dash),
                marker=dict(size=[7 if a else 3 for a in applied], color=colour),
                customdata=[[r["registration_applied_share"], r["readmitted_share"], *i]
                            for r, i in zip(sel, interval, strict=True)],
                hovertemplate="%{x|%H:%M} UTC: %{y} (95 %: %{customdata[2]} to "
                              "%{customdata[3]})<br>applied %{customdata[0]}, fused although "
                              "excluded %{customdata[1]}<extra>" + name + "</extra>",
                row=row, col=1)
    fig = _layout(fig, "Online registration per radar (reported − true; large markers: "
                  "applied before fusion)", height=190 * len(_REGISTRATION_PANELS))
    fig.update_xaxes(type="date", range=[_dt(start_ns), _dt(end_ns)])
    fig.update_xaxes(title_text="time, UTC", row=len(_REGISTRATION_PANELS), col=1)
    return fig


# --- airfield, own ship, gaps -------------------------------------------------------------


def surface_accuracy_bars(rows: list[dict[str, Any]], req: RequirementsConfig
                          ) -> go.Figure | None:
    """95th-percentile error per ED-87 area and source, with the area's limit."""
    rows = [r for r in rows if r["p95_error_m"] is not None]
    if not rows:
        return None
    order = _sources(rows)
    areas = [a for a in req.ed87_position_p95_m if any(r["area"] == a for r in rows)]
    areas += sorted({r["area"] for r in rows} - set(areas))
    fig = go.Figure()
    for src in order:
        by_area = {r["area"]: r for r in rows if r["source"] == src}
        fig.add_bar(x=areas, y=[by_area.get(a, {}).get("p95_error_m") for a in areas],
                    name=src, marker_color=source_colour(src, order),
                    customdata=[by_area.get(a, {}).get("scored") for a in areas],
                    hovertemplate="%{x}: p95 %{y} m, %{customdata} scored<extra>" + src
                                  + "</extra>")
    limits = [req.ed87_position_p95_m.get(a) for a in areas]
    fig.add_scatter(x=areas, y=limits, mode="markers", name="ED-87 limit (fused)",
                    marker=dict(symbol="line-ew", size=90, line=dict(width=3, color=LIMIT)),
                    hovertemplate="%{x}: ED-87 95% ≤ %{y} m<extra></extra>")
    _limit_line(fig, req.sensor_position_p95_m,
                f"ED-116/117 sensor level ≤ {req.sensor_position_p95_m:g} m")
    fig = _layout(fig, "Airfield surface accuracy, 95th percentile, per ED-87 area (log scale)",
                  barmode="group", yaxis_title="error, m (95th percentile)")
    values = [r["p95_error_m"] for r in rows] + [v for v in limits if v is not None]
    values.append(req.sensor_position_p95_m)
    fig.update_yaxes(type="log", range=[math.log10(max(min(values), 1e-3) / 2),
                                        math.log10(max(values) * 2)])
    return fig


def fault_timeline(rows: list[dict[str, Any]], start_ns: int, end_ns: int) -> go.Figure | None:
    """Airfield channel exclusions and GNSS outages as bars on one time axis."""
    if not rows:
        return None
    lanes = sorted({r["lane"] for r in rows}, key=lambda s: (s.startswith("GNSS"), s))
    kinds = sorted({r["kind"] for r in rows})
    fig = go.Figure()
    for i, kind in enumerate(kinds):
        sel = [r for r in rows if r["kind"] == kind]
        fig.add_bar(y=[r["lane"] for r in sel],
                    x=[max(r["duration_s"], 5.0) * 1000 for r in sel],
                    base=[r["start_utc"] for r in sel], orientation="h", name=kind,
                    marker_color=SOURCE_COLOURS[i % len(SOURCE_COLOURS)],
                    customdata=[[f"{r['start_utc']:%H:%M:%S}", r["duration_s"]] for r in sel],
                    hovertemplate="%{y}: from %{customdata[0]} UTC for %{customdata[1]} s"
                                  "<extra>" + kind + "</extra>")
    fig = _layout(fig, "Channel faults: airfield exclusions and GNSS outages",
                  height=140 + 40 * len(lanes), barmode="overlay",
                  xaxis_title="time, UTC")
    fig.update_xaxes(type="date", range=[_dt(start_ns), _dt(end_ns)])
    fig.update_yaxes(categoryorder="array", categoryarray=lanes[::-1])
    return fig


def heading_error(rows: list[dict[str, Any]]) -> go.Figure | None:
    """Own-ship heading error: the gyrocompass alone and the integrated solution."""
    rows = [r for r in rows if r["gyro_error_deg"] is not None or r["heading_error_deg"]
            is not None]
    if not rows:
        return None
    fig = make_subplots(rows=2, cols=1, shared_xaxes=True, vertical_spacing=0.08,
                        subplot_titles=["gyrocompass alone", "integrated (gyro + GNSS + log)"])
    for platform in sorted({r["platform_id"] for r in rows}):
        sel = [r for r in rows if r["platform_id"] == platform]
        t = [r["time_utc"] for r in sel]
        fig.add_scatter(x=t, y=[r["gyro_error_deg"] for r in sel], name=f"{platform}: gyro",
                        line=dict(color="#e07b00"), row=1, col=1)
        fig.add_scatter(x=t, y=[r["heading_error_deg"] for r in sel],
                        name=f"{platform}: integrated", line=dict(color=FUSED), row=2, col=1)
        sig = [r["sigma_heading_deg"] if r["converged"] else None for r in sel]
        fig.add_scatter(x=t, y=[3 * s if s is not None else None for s in sig], mode="lines",
                        name="±3σ (converged)", line=dict(color="#999", dash="dot", width=1),
                        row=2, col=1)
        fig.add_scatter(x=t, y=[-3 * s if s is not None else None for s in sig], mode="lines",
                        showlegend=False, line=dict(color="#999", dash="dot", width=1),
                        row=2, col=1)
        for a, b in _runs(t, [r["emergency_share"] > 0 for r in sel]):
            fig.add_vrect(x0=a, x1=b, fillcolor="#f0ad4e", opacity=0.25, line_width=0,
                          row="all", col=1)
    fig.update_yaxes(title_text="deg", row=1, col=1)
    fig.update_yaxes(title_text="deg", row=2, col=1)
    fig = _layout(fig, "Own-ship heading error against truth (orange bands: GNSS emergency "
                       "mode)", height=480)
    return fig


def _runs(t: list[Any], flags: list[bool]) -> list[tuple[Any, Any]]:
    out, start = [], None
    for i, f in enumerate(flags):
        if f and start is None:
            start = t[i]
        if not f and start is not None:
            out.append((start, t[i]))
            start = None
    if start is not None:
        out.append((start, t[-1]))
    return out


def gap_errors(rows: list[dict[str, Any]]) -> go.Figure | None:
    """Data-gap forecasts: error of the particle mean and the 90% region radius by lead."""
    rows = [r for r in rows if r["lead_min"] is not None]
    if not rows:
        return None
    fig = go.Figure()
    fig.add_scatter(x=[r["lead_min"] for r in rows], y=[r["region90_radius_m"] for r in rows],
                    mode="markers", name="90% region radius",
                    marker=dict(symbol="circle-open", size=9, color="#6b6b6b"),
                    customdata=[[r["mmsi"], r["most_likely_zone"], r["most_likely_zone_p"]]
                                for r in rows],
                    hovertemplate="MMSI %{customdata[0]}, lead %{x} min: radius %{y} m<br>"
                                  "most likely zone %{customdata[1]} (p %{customdata[2]})"
                                  "<extra></extra>")
    scored = [r for r in rows if r["error_m"] is not None]
    if scored:
        fig.add_scatter(x=[r["lead_min"] for r in scored], y=[r["error_m"] for r in scored],
                        mode="markers", name="error of the forecast mean",
                        marker=dict(size=8, color=[FUSED if r["true_in_region90"] else LIMIT
                                                   for r in scored]),
                        customdata=[[r["mmsi"], r["reference"]] for r in scored],
                        hovertemplate="MMSI %{customdata[0]}, lead %{x} min: error %{y} m vs "
                                      "%{customdata[1]}<extra></extra>")
    title = ("Data-gap forecasts: error vs the 90% region (red: reference outside the region)"
             if scored else "Data-gap forecasts: size of the 90% region by lead time (nothing "
                            "to score them against in this window)")
    fig = _layout(fig, title, xaxis_title="lead time, min", yaxis_title="m (log scale)",
                  showlegend=True)
    fig.update_yaxes(type="log")
    return fig


# --- maps ---------------------------------------------------------------------------------


def _closed(poly: Sequence[Sequence[float]]) -> tuple[list[float], list[float]]:
    lats = [p[0] for p in poly] + [poly[0][0]]
    lons = [p[1] for p in poly] + [poly[0][1]]
    return lons, lats


def _lines(points: Iterable[tuple[float, float] | None]) -> tuple[list, list]:
    xs: list[float | None] = []
    ys: list[float | None] = []
    for p in points:
        xs.append(None if p is None else p[0])
        ys.append(None if p is None else p[1])
    return xs, ys


def _track_layers(rows: list[dict[str, Any]], cfg: Config) -> dict[str, list]:
    """Layer -> [(lon, lat) | None, ...]: each track a run, separated by None."""
    o = cfg.region
    out: dict[str, list] = {}
    enu = [r for r in rows if r["lat_deg"] is None and r["x_enu_m"] is not None]
    if enu:
        lat, lon = enu_to_geodetic(np.array([r["x_enu_m"] for r in enu]),
                                   np.array([r["y_enu_m"] for r in enu]),
                                   o.origin_lat_deg, o.origin_lon_deg)
        for r, la, lo in zip(enu, lat, lon, strict=True):
            r["lat_deg"], r["lon_deg"] = float(la), float(lo)
    last: tuple[str, str] | None = None
    for r in rows:
        if r["lat_deg"] is None:
            continue
        pts = out.setdefault(r["layer"], [])
        if last is not None and last != (r["layer"], r["track"]) and last[0] == r["layer"]:
            pts.append(None)
        pts.append((r["lon_deg"], r["lat_deg"]))
        last = (r["layer"], r["track"])
    return out


def _circle(lat: float, lon: float, radius_m: float, n: int = 36) -> tuple[list, list]:
    a = np.linspace(0, 2 * np.pi, n + 1)
    dlat = radius_m * np.cos(a) / 111_320.0
    dlon = radius_m * np.sin(a) / (111_320.0 * math.cos(math.radians(lat)))
    return list(lon + dlon), list(lat + dlat)


def maritime_map(cfg: Config, tracks: list[dict[str, Any]], forecasts: list[dict[str, Any]]
                 ) -> go.Figure:
    """The region: coastline (admissible water, islands), sectors, fairway legs, radar
    sites, airfield areas, the window's tracks by layer and the gap forecasts' regions."""
    fig = go.Figure()
    gaps = (cfg.families or {}).get("gaps")
    for poly in getattr(gaps, "admissible", ()) or ():
        x, y = _closed(poly.polygon_lat_lon_deg)
        fig.add_scatter(x=x, y=y, fill="toself", fillcolor=WATER, mode="lines",
                        line=dict(color="#9cbcd9", width=1), hoverinfo="skip",
                        name="water ([gaps] admissible area)", legendgroup="water",
                        showlegend=poly is gaps.admissible[0])
    for poly in getattr(gaps, "islands", ()) or ():
        x, y = _closed(poly.polygon_lat_lon_deg)
        fig.add_scatter(x=x, y=y, fill="toself", fillcolor=LAND, mode="lines",
                        line=dict(color="#9cbcd9", width=1), name=poly.name, showlegend=False,
                        hovertemplate=poly.name + "<extra>island</extra>")
    for s in cfg.sectors:
        x, y = _closed(s.polygon_lat_lon_deg)
        fig.add_scatter(x=x, y=y, mode="lines", line=dict(color="#555", dash="dash", width=1.5),
                        name="sectors", legendgroup="sectors",
                        showlegend=s is cfg.sectors[0], hovertemplate=s.name + "<extra></extra>")
        fig.add_annotation(x=float(np.mean(x[:-1])), y=float(np.max(y[:-1])), text=s.name,
                           showarrow=False, yshift=-10, font=dict(size=11, color="#333"))
    for leg in cfg.fairway_legs:
        fig.add_scatter(x=[leg.start_lon_deg, leg.end_lon_deg],
                        y=[leg.start_lat_deg, leg.end_lat_deg], mode="lines+text",
                        line=dict(color="#d4a017", width=5), opacity=0.6,
                        text=[leg.leg_id, ""], textposition="top center",
                        name="fairway legs", legendgroup="legs",
                        showlegend=leg is cfg.fairway_legs[0],
                        hovertemplate="leg " + leg.leg_id + "<extra></extra>")
    airfield = (cfg.families or {}).get("airfield")
    for s in getattr(airfield, "sectors", ()) or ():
        x, y = _closed(s.polygon_lat_lon_deg)
        fig.add_scatter(x=x, y=y, fill="toself", fillcolor=AREA_COLOURS.get(s.area, "#ddd"),
                        mode="lines", line=dict(width=0.5, color="#888"), showlegend=False,
                        hovertemplate=f"{s.name} ({s.area})<extra>airfield</extra>")
    layers = _track_layers(tracks, cfg)
    radar_layers = sorted(k for k in layers if k.startswith("radar"))
    style = {"ais": dict(color=AIS, width=1, dash="dot"), "airfield": dict(color=AIRFIELD,
                                                                           width=1.2)}
    for i, name in enumerate(radar_layers):
        style[name] = dict(color=SOURCE_COLOURS[i % len(SOURCE_COLOURS)], width=1)
    style["fused"] = dict(color=FUSED, width=2)
    for name in ["ais", *radar_layers, "airfield", "fused"]:
        if name not in layers:
            continue
        x, y = _lines(layers[name])
        fig.add_scatter(x=x, y=y, mode="lines", line=style[name], name=name,
                        opacity=0.9 if name == "fused" else 0.7, hoverinfo="skip",
                        visible=True if name in ("fused", "airfield", "ais") else "legendonly")
    for r in forecasts:
        if r["lat_deg"] is None or r["region90_radius_m"] is None:
            continue
        x, y = _circle(r["lat_deg"], r["lon_deg"], r["region90_radius_m"])
        fig.add_scatter(x=x, y=y, mode="lines", line=dict(color="#c0392b", width=1),
                        fill="toself", fillcolor="rgba(192,57,43,0.08)",
                        name="gap forecast 90% regions", legendgroup="gaps",
                        showlegend=r is forecasts[0],
                        hovertemplate=f"MMSI {r['mmsi']} at +{r['lead_min']} min: "
                                      f"{r['most_likely_zone']} (p {r['most_likely_zone_p']})"
                                      "<extra>gap forecast</extra>")
    fig.add_scatter(x=[s.lon_deg for s in cfg.radar_sites], y=[s.lat_deg for s in cfg.radar_sites],
                    mode="markers+text", text=[s.site_id for s in cfg.radar_sites],
                    textposition="top center", marker=dict(symbol="triangle-up", size=13,
                                                           color="#000"),
                    name="radar sites", hovertemplate="%{text}<extra>radar site</extra>")
    lon_range, lat_range = _extent(cfg, tracks)
    lat0 = cfg.region.origin_lat_deg
    fig = _layout(fig, "Map of the window's tracks (fused shown; click the legend for each "
                       "radar)", height=640)
    fig.update_layout(plot_bgcolor=LAND, legend=dict(orientation="v", y=1, x=1.01,
                                                     xanchor="left", yanchor="top"),
                      margin=dict(r=220))
    fig.update_xaxes(range=lon_range, title_text="longitude, deg E", showgrid=False)
    fig.update_yaxes(range=lat_range, title_text="latitude, deg N", showgrid=False,
                     scaleanchor="x", scaleratio=1.0 / math.cos(math.radians(lat0)))
    return fig


def _extent(cfg: Config, tracks: list[dict[str, Any]]) -> tuple[list[float], list[float]]:
    lons: list[float] = []
    lats: list[float] = []
    for s in cfg.sectors:
        lats += [p[0] for p in s.polygon_lat_lon_deg]
        lons += [p[1] for p in s.polygon_lat_lon_deg]
    for leg in cfg.fairway_legs:
        lats += [leg.start_lat_deg, leg.end_lat_deg]
        lons += [leg.start_lon_deg, leg.end_lon_deg]
    if not lats:
        lats = [r["lat_deg"] for r in tracks if r["lat_deg"] is not None] or [0.0]
        lons = [r["lon_deg"] for r in tracks if r["lon_deg"] is not None] or [0.0]
    pad_lat = 0.05 * (max(lats) - min(lats) or 0.01)
    pad_lon = 0.05 * (max(lons) - min(lons) or 0.01)
    return ([min(lons) - pad_lon, max(lons) + pad_lon], [min(lats) - pad_lat, max(lats) + pad_lat])


def airfield_map(cfg: Config, tracks: list[dict[str, Any]]) -> go.Figure | None:
    """The airfield in metres east/north of its reference point: ED-87 areas and the
    fused surface tracks."""
    airfield = (cfg.families or {}).get("airfield")
    rows = [r for r in tracks if r["layer"] == "airfield" and r["lat_deg"] is not None]
    if airfield is None or not rows:
        return None
    lat0, lon0 = airfield.reference_lat_deg, airfield.reference_lon_deg
    fig = go.Figure()
    shown: set[str] = set()
    for s in airfield.sectors:
        lons, lats = _closed(s.polygon_lat_lon_deg)
        e, n = geodetic_to_enu(np.array(lats), np.array(lons), lat0, lon0)
        fig.add_scatter(x=list(e), y=list(n), fill="toself",
                        fillcolor=AREA_COLOURS.get(s.area, "#ddd"), mode="lines",
                        line=dict(width=0.5, color="#888"), name=s.area, legendgroup=s.area,
                        showlegend=s.area not in shown,
                        hovertemplate=f"{s.name} ({s.area})<extra></extra>")
        shown.add(s.area)
    e, n = geodetic_to_enu(np.array([r["lat_deg"] for r in rows]),
                           np.array([r["lon_deg"] for r in rows]), lat0, lon0)
    pts: list[tuple[float, float] | None] = []
    last = None
    for r, x, y in zip(rows, e, n, strict=True):
        if last is not None and last != r["track"]:
            pts.append(None)
        pts.append((float(x), float(y)))
        last = r["track"]
    x, y = _lines(pts)
    fig.add_scatter(x=x, y=y, mode="lines+markers", marker=dict(size=3), name="fused tracks",
                    line=dict(color=AIRFIELD, width=1.2), hoverinfo="skip")
    fig = _layout(fig, f"Airfield {airfield.name}: fused surface tracks over the ED-87 areas",
                  height=430, xaxis_title="m east of the reference point",
                  yaxis_title="m north")
    fig.update_yaxes(scaleanchor="x", scaleratio=1.0)
    return fig


def _dt(t_ns: int) -> datetime:
    return datetime.fromtimestamp(t_ns / 1e9, UTC).replace(tzinfo=None)
