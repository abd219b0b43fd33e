"""ASTERIX editions the decoder reads (filled in by the editions work)."""

from __future__ import annotations

EDITIONS: dict[int, dict[str, str]] = {}
