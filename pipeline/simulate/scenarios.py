"""Every scenario ``surveil simulate`` can write, by name."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from pipeline.config import Config
from pipeline.simulate.airfield_mcap import simulate_airfield_archive
from pipeline.simulate.channel_mcap import (
    simulate_channel_archive,
    simulate_channel_clean_archive,
)
from pipeline.simulate.gaps_mcap import write_gaps_archive
from pipeline.simulate.ownship import simulate_ownship_archive

ScenarioWriter = Callable[[Config, int, float, int, Path], list[Path]]
"""(cfg, start_ns, duration_s, seed, out_dir) -> MCAP files written, in time order."""

# One entry per scenario; each sensor family adds its own line.
SCENARIOS: dict[str, ScenarioWriter] = {
    "channel": simulate_channel_archive,
    "channel-clean": simulate_channel_clean_archive,
    "airfield": simulate_airfield_archive,
    "gaps": write_gaps_archive,
    "ownship": simulate_ownship_archive,
}
