"""No hidden process state in ingest: importing changes nothing in the process; the
IngestContext owns the buffer pool, the helper threads and the allocator setting, and
releases its threads at its end; each worker process of a pool makes its own."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

from mcap_fixtures import radar_messages, write_mcap

from pipeline.decode import json_columns
from pipeline.executors import make_executor
from pipeline.ingest import IngestContext, IngestUnit, ingest_file

REPO = Path(__file__).resolve().parents[2]

# Imports every module of pipeline/ and jobs/ in a fresh interpreter and reports the
# Python threads before and after, and every lookup of glibc's mallopt (the audit event
# ctypes raises when a C function is looked up by name); then enters an IngestContext.
_SCRIPT = """
import importlib, json, pkgutil, sys, threading
mallopt = []
sys.addaudithook(
    lambda event, args: mallopt.append(event)
    if event == "ctypes.dlsym" and len(args) > 1 and args[1] == "mallopt" else None
)
before = threading.active_count()
import jobs, pipeline
names = [m.name for pkg in (pipeline, jobs)
         for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + ".")]
for name in names:
    importlib.import_module(name)
imported = {"threads": threading.active_count() - before, "mallopt": len(mallopt),
            "modules": len(names)}
from pipeline.ingest import IngestContext
with IngestContext() as ctx:
    ctx.views.warm_up()
    entered = {"mallopt": len(mallopt)}
left = {"threads": threading.active_count() - before}
print(json.dumps({"imported": imported, "entered": entered, "left": left}))
"""


def test_importing_every_module_changes_nothing_in_the_process():
    out = subprocess.run(
        [sys.executable, "-c", _SCRIPT], cwd=REPO, capture_output=True, text=True, check=True
    )
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["imported"]["modules"] > 100  # every module of pipeline/ and jobs/
    assert got["imported"]["threads"] == 0 and got["imported"]["mallopt"] == 0
    assert got["entered"]["mallopt"] >= 1  # the context applies the allocator setting
    assert got["left"]["threads"] == 0  # ... and joins the threads it started


def _helper_threads() -> set[str]:
    prefixes = ("json-columns", "sha256", "mcap-fetch", "duckdb-warm-up", "stage")
    return {t.name.split("_")[0] for t in threading.enumerate() if t.name.startswith(prefixes)}


def test_context_owns_the_pools_and_releases_them(tmp_path, cfg, monkeypatch):
    monkeypatch.setattr(json_columns, "PARALLEL_ROWS", 10)  # split even a small group
    monkeypatch.setenv("SURVEIL_THREADS_PER_WORKER", "2")
    src = write_mcap(tmp_path / "a.mcap", radar_messages(400), chunk_size=4096)
    unit = IngestUnit(str(src), str(tmp_path / "wh"), str(tmp_path / "stage"), cfg.validation)
    before = threading.active_count()
    with IngestContext(keep_freed_memory=False) as ctx:
        m = ingest_file(unit, ctx)
        buffers = list(ctx.chunk_buffers._buffers)
        during = _helper_threads()
        again = ingest_file(unit, ctx)  # the second file reuses the first one's buffers
        assert all(any(b is c for c in ctx.chunk_buffers._buffers) for b in buffers)
    assert m.rows["radar_tracks"] == again.rows["radar_tracks"] == 400 and buffers
    assert {"json-columns", "sha256"} <= during
    assert threading.active_count() == before and not _helper_threads()
    assert ctx.chunk_buffers is None and ctx.parse_pool is None and ctx.hasher is None


def _context_of_worker(unit: int, ctx: IngestContext) -> tuple[int, int, bool]:
    return os.getpid(), id(ctx), ctx.chunk_buffers is not None


def test_each_worker_process_makes_its_own_context():
    with IngestContext(keep_freed_memory=False) as ctx:
        serial = list(make_executor("serial", 1, 1).map_units(
            _context_of_worker, [1, 2], context=ctx.for_workers()))  # fmt: skip
        pooled = list(make_executor("process", 2, 1).map_units(
            _context_of_worker, [1, 2, 3, 4], context=ctx.for_workers()))  # fmt: skip
    assert {r.value for r in serial} == {(os.getpid(), id(ctx), True)}  # the driver's own
    assert all(r.ok for r in pooled), [r.error for r in pooled]
    pids = {r.value[0] for r in pooled}
    assert os.getpid() not in pids and all(r.value[2] for r in pooled)
    # one context per worker process, kept for its units
    assert len({(r.value[0], r.value[1]) for r in pooled}) == len(pids)
