"""`surveil simulate`: write a simulated scenario as an MCAP archive (one file per hour).

The CLI (``jobs/cli.py``) parses the options and calls :func:`run_simulate`.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

from jobs.common import UsageError
from pipeline.config import Config
from pipeline.simulate import DEFAULT_START_NS
from pipeline.simulate.airfield_mcap import simulate_airfield_archive
from pipeline.simulate.channel import simulate_channel
from pipeline.simulate.channel_mcap import write_channel_archive
from pipeline.simulate.gaps_mcap import write_gaps_archive
from pipeline.simulate.ownship import simulate_ownship_archive

"""2026-01-15T00:00:00Z, ns since the Unix epoch."""


def _channel(cfg: Config, start_ns: int, duration_s: float, seed: int, out_dir: Path) -> list[Path]:
    scenario = simulate_channel(cfg, start_ns=start_ns, duration_s=duration_s, seed=seed)
    return write_channel_archive(scenario, out_dir, scenario_name="channel")


ScenarioWriter = Callable[[Config, int, float, int, Path], list[Path]]
"""(cfg, start_ns, duration_s, seed, out_dir) -> MCAP files written, in time order."""

# One entry per scenario; each sensor family adds its own line.
SCENARIOS: dict[str, ScenarioWriter] = {
    "channel": _channel,
    "airfield": simulate_airfield_archive,
    "gaps": write_gaps_archive,
    "ownship": simulate_ownship_archive,
}

_DURATION = re.compile(
    r"^(?:(?P<h>\d+(?:\.\d+)?)h)?(?:(?P<m>\d+(?:\.\d+)?)m)?(?:(?P<s>\d+(?:\.\d+)?)s)?$")


def parse_duration(text: str) -> float:
    """``"1h"``, ``"30m"``, ``"90s"``, ``"2h30m"``, ``"1.5h"`` or plain seconds
    (``"600"``) -> seconds. Raises ValueError for anything else or a zero duration."""
    t = text.strip().lower()
    try:
        seconds = float(t)
    except ValueError:
        m = _DURATION.match(t)
        if not t or m is None:
            raise ValueError(
                f"invalid duration {text!r}: use e.g. 1h, 30m, 90s, 2h30m or seconds"
            ) from None
        seconds = (float(m["h"] or 0) * 3600.0 + float(m["m"] or 0) * 60.0
                   + float(m["s"] or 0))
    if not seconds > 0 or seconds == float("inf"):
        raise ValueError(f"invalid duration {text!r}: must be positive and finite")
    return seconds


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
