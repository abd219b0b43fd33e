"""What writes each warehouse table, and why a report came out empty: the real cause.

A report with no rows says why, per source table with no rows in the window, the first
cause that holds (issue 35: every radar report said "`radar_tracks` has none ...
`simulate --scenario channel`" on a warehouse of real AIS; airfield reports blamed
``airfield_truth`` when 6,666 reports had been rejected as ``unknown_sensor``):

1. the site declares no sensor of that kind (no radar site, no ``[airfield]``, no
   fairway leg): "not applicable at this site", and what would change that;
2. its inputs have no rows in the window (of this site): which, and whether they hold
   rows at other times;
3. its inputs' rows were not used: the batch rejects of the window by cause
   (``unknown_sensor``: the SAC/SIC to declare; ``unknown_site``: the radar site ids);
4. a threshold the data cannot reach (a log shorter than ``[gaps] gap_threshold_s``, no
   GNSS outage to report);
5. a reference it is scored against is absent (truth, ``airfield_truth``: real
   recordings have none);
6. no batch covers the window: the command to run.

Simulator hints (``surveil simulate --scenario channel``) are given only on a warehouse
whose site holds simulated rows (truth tables); a warehouse of real data is never told
to simulate. Raw tables come from ``surveil ingest`` of an archive, derived tables from
``surveil batch`` (the family that owns them) or a calibration command.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import duckdb

from pipeline import families
from pipeline.config import Config
from pipeline.reports import ALL_TIME, ReportSql, open_warehouse
from pipeline.tables import spec, table_specs
from pipeline.units import NS

# raw tables -> the `surveil simulate` scenario that writes them (the demo hour has
# channel, airfield and ownship)
_SCENARIO_OF = {
    "radar_tracks": "channel", "ais_reports": "channel", "ais_static": "channel",
    "truth": "channel", "airfield_obs": "airfield", "airfield_truth": "airfield",
    "nav_gnss": "ownship", "nav_heading": "ownship", "nav_speed_log": "ownship",
    "nav_gyro_signals": "ownship", "ownship_truth": "ownship",
}
_CALIBRATIONS = {
    "radar_bias_by_site": "surveil calibrate-radars --from T --to T",
    "sensor_error_models": "surveil calibrate --from T --to T",
}
REFERENCES = ("truth", "airfield_truth", "ownship_truth")
NAV_INPUTS = ("nav_gnss", "nav_heading", "nav_speed_log", "nav_gyro_signals")
# a report scored against a reference: (the reference, what it scores)
_SCORED = {
    "surface_accuracy_by_area": ("airfield_truth", "surface position accuracy"),
    "siap_by_sector": ("truth", "SIAP"),
    "gap_forecast_calibration": ("truth", "the forecasts' calibration"),
}


def producer(table: str, simulated: bool = True) -> str:
    """The command that writes ``table``, as a user would type it (the simulator's
    scenario only when ``simulated``: a warehouse of real data is never told to simulate)."""
    if table in _CALIBRATIONS:
        return f"`{_CALIBRATIONS[table]}`"
    for fam in families.FAMILIES:  # (the stages import only when asked: PEP 562)
        if table in fam.outputs:
            return f"`surveil batch --from T --to T` ({fam.name} family)"
    kind = spec(table).kind if table in table_specs() else "raw"
    if kind in ("raw", "ledger"):
        scenario = _SCENARIO_OF.get(table) if simulated else None
        hint = f" (simulated: `surveil simulate --scenario {scenario}`)" if scenario else ""
        return f"`surveil ingest ARCHIVE`{hint}"
    return "`surveil batch --from T --to T`"


@dataclass
class _Ctx:
    """One explanation's window, site and config, and the counts it has looked up."""

    con: duckdb.DuckDBPyConnection
    start_ns: int
    end_ns: int
    sector: str | None
    cfg: Config | None
    site: str | None
    cache: dict[tuple, int] = field(default_factory=dict)

    def count(self, table: str, window: bool = True, where: str = "", params: tuple = ()
              ) -> int:
        key = (table, window, where, params)
        if key not in self.cache:
            self.cache[key] = _count(self.con, table, self.start_ns if window else None,
                                     self.end_ns if window else None, site=self.site,
                                     where=where, params=params)
        return self.cache[key]

    @property
    def decl(self) -> families.Declared | None:
        return None if self.cfg is None else families.declared(self.cfg)

    @property
    def simulated(self) -> bool:
        """The site holds simulated rows (a reference table has rows): only then may a
        cause suggest the simulator."""
        return any(self.count(t, window=False) for t in (*REFERENCES, "fault_truth"))


