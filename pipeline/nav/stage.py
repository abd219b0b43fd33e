"""The nav family's stage: own-ship integrated navigation (gyro/GNSS/log paper).

One work unit covers the whole window (``unit_s = None``): the Kalman filter runs over
continuous data, and it reads ``warmup_s`` of inputs before the window so that its rows
in the window come from a converged filter whatever the window's cut. Inputs:
``nav_gnss``, ``nav_heading``, ``nav_speed_log`` (NMEA, ROS, ...), ``nav_gyro_signals``
and, in simulated logs, ``ownship_truth``. Outputs ``nav_solution`` (rows in the window)
and ``nav_outages`` (outages starting in the window). Deterministic: no randomness.
"""

from __future__ import annotations

from pipeline.config import Config
from pipeline.family import Family, Inputs, Outputs, TableInput, Window
from pipeline.nav.config import DECLARATION, ownship_config, parse_ownship
from pipeline.nav.solution import nav_window

OUTPUTS = DECLARATION.outputs  # the tables the stage writes (its config module)

GNSS_COLUMNS = ("time_ns", "platform_id", "lat_deg", "lon_deg", "fix_quality", "fix_valid",
                "sog_mps", "cog_rad")
HEADING_COLUMNS = ("time_ns", "platform_id", "heading_rad", "is_magnetic")
LOG_COLUMNS = ("time_ns", "platform_id", "speed_water_mps")
GYRO_COLUMNS = ("time_ns", "platform_id", "accel_signal_rad", "amplifier_rad")
TRUTH_COLUMNS = ("time_ns", "platform_id", "lat_deg", "lon_deg", "heading_rad")


def inputs(cfg: Config) -> tuple[TableInput, ...]:
    """The sensor tables from ``warmup_s`` before the window; truth 1 s around it."""
    warmup_s = ownship_config(cfg).nav.warmup_s
    return (
        TableInput("nav_gnss", before_s=warmup_s, columns=GNSS_COLUMNS),
        TableInput("nav_heading", before_s=warmup_s, columns=HEADING_COLUMNS),
        TableInput("nav_speed_log", before_s=warmup_s, columns=LOG_COLUMNS),
        TableInput("nav_gyro_signals", before_s=warmup_s, columns=GYRO_COLUMNS),
        TableInput("ownship_truth", before_s=1.0, after_s=1.0, columns=TRUTH_COLUMNS),
    )


def stage(tables: Inputs, window: Window, cfg: Config) -> Outputs:
    """``nav_solution`` and ``nav_outages`` for the window."""
    truth = tables["ownship_truth"]
    return nav_window(
        tables["nav_gnss"], tables["nav_heading"], tables["nav_speed_log"],
        tables["nav_gyro_signals"], truth if truth.height else None,
        start_ns=window.start_ns, end_ns=window.end_ns, cfg=cfg, oc=ownship_config(cfg))


FAMILY = Family(
    name="nav",
    sections=("ownship",),
    parse_config=parse_ownship,
    inputs=inputs,
    outputs=OUTPUTS,
    stage=stage,
    unit_s=None,
    config_fields=DECLARATION.config_fields,
)
