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

TIME_MIN_NS = 0
TIME_MAX_NS = 2**63 - 1
"""The representable times: int64 ns since the epoch (the warehouse's ``*_ns`` columns)
that an MCAP log time (uint64) also holds, 1970-01-01T00:00:00Z to
2262-04-11T23:47:16.854775807Z. A time outside (a two-digit ZDA year, a corrupt tag
block, a record header from another clock) is rejected with a reason, never wrapped."""
TIME_MAX_DAYS = TIME_MAX_NS // (86_400 * NS)
"""Whole days since 1970-01-01 inside the representable range (2262-04-10 is the last)."""


def time_in_range(t_ns: int) -> bool:
    """``TIME_MIN_NS <= t_ns <= TIME_MAX_NS`` (exact: Python ints, no wrap-around)."""
    return TIME_MIN_NS <= t_ns <= TIME_MAX_NS


def iso(t_ns: int) -> str:
    """int64 ns UTC -> ISO 8601 with a Z (milliseconds shown when not whole seconds)."""
    import datetime as dt

    secs, ns = divmod(int(t_ns), NS)
    base = dt.datetime.fromtimestamp(secs, dt.UTC).strftime("%Y-%m-%dT%H:%M:%S")
    return f"{base}.{ns // MS_NS:03d}Z" if ns else f"{base}Z"


def describe_time(t_ns: int) -> str:
    """``t_ns`` as ISO 8601 UTC when a calendar can show it, else the number of ns."""
    import datetime as dt

    try:
        epoch = dt.datetime(1970, 1, 1, tzinfo=dt.UTC)
        return (epoch + dt.timedelta(microseconds=t_ns // 1000)).isoformat()
    except OverflowError:
        return f"{t_ns} ns"


NM_M = 1852.0
"""Metres per international nautical mile."""
KNOT_MPS = NM_M / 3600.0
"""Metres per second per knot."""