def _count(con: duckdb.DuckDBPyConnection, table: str, start_ns: int | None = None,
           end_ns: int | None = None, sector: str | None = None, *, site: str | None = None,
           where: str = "", params: tuple = ()) -> int:
    t = spec(table)
    clauses, args = [], []
    if start_ns is not None and t.time_column:
        clauses.append(f'"{t.time_column}" >= ? AND "{t.time_column}" < ?')
        args += [int(start_ns), int(end_ns)]
    if sector is not None and "sector" in t.schema.names:
        clauses.append("sector = ?")
        args.append(sector)
    if site is not None and "site" in t.schema.names:
        clauses.append("site = ?")
        args.append(site)
    if where:
        clauses.append(where)
        args += list(params)
    sql = f'SELECT count(*) FROM "{table}"' + (" WHERE " + " AND ".join(clauses)
                                                if clauses else "")
    return int(con.execute(sql, args).fetchall()[0][0])


def _batch_rejects(ctx: _Ctx, code: str) -> list[str]:
    """The batch rejects of the window with ``code``: their reasons, most rows first."""
    clauses = ["stage = 'batch'", "reason_code = ?", "log_time_ns >= ?", "log_time_ns < ?"]
    args: list = [code, ctx.start_ns, ctx.end_ns]
    if ctx.site is not None:
        clauses.append("site = ?")
        args.append(ctx.site)
    rows = ctx.con.execute(
        "SELECT reason, count(*) AS n FROM rejects WHERE " + " AND ".join(clauses)
        + " GROUP BY reason ORDER BY n DESC, reason LIMIT 6", args).fetchall()
    return [f"{r}" + (f" ({n:,} rows)" if n > 1 else "") for r, n in rows]


def _elsewhere(ctx: _Ctx, table: str) -> str:
    """`` (N rows at other times)``, or on a simulated warehouse without any row the
    command that writes them."""
    total = ctx.count(table, window=False)
    if total:
        return f" ({total:,} rows at other times)"
    return f": {producer(table)} writes them" if ctx.simulated else ""


def _raw_cause(ctx: _Ctx, table: str) -> str:
    total = ctx.count(table, window=False)
    if total:
        return f"{table} has no rows in the window ({total:,} rows at other times)"
    if ctx.simulated:
        return f"{table} is empty: {producer(table)} writes it"
    return f"{table} is empty: the site's recordings hold none"


def _family(table: str) -> str | None:
    for fam in families.FAMILIES:
        if table in fam.outputs:
            return fam.name
    return None


def _not_batched(ctx: _Ctx, fam: str) -> str | None:
    """``run surveil batch`` when no committed unit of ``fam`` (of the site) overlaps
    the window, else None."""
    n = ctx.count("batch_units", window=False, where="family = ? AND start_ns < ? AND end_ns > ?",
                  params=(fam, ctx.end_ns, ctx.start_ns))
    return None if n else (f"no batch has run over this window ({fam} family): "
                           "`surveil batch --from T --to T`")


