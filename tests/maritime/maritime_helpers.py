"""Helpers for the maritime audit tests: the `channel` scenario as canonical input
tables in memory (no MCAP round trip), and configs with extra sections."""

from __future__ import annotations

import numpy as np
import polars as pl

from pipeline.config import Config
from pipeline.decode.ais import decode_ais_sentences
from pipeline.families import config_from_mapping
from pipeline.family import Window
from pipeline.maritime.config import without_faults
from pipeline.maritime.stage import stage
from pipeline.simulate.channel import simulate_channel
from pipeline.simulate.scenarios import with_scenario
from pipeline.units import NS

T0_NS = 1_768_435_200 * NS  # 2026-01-15T00:00:00Z


def with_sections(cfg: Config, **sections: dict) -> Config:
    """``cfg`` with TOML sections replaced (e.g. radar_bias={...}), parsed again as the
    simulator's world (it may hold [radar_bias.simulate])."""
    return config_from_mapping({**cfg.sections, **sections}, cfg.source, scenario=True)


def biased(cfg: Config, simulate: dict[str, dict], *, apply: bool = False,
           correction: dict[str, dict] | None = None) -> Config:
    """``cfg`` whose [radar_bias] injects ``simulate`` (site -> range_bias_m,
    azimuth_bias_deg, time_offset_s) and optionally applies ``correction``."""
    base = dict(cfg.section("radar_bias"))
    base.update(apply=apply, simulate=simulate, correction=correction or {})
    return with_sections(cfg, radar_bias=base)


def scenario_tables(cfg: Config, *, duration_s: float, seed: int, start_ns: int = T0_NS,
                    faults: bool = False) -> tuple[pl.DataFrame, pl.DataFrame, pl.DataFrame]:
    """(radar_tracks, ais_reports, truth) of the channel scenario, canonical columns
    (radar_tracks also keeps the simulator's ``status``: new/confirmed/coasting);
    without the config's fault schedule unless ``faults``."""
    # the fault schedule: the demo site's scenario file (config/scenarios/channel.toml)
    world = with_scenario(cfg, ["channel"])
    sc = simulate_channel(world if faults else without_faults(world), start_ns=start_ns,
                          duration_s=duration_s, seed=seed)
    radar = sc.radar_reports.rename(
        {"track_id": "local_track_id", "x_m": "x_site_m", "y_m": "y_site_m"}
    ).with_columns(pl.lit("sim").alias("source_file"),
                                  pl.lit("/radar").alias("topic"))
    sentences = [s.encode() for s in sc.ais_sentences["sentence"].to_list()]
    reports, _, _ = decode_ais_sentences(
        sentences, sc.ais_sentences["log_time_ns"].to_numpy().astype(np.int64),
        source_file="sim", topic="/ais")
    return radar, pl.from_arrow(reports), sc.truth


def batch_tables(cfg: Config, *, duration_s: float, seed: int, margin_s: float = 60.0
                 ) -> dict[str, pl.DataFrame]:
    """The maritime stage over the scenario, in memory, on the epochs from ``margin_s``
    after the start to ``margin_s`` before the end (the tables the batch commits: not
    the stage's ``_`` outputs for the stitch)."""
    radar, ais, truth = scenario_tables(cfg, duration_s=duration_s, seed=seed)
    inputs = {"radar_tracks": radar, "ais_reports": ais, "truth": truth}
    window = Window(T0_NS + round(margin_s * NS), T0_NS + round((duration_s - margin_s) * NS))
    out = stage(inputs, window, cfg)
    return {name: frame for name, frame in out.items() if not name.startswith("_")}
