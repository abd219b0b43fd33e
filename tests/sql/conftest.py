"""The report tests' warehouse: every family with rows (issue 40 item 7)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from pipeline.config import Config
from pipeline.units import NS

WORLD_START_NS = 1_768_438_200 * NS  # 2026-01-15T00:50:00Z: files on both sides of 01:00
# each scenario's simulated seconds: the channel scene with its faults and injected radar
# biases, the airfield with its faults, the own ship past its convergence (600 s) and its
# first GNSS outage (960 s), the gaps scene past its first AIS silences (720-1500 s)
WORLD_DURATION_S = {"channel": 900.0, "airfield": 900.0, "ownship": 1500.0, "gaps": 1800.0}


@dataclass(frozen=True)
class World:
    cfg: Config
    warehouse: Path
    start_ns: int
    end_ns: int


@pytest.fixture(scope="session")
def world(tmp_path_factory: pytest.TempPathFactory, cfg: Config) -> World:
    """simulate (four scenarios, seed 7) -> MCAP -> ingest -> batch -> calibrate-radars,
    into one warehouse of four sites (~30 s)."""
    from jobs.batch import run_batch
    from jobs.simulate import run_simulate
    from pipeline.batch.calibrate import run_calibration
    from pipeline.ingest.driver import run_ingest
    from pipeline.simulate.scenarios import with_scenario

    root = tmp_path_factory.mktemp("world")
    c = with_scenario(cfg, list(WORLD_DURATION_S))
    files = [f for name, duration_s in WORLD_DURATION_S.items()
             for f in run_simulate(name, duration_s, 7, root / "archive", c,
                                   start_ns=WORLD_START_NS)]
    wh = root / "warehouse"
    ingest = run_ingest(files, c, wh, executor="serial")
    assert ingest.exit_code == 0, ingest.render()
    end_ns = WORLD_START_NS + int(max(WORLD_DURATION_S.values()) * NS)
    batch = run_batch(c, wh, start_ns=WORLD_START_NS, end_ns=end_ns, executor_kind="serial")
    assert batch.exit_code == 0, batch.render()
    run_calibration(c, wh, start_ns=WORLD_START_NS,
                    end_ns=WORLD_START_NS + int(WORLD_DURATION_S["channel"] * NS))
    return World(c, wh, WORLD_START_NS, end_ns)