def _maritime(ctx: _Ctx, table: str) -> str:
    decl = ctx.decl
    radars = decl.radars if decl is not None else ()
    needs_radar = table not in ("maritime_channel_health",)
    if needs_radar and decl is not None and not radars:
        return (f"{table}: not applicable at this site: no radar site is declared "
                "([[radar_sites]]), so there is no fused picture; AIS alone gets its "
                "self-test (channel_faults_by_sector)")
    if table == "cross_track_by_leg" and decl is not None and not decl.legs:
        return (f"{table}: not applicable at this site: no fairway leg is declared "
                "([[fairway_legs]])")
    if table == "identifications" and not ctx.count("ais_reports"):
        return f"{table} has no rows: no AIS report in the window" + _elsewhere(ctx,
                                                                               "ais_reports")
    if needs_radar and not ctx.count("radar_tracks"):
        unknown = _batch_rejects(ctx, "unknown_site")
        if unknown:
            return (f"{table} has no rows: the window's radar reports were not used: "
                    + "; ".join(unknown) + " (declare the site in [[radar_sites]])")
        return (f"{table} has no rows: no radar report in the window "
                f"({len(radars)} radar site(s) declared: {', '.join(radars)})"
                + _elsewhere(ctx, "radar_tracks"))
    if not needs_radar and not ctx.count("radar_tracks") and not ctx.count("ais_reports"):
        return f"{table} has no rows: no radar report and no AIS report in the window"
    if needs_radar:
        unknown = _batch_rejects(ctx, "unknown_site")
        if unknown and not ctx.count("associations"):
            return (f"{table} has no rows: the window's radar reports were not used: "
                    + "; ".join(unknown) + " (declare the site in [[radar_sites]])")
    return _not_batched(ctx, "maritime") or ""


def _airfield(ctx: _Ctx, table: str) -> str:
    decl = ctx.decl
    if decl is not None and not decl.airfield:
        held = ctx.count("airfield_obs")
        return (f"{table}: not applicable at this site: no airfield is declared ([airfield])"
                + (f"; airfield_obs holds {held:,} reports in the window: `surveil config "
                   "init` declares their sensors" if held else ""))
    if not ctx.count("airfield_obs"):
        return (f"{table} has no rows: no airfield report (airfield_obs) in the window"
                + _elsewhere(ctx, "airfield_obs"))
    unknown = _batch_rejects(ctx, "unknown_sensor")
    if unknown and not ctx.count("channel_health"):
        return (f"{table} has no rows: the window's airfield reports were not used: "
                + "; ".join(unknown))
    return _not_batched(ctx, "airfield") or ""


def _gaps(ctx: _Ctx, table: str) -> str:
    if not ctx.count("ais_reports"):
        return f"{table} has no rows: no AIS report in the window" + _elsewhere(
            ctx, "ais_reports")
    g = (ctx.cfg.families or {}).get("gaps") if ctx.cfg is not None else None
    threshold = getattr(g, "gap_threshold_s", None)
    if threshold is not None:
        span = ctx.con.execute(
            "SELECT min(time_ns), max(time_ns) FROM ais_reports WHERE time_ns >= ? AND "
            "time_ns < ?" + (" AND site = ?" if ctx.site is not None else ""),
            [ctx.start_ns, ctx.end_ns] + ([ctx.site] if ctx.site is not None else [])
        ).fetchall()[0]
        length_s = (span[1] - span[0]) / NS if span[0] is not None else 0.0
        if length_s <= threshold:
            return (f"{table} has no rows: the AIS log is {length_s:,.0f} s long, no vessel can "
                    f"be silent for [gaps] gap_threshold_s = {threshold:g} s in it")
        return (f"{table} has no rows: no vessel was silent longer than [gaps] "
                f"gap_threshold_s = {threshold:g} s in the window")
    return _not_batched(ctx, "gaps") or ""


def _nav(ctx: _Ctx, table: str) -> str:
    if not any(ctx.count(t) for t in NAV_INPUTS):
        return (f"{table} has no rows: no own-ship data ({', '.join(NAV_INPUTS)}) in the "
                "window")
    if table == "nav_outages" and ctx.count("nav_solution"):
        return (f"{table} has no rows: no GNSS outage in the window (nav_solution has "
                f"{ctx.count('nav_solution'):,} rows)")
    return _not_batched(ctx, "nav") or ""


