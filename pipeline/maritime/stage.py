"""The maritime family's stage: radar track reports + AIS (+ truth) -> the fused picture.

Composes the pure steps for the epochs of one window: alignment to the regional frame,
two-step synchronisation (multi-radar paper eq. 7-13), track-to-track association
(two-radar identification paper eq. 7-16), channel integrity of every radar and AIS
transponder (airfield paper eq. 21-23; a channel in fault is left out of the fusion and
the identification), online registration and estimated accuracy of each radar from the
integrity's residuals (issue 38: a biased radar corrected and fused again, a degraded
one down-weighted; ``pipeline.maritime.registration``; where a registration is applied,
association, integrity and registration run a second time on the synchronised reports
corrected by it, so that the corrected radar's tracks join the other radars' system
tracks; ``maritime_channel_health`` and the AIS exclusions stay the first pass's, the
channels as reported), fusion (multi-radar paper eq. 14), geodetic
position, sectors, cross-track deviation (eq. 1-6), AIS identification, accuracy
against truth (or AIS), SIAP per sector and cross-track error per leg.

**Continuity across work units.** The batch cuts a window into units that run
independently; the steps carry state from epoch to epoch (the association's pairings,
the integrity's exclusions and reference tracks, the identity test's held sums) and the
reconstructed AIS reference is smoothed over the reports on both sides of an epoch. So
a unit runs the tracking steps over its window widened by :func:`continuity_margins_s`
(a lead-in that lets that state settle, a look-ahead for the smoother) and keeps the
epochs of its own window; the system track ids of the lead-in are handed to
:mod:`pipeline.maritime.stitch`, which continues the ids of the unit before. Results
then do not depend on where units are cut (tests/jobs/test_unit_cuts.py).
"""

from __future__ import annotations

import numpy as np
import polars as pl

from pipeline.config import Config
from pipeline.family import Family, Inputs, Outputs, TableInput, Window
from pipeline.geometry import add_geodetic, assign_sectors, cross_track
from pipeline.maritime.align import align_reports
from pipeline.maritime.associate import associate_tracks, split_parents
from pipeline.maritime.config import (
    DECLARATION,
    SECTIONS,
    MaritimeConfig,
    maritime_config,
    parse_maritime,
)
from pipeline.maritime.cross_track import cross_track_by_leg
from pipeline.maritime.evaluate import radar_detection
from pipeline.maritime.fuse import fuse
from pipeline.maritime.identity import identify
from pipeline.maritime.integrity import (
    IntegrityResult,
    RegistrationEvidence,
    check_channels,
    site_positions_enu,
)
from pipeline.maritime.reference import reconstruct, truth_reference
from pipeline.maritime.registration import (
    Estimate,
    Registration,
    as_reported,
    correct_reports,
    moves_a_report,
    register,
    scale_covariances,
    stated_accuracy_scale,
    stated_velocity_scale,
    with_stated_scale,
)
from pipeline.maritime.score import pair_with_truth, score_tracks
from pipeline.maritime.siap import siap_by_sector
from pipeline.maritime.stitch import (
    LEAD_ASSOCIATIONS,
    SEAM_COLUMNS,
    SEAM_S,
    join_units,
    unit_seam,
)
from pipeline.maritime.sync import epoch_grid, synchronise
from pipeline.units import NS

UNIT_REPORTS = 300_000
"""Radar reports per work unit at most (about): ~2.5 KB of worker memory per report
read (docs/scale.md), so a unit stays well under 2 GB at any traffic density."""

OUTPUTS = DECLARATION.outputs  # the tables the stage writes (pipeline.maritime.config)


def continuity_margins_s(cfg: Config) -> tuple[float, float]:
    """(lead-in, look-ahead) a unit tracks beyond its window, s: ``[ais]
    identity_window_s`` on either side (the identity test's history before; the
    smoothed reference's reports after), plus ``[channel_integrity] unit_settle_s``
    before (at least the seam the stitch compares, ``SEAM_S``); with ``unit_settle_s =
    0`` that seam alone (no continuity but the ids')."""
    settle_s = maritime_config(cfg).integrity.unit_settle_s
    if settle_s == 0:
        return SEAM_S, 0.0
    vote_s = cfg.ais.identity_window_s
    return vote_s + max(settle_s, SEAM_S), vote_s


def inputs(cfg: Config) -> tuple[TableInput, ...]:
    """Over the window widened by :func:`continuity_margins_s`: radar reports from two
    scan periods before it (an epoch takes each radar's latest scan ending within one
    period before it, and a scan's reports start one period before its end; plus 1 s of
    slack), AIS reports from the identification's report age before it, truth 2 s
    around it."""
    # (no radar site: an AIS-only site; its radar reports, if any, are rejects)
    scan_margin_s = 2 * max((s.scan_period_s for s in cfg.radar_sites), default=4.0) + 1.0
    lead_s, look_s = continuity_margins_s(cfg)
    # the steps order the rows themselves: no sort of every row read
    return (
        TableInput("radar_tracks", before_s=lead_s + scan_margin_s, after_s=look_s,
                   sorted=False),
        TableInput("ais_reports", before_s=lead_s + cfg.ais.max_report_age_s,
                   after_s=look_s, sorted=False),
        TableInput("truth", before_s=lead_s + 2.0, after_s=look_s + 2.0, sorted=False),
    )


