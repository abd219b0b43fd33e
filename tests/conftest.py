"""Shared fixtures: a short seeded `channel` scenario run through the real chain
(simulator -> zstd MCAP on disk -> ingest -> Delta warehouse -> batch)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

import jobs  # noqa: F401  (first: caps polars to one thread before polars loads)
from pipeline.config import Config
from pipeline.families import load_config
from pipeline.units import NS
from tests.real_data import REAL_DATA, real_data_dir  # noqa: F401  (re-exported)

# 00:50 -> 01:10: two archive files and two batch units across the hour boundary
E2E_START_NS = 1_768_438_200 * NS  # 2026-01-15T00:50:00Z
E2E_DURATION_S = 1200.0


@dataclass(frozen=True)
class E2E:
    cfg: Config
    archive: list[Path]
    warehouse: Path
    start_ns: int
    end_ns: int


@pytest.fixture(scope="session")
def cfg() -> Config:
    return load_config()


@pytest.fixture(scope="session")
def e2e(tmp_path_factory: pytest.TempPathFactory, cfg: Config) -> E2E:
    from jobs.batch import run_batch
    from jobs.simulate import run_simulate
    from pipeline.ingest.driver import run_ingest

    root = tmp_path_factory.mktemp("e2e")
    # the fault-free scenario: the spine's properties (the fault schedule of the default
    # config is exercised by tests/maritime/test_integrity*.py)
    files = run_simulate("channel-clean", E2E_DURATION_S, 7, root / "archive", cfg,
                         start_ns=E2E_START_NS)
    warehouse = root / "warehouse"
    ingest = run_ingest(files, cfg, warehouse, executor="serial")
    assert ingest.exit_code == 0, ingest.render()
    end_ns = E2E_START_NS + int(E2E_DURATION_S * NS)
    batch = run_batch(cfg, warehouse, start_ns=E2E_START_NS, end_ns=end_ns, executor_kind="serial")
    assert batch.exit_code == 0, batch.render()
    assert sorted(p.name for p in warehouse.iterdir()) == ["surveil.duckdb", "tables"]
    return E2E(cfg, files, warehouse, E2E_START_NS, end_ns)


@pytest.fixture(scope="session")
def s3_server():
    """moto's S3 server on loopback for the session (tests/s3_server.py); skips without
    moto."""
    from tests.s3_server import running_server

    with running_server() as server:
        yield server


@pytest.fixture
def s3(s3_server, monkeypatch):
    """The S3 server, with the standard AWS_* variables pointing at it for this test."""
    for k, v in s3_server.env().items():
        monkeypatch.setenv(k, v)
    return s3_server