def _calibration(ctx: _Ctx, table: str) -> str:
    decl = ctx.decl
    if table == "radar_bias_by_site" and decl is not None and not decl.radars:
        return (f"{table}: not applicable at this site: no radar site is declared "
                "([[radar_sites]])")
    if table == "sensor_error_models":
        return (f"{table} is empty: `surveil calibrate --from T --to T` fits the airfield "
                "sensors' models against a reference (airfield_truth); without one the batch "
                "scales each sensor's default model to the data (channel_health.error_model)")
    return f"{table} has no rows in the window: {producer(table)} writes it"


def _derived_cause(ctx: _Ctx, table: str) -> str:
    fam = _family(table)
    why = {"maritime": _maritime, "airfield": _airfield, "gaps": _gaps, "nav": _nav}.get(
        fam or "", lambda c, t: "")(ctx, table)
    if why:
        return why
    if table in _CALIBRATIONS:
        return _calibration(ctx, table)
    total = ctx.count(table, window=False)
    if total:
        return f"{table} has no rows in the window ({total:,} rows at other times)"
    return f"{table} has no rows in the window"


def why_empty(
    con: duckdb.DuckDBPyConnection,
    tables: Iterable[str],
    *,
    start_ns: int,
    end_ns: int,
    sector: str | None = None,
    cfg: Config | None = None,
    site: str | None = None,
    report: str | None = None,
) -> str:
    """One or two sentences: why queries over ``tables`` have nothing in the window for
    ``site`` (module docstring; ``con`` has the warehouse views, ``cfg`` says what the
    site declares)."""
    ctx = _Ctx(con, start_ns, end_ns, sector, cfg, site)
    reasons = []
    for table in tables:
        if table not in table_specs():
            continue
        in_window = ctx.count(table)
        if in_window and sector is not None and "sector" in spec(table).schema.names:
            if _count(con, table, start_ns, end_ns, sector, site=site) == 0:
                reasons.append(f"{table} has {in_window:,} rows in the window, none in sector "
                               f"{sector!r}")
            continue
        if in_window:
            continue
        kind = spec(table).kind
        reasons.append(_raw_cause(ctx, table) if kind in ("raw", "ledger")
                       else _derived_cause(ctx, table))
    reasons = _merged(reasons)
    if not reasons:
        ref = _SCORED.get(report or "")
        if ref is not None and not ctx.count(ref[0], window=False):
            return (f"not applicable at this site: {ref[1]} is scored against a reference "
                    f"({ref[0]}), and the site's recordings have none")
        return ("the source tables have rows in the window, but none the report keeps "
                "(e.g. no reference to score against)")
    return "; ".join(reasons)


def _merged(reasons: list[str]) -> list[str]:
    """Reasons that say the same of several tables, once: ``system_tracks, track_errors:
    not applicable ...``."""
    out: list[tuple[list[str], str]] = []
    for r in reasons:
        head, sep, rest = r.partition(": ")
        names = head.split(" ")[0] if sep else ""
        tail = (head[len(names):] + sep + rest) if names else r
        for tables_, text in out:
            if names and text == tail:
                tables_.append(names)
                break
        else:
            out.append(([names] if names else [], tail))
    return [", ".join(t) + text if t else text for t, text in out]


def explain_empty_report(con: duckdb.DuckDBPyConnection, report: ReportSql, *, start_ns: int,
                         end_ns: int, sector: str | None = None, cfg: Config | None = None,
                         site: str | None = None) -> str:
    """Why report ``report`` has no rows, from the tables its header names."""
    return why_empty(con, report.source_tables(), start_ns=start_ns, end_ns=end_ns,
                     sector=sector, cfg=cfg, site=site, report=report.name)


def explain_empty(warehouse: Path, report: ReportSql, *, start_ns: int | None,
                  end_ns: int | None, sector: str | None, cfg: Config | None = None,
                  site: str | None = None) -> str:
    """Why ``report`` has no rows in the window: what its source tables hold and which
    command writes them."""
    con = open_warehouse(warehouse)
    try:
        return explain_empty_report(
            con, report, start_ns=ALL_TIME[0] if start_ns is None else start_ns,
            end_ns=ALL_TIME[1] if end_ns is None else end_ns, sector=sector, cfg=cfg,
            site=site)
    finally:
        con.close()