def stage(tables: Inputs, window: Window, cfg: Config) -> Outputs:
    """The maritime tables for the epochs in ``window``.

    Returns frames for ``associations``, ``system_tracks``, ``identifications``,
    ``track_errors``, ``siap_by_sector`` (empty without truth), ``cross_track_by_leg``,
    ``maritime_channel_health`` and batch ``rejects`` (reports from unknown sites), and
    the lead-in's associations for the stitch (``LEAD_ASSOCIATIONS``, not a table).
    """
    mc = maritime_config(cfg)
    start_ns, end_ns = window.start_ns, window.end_ns
    lead_s, look_s = continuity_margins_s(cfg)
    track_start_ns, track_end_ns = start_ns - round(lead_s * NS), end_ns + round(look_s * NS)
    ais = tables["ais_reports"]
    truth = tables.get("truth")
    truth = truth if truth is not None and truth.height else None
    aligned, unknown = align_reports(tables["radar_tracks"], cfg)
    epochs = epoch_grid(track_start_ns, track_end_ns, mc.sync.epoch_period_s)
    synced = synchronise(aligned, epochs_ns=epochs, sync=mc.sync)
    # the channels' health is tested on the reports as reported (the first pass), on
    # covariances the stated-accuracy check scaled where it finds them too small
    associated, fusable, integrity, reg = _tracked(synced, aligned, ais, epochs,
                                                   track_start_ns, cfg)
    sites = [s.site_id for s in cfg.radar_sites]
    stated = _stated_scales(integrity.evidence, mc) if reg is not None else None
    if stated is not None and any((s > 1.0).any() for s in stated):
        # a site noisier than its sigmas say for minutes on end: tracked again on its
        # covariances scaled so (else it fails the integrity test all along)
        synced = scale_covariances(synced, integrity.evidence.epochs, *stated, sites,
                                   site_positions_enu(cfg))
        associated, fusable, integrity, reg = _tracked(synced, aligned, ais, epochs,
                                                       track_start_ns, cfg)
    if reg is not None and reg.estimate.applied.any():
        corrected = correct_reports(synced, reg.estimate, site_positions_enu(cfg), sites,
                                    cfg.sectors, cfg.region)
        if moves_a_report(synced, corrected):
            # the second pass: the reports corrected where a registration moves them, so
            # the corrected radar's tracks associate with the other radars' (no
            # duplicate born); its integrity test decides which radar rows are fused
            associated, fusable, _, reg = _tracked(corrected, aligned, ais, epochs,
                                                   track_start_ns, cfg, reg.estimate)
    if "reported_P_xx" in associated.columns:
        associated = as_reported(associated)
    registration = reg.table if reg is not None else pl.DataFrame()
    if registration.height:
        registration = with_stated_scale(registration, integrity.evidence.epochs, stated,
                                          sites)
    fused = fuse(fusable.filter(pl.col("used")))
    fused = add_geodetic(fused, cfg.region)
    fused = assign_sectors(fused, cfg.sectors, cfg.region)
    fused = cross_track(fused, cfg.fairway_legs, cfg.region, mc.max_cross_track_m)
    ais_used = ais.join(integrity.ais_excluded, on=["mmsi", "time_ns"], how="anti")
    identifications, fused = identify(
        fused, ais_used, cfg=cfg.ais, region=cfg.region,
        lineage=split_parents(associated, mc.association.track_timeout_s))
    # the reconstructed reference of the AIS vessels the integrity kept (issue 37), over
    # the whole tracked span (its smoothing reaches into the margins)
    reference, knots = reconstruct(ais_used, cfg.region, cfg.ais, mc.reference)
    # the unit's own epochs from here on (the margins only carried state and votes)
    own = pl.col("time_ns").is_between(start_ns, end_ns, closed="left")
    lead = associated.filter(pl.col("time_ns").is_between(
        start_ns - round(SEAM_S * NS), start_ns, closed="left"))
    tracked = fused  # SIAP's track-to-truth hysteresis also runs over the margins
    associated, fused = associated.filter(own), fused.filter(own)
    identifications = identifications.filter(own)
    # one pairing of the tracks with truth for the scoring and SIAP
    pairing = None if truth is None else pair_with_truth(
        tracked, truth, epochs, cfg.region, near_m=mc.siap.max_distance_m)
    errors = score_tracks(
        fused, associated, truth=truth, ais_reports=ais, region=cfg.region, sectors=cfg.sectors,
        reference=reference, reference_cfg=mc.reference, sites=cfg.radar_sites, pairing=pairing,
    )
    associations = associated.with_columns(
        pl.col("P_xx").sqrt().alias("sigma_x_m"),
        pl.col("P_yy").sqrt().alias("sigma_y_m"),
        pl.col("P_xy").alias("cov_xy_m2"),
    )
    siap = siap_by_sector(
        tracked, truth, epochs_ns=epochs, epoch_period_s=mc.sync.epoch_period_s,
        region=cfg.region, sectors=cfg.sectors, cfg=mc.siap, start_ns=start_ns, end_ns=end_ns,
        reference=reference, pairing=pairing,
    )
    detection = _detection(aligned, associations, errors, truth, reference, ais, cfg,
                           start_ns, end_ns)
    cross = cross_track_by_leg(
        fused, associations, errors, legs=cfg.fairway_legs, region=cfg.region,
        sites=cfg.radar_sites,
    )
    return {
        "associations": associations,
        "system_tracks": fused,
        "identifications": identifications,
        "track_errors": errors,
        "reference_tracks": knots.filter(own),
        "siap_by_sector": siap,
        "cross_track_by_leg": cross,
        "radar_detection": detection,
        "maritime_channel_health": integrity.health.filter(own),
        "sensor_registration": registration.filter(own) if registration.height
        else registration,
        "rejects": _unknown_site_rejects(unknown, start_ns, end_ns),
        LEAD_ASSOCIATIONS: lead.select("time_ns", "site_id", "local_track_id",
                                       "system_track_id"),
    }


