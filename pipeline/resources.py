"""Locate the repository's data folders (schemas/, sql/, config/).

From a source checkout or an editable install they are the top-level folders of the
repository; from a wheel they are shipped as ``pipeline/_resources/<name>``.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE_DIR = Path(__file__).resolve().parent


def resource_path(name: str) -> Path:
    """Path of the top-level data folder ``name`` (``schemas``, ``sql`` or ``config``)."""
    in_repo = _PACKAGE_DIR.parent / name
    if in_repo.is_dir():
        return in_repo
    return _PACKAGE_DIR / "_resources" / name
