"""The Ray executor runs the same batch units as the process pool: a local Ray cluster
(loopback, 2 workers) gives exactly the rows of the process executor on a region slice
that spans two units (an hour seam: ids stitched, one unit relabelled by a worker)."""

from __future__ import annotations

from pathlib import Path

import pytest

ray = pytest.importorskip(
    "ray", reason="Ray is the optional extra surveil-pipeline[ray]; not installed here"
)

from jobs.batch import run_batch  # noqa: E402
from jobs.simulate import run_simulate  # noqa: E402
from pipeline.families import load_config  # noqa: E402
from pipeline.ingest.driver import run_ingest  # noqa: E402
from pipeline.maritime.stage import OUTPUTS  # noqa: E402
from pipeline.units import NS  # noqa: E402
from pipeline.warehouse.delta import read_table  # noqa: E402

START_NS = 1_768_488_900 * NS  # 14:55 UTC
END_NS = START_NS + 600 * NS  # 15:05: two units, seam at 15:00


@pytest.fixture(scope="module")
def region(tmp_path_factory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("ray-region")
    files = run_simulate("region", 620.0, 3, d / "archive", load_config(),
                         start_ns=START_NS - 10 * NS, ships=60, radars=3)
    cfg = load_config(d / "archive" / "region.toml")
    run_ingest(files, cfg, d / "wh", executor="serial")
    return d / "archive" / "region.toml", d / "wh"


def _tables(wh: Path) -> dict:
    return {name: read_table(wh, name, start_ns=START_NS, end_ns=END_NS) for name in OUTPUTS}


def test_ray_gives_the_rows_of_the_process_pool(region) -> None:
    config, wh = region
    cfg = load_config(config)
    s = run_batch(cfg, wh, start_ns=START_NS, end_ns=END_NS, executor_kind="process",
                  families=("maritime",))
    assert s.committed and not s.failed_units and s.units_total == 2
    expected = _tables(wh)
    assert expected["associations"].num_rows > 5000
    ray.init(num_cpus=2, include_dashboard=False, _node_ip_address="127.0.0.1",
             object_store_memory=200 * 1024 * 1024, log_to_driver=False)
    try:
        s = run_batch(cfg, wh, start_ns=START_NS, end_ns=END_NS, executor_kind="ray",
                      families=("maritime",))
    finally:
        ray.shutdown()
    assert s.committed and not s.failed_units
    got = _tables(wh)
    for name in OUTPUTS:
        assert got[name].equals(expected[name]), name
