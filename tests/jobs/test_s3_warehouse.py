"""The warehouse on a real S3-compatible server (moto's, on loopback: tests/s3_server.py;
issue 39, item 2). `surveil ingest` into ``s3://BUCKET/wh`` (credentials and endpoint
from the standard AWS_* variables), then batch and reprocess there, give every table
and every shipped report the rows the same steps give on local disk; nothing is written
to the working folder (the code before took ``s3://...`` for a folder named ``s3:``). A
batch killed between its table commits on object storage leaves readers every table as
before (never a mix), and its re-run gives the clean run's rows."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import polars as pl
import pytest

from jobs.batch import run_batch
from jobs.reprocess import run_reprocess
from pipeline.families import FAMILIES
from pipeline.reports import list_reports, run_named_report
from pipeline.tables import table_specs
from pipeline.units import NS
from pipeline.warehouse import pending
from pipeline.warehouse.crashpoints import ENV
from pipeline.warehouse.delta import read_table
from pipeline.warehouse.location import Location, parse_location

ROOT = Path(__file__).resolve().parents[2]
DERIVED = [name for fam in FAMILIES for name in fam.outputs]


def _rows(wh: Path | Location, name: str) -> pl.DataFrame:
    """A table's rows in one order, without the wall-clock columns (``*_at_ns``)."""
    t = pl.from_arrow(read_table(wh, name))
    t = t.drop([c for c in t.columns if c.endswith("_at_ns")])
    return t.sort(t.columns) if t.height else t


def _surveil(env: dict[str, str], cwd: Path, *args: str, crash_at: str | None = None
             ) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if k != ENV} | env | {"PYTHONPATH": str(ROOT)}
    if crash_at is not None:
        full[ENV] = crash_at
    return subprocess.run([sys.executable, "-m", "jobs.cli", *args], cwd=cwd, env=full,
                          capture_output=True, text=True, check=False, timeout=600)


@pytest.fixture(scope="module")
def on_s3(e2e, s3_server, tmp_path_factory):
    """The e2e archive ingested (by the CLI, in a working folder that must stay empty),
    batched and reprocessed on S3; the same batch and reprocess on a local copy of the
    e2e warehouse."""
    root = tmp_path_factory.mktemp("s3-e2e")
    bucket = s3_server.bucket()
    with pytest.MonkeyPatch.context() as mp:
        for k, v in s3_server.env().items():
            mp.setenv(k, v)
        wh = parse_location(f"s3://{bucket}/wh")
        cwd = root / "cwd"
        cwd.mkdir()
        res = _surveil(s3_server.env(), cwd, "--warehouse", wh.uri, "ingest",
                       *map(str, e2e.archive), "--executor", "process")
        assert res.returncode == 0, res.stderr
        assert list(cwd.iterdir()) == []  # nothing in ./s3:/...
        ingested = {n: _rows(wh, n) for n in table_specs()}
        batch = run_batch(e2e.cfg, wh, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
                          executor_kind="process")
        assert batch.exit_code == 0, batch.render()
        batched = {n: _rows(wh, n) for n in table_specs()}
        window = (e2e.start_ns + 300 * NS, e2e.start_ns + 720 * NS)  # across the hour seam
        again = run_reprocess(e2e.cfg, wh, start_ns=window[0], end_ns=window[1],
                              executor_kind="serial")
        assert again.exit_code == 0, again.render()
        local = root / "local"
        shutil.copytree(e2e.warehouse, local)
        run_reprocess(e2e.cfg, local, start_ns=window[0], end_ns=window[1],
                      executor_kind="serial")
        yield {"wh": wh, "bucket": bucket, "ingested": ingested, "batched": batched,
               "local": local, "env": s3_server.env(), "root": root}


def test_ingest_and_batch_on_s3_equal_local_disk_table_for_table(e2e, on_s3):
    assert on_s3["ingested"]["radar_tracks"].height > 1000
    assert on_s3["batched"]["associations"].height > 1000
    for name in table_specs():
        local = _rows(e2e.warehouse, name)
        what = on_s3["batched"] if name != "ingest_ledger" else on_s3["ingested"]
        assert what[name].equals(local), name


def test_a_reprocess_on_s3_equals_the_same_reprocess_on_local_disk(s3, on_s3):
    for name in table_specs():
        assert _rows(on_s3["wh"], name).equals(_rows(on_s3["local"], name)), name
    keys = s3.keys(on_s3["bucket"], "wh/")
    assert not [k for k in keys if k.startswith(("wh/_staging/", "wh/_pending/",
                                                 "wh/_continue/")) and not k.endswith("/")]


