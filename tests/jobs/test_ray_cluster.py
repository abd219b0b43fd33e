"""A Ray cluster of several nodes with the warehouse on object storage (issue 39, item 3):
two raylet nodes on this machine (``ray.cluster_utils.Cluster``, one CPU each), the
region slice's warehouse on moto's S3 server; the batch run as Ray tasks gives exactly
the rows of the process executor, and no task sent to a worker names a local path (the
warehouse, its staging, every manifest's files and seams are ``s3://`` objects)."""

from __future__ import annotations

import dataclasses
import pickle
from pathlib import Path
from typing import ClassVar

import pytest

ray = pytest.importorskip(
    "ray", reason="Ray is the optional extra surveil-pipeline[cluster]; not installed here")
cluster_utils = pytest.importorskip("ray.cluster_utils")

import pipeline.batch.driver as driver  # noqa: E402
from jobs.batch import run_batch  # noqa: E402
from jobs.simulate import run_simulate  # noqa: E402
from pipeline.batch.worker import BatchUnit, FinalizeTask  # noqa: E402
from pipeline.executors import UnitQueue  # noqa: E402
from pipeline.families import load_config  # noqa: E402
from pipeline.ingest.driver import run_ingest  # noqa: E402
from pipeline.maritime.stage import OUTPUTS  # noqa: E402
from pipeline.units import NS  # noqa: E402
from pipeline.warehouse.delta import read_table  # noqa: E402
from pipeline.warehouse.location import parse_location  # noqa: E402

START_NS = 1_768_488_900 * NS  # 14:55 UTC
END_NS = START_NS + 600 * NS  # 15:05: two units, seam at 15:00


class _Recorded(UnitQueue):
    """The driver's queue of tasks, keeping the bytes of each task as it is sent."""

    sent: ClassVar[list[bytes]] = []

    def take(self) -> list:
        out = super().take()
        _Recorded.sent += [pickle.dumps(u) for u in out]
        self.units = getattr(self, "units", []) + out
        return out


def _tables(wh) -> dict:
    return {name: read_table(wh, name, start_ns=START_NS, end_ns=END_NS) for name in OUTPUTS}


def test_a_two_node_ray_cluster_on_s3_gives_the_rows_of_the_process_pool(
        s3, tmp_path, monkeypatch):
    files = run_simulate("region", 620.0, 3, tmp_path / "archive", load_config(),
                         start_ns=START_NS - 10 * NS, ships=60, radars=3)
    # the config as sent to workers names no file of this machine either
    cfg = dataclasses.replace(load_config(tmp_path / "archive" / "region.toml"),
                              source="(region.toml)")
    wh = parse_location(f"s3://{s3.bucket()}/wh")
    run_ingest(files, cfg, wh, executor="serial")
    s = run_batch(cfg, wh, start_ns=START_NS, end_ns=END_NS, executor_kind="process",
                  families=("maritime",))
    assert s.committed and not s.failed_units and s.units_total == 2
    expected = _tables(wh)
    assert expected["associations"].num_rows > 5000

    # two raylets (the head and one more), one CPU each; workers inherit the AWS_*
    # variables the fixture set (as `ray start` from a shell that exports them)
    cluster = cluster_utils.Cluster(initialize_head=True, head_node_args={
        "num_cpus": 1, "object_store_memory": 80 * 2**20, "include_dashboard": False})
    try:
        cluster.add_node(num_cpus=1, object_store_memory=80 * 2**20)
        cluster.wait_for_nodes()
        ray.init(address=cluster.address, log_to_driver=False)
        assert len([n for n in ray.nodes() if n["Alive"]]) == 2
        _Recorded.sent = []
        monkeypatch.setattr(driver, "UnitQueue", _Recorded)
        s = run_batch(cfg, wh, start_ns=START_NS, end_ns=END_NS, executor_kind="ray",
                      families=("maritime",))
    finally:
        ray.shutdown()
        cluster.shutdown()
    assert s.committed and not s.failed_units, s.render()
    got = _tables(wh)
    for name in OUTPUTS:
        assert got[name].equals(expected[name]), name
    tasks = [pickle.loads(b) for b in _Recorded.sent]
    assert sum(isinstance(t, BatchUnit) for t in tasks) == 2
    assert sum(isinstance(t, FinalizeTask) for t in tasks) == 2
    local = str(tmp_path).encode()
    assert not [b for b in _Recorded.sent if local in b]  # no path of this machine's
    for t in tasks:
        if isinstance(t, BatchUnit):
            assert str(t.warehouse).startswith("s3://") and str(t.staging_dir).startswith(
                "s3://")
        else:
            m = t.manifest
            assert m.staging_dir.startswith("s3://") and m.seam.path.startswith("s3://")
            assert all(p.startswith("s3://") for ps in m.files.values() for p in ps)
    assert Path.cwd().joinpath("s3:").exists() is False
