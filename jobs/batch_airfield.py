"""The ``airfield`` batch family and the ``surveil calibrate`` job.

Batch (one unit per UTC hour): read ``airfield_obs`` and ``airfield_truth`` from
``LEAD_IN_S`` before the unit (the filter's lead-in: tracks are warm at the unit start)
and the stored ``sensor_error_models``; run :func:`airfield_stage`; return
``airfield_tracks`` and ``channel_health`` for the unit, plus batch ``rejects`` rows
for reports of sensors that are not in the ``[airfield]`` config (one row per sensor,
with the count). A config without ``[airfield]`` (or a warehouse without airfield data)
yields empty tables.

Calibrate: fit the coloured-error models over [from, to) against the reference channel
and replace that window of ``sensor_error_models`` (predicate on ``fit_start_ns``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from jobs.common import UsageError
from pipeline.airfield.calibrate import calibrate, stored_models
from pipeline.airfield.config import AirfieldConfig, airfield_config
from pipeline.airfield.frames import config_sensor_id, sensor_rows, to_common_frame
from pipeline.airfield.fusion import fuse_airfield
from pipeline.airfield.score import score
from pipeline.config import Config
from pipeline.tables import conform
from pipeline.warehouse.delta import read_table, replace_window
from pipeline.warehouse.views import rebuild_views_file

log = logging.getLogger(__name__)

NS = 1_000_000_000
LEAD_IN_S = 120
UNIT_S = 3600
OUTPUTS = ("airfield_tracks", "channel_health")


def target_reports(obs: pl.DataFrame) -> pl.DataFrame:
    """Target reports only (CAT010 status messages carry no position)."""
    if "message_type" not in obs.columns:
        return obs
    return obs.filter(pl.col("message_type").is_null()
                      | (pl.col("message_type") == "target report"))


def unknown_sensor_rejects(obs: pl.DataFrame, cfg: AirfieldConfig, start_ns: int,
                           end_ns: int) -> pl.DataFrame:
    """One batch rejects row per sensor whose reports (logged in the window) belong to no
    configured airfield sensor, with their count: nothing is dropped silently."""
    inside = obs.filter(pl.col("log_time_ns").is_between(start_ns, end_ns, closed="left"))
    lost = inside.filter(config_sensor_id(inside, cfg).is_null())
    if lost.height == 0:
        return pl.DataFrame()
    return lost.group_by("sensor_id").agg(
        pl.col("log_time_ns").min(), pl.col("source_file").first(), pl.col("topic").first(),
        pl.len().alias("n")).select(
        "log_time_ns", "source_file", "topic", pl.lit("batch").alias("stage"),
        pl.lit("unknown_sensor").alias("reason_code"),
        pl.format("{} airfield_obs reports from sensor {} not in the [airfield] config",
                  pl.col("n"), pl.col("sensor_id")).alias("reason"))


@dataclass(frozen=True, eq=False)
class StageOutput:
    tracks: pl.DataFrame
    health: pl.DataFrame
    rejects: pl.DataFrame
    model_source: dict[str, str]


def airfield_stage(obs: pl.DataFrame, truth: pl.DataFrame | None, model_rows: pl.DataFrame,
                   cfg: AirfieldConfig, *, start_ns: int, end_ns: int) -> StageOutput:
    """The pure airfield stage: raw reports (+ reference, + stored models) -> fused
    tracks, channel health and rejects for [start_ns, end_ns)."""
    reports = target_reports(obs)
    rejects = unknown_sensor_rejects(reports, cfg, start_ns, end_ns)
    common = to_common_frame(sensor_rows(reports, cfg), cfg)
    models = stored_models(model_rows, cfg, end_ns)
    tracks, health = fuse_airfield(common, cfg, models, start_ns=start_ns, end_ns=end_ns)
    if tracks.height:
        tracks, health = score(tracks, health, truth, cfg)
    return StageOutput(tracks, health, rejects, dict(models.source))


def airfield_unit(warehouse: Path, cfg: Config, start_ns: int, end_ns: int
                  ) -> dict[str, pl.DataFrame]:
    """``BatchFamily.compute_unit`` of the airfield family."""
    if not cfg.section("airfield"):
        return {}
    acfg = airfield_config(cfg)
    lead = LEAD_IN_S * NS
    obs = pl.from_arrow(read_table(warehouse, "airfield_obs", start_ns=start_ns - lead,
                                   end_ns=end_ns))
    if obs.height == 0:
        return {}
    truth = pl.from_arrow(read_table(warehouse, "airfield_truth", start_ns=start_ns - lead,
                                     end_ns=end_ns))
    rows = pl.from_arrow(read_table(warehouse, "sensor_error_models"))
    out = airfield_stage(obs, truth if truth.height else None, rows, acfg,
                         start_ns=start_ns, end_ns=end_ns)
    log.info("airfield unit %s: models %s", start_ns, out.model_source)
    result = {"airfield_tracks": out.tracks, "channel_health": out.health}
    if out.rejects.height:
        result["rejects"] = out.rejects
    return {k: v for k, v in result.items() if v.height}


@dataclass
class CalibrateSummary:
    start_ns: int
    end_ns: int
    rows: int
    fits: dict[str, str]

    def render(self) -> str:
        lines = [f"sensor_error_models: {self.rows} rows for fit window "
                 f"[{self.start_ns}, {self.end_ns})"]
        lines += [f"  {k:<18} {v}" for k, v in sorted(self.fits.items())]
        return "\n".join(lines)


def run_calibrate(cfg: Config, warehouse: Path, *, start_ns: int, end_ns: int,
                  max_order: int = 4, min_speed_mps: float = 0.0) -> CalibrateSummary:
    """Fit and store every configured sensor's error models for [start_ns, end_ns)."""
    acfg = airfield_config(cfg)
    obs = target_reports(pl.from_arrow(read_table(warehouse, "airfield_obs",
                                                  start_ns=start_ns, end_ns=end_ns)))
    truth = pl.from_arrow(read_table(warehouse, "airfield_truth", start_ns=start_ns,
                                     end_ns=end_ns))
    if obs.height == 0:
        raise UsageError("no airfield_obs rows in the window: ingest the archive first")
    if truth.height == 0:
        raise UsageError("no airfield_truth rows in the window: calibrate needs a reference "
                         "(simulated truth, or DGNSS reference vehicles on the truth channel)")
    common = to_common_frame(sensor_rows(obs, acfg), acfg)
    rows, fits = calibrate(common, truth, acfg, start_ns=start_ns, end_ns=end_ns,
                           max_order=max_order, min_speed_mps=min_speed_mps)
    if rows.height == 0:
        raise UsageError("too few matched reports in the window to fit any error model")
    table = conform("sensor_error_models", rows)
    replace_window(warehouse, "sensor_error_models", table, start_ns=start_ns, end_ns=end_ns)
    rebuild_views_file(warehouse)
    desc = {k: f"AR({f.model.order}) on {f.n_rows} rows, BIC "
               + ", ".join(f"{p}:{b:.0f}" for p, b in sorted(f.bic_by_order.items()))
            for k, f in fits.items()}
    return CalibrateSummary(start_ns, end_ns, table.num_rows, desc)