def test_every_report_on_s3_equals_local_disk(e2e, s3, on_s3):
    names = list_reports()
    assert len(names) >= 10
    for name in names:
        kw = {"start_ns": e2e.start_ns, "end_ns": e2e.end_ns, "cfg": e2e.cfg}
        remote = run_named_report(on_s3["wh"], name, **kw)
        local = run_named_report(on_s3["local"], name, **kw)
        assert remote.equals(local), name


def test_surveil_sql_reads_the_s3_warehouse(e2e, on_s3):
    res = _surveil(on_s3["env"], on_s3["root"], "--warehouse", on_s3["wh"].uri, "sql",
                   "SELECT count(*) AS n FROM associations", "--format", "csv")
    assert res.returncode == 0, res.stderr
    assert int(res.stdout.split()[-1]) == _rows(on_s3["local"], "associations").height


def test_a_batch_killed_between_commits_on_s3_leaves_every_table_old(e2e, s3, on_s3):
    """Killed after its first table's commit (``batch.associations``) with a config that
    changes every derived table: readers see every table as before (the pending marker
    on S3 pins them); the next batch gives the rows of a clean local run."""
    root, wh = on_s3["root"], on_s3["wh"]
    config = root / "changed.toml"
    config.write_text(Path(e2e.cfg.source).read_text()
                      .replace("epoch_period_s = 4.0", "epoch_period_s = 5.0"))
    clean = root / "clean"
    shutil.copytree(on_s3["local"], clean)
    from pipeline.families import load_config

    run_batch(load_config(config), clean, start_ns=e2e.start_ns, end_ns=e2e.end_ns,
              executor_kind="serial")
    before = {n: _rows(wh, n) for n in DERIVED}
    assert not _rows(clean, "associations").equals(before["associations"])
    args = ("--warehouse", wh.uri, "--config", str(config), "batch", "--from",
            str(e2e.start_ns), "--to", str(e2e.end_ns), "--executor", "serial")
    res = _surveil(on_s3["env"], root, *args, crash_at="batch.associations")
    assert res.returncode == -signal.SIGKILL, (res.returncode, res.stderr)
    assert pending.markers(wh)  # the dead job's marker, on S3
    for name in DERIVED:
        assert _rows(wh, name).equals(before[name]), name
    # the dead job's lease is taken over at once (its pid is gone on this host)
    res = _surveil(on_s3["env"], root, *args)
    assert res.returncode == 0, res.stderr
    assert pending.markers(wh) == []
    for name in DERIVED:
        assert _rows(wh, name).equals(_rows(clean, name)), name


def test_an_archive_on_s3_ingests_the_rows_of_the_local_files(e2e, s3, on_s3):
    """`surveil run`'s folders and ingest's paths may be s3:// prefixes: each worker
    reads its object (a local copy), the ledger names it by its URI; the rows are those
    of the same files on disk (their source_file aside)."""
    from pipeline.ingest.driver import run_ingest

    bucket, client = on_s3["bucket"], s3.client()
    for f in e2e.archive:
        client.upload_file(str(f), bucket, f"archive/site-a/{Path(f).name}")
    wh = parse_location(f"s3://{bucket}/from-s3")
    s = run_ingest([f"s3://{bucket}/archive"], e2e.cfg, wh, executor="process")
    assert s.exit_code == 0 and s.files_ok == len(e2e.archive), s.render()
    ledger = _rows(wh, "ingest_ledger")
    assert sorted(ledger["source_file"]) == sorted(
        f"s3://{bucket}/archive/site-a/{Path(f).name}" for f in e2e.archive)
    def rows(w, name: str) -> pl.DataFrame:
        t = pl.from_arrow(read_table(w, name))
        t = t.drop([c for c in t.columns if c == "source_file" or c.endswith("_at_ns")])
        return t.sort(t.columns) if t.height else t

    for name in ("radar_tracks", "ais_reports", "truth", "rejects"):
        assert rows(wh, name).equals(rows(e2e.warehouse, name)), name
    again = run_ingest([f"s3://{bucket}/archive"], e2e.cfg, wh, executor="serial")
    assert again.files_skipped == len(e2e.archive)  # unchanged: the ledger skips them
