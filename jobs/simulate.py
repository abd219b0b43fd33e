"""`surveil simulate`: write a simulated scenario as an MCAP archive (one file per hour)."""

from __future__ import annotations

from pathlib import Path

from jobs.common import UsageError, parse_duration
from pipeline.config import Config
from pipeline.simulate import DEFAULT_START_NS
from pipeline.simulate.scenarios import SCENARIOS

__all__ = ["DEFAULT_START_NS", "parse_duration", "run_simulate"]


def run_simulate(
    scenario: str,
    duration_s: float,
    seed: int,
    out_dir: Path,
    cfg: Config,
    start_ns: int | None = None,
) -> list[Path]:
    """Simulate ``scenario`` for ``duration_s`` seconds from ``start_ns`` (ns since the
    Unix epoch, UTC; default 2026-01-15T00:00:00Z) and write it under ``out_dir`` as
    hourly MCAP files; return their paths in time order."""
    if scenario not in SCENARIOS:
        raise UsageError(
            f"unknown scenario {scenario!r}: available scenarios are {', '.join(SCENARIOS)}")
    start = DEFAULT_START_NS if start_ns is None else int(start_ns)
    return SCENARIOS[scenario](cfg, start, duration_s, seed, Path(out_dir))
