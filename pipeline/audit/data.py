"""Everything one audit page shows, read through the same SQL reports as ``surveil report``.

:func:`collect` runs each report of :data:`AUDIT_REPORTS` over the window (and sector)
on a DuckDB connection whose views are the warehouse tables, judges the requirements on
their rows, and notes for every empty report why it is empty (:mod:`pipeline.catalog`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import duckdb
import pyarrow as pa

from pipeline.batch.provenance import rows_provenance
from pipeline.catalog import explain_empty_report
from pipeline.config import Config
from pipeline.families import declared
from pipeline.reports import load_report, run_report, site_geometry
from pipeline.requirements import Verdict, evaluate, requirements_config

AUDIT_REPORTS = (
    "accuracy_by_sector", "accuracy_over_time", "identification_by_sector", "siap_by_sector",
    "cross_track_by_leg", "cross_track_along_leg", "radar_bias_by_site",
    "surface_accuracy_by_area", "channel_faults_by_sector", "fault_timeline", "nav_quality",
    "nav_heading_error", "gap_forecasts", "gap_forecast_calibration", "map_tracks",
    "channel_fault_episodes", "ais_traffic", "ais_quality",
    # online registration (issue 38)
    "registration_over_time", "sensor_registration",
    # evaluation without truth (issue 37)
    "detection_by_sector", "radar_coverage", "track_continuity", "latency_by_sensor",
    "error_decomposition", "false_tracks", "dubious_tracks", "reference_quality",
    "target_drilldown", "target_points", "surface_detection_by_area",
)
MAP_POINTS_PER_TRACK_HOUR = 180  # map_tracks thinning: one point per track every 20 s per hour


@dataclass(frozen=True)
class AuditData:
    """The reports of one audit window, their verdicts, and why some are empty."""

    cfg: Config
    warehouse: Path
    start_ns: int
    end_ns: int
    sector: str | None
    reports: Mapping[str, pa.Table]
    empty_reasons: Mapping[str, str]
    verdicts: tuple[Verdict, ...]
    params: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    # the config digests behind the rows (pipeline.batch.provenance) and the warnings
    # when one family's rows in the window come from several configs
    provenance: tuple[str, ...] = ()
    provenance_warnings: tuple[str, ...] = ()

    def table(self, name: str) -> pa.Table:
        return self.reports[name]

    def rows(self, name: str) -> list[dict[str, Any]]:
        return self.reports[name].to_pylist()


def map_step_s(start_ns: int, end_ns: int) -> float:
    """Thinning of the map's tracks: ~180 points per track over the window (>= 5 s)."""
    return max(5.0, round((end_ns - start_ns) / 1e9 / MAP_POINTS_PER_TRACK_HOUR))


def _has_rows(con: duckdb.DuckDBPyConnection, table: str, site: str | None) -> bool:
    sql = f'SELECT count(*) FROM "{table}"' + (" WHERE site = ?" if site is not None else "")
    return bool(con.execute(sql, [site] if site is not None else []).fetchall()[0][0])


def not_applicable(con: duckdb.DuckDBPyConnection, cfg: Config, site: str | None
                   ) -> dict[str, str]:
    """Requirement group -> why it does not apply at ``site`` (``requirements.evaluate``):
    no radar (no fused picture to judge), no fairway leg, no reference to score SIAP or
    the airfield's accuracy against."""
    decl = declared(cfg)
    out: dict[str, str] = {}
    if not decl.radars:
        out = dict.fromkeys(("maritime", "siap", "cross_track"), "no radar at this site")
    else:
        if not decl.legs:
            out["cross_track"] = "no fairway leg declared at this site"
        if not _has_rows(con, "truth", site):
            out["siap"] = "no truth at this site (SIAP is scored against a reference)"
    if decl.airfield and not _has_rows(con, "airfield_truth", site):
        out["airfield"] = ("no reference (airfield_truth) at this site: accuracy and "
                           "identification are scored against one")
    return out


def collect(con: duckdb.DuckDBPyConnection, cfg: Config, warehouse: Path, *, start_ns: int,
            end_ns: int, sector: str | None = None, site: str | None = None) -> AuditData:
    """Run every audit report over ``[start_ns, end_ns)`` (one sector, or all) of
    ``site`` (None: every row, for a warehouse of one site)."""
    req = requirements_config(cfg)
    reports: dict[str, pa.Table] = {}
    reasons: dict[str, str] = {}
    params: dict[str, dict[str, Any]] = {}
    for name in AUDIT_REPORTS:
        report = load_report(name)
        extra = {"step_s": map_step_s(start_ns, end_ns)} if name in (
            "map_tracks", "target_points") else {}
        params[name] = extra
        table = run_report(con, report, start_ns=start_ns, end_ns=end_ns, sector=sector,
                           requirements=req, params=extra, site=site,
                           geometry=site_geometry(cfg))
        reports[name] = table
        if table.num_rows == 0:
            reasons[name] = explain_empty_report(con, report, start_ns=start_ns, end_ns=end_ns,
                                                 sector=sector, cfg=cfg, site=site)
    airfield = (cfg.families or {}).get("airfield") is not None
    verdicts = evaluate(
        reports, req,
        sectors=[s.name for s in cfg.sectors] if sector is None else [sector],
        legs=[leg.leg_id for leg in cfg.fairway_legs],
        airfield=airfield and sector is None,
        not_applicable=not_applicable(con, cfg, site),
    )
    derived = [t for name in AUDIT_REPORTS for t in load_report(name).source_tables()]
    lines, warnings = rows_provenance(warehouse, cfg, derived, start_ns, end_ns, site)
    return AuditData(cfg=cfg, warehouse=warehouse, start_ns=start_ns, end_ns=end_ns,
                     sector=sector, reports=reports, empty_reasons=reasons,
                     verdicts=tuple(verdicts), params=params, provenance=tuple(lines),
                     provenance_warnings=tuple(warnings))
