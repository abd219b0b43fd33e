"""Every input saved under ``tests/fuzz/regressions/<target>/`` (crashes found by
``make fuzz``, and the crash inputs of issue 18) replayed through its fuzz target
(``fuzz/targets.py``): each must now pass without an exception."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
from fuzz.targets import TARGETS  # noqa: E402

HERE = Path(__file__).resolve().parent / "regressions"
CASES = sorted((t.name, p) for t in HERE.iterdir() if t.is_dir() for p in t.iterdir())


@pytest.mark.parametrize(("target", "path"), CASES, ids=[f"{t}/{p.name}" for t, p in CASES])
def test_saved_input_passes(target, path):
    TARGETS[target](path.read_bytes())
