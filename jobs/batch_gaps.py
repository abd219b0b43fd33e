"""Batch family ``gaps``: particle-filter forecasts of vessels across data gaps.

One work unit covers the whole window (``UNIT_S = None``): a gap's filter needs the
vessel's messages from before the window. The unit reads, from the warehouse,

- ``ais_reports`` and ``system_tracks`` (those with an MMSI) from ``lookback_s`` (the
  longest forecast horizon plus the lead-in) before the window to ``max_horizon_s``
  after it: a gap whose forecasts fall in the window may have begun that much earlier,
  and whether (and when) the vessel reappeared is looked up that far ahead;
- ``truth`` over the window, when the log is simulated.

``system_tracks`` are read as committed before this batch: the maritime family writes
them in the same run and commits at the end, so a first batch of a window forecasts from
AIS alone and a re-run (``surveil reprocess`` or the next nightly run) also uses the
identified radar tracks. The random generator is seeded by the window, so re-running a
window reproduces its rows exactly.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl

from pipeline.config import Config
from pipeline.gaps import forecast_gaps, gaps_config
from pipeline.warehouse.delta import read_table

NS = 1_000_000_000
OUTPUTS = ("gap_forecasts",)
UNIT_S = None

AIS_COLUMNS = ["time_ns", "mmsi", "ais_class", "lat_deg", "lon_deg", "sog_mps", "cog_rad"]
TRACK_COLUMNS = [
    "time_ns",
    "mmsi",
    "x_enu_m",
    "y_enu_m",
    "lat_deg",
    "lon_deg",
    "sigma_x_m",
    "sigma_y_m",
    "cov_xy_m2",
    "course_rad",
    "speed_mps",
    "sigma_course_rad",
    "sigma_speed_mps",
]
TRUTH_COLUMNS = ["time_ns", "mmsi", "lat_deg", "lon_deg"]


def window_rng(start_ns: int, end_ns: int) -> np.random.Generator:
    """The unit's random generator, seeded by its window (non-negative seed words)."""
    return np.random.default_rng([int(start_ns) % 2**63, int(end_ns) % 2**63])


def gaps_unit(warehouse: Path, cfg: Config, start_ns: int, end_ns: int) -> dict[str, pl.DataFrame]:
    """``gap_forecasts`` rows with forecast time in [start_ns, end_ns)."""
    g = gaps_config(cfg)
    lo = start_ns - int(g.lookback_s * NS)
    hi = end_ns + int(g.max_horizon_s * NS)
    ais = pl.from_arrow(
        read_table(warehouse, "ais_reports", start_ns=lo, end_ns=hi, columns=AIS_COLUMNS)
    )
    tracks = pl.from_arrow(
        read_table(warehouse, "system_tracks", start_ns=lo, end_ns=hi, columns=TRACK_COLUMNS)
    )
    truth = pl.from_arrow(
        read_table(
            warehouse,
            "truth",
            start_ns=start_ns - 2 * NS,
            end_ns=end_ns + 2 * NS,
            columns=TRUTH_COLUMNS,
        )
    )
    out = forecast_gaps(
        ais,
        tracks,
        truth if truth.height else None,
        cfg=cfg,
        gaps_cfg=g,
        start_ns=start_ns,
        end_ns=end_ns,
        data_end_ns=hi,
        rng=window_rng(start_ns, end_ns),
    )
    return {"gap_forecasts": out}
