"""Units and time constants, defined once.

Times inside surveil are int64 nanoseconds since the Unix epoch, UTC (``*_ns``);
durations in configuration and docstrings are seconds (``*_s``). Distances are metres,
speeds m/s, angles radians unless the name says ``_deg``.
"""

from __future__ import annotations

NS = 1_000_000_000
"""Nanoseconds per second."""
MS_NS = 1_000_000
"""Nanoseconds per millisecond."""
US_NS = 1_000
"""Nanoseconds per microsecond."""

NM_M = 1852.0
"""Metres per international nautical mile."""
KNOT_MPS = NM_M / 3600.0
"""Metres per second per knot."""
