"""Bit-identical runs: the commands' process runs polars on one thread (``jobs/__init__``),
since polars' per-group float sums depend on how its threads split the rows (a crash
trial's "exactly old or exactly new" failed on SIAP's summed errors under load)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import polars as pl

ROOT = Path(__file__).resolve().parents[2]
_PROBE = "import jobs.cli, polars; print(polars.thread_pool_size())"


def _threads_in_a_command_process(**env: str) -> int:
    base = {k: v for k, v in os.environ.items() if k != "POLARS_MAX_THREADS"}
    out = subprocess.run([sys.executable, "-c", _PROBE], cwd=ROOT, env={**base, **env},
                         capture_output=True, text=True, check=True)
    return int(out.stdout.split()[-1])


def test_a_command_process_runs_polars_on_one_thread():
    assert _threads_in_a_command_process() == 1


def test_an_explicit_polars_max_threads_wins():
    assert _threads_in_a_command_process(POLARS_MAX_THREADS="2") == 2


def test_the_test_session_runs_polars_on_one_thread():
    # the in-process fixtures (e2e warehouse) are built as the commands build them
    assert pl.thread_pool_size() == 1
