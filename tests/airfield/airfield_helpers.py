"""Shared pieces of the airfield tests (imported by the test modules; no fixtures here)."""

from __future__ import annotations

import polars as pl

from pipeline.airfield.config import AirfieldConfig, airfield_config
from pipeline.config import Config
from pipeline.units import NS

START_NS = 1_768_435_200 * NS  # 2026-01-15T00:00:00Z


def acfg(cfg: Config) -> AirfieldConfig:
    return airfield_config(cfg)


def seconds(df: pl.DataFrame, start_ns: int = START_NS) -> pl.DataFrame:
    """Add t_s: whole seconds since ``start_ns``."""
    return df.with_columns(((pl.col("time_ns") - start_ns) // NS).alias("t_s"))
