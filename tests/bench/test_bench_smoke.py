"""The ingest benchmark at a tiny size: it runs end to end and prints its table (no timing
asserts); the files it writes are valid MCAP that the mcap reader checks CRC by CRC."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "bench" / "ingest.py"


def load_bench():
    spec = importlib.util.spec_from_file_location("bench_ingest", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("variant", ["json", "protobuf", "ros2"])
def test_bulk_writer_makes_valid_mcap(tmp_path, variant):
    bench = load_bench()
    path = bench.make_files(tmp_path, 9000, [variant])[variant]
    with open(path, "rb") as f:
        records = list(StreamReader(f, validate_crcs=True).records)  # chunk CRCs checked
    assert sum(type(r).__name__ == "MessageIndex" for r in records) > 1
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        times = [m.log_time for _, _, m in reader.iter_messages(log_time_order=False)]
    assert summary.statistics.message_count == len(times) == 9000
    assert times == sorted(times) and len(summary.chunk_indexes) > 1
    (channel,) = summary.channels.values()
    assert (channel.message_encoding, summary.schemas[channel.schema_id].name) == (
        bench.VARIANTS[variant][0],
        bench.VARIANTS[variant][2],
    )


def test_bench_runs_and_prints_its_table(tmp_path):
    cmd = [
        sys.executable, str(SCRIPT), "--messages", "800", "--executors", "serial",
        "--no-tracemalloc", "--in-process", "--workdir", str(tmp_path),
    ]  # fmt: skip
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, check=False)
    assert res.returncode == 0, res.stderr[-3000:]
    out = res.stdout
    assert "machine:" in out and "x baseline" in out and "x floor" in out
    rows = [
        ln.split()
        for ln in out.splitlines()
        if ln.split()[:1] in (["json"], ["protobuf"], ["ros2"])
    ]
    rows = [r for r in rows if len(r) >= 10]
    got = {(r[0], r[1], r[2]) for r in rows}
    for v in ("json", "protobuf", "ros2"):
        for n in ("200", "800"):
            assert {(v, n, "floor"), (v, n, "surveil"), (v, n, "baseline")} <= got
    sizes = [int(r[1].replace(",", "")) for r in rows]
    assert sizes == sorted(sizes)  # the table lists sizes ascending ...
    assert out.index("wrote 800 reports") < out.index("wrote 200 reports")  # ... N runs first
