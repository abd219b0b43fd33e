"""The crash bench at a tiny size (slow: a few real subprocess runs): it runs end to end
and prints its totals; no row lost or duplicated."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_crash_bench_two_batch_trials(tmp_path):
    res = subprocess.run([sys.executable, str(REPO / "bench" / "crash.py"), "--trials", "2",
                          "--commands", "batch", "--workdir", str(tmp_path)],
                         cwd=REPO, capture_output=True, text=True, check=False, timeout=1800)
    assert res.returncode == 0, res.stderr
    totals = dict(line.strip().rsplit(None, 1) for line in
                  res.stdout.split("totals:")[1].splitlines()
                  if line.strip() and line.strip()[-1].isdigit() and ":" not in line)
    assert totals["trials"] == "2"
    assert totals["rows lost"] == "0" and totals["rows duplicated"] == "0"
    assert totals["re-runs not converged"] == "0" and totals["reports failing"] == "0"
