"""The gaps family's stage: particle-filter forecasts of vessels across data gaps.

Work units are UTC hours: a gap's filter needs the vessel's messages from before the
unit, which the unit reads itself (its inputs' margins), so units are independent and a
day never sits in one worker's memory. The stage reads

- ``ais_reports`` and ``system_tracks`` (those with an MMSI) from ``lookback_s`` (the
  longest forecast horizon plus the lead-in) before the window to ``max_horizon_s``
  after it: a gap whose forecasts fall in the window may have begun that much earlier,
  and whether (and when) the vessel reappeared is looked up that far ahead;
- ``truth`` over the window, when the log is simulated.

``system_tracks`` are this batch's: the gaps family runs in a later wave than the
maritime family and reads its staged rows inside the window (``pipeline.batch.plan.family_waves``),
the committed ones outside it. The random generator is seeded by the unit's window, so
re-running a window reproduces its rows exactly. The unit runs its batches of gaps on
``execution.threads_per_worker`` threads: a worker granted spare cores (the batch's
lone unit of a wave, ``pipeline.batch.plan.granted``) uses them; the rows are the same either way.
"""

from __future__ import annotations

import numpy as np

from pipeline.config import Config
from pipeline.family import Family, Inputs, Outputs, TableInput, Window
from pipeline.gaps.config import DECLARATION, gaps_config, parse_gaps
from pipeline.gaps.forecast import forecast_gaps
from pipeline.units import NS

OUTPUTS = DECLARATION.outputs  # the tables the stage writes (its config module)

AIS_COLUMNS = ("time_ns", "mmsi", "ais_class", "lat_deg", "lon_deg", "sog_mps", "cog_rad")
TRACK_COLUMNS = (
    "time_ns", "mmsi", "x_enu_m", "y_enu_m", "lat_deg", "lon_deg", "sigma_x_m", "sigma_y_m",
    "cov_xy_m2", "course_rad", "speed_mps", "sigma_course_rad", "sigma_speed_mps",
)
TRUTH_COLUMNS = ("time_ns", "mmsi", "lat_deg", "lon_deg")


def window_rng(start_ns: int, end_ns: int) -> np.random.Generator:
    """The unit's random generator, seeded by its window (non-negative seed words)."""
    return np.random.default_rng([int(start_ns) % 2**63, int(end_ns) % 2**63])


def inputs(cfg: Config) -> tuple[TableInput, ...]:
    g = gaps_config(cfg)
    return (
        TableInput("ais_reports", before_s=g.lookback_s, after_s=g.max_horizon_s,
                   columns=AIS_COLUMNS),
        TableInput("system_tracks", before_s=g.lookback_s, after_s=g.max_horizon_s,
                   columns=TRACK_COLUMNS),
        TableInput("truth", before_s=2.0, after_s=2.0, columns=TRUTH_COLUMNS),
    )


def stage(tables: Inputs, window: Window, cfg: Config) -> Outputs:
    """``gap_forecasts`` rows with forecast time in the window."""
    g = gaps_config(cfg)
    truth = tables["truth"]
    out = forecast_gaps(
        tables["ais_reports"],
        tables["system_tracks"],
        truth if truth.height else None,
        cfg=cfg,
        gaps_cfg=g,
        start_ns=window.start_ns,
        end_ns=window.end_ns,
        data_end_ns=window.end_ns + int(g.max_horizon_s * NS),
        rng=window_rng(window.start_ns, window.end_ns),
        threads=cfg.execution.threads_per_worker,
    )
    return {"gap_forecasts": out}


FAMILY = Family(
    name="gaps",
    sections=("gaps",),
    parse_config=parse_gaps,
    inputs=inputs,
    outputs=OUTPUTS,
    stage=stage,
    # hourly units: each reads its own lookback and horizon (inputs), so a day is not
    # one worker holding a day of fused tracks (~2.6 GB for a 1,000-ship region day)
    unit_s=3600,
    config_fields=DECLARATION.config_fields,
)
