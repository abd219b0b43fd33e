"""``surveil simulate --scenario gaps``: the ``gaps`` scenario as an MCAP archive.

Same channel conventions as the ``channel`` scenario (``/ais/nmea`` ``!AIVDM``
sentences, ``/truth/vessels`` JSON; one zstd MCAP file per UTC hour), written by
:func:`pipeline.io.mcap_write.write_channel_archive`; no radar channels.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.config import Config
from pipeline.simulate.channel_mcap import write_channel_archive
from pipeline.simulate.gaps import simulate_gaps


def write_gaps_archive(
    cfg: Config, start_ns: int, duration_s: float, seed: int, out_dir: Path
) -> list[Path]:
    """Simulate the ``gaps`` scenario and write it under ``out_dir``; return the files."""
    scenario = simulate_gaps(cfg, start_ns=start_ns, duration_s=duration_s, seed=seed)
    return write_channel_archive(scenario.as_channel_scenario(), out_dir, scenario_name="gaps")