def _stated_scales(evidence: RegistrationEvidence, mc: MaritimeConfig
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The stated-accuracy check's (K, C, 2) scales of each site's position (range,
    azimuth) and velocity (speed, course) sigmas."""
    return (stated_accuracy_scale(evidence, mc.registration),
            stated_velocity_scale(evidence, mc.registration, mc.integrity.ais_sigma_sog_mps,
                                  mc.integrity.ais_sigma_cog_rad))


def _tracked(synced: pl.DataFrame, aligned: pl.DataFrame, ais: pl.DataFrame, epochs,
             start_ns: int, cfg: Config, corrected_by: Estimate | None = None
             ) -> tuple[pl.DataFrame, pl.DataFrame, IntegrityResult, Registration | None]:
    """Association, integrity and registration of the synchronised reports: (associations
    with ``used`` as fused, the rows to fuse as corrected, the integrity's result, the
    registration or None when ``[registration]`` is off). ``corrected_by``: the estimate
    ``synced`` was corrected by (:func:`~pipeline.maritime.registration.register`)."""
    mc = maritime_config(cfg)
    associated = associate_tracks(synced, cfg=mc.association)
    associated = assign_sectors(associated, cfg.sectors, cfg.region)
    integrity = check_channels(
        associated, aligned, ais, epochs_ns=epochs, start_ns=start_ns, cfg=cfg, mc=mc
    )
    if not mc.registration.enabled:
        return integrity.associations, integrity.associations, integrity, None
    reg = register(integrity.associations, integrity.evidence, mc.registration,
                   radar_q=mc.integrity.radar_q, outlier_q=mc.integrity.outlier_q,
                   epoch_period_s=mc.sync.epoch_period_s,
                   sites=[s.site_id for s in cfg.radar_sites],
                   sector_names=[s.name for s in cfg.sectors], corrected_by=corrected_by)
    return reg.associations, reg.corrected, integrity, reg


def _detection(aligned: pl.DataFrame, associations: pl.DataFrame, errors: pl.DataFrame,
               truth: pl.DataFrame | None, reference, ais: pl.DataFrame, cfg: Config,
               start_ns: int, end_ns: int) -> pl.DataFrame:
    """``radar_detection`` rows against truth (every vessel) when the log has it, else
    against the reconstructed reference (issue 37); target class = AIS class A / B, or
    'none' for a vessel without AIS."""
    rc = maritime_config(cfg).reference
    ais_class = ais.select(pl.col("mmsi").alias("reference_id"),
                           pl.col("ais_class").alias("target_class")).unique("reference_id")
    if truth is not None:
        ref = truth_reference(truth, cfg.region)
        classes = (truth.select(pl.col("vessel_id").cast(pl.Int64).alias("reference_id"),
                                "mmsi").unique("reference_id")
                   .join(ais_class.rename({"reference_id": "mmsi"}), on="mmsi", how="left")
                   .select("reference_id", pl.col("target_class").fill_null("none")))
    else:
        ref, classes = reference, ais_class
    return radar_detection(
        aligned, associations, errors, ref, sites=cfg.radar_sites, sectors=cfg.sectors,
        region=cfg.region, classes=classes, start_ns=start_ns, end_ns=end_ns,
        max_distance_m=rc.detection_max_distance_m, range_bin_m=rc.coverage_range_bin_m,
        azimuth_bin_deg=rc.coverage_azimuth_bin_deg)


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
    config_fields=DECLARATION.config_fields,
    unit_s=3600,
    unit_rows=UNIT_REPORTS,
    unit_table="radar_tracks",
    sorted_outputs=True,
    unit_seam=unit_seam,
    join_units=join_units,
    stitch_lookback_s=600.0,  # the rows before a window: their last SEAM_S lie in these 10 min
    seam_columns={"associations": SEAM_COLUMNS},
)
