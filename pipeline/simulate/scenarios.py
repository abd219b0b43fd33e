"""Every scenario ``surveil simulate`` can write, by name."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from pipeline.config import DEFAULT_CONFIG_PATH, Config
from pipeline.configspec import SCENARIO_DIR
from pipeline.families import with_scenario_files
from pipeline.resources import resource_path
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

SCENARIO_FILES: dict[str, str] = {
    "channel": "channel.toml", "channel-clean": "channel.toml",
    "airfield": "airfield.toml", "ownship": "ownship.toml",
}
"""The shipped scenario file of each scenario that has one (``config/scenarios/``): the
simulator's world on top of the site config (fault schedules, injected biases, the own
ship's voyage). ``gaps`` and ``region`` take everything from the site config (the region
scenario writes its own, ``region.toml``)."""


def shipped_scenario_file(scenario: str) -> Path | None:
    """``config/scenarios/<file>`` of ``scenario``, or None when it has none."""
    name = SCENARIO_FILES.get(scenario)
    return None if name is None else resource_path("config") / "scenarios" / name


def with_scenario(cfg: Config, scenarios: Sequence[str],
                  scenario_config: str | Path | None = None) -> Config:
    """``cfg`` with the simulator's world of ``scenarios`` on top: ``scenario_config``
    when given; else, for the shipped demo site (``config/surveil.toml``), each
    scenario's shipped file (``config/scenarios/``: the demo's fault schedules); else
    nothing (a site of your own is simulated without faults unless you give a scenario
    file). A ``cfg`` that already carries scenario files (or was built in memory) is
    returned as it is. :class:`~pipeline.config.ConfigError` when the file is bad."""
    if cfg.scenario_files:
        return cfg
    if scenario_config is not None:
        files = [Path(scenario_config)]
    elif cfg.source and Path(cfg.source).resolve() == DEFAULT_CONFIG_PATH.resolve():
        files = list(dict.fromkeys(f for s in scenarios
                                   if (f := shipped_scenario_file(s)) is not None))
    else:
        files = []
    return with_scenario_files(cfg, files) if files else cfg


__all__ = ["DEFAULT_DURATION_S", "SCENARIOS", "SCENARIO_DIR", "SCENARIO_FILES",
           "SCENARIO_OPTIONS", "shipped_scenario_file", "with_scenario"]
