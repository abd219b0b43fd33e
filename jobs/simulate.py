"""`surveil simulate`: write a simulated scenario as an MCAP archive (one file per hour)."""

from __future__ import annotations

from pathlib import Path

from jobs.common import UsageError, parse_duration
from pipeline.config import Config
from pipeline.simulate import DEFAULT_START_NS
from pipeline.simulate.scenarios import (
    DEFAULT_DURATION_S,
    SCENARIO_OPTIONS,
    SCENARIOS,
    with_scenario,
)

__all__ = ["DEFAULT_START_NS", "default_duration_s", "parse_duration", "run_simulate"]


def default_duration_s(scenario: str) -> float:
    """The scenario's duration when none is given, s (one hour unless it says otherwise)."""
    return DEFAULT_DURATION_S.get(scenario, 3600.0)


def run_simulate(
    scenario: str,
    duration_s: float | None,
    seed: int,
    out_dir: Path,
    cfg: Config,
    start_ns: int | None = None,
    scenario_config: str | Path | None = None,
    **options: int,
) -> list[Path]:
    """Simulate ``scenario`` for ``duration_s`` seconds (``None``: its default) from
    ``start_ns`` (ns since the Unix epoch, UTC; default 2026-01-15T00:00:00Z) and write
    it under ``out_dir`` as hourly MCAP files; return their paths in time order.

    ``options`` (e.g. ``ships``, ``radars`` for ``region``) go to scenarios that take
    them (SCENARIO_OPTIONS); ``None`` values mean the scenario's default. The simulator's
    world (fault schedules, injected biases) comes from ``scenario_config``, else for
    the demo site from the scenario's shipped file
    (:func:`pipeline.simulate.scenarios.with_scenario`)."""
    if scenario not in SCENARIOS:
        raise UsageError(
            f"unknown scenario {scenario!r}: available scenarios are {', '.join(SCENARIOS)}")
    given = {k: v for k, v in options.items() if v is not None}
    allowed = SCENARIO_OPTIONS.get(scenario, ())
    extra = sorted(set(given) - set(allowed))
    if extra:
        raise UsageError(
            f"scenario {scenario!r} takes no --{', --'.join(extra)} "
            f"(only the region scenario has --ships/--radars)")
    for k, v in given.items():
        if v < 1:
            raise UsageError(f"--{k} must be at least 1, got {v}")
    start = DEFAULT_START_NS if start_ns is None else int(start_ns)
    duration = default_duration_s(scenario) if duration_s is None else duration_s
    needs = [what for what, have in (("[[radar_sites]]", cfg.radar_sites),
                                     ("[[fairway_legs]]", cfg.fairway_legs))
             if scenario in ("channel", "channel-clean", "gaps") and not have]
    if needs:  # every family is optional in a site config; this scenario's world is not
        raise UsageError(f"scenario {scenario!r} simulates ships on a fairway seen by radars: "
                         f"config {cfg.source} has no {' and no '.join(needs)} (the demo site "
                         "config/surveil.toml has both)")
    world = with_scenario(cfg, [scenario], scenario_config)
    return SCENARIOS[scenario](world, start, duration, seed, Path(out_dir), **given)
