"""The airfield family's stage (airfield paper): SMR + MLAT + VASN reports -> fused
surface tracks and channel health.

One unit per UTC hour: ``airfield_obs`` and ``airfield_truth`` from ``LEAD_IN_S`` before
the unit (the filter's lead-in: tracks are warm at the unit start) and the stored
``sensor_error_models``; returns ``airfield_tracks`` and ``channel_health`` for the unit,
plus batch ``rejects`` rows for reports of sensors that are not in the ``[airfield]``
config (one row per sensor, with the count). A config without ``[airfield]`` (or a
warehouse without airfield data) yields empty tables.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import polars as pl

from pipeline.airfield.calibrate import calibrate, stored_models
from pipeline.airfield.config import DECLARATION, SENSOR_KINDS, AirfieldConfig, parse_airfield
from pipeline.airfield.frames import config_sensor_id, sensor_rows, to_common_frame
from pipeline.airfield.fusion import fuse_airfield_run
from pipeline.airfield.reference import empty_reference, smooth
from pipeline.airfield.score import score
from pipeline.airfield.selfcal import scaled_models
from pipeline.config import Config
from pipeline.family import Family, Inputs, Outputs, TableInput, Window

log = logging.getLogger(__name__)

LEAD_IN_S = 120
UNIT_S = 3600
OUTPUTS = DECLARATION.outputs  # the tables the stage writes (its config module)


def target_reports(obs: pl.DataFrame) -> pl.DataFrame:
    """Target reports only (CAT010 status messages carry no position)."""
    if "message_type" not in obs.columns:
        return obs
    return obs.filter(pl.col("message_type").is_null()
                      | (pl.col("message_type") == "target report"))


def unknown_sensor_rejects(obs: pl.DataFrame, cfg: AirfieldConfig, start_ns: int,
                           end_ns: int) -> pl.DataFrame:
    """One batch rejects row per sensor whose reports (logged in the window) belong to no
    configured airfield sensor, with their count, its kind and what to declare: nothing
    is dropped silently (issue 35: 6,666 reports of SMR 0/7 were rejected and the reports
    blamed the missing reference). A kind the family does not fuse (ADS-B, system
    tracks, PSR/SSR) says so instead (reason_code ``unfused_sensor_kind``)."""
    inside = obs.filter(pl.col("log_time_ns").is_between(start_ns, end_ns, closed="left"))
    lost = inside.filter(config_sensor_id(inside, cfg).is_null())
    if lost.height == 0:
        return pl.DataFrame()
    fused = pl.col("sensor_kind").is_in(list(SENSOR_KINDS))
    declare = pl.when(pl.col("sac").is_not_null() & pl.col("sic").is_not_null()).then(
        pl.format("declare it in [[airfield.sensors]] with kind = \"{}\", sac = {}, sic = {} "
                  "(`surveil config init` writes it)", pl.col("sensor_kind"), pl.col("sac"),
                  pl.col("sic"))).otherwise(
        pl.format("declare it in [[airfield.sensors]] with sensor_id = \"{}\"",
                  pl.col("sensor_id")))
    return lost.group_by("sensor_id").agg(
        pl.col("log_time_ns").min(), pl.col("source_file").first(), pl.col("topic").first(),
        pl.col("sensor_kind").first(), pl.col("sac").first(), pl.col("sic").first(),
        pl.len().alias("n")).sort("sensor_id").select(
        "log_time_ns", "source_file", "topic", pl.lit("batch").alias("stage"),
        pl.when(fused).then(pl.lit("unknown_sensor")).otherwise(pl.lit("unfused_sensor_kind"))
        .alias("reason_code"),
        pl.when(fused).then(pl.format(
            "{} airfield_obs reports from sensor {} ({}) not in the [airfield] config: {}",
            pl.col("n"), pl.col("sensor_id"), pl.col("sensor_kind"), declare))
        .otherwise(pl.format(
            "{} airfield_obs reports from sensor {} ({}): the airfield family fuses smr, mlat "
            "and vasn only (the rows stay in airfield_obs)", pl.col("n"), pl.col("sensor_id"),
            pl.col("sensor_kind"))).alias("reason"))


@dataclass(frozen=True, eq=False)
class StageOutput:
    tracks: pl.DataFrame
    health: pl.DataFrame
    rejects: pl.DataFrame
    model_source: dict[str, str]
    reference: pl.DataFrame


def airfield_stage(obs: pl.DataFrame, truth: pl.DataFrame | None, model_rows: pl.DataFrame,
                   cfg: AirfieldConfig, *, start_ns: int, end_ns: int) -> StageOutput:
    """The pure airfield stage: raw reports (+ reference, + stored models) -> fused
    tracks, channel health and rejects for [start_ns, end_ns)."""
    reports = target_reports(obs)
    rejects = unknown_sensor_rejects(reports, cfg, start_ns, end_ns)
    common = to_common_frame(sensor_rows(reports, cfg), cfg)
    models = stored_models(model_rows, cfg, end_ns)
    models = scaled_models(common, cfg, models, start_ns=start_ns, end_ns=end_ns)
    tracks, health, run = fuse_airfield_run(common, cfg, models, start_ns=start_ns,
                                            end_ns=end_ns, record=True)
    # the reconstructed reference: the fused filter smoothed (issue 37)
    reference = empty_reference() if run is None else smooth(run).filter(
        pl.col("time_ns").is_between(start_ns, end_ns, closed="left")
    ).sort("time_ns", "track_id")
    if tracks.height:
        tracks, health = score(tracks, health, truth, cfg, reference)
    if health.height:  # where each row's error model came from (config, default, fit)
        health = health.with_columns(
            pl.col("channel").replace_strict(dict(models.source), default=None,
                                             return_dtype=pl.String).alias("error_model"))
    return StageOutput(tracks, health, rejects, dict(models.source), reference)


def inputs(cfg: Config) -> tuple[TableInput, ...]:
    """Reports and reference from the lead-in before the unit; every stored model."""
    if cfg.family("airfield") is None:
        return ()
    return (
        TableInput("airfield_obs", before_s=LEAD_IN_S),
        TableInput("airfield_truth", before_s=LEAD_IN_S),
        TableInput("sensor_error_models", whole_table=True),
    )


def stage(tables: Inputs, window: Window, cfg: Config) -> Outputs:
    """``Family.stage`` of the airfield family (nothing without ``[airfield]`` or data)."""
    acfg = cfg.family("airfield")
    if acfg is None or tables["airfield_obs"].height == 0:
        return {}
    truth = tables["airfield_truth"]
    out = airfield_stage(tables["airfield_obs"], truth if truth.height else None,
                         tables["sensor_error_models"], acfg,
                         start_ns=window.start_ns, end_ns=window.end_ns)
    log.info("airfield unit %s: models %s", window.start_ns, out.model_source)
    result = {"airfield_tracks": out.tracks, "channel_health": out.health,
              "airfield_reference": out.reference}
    if out.rejects.height:
        result["rejects"] = out.rejects
    return {k: v for k, v in result.items() if v.height}


FAMILY = Family(
    name="airfield",
    sections=("airfield",),
    parse_config=parse_airfield,
    inputs=inputs,
    outputs=OUTPUTS,
    stage=stage,
    unit_s=UNIT_S,
    config_fields=DECLARATION.config_fields,
)


def calibration(obs: pl.DataFrame, truth: pl.DataFrame, cfg: AirfieldConfig, *,
                start_ns: int, end_ns: int, max_order: int = 4, min_speed_mps: float = 0.0
                ) -> tuple[pl.DataFrame, dict]:
    """The pure part of ``surveil calibrate``: each sensor's coloured-error AR models
    fitted over [start_ns, end_ns) against the reference (airfield paper eq. 2, 7, 8).
    Returns (``sensor_error_models`` rows, {channel: fit})."""
    common = to_common_frame(sensor_rows(target_reports(obs), cfg), cfg)
    return calibrate(common, truth, cfg, start_ns=start_ns, end_ns=end_ns,
                     max_order=max_order, min_speed_mps=min_speed_mps)
