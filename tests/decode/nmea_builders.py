"""Builders for NMEA 0183 test input: sentences with correct checksums, tag blocks, and a
one-call decode. Imported by tests/decode/test_nmea*.py and tests/io/test_legacy_import.py
(no conftest.py on purpose)."""

from __future__ import annotations

from functools import reduce

import numpy as np

from pipeline.decode.nmea import decode_nmea_sentences
from pipeline.units import NS

T0_NS = 1_767_225_600 * 10**9  # 2026-01-01T00:00:00Z

SRC, TOPIC, PLATFORM = "/arch/nav.mcap", "/nav/nmea", "ship-1"


def xor(text: str) -> int:
    """Reference NMEA checksum: XOR of the characters, one at a time."""
    return reduce(lambda a, c: a ^ ord(c), text, 0)


def sentence(body: str, start: str = "$") -> bytes:
    """``$<body>*hh`` with the right checksum (``body`` without ``$`` and ``*``)."""
    return f"{start}{body}*{xor(body):02X}".encode()


def tag_block(content: str) -> str:
    """``\\<content>*hh\\`` with the right checksum."""
    return f"\\{content}*{xor(content):02X}\\"


def times(n: int, *, start_ns: int = T0_NS, step_ns: int = NS) -> np.ndarray:
    return start_ns + np.arange(n, dtype=np.int64) * step_ns


def decode(lines: list[bytes], log_time_ns: np.ndarray | None = None) -> dict:
    """``decode_nmea_sentences`` with fixed provenance; log times 1 s apart from T0."""
    t = times(len(lines)) if log_time_ns is None else log_time_ns
    return decode_nmea_sentences(lines, t, source_file=SRC, topic=TOPIC, platform_id=PLATFORM)


def rows(tables: dict, name: str) -> list[dict]:
    return tables[name].to_pylist()


def reasons(tables: dict) -> list[str]:
    return tables["rejects"].column("reason_code").to_pylist()
