"""A batch killed mid-run (a real subprocess, SIGKILL) leaves the previous window's data
intact and readable: each derived table holds exactly the old rows or exactly the new."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import polars as pl
import pytest

from jobs.common import iso
from pipeline.reports import run_named_report
from pipeline.warehouse.delta import read_table

DERIVED = ("system_tracks", "associations", "identifications", "track_errors")


def _rows(warehouse: Path) -> dict[str, pl.DataFrame]:
    out = {}
    for name in DERIVED:
        t = pl.from_arrow(read_table(warehouse, name))
        out[name] = t.sort(t.columns)
    return out


def _batch_cmd(config: Path, warehouse: Path, e2e) -> list[str]:
    return [
        sys.executable, "-m", "jobs.cli", "--config", str(config), "--warehouse", str(warehouse),
        "batch", "--from", iso(e2e.start_ns), "--to", iso(e2e.end_ns), "--executor", "serial",
    ]


@pytest.mark.skipif(sys.platform == "win32", reason="SIGKILL")
def test_sigkill_mid_batch_keeps_old_window(e2e, tmp_path):
    warehouse = tmp_path / "wh"
    shutil.copytree(e2e.warehouse, warehouse)
    old = _rows(warehouse)
    # a config change that alters the output, so old and new rows differ
    default = Path(e2e.cfg.source).read_text()
    config = tmp_path / "changed.toml"
    config.write_text(default.replace("epoch_period_s = 4.0", "epoch_period_s = 5.0"))
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}

    # the same batch run to completion on a copy: its duration and its (new) rows
    timing = tmp_path / "timing"
    shutil.copytree(e2e.warehouse, timing)
    t0 = time.monotonic()
    full = subprocess.run(_batch_cmd(config, timing, e2e), env=env,
                          capture_output=True, text=True, check=False)
    full_s = time.monotonic() - t0
    assert full.returncode == 0, full.stderr
    new = _rows(timing)
    assert any(not new[n].equals(old[n]) for n in DERIVED), "config change had no effect"

    kills = 0
    for frac in (0.5, 0.8, 0.9, 0.95):
        proc = subprocess.Popen(_batch_cmd(config, warehouse, e2e), env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(full_s * frac)
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            kills += 1
        proc.wait()
        now = _rows(warehouse)
        for name in DERIVED:
            # exactly the old rows or exactly the new rows: never a mix, never duplicates
            assert now[name].equals(old[name]) or now[name].equals(new[name]), name
        # still readable by the reports
        assert run_named_report(warehouse, "accuracy_by_sector").num_rows > 0
    assert kills >= 1, "batch finished before any kill: test proves nothing"
