"""Where the public real recordings are (``../shared/data/real``, or ``$SURVEIL_REAL_DATA``):
imported by the tests that read them (``tests/conftest.py`` re-exports it; a package's own
conftest may shadow the name ``conftest``)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REAL_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"


def real_data_dir() -> Path:
    """../shared/data/real, or skip: those recordings are not part of the repository."""
    env = os.environ.get("SURVEIL_REAL_DATA")
    path = Path(env) if env else REAL_DATA
    if not path.is_dir():
        pytest.skip(f"real recordings not available at {path} (set SURVEIL_REAL_DATA)")
    return path
