"""The commented site config ``surveil config init`` writes for a :class:`Proposal`.

Every line says what it is and its unit; proposals (sectors, positions estimated from the
data) say PROPOSED, what could not be known says UNKNOWN. Only what the recordings tell
is written; every other section takes its documented defaults (``surveil config check
FILE`` prints them all, ``config/site-template.toml`` explains each). The requirement
presets are written commented out: the figures are the site's to choose.
"""

from __future__ import annotations

import datetime as dt
import math

from pipeline.configspec import toml_value
from pipeline.siteconfig.propose import Proposal, seconds_span
from pipeline.units import NS

COMMENT_COLUMN = 34


def _iso(t_ns: int | None) -> str:
    if t_ns is None:
        return "?"
    return dt.datetime.fromtimestamp(t_ns / NS, dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _kv(key: str, value: object, comment: str = "", commented: bool = False) -> str:
    text = f"{'# ' if commented else ''}{key} = {toml_value(value)}"
    if comment:
        text = f"{text:<{COMMENT_COLUMN - 1}} # {comment}"
    return text


def _deg(x: float) -> float:
    return round(float(x), 6)


def _wrap(text: str, prefix: str = "# ", width: int = 92) -> list[str]:
    words, lines, line = text.split(), [], prefix
    for w in words:
        if len(line) + len(w) + 1 > width and line.strip() != prefix.strip():
            lines.append(line.rstrip())
            line = prefix
        line += w + " "
    lines.append(line.rstrip())
    return lines


def _polygon(points: list[tuple[float, float]]) -> str:
    return "[" + ", ".join(f"[{_deg(a)}, {_deg(b)}]" for a, b in points) + "]"


def render(p: Proposal, *, sources: list[str], today: dt.date | None = None) -> str:
    """The config text (see the module docstring)."""
    s = p.survey
    day = (today or dt.datetime.now(dt.UTC).date()).isoformat()
    out: list[str] = []
    add = out.append
    add(f"# surveil site config for {p.name!r}")
    add(f"# written by `surveil config init` on {day} from")
    for src in sources[:6]:
        add(f"#   {src}")
    if len(sources) > 6:
        add(f"#   ... and {len(sources) - 6} more")
    add(f"# ({'site ' + repr(s.site) + ', ' if s.site else ''}recordings {_iso(s.start_ns)} .. "
        f"{_iso(s.end_ns)}, {seconds_span(s):,.0f} s).")
    out += _wrap("Every line says what it is and its unit. PROPOSED: derived from the data, "
                 "check it; UNKNOWN: the data could not tell, set it. Every section left out "
                 "takes its documented default (`surveil config check FILE` prints every "
                 "value; config/site-template.toml explains each). Angles in degrees, "
                 "distances in metres, times in seconds. docs/site.md walks the next steps.")
    add("")
    add("[region]")
    add(_kv("name", p.name, "the region's name (reports, the audit page)"))
    add(_kv("origin_lat_deg", _deg(p.origin[0]), "deg N: the local frame's origin"))
    add(_kv("origin_lon_deg", _deg(p.origin[1]), "deg E"))
    out += _wrap(f"origin: {p.origin_note}", "#   ")
    add(_kv("origin_height_m", 0.0, "m above the WGS-84 ellipsoid"))
    add("")
    _ais(p, out)
    _radars(p, out)
    _sectors(p, out)
    _airfield(p, out)
    _ownship(p, out)
    _gaps(p, out)
    _requirements(out)
    return "\n".join(out).rstrip() + "\n"


def _ais(p: Proposal, out: list[str]) -> None:
    s = p.survey
    add = out.append
    if not s.ais:
        add("# --- AIS: none in the recordings (ais_reports is empty).")
        add("")
        return
    n = sum(a.reports for a in s.ais)
    add(f"# --- AIS: {len(s.ais)} source(s), {n:,} position reports. AIS needs no declaration:")
    add("# every transponder is tested (its kinematic self-test; against the radar picture where")
    add("# radar sites are declared). [ais] below keeps its defaults (commented).")
    for a in s.ais[:10]:
        add(f"#   {a.topic}: {a.reports:,} reports of {a.mmsis:,} MMSI ({a.class_b:,} class B), "
            f"{_iso(a.start_ns)} .. {_iso(a.end_ns)}")
    add("# [ais]")
    add(_kv("gate_probability", 0.999, "AIS-to-track chi-square gate probability",
            commented=True))
    add(_kv("sigma_position_m", 10.0, "assumed AIS (GNSS) position sigma, m", commented=True))
    add("")


def _radars(p: Proposal, out: list[str]) -> None:
    add = out.append
    if not p.radars:
        add("# --- radar sites: none in the recordings (radar_tracks is empty). A radar is")
        add("# declared as [[radar_sites]] (site_id, lat_deg, lon_deg, scan_period_s, max_range_m;")
        add("# config/site-template.toml).")
        add("")
        return
    add(f"# --- radar sites: {len(p.radars)} in the recordings (radar_tracks). The batch uses "
        "each report's own")
    add("# sigmas; the ones below are the data's medians (what the simulator and the "
        "experiments assume).")
    for r in p.radars:
        src = r.source
        off = r.lat_deg is None
        c = "# " if off else ""
        add("")
        out += _wrap(r.note)
        add(f"{c}[[radar_sites]]")
        add(_kv("site_id", src.site_id, "the tracker's site id in the recordings "
                f"({src.reports:,} reports, {src.tracks:,} tracks)", off))
        add(_kv("lat_deg", _deg(r.lat_deg or 0.0), "deg N: the antenna", off))
        add(_kv("lon_deg", _deg(r.lon_deg or 0.0), "deg E", off))
        add(_kv("height_m", 0.0, "antenna height, m (not in the data)", off))
        add(_kv("north_alignment_deg", 0.0, "added to reported azimuths, deg", off))
        add(_kv("scan_period_s", round(src.scan_period_s or 4.0, 3),
                "antenna period, s (the reports' median)", off))
        add(_kv("max_range_m", round(max(src.max_range_m or 0.0, 1000.0) * 1.05, -2),
                "instrumented range, m (5 % beyond the farthest report)", off))
        for key, value, unit in (
                ("sigma_range_m", src.sigma_range_m, "m"),
                ("sigma_azimuth_deg", _rad_deg(src.sigma_azimuth_rad), "deg"),
                ("sigma_speed_mps", src.sigma_speed_mps, "m/s"),
                ("sigma_course_deg", _rad_deg(src.sigma_course_rad), "deg")):
            if value is not None and value > 0:
                add(_kv(key, round(float(value), 4), f"1-sigma, {unit} (the reports' median)",
                        off))
    add("")


def _rad_deg(x: float | None) -> float | None:
    return None if x is None else math.degrees(x)


def _sectors(p: Proposal, out: list[str]) -> None:
    add = out.append
    if not p.sectors:
        if p.survey.ais or p.survey.radars:
            add("# --- sectors: none (no positions to draw them over).")
            add("")
        return
    out += _wrap(f"--- {p.sectors_note}")
    for sec in p.sectors:
        add("[[sectors]]")
        add(_kv("name", sec.name, sec.note))
        add(f"polygon = {_polygon(sec.polygon)}   # [lat_deg, lon_deg] vertices")
        add("")
    add("# Fairway legs ([[fairway_legs]]: leg_id, start = [lat_deg, lon_deg], end = [...]) give")
    add("# the cross-track reports; the data cannot tell where your fairway is.")
    add("")


def _airfield(p: Proposal, out: list[str]) -> None:
    a = p.airfield
    add = out.append
    if a is None:
        add("# --- airfield: none in the recordings (airfield_obs is empty).")
        add("")
        return
    n = sum(x.reports for x in p.survey.airfield)
    add(f"# --- airfield: {len(p.survey.airfield)} data source(s), {n:,} target reports "
        "(airfield_obs).")
    if not a.sensors:  # nothing the airfield family fuses: no [airfield] (the batch skips it)
        for s, why in a.other:
            add(f"# not declared: {s.sensor_id} ({s.kind}"
                f"{f', CAT{s.category:03d}' if s.category is not None else ''}, "
                f"{s.reports:,} reports):")
            out += _wrap(why, "#   ")
        add("# No [airfield] section: none of these is a sensor the airfield family fuses.")
        add("")
        return
    add("[airfield]")
    add(_kv("name", f"{p.name}-airfield", "the airfield's name"))
    add(_kv("reference_lat_deg", _deg(a.reference_lat_deg), "deg N: airfield reference point"))
    add(_kv("reference_lon_deg", _deg(a.reference_lon_deg), "deg E"))
    out += _wrap(f"reference point: {a.reference_note}", "#   ")
    add("")
    out += _wrap("Sensors. No error model is given: each starts from the documented default of "
                 "its kind (docs/airfield.md, 'Default error models'), scaled to the data in "
                 "the batch, and every row computed with it says so (channel_health."
                 "error_model); `surveil calibrate` against a reference fits one (table "
                 "sensor_error_models), or write position_ar / position_gamma here.")
    for sp in a.sensors:
        s = sp.source
        add("[[airfield.sensors]]")
        add(_kv("sensor_id", sp.sensor_id, "your name for it"))
        add(_kv("kind", s.kind, {"smr": "surface movement radar: range/azimuth",
                                 "mlat": "multilateration: x/y from the reference point",
                                 "vasn": "vibro-acoustic sensor network: x/y, velocity"}[s.kind]))
        if s.sac is not None and s.sic is not None:
            add(_kv("sac", int(s.sac), "ASTERIX system area code (its records' I010/010)"))
            add(_kv("sic", int(s.sic), f"ASTERIX system identification code: {s.reports:,} "
                    f"reports, {s.targets:,} targets"))
        add(_kv("lat_deg", _deg(sp.lat_deg), "deg N: " + ("the antenna" if s.kind == "smr"
                                                          else "its frame's origin")))
        add(_kv("lon_deg", _deg(sp.lon_deg), "deg E"))
        out += _wrap(f"position: {sp.note}", "#   ")
        add("")
    for s, why in a.other:
        add(f"# not declared: {s.sensor_id} ({s.kind}"
            f"{f', CAT{s.category:03d}' if s.category is not None else ''}, {s.reports:,} "
            "reports):")
        out += _wrap(why, "#   ")
    if a.other:
        add("")
    add("# Airfield sectors ([[airfield.sectors]]: name, area = manoeuvring | apron_taxiway |")
    add("# stand, polygon) judge the ED-87 figures per area; the data cannot tell your areas.")
    add("")


def _ownship(p: Proposal, out: list[str]) -> None:
    add = out.append
    if not p.survey.platforms:
        add("# --- own ship: none in the recordings (nav_gnss, nav_heading, nav_speed_log are "
            "empty).")
        add("")
        return
    add(f"# --- own ship: {len(p.survey.platforms)} platform(s). The nav family needs no "
        "declaration; [ownship]")
    add("# keeps its defaults (`surveil config check FILE` prints them).")
    for pl_ in p.survey.platforms:
        add(f"#   {pl_.platform_id}: {pl_.fixes:,} GNSS fixes, {pl_.headings:,} headings, "
            f"{pl_.speed_logs:,} speed-log sentences ({', '.join(pl_.sentences)}"
            f"{'; talkers ' + ', '.join(pl_.talkers) if pl_.talkers else ''})")
    add("")


def _gaps(p: Proposal, out: list[str]) -> None:
    add = out.append
    if not p.survey.ais:
        return
    w = p.water
    if w is None:
        add("# --- data gaps: no coastline given (`surveil config init --coastline FILE`, "
            "GeoJSON or WKT):")
        add("# forecasts of silent ships are not held off the land.")
        add("")
        return
    out += _wrap(f"--- data gaps: the admissible area from {w.source}: its polygons hold "
                 f"{w.inside_share:.0%} of the vessels' positions, so they are {w.kind}; "
                 f"clipped to the traffic's extent padded by 40 km.")
    for i, ring in enumerate(w.admissible):
        add("[[gaps.admissible]]")
        add(_kv("name", f"water-{i + 1}", "where a silent ship may be"))
        add(f"polygon = {_polygon(ring)}   # [lat_deg, lon_deg] vertices")
        add("")
    for i, ring in enumerate(w.islands):
        add("[[gaps.islands]]")
        add(_kv("name", f"land-{i + 1}", "land inside the water: not admissible"))
        add(f"polygon = {_polygon(ring)}   # [lat_deg, lon_deg] vertices")
        add("")


def _requirements(out: list[str]) -> None:
    out += [
        "# --- requirements the audit judges the reports against (commented: the figures are",
        "# yours to choose; without them the defaults below apply, docs/audit.md).",
        "# [requirements]",
        _kv("min_samples", 100, "fewest scored samples behind a pass / fail", commented=True),
        "# [requirements.maritime]",
        _kv("position_p95_m", 100.0, "fused position error, 95th percentile, m",
            commented=True),
        _kv("identification_share", 0.99, "fused track time with the right MMSI",
            commented=True),
        _kv("cross_track_rms_60s_p95_m", 50.0, "60-s RMS cross-track error, 95 %, m",
            commented=True),
        _kv("siap_completeness", 0.95, "SIAP completeness (needs truth)", commented=True),
        "# [requirements.airfield]",
        _kv("sensor_position_p95_m", 7.5, "ED-116/117 sensor level: 95 % within, m",
            commented=True),
        _kv("p_identification", 0.999, "ED-87 probability of identification", commented=True),
        "# [requirements.ed87_position_p95_m]",
        _kv("manoeuvring", 12.0, "ED-87: 95 % of fused positions within, m", commented=True),
        _kv("apron_taxiway", 20.0, "m", commented=True),
        _kv("stand", 25.0, "m", commented=True),
    ]


def summary_lines(p: Proposal) -> list[str]:
    """What config init found, for the terminal."""
    s = p.survey
    lines = [f"region {p.name!r}: origin {p.origin[0]:.5f}, {p.origin[1]:.5f} "
             f"({'known' if p.origin_known else 'UNKNOWN'}), recordings {_iso(s.start_ns)} .. "
             f"{_iso(s.end_ns)}"]
    if s.ais:
        lines.append(f"AIS: {len(s.ais)} source(s), {sum(a.reports for a in s.ais):,} reports, "
                     f"{sum(a.mmsis for a in s.ais):,} MMSI")
    for r in p.radars:
        lines.append(f"radar {r.source.site_id}: "
                     + ("located (PROPOSED)" if r.lat_deg is not None else "position UNKNOWN"))
    if p.airfield is not None:
        for sp in p.airfield.sensors:
            lines.append(f"airfield {sp.source.kind} {sp.sensor_id}: "
                         + ("located" if sp.located else "position UNKNOWN"))
        for src, _ in p.airfield.other:
            lines.append(f"airfield source {src.sensor_id} ({src.kind}): not declared")
    for pf in s.platforms:
        lines.append(f"own ship {pf.platform_id}: {pf.fixes:,} fixes")
    if p.sectors:
        lines.append(f"sectors: {len(p.sectors)} PROPOSED ({', '.join(x.name for x in p.sectors)})")
    if p.water is not None:
        lines.append(f"coastline: {p.water.kind} polygons ({len(p.water.admissible)} admissible, "
                     f"{len(p.water.islands)} islands)")
    lines += [f"WARNING: {w}" for w in p.warnings]
    return lines


