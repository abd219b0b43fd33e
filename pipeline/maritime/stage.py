"""The maritime family's stage: radar track reports + AIS (+ truth) -> the fused picture.

Composes the pure steps for the epochs of one window: alignment to the regional frame,
two-step synchronisation (multi-radar paper eq. 7-13), track-to-track association
(two-radar identification paper eq. 7-16), channel integrity of every radar and AIS
transponder (airfield paper eq. 21-23; a channel in fault is left out of the fusion and
the identification), fusion (multi-radar paper eq. 14), geodetic
position, sectors, cross-track deviation (eq. 1-6), AIS identification, accuracy
against truth (or AIS), SIAP per sector and cross-track error per leg.
"""

from __future__ import annotations

import polars as pl

from pipeline.config import Config
from pipeline.family import Family, Inputs, Outputs, TableInput, Window
from pipeline.geometry import add_geodetic, assign_sectors, cross_track
from pipeline.maritime.align import align_reports
from pipeline.maritime.associate import associate_tracks
from pipeline.maritime.config import SECTIONS, maritime_config, parse_maritime
from pipeline.maritime.cross_track import cross_track_by_leg
from pipeline.maritime.fuse import fuse
from pipeline.maritime.identity import identify
from pipeline.maritime.integrity import check_channels
from pipeline.maritime.score import score_tracks
from pipeline.maritime.siap import siap_by_sector
from pipeline.maritime.stitch import join_units, unit_seam
from pipeline.maritime.sync import epoch_grid, synchronise
from pipeline.units import NS

UNIT_REPORTS = 300_000
"""Radar reports per work unit at most (about): ~2.5 KB of worker memory per report
read (docs/scale.md), so a unit stays well under 2 GB at any traffic density."""

DERIVED_TABLES = ("associations", "system_tracks", "identifications", "track_errors")
# maritime audit tables (docs/maritime.md): SIAP against truth, cross-track error per leg
AUDIT_TABLES = ("siap_by_sector", "cross_track_by_leg")
# channel integrity (issue 22): every radar per sector and every AIS transponder
INTEGRITY_TABLES = ("maritime_channel_health",)
OUTPUTS = DERIVED_TABLES + AUDIT_TABLES + INTEGRITY_TABLES


def inputs(cfg: Config) -> tuple[TableInput, ...]:
    """Radar reports from two scan periods before the window (an epoch takes each radar's
    latest scan ending within one period before it, and a scan's reports start one
    period before its end; plus 1 s of slack), AIS reports from the identification's
    report age before it, truth 2 s around it."""
    scan_margin_s = 2 * max(s.scan_period_s for s in cfg.radar_sites) + 1.0
    # the steps order the rows themselves: no sort of every row read
    return (
        TableInput("radar_tracks", before_s=scan_margin_s, sorted=False),
        TableInput("ais_reports", before_s=cfg.ais.max_report_age_s, sorted=False),
        TableInput("truth", before_s=2.0, after_s=2.0, sorted=False),
    )


def stage(tables: Inputs, window: Window, cfg: Config) -> Outputs:
    """The maritime tables for the epochs in ``window``.

    Returns frames for ``associations``, ``system_tracks``, ``identifications``,
    ``track_errors``, ``siap_by_sector`` (empty without truth), ``cross_track_by_leg``,
    ``maritime_channel_health`` and batch ``rejects`` (reports from unknown sites).
    """
    mc = maritime_config(cfg)
    start_ns, end_ns = window.start_ns, window.end_ns
    ais = tables["ais_reports"]
    truth = tables.get("truth")
    truth = truth if truth is not None and truth.height else None
    aligned, unknown = align_reports(tables["radar_tracks"], cfg)
    epochs = epoch_grid(start_ns, end_ns, mc.sync.epoch_period_s)
    synced = synchronise(aligned, epochs_ns=epochs, sync=mc.sync)
    id_base = (start_ns // NS) * 10_000
    associated = associate_tracks(synced, cfg=mc.association, id_base=id_base)
    associated = assign_sectors(associated, cfg.sectors, cfg.region)
    integrity = check_channels(
        associated, aligned, ais, epochs_ns=epochs, start_ns=start_ns, cfg=cfg, mc=mc
    )
    associated = integrity.associations
    fused = fuse(associated.filter(pl.col("used")))
    fused = add_geodetic(fused, cfg.region)
    fused = assign_sectors(fused, cfg.sectors, cfg.region)
    fused = cross_track(fused, cfg.fairway_legs, cfg.region, mc.max_cross_track_m)
    ais_used = ais.join(integrity.ais_excluded, on=["mmsi", "time_ns"], how="anti")
    identifications, fused = identify(fused, ais_used, cfg=cfg.ais, region=cfg.region)
    errors = score_tracks(
        fused, associated, truth=truth, ais_reports=ais, region=cfg.region, sectors=cfg.sectors
    )
    associations = associated.with_columns(
        pl.col("P_xx").sqrt().alias("sigma_x_m"),
        pl.col("P_yy").sqrt().alias("sigma_y_m"),
        pl.col("P_xy").alias("cov_xy_m2"),
    )
    siap = siap_by_sector(
        fused, truth, epochs_ns=epochs, epoch_period_s=mc.sync.epoch_period_s,
        region=cfg.region, sectors=cfg.sectors, cfg=mc.siap, start_ns=start_ns, end_ns=end_ns,
    )
    cross = cross_track_by_leg(
        fused, associations, errors, legs=cfg.fairway_legs, region=cfg.region,
        sites=cfg.radar_sites,
    )
    return {
        "associations": associations,
        "system_tracks": fused,
        "identifications": identifications,
        "track_errors": errors,
        "siap_by_sector": siap,
        "cross_track_by_leg": cross,
        "maritime_channel_health": integrity.health.filter(
            pl.col("time_ns").is_between(start_ns, end_ns, closed="left")
        ),
        "rejects": _unknown_site_rejects(unknown, start_ns, end_ns),
    }


def _unknown_site_rejects(unknown: pl.DataFrame, start_ns: int, end_ns: int) -> pl.DataFrame:
    """Reports from sites missing in the config: rejects rows (those logged in the window)."""
    unknown = unknown.filter(pl.col("log_time_ns").is_between(start_ns, end_ns, closed="left"))
    if unknown.height == 0:
        return pl.DataFrame()
    return unknown.select(
        pl.col("log_time_ns"),
        pl.col("source_file"),
        pl.col("topic"),
        pl.lit("batch").alias("stage"),
        pl.lit("unknown_site").alias("reason_code"),
        (pl.lit("radar site not in config: ") + pl.col("site_id")).alias("reason"),
    )


FAMILY = Family(
    name="maritime",
    sections=SECTIONS,
    parse_config=parse_maritime,
    inputs=inputs,
    outputs=OUTPUTS,
    stage=stage,
    unit_s=3600,
    unit_rows=UNIT_REPORTS,
    unit_table="radar_tracks",
    sorted_outputs=True,
    unit_seam=unit_seam,
    join_units=join_units,
    stitch_lookback_s=600.0,  # the unit before a window: its last epoch lies in these 10 min
)
