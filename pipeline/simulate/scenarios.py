"""Every scenario ``surveil simulate`` can write, by name."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from pipeline.simulate.airfield_mcap import simulate_airfield_archive
from pipeline.simulate.channel_mcap import (
    simulate_channel_archive,
    simulate_channel_clean_archive,
)
from pipeline.simulate.gaps_mcap import write_gaps_archive
from pipeline.simulate.ownship import simulate_ownship_archive
from pipeline.simulate.region_mcap import DEFAULT_DURATION_S as REGION_DURATION_S
from pipeline.simulate.region_mcap import simulate_region_archive

ScenarioWriter = Callable[..., list[Path]]
"""(cfg, start_ns, duration_s, seed, out_dir, **options) -> MCAP files written, in time
order; ``options`` are the scenario's own (SCENARIO_OPTIONS)."""

# One entry per scenario; each sensor family adds its own line.
SCENARIOS: dict[str, ScenarioWriter] = {
    "channel": simulate_channel_archive,
    "channel-clean": simulate_channel_clean_archive,
    "airfield": simulate_airfield_archive,
    "gaps": write_gaps_archive,
    "ownship": simulate_ownship_archive,
    "region": simulate_region_archive,
}

SCENARIO_OPTIONS: dict[str, tuple[str, ...]] = {"region": ("ships", "radars")}
"""Keyword options a scenario takes besides (start, duration, seed, out_dir)."""

DEFAULT_DURATION_S: dict[str, float] = {"region": REGION_DURATION_S}
"""Duration when none is given: one hour, except where listed."""
