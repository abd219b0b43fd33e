"""Batch family ``nav``: own-ship integrated navigation (gyro/GNSS/log paper).

One work unit covers the whole window (``unit_s = None``): the Kalman filter runs over
continuous data, and it reads ``warmup_s`` of inputs before the window so that its rows
in the window come from a converged filter whatever the window's cut. Inputs:
``nav_gnss``, ``nav_heading``, ``nav_speed_log`` (NMEA, ROS, ...), ``nav_gyro_signals``
and, in simulated logs, ``ownship_truth``. Outputs ``nav_solution`` (rows in the window)
and ``nav_outages`` (outages starting in the window). Deterministic: no randomness.
"""

from __future__ import annotations

from pathlib import Path

import polars as pl

from pipeline.config import Config
from pipeline.nav.config import ownship_config
from pipeline.nav.solution import nav_window
from pipeline.warehouse.delta import read_table

NS = 1_000_000_000
OUTPUTS = ("nav_solution", "nav_outages")

GNSS_COLUMNS = ["time_ns", "platform_id", "lat_deg", "lon_deg", "fix_quality", "fix_valid",
                "sog_mps", "cog_rad"]
HEADING_COLUMNS = ["time_ns", "platform_id", "heading_rad", "is_magnetic"]
LOG_COLUMNS = ["time_ns", "platform_id", "speed_water_mps"]
GYRO_COLUMNS = ["time_ns", "platform_id", "accel_signal_rad", "amplifier_rad"]
TRUTH_COLUMNS = ["time_ns", "platform_id", "lat_deg", "lon_deg", "heading_rad"]


def nav_unit(warehouse: Path, cfg: Config, start_ns: int, end_ns: int) -> dict[str, pl.DataFrame]:
    """``nav_solution`` and ``nav_outages`` for [start_ns, end_ns)."""
    oc = ownship_config(cfg)
    lo = start_ns - int(oc.nav.warmup_s * NS)

    def read(name: str, columns: list[str], a: int = lo, b: int = end_ns) -> pl.DataFrame:
        return pl.from_arrow(read_table(warehouse, name, start_ns=a, end_ns=b, columns=columns))

    truth = read("ownship_truth", TRUTH_COLUMNS, start_ns - NS, end_ns + NS)
    return nav_window(
        read("nav_gnss", GNSS_COLUMNS), read("nav_heading", HEADING_COLUMNS),
        read("nav_speed_log", LOG_COLUMNS), read("nav_gyro_signals", GYRO_COLUMNS),
        truth if truth.height else None, start_ns=start_ns, end_ns=end_ns, cfg=cfg, oc=oc)
