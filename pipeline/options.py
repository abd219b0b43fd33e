"""What users type for a command: times, durations, site names, parsed and checked.

The command line (``jobs/``) and the engines share these, so that a time, a duration or a
site name means the same everywhere and a bad one is a :class:`UsageError` (exit 2).
"""

from __future__ import annotations

import re
from datetime import UTC, datetime

from pipeline.errors import UsageError
from pipeline.tables import SITE_NAME_RULE, is_site_name


def checked_site(name: str) -> str:
    """A ``--site`` name: 1-64 letters, digits, ``.``, ``_``, ``-``, starting with a
    letter or digit (:data:`pipeline.tables.SITE_NAME`); :class:`UsageError` otherwise."""
    if not is_site_name(name):
        raise UsageError(f"--site {name!r}: {SITE_NAME_RULE}")
    return name


def parse_time_ns(text: str) -> int:
    """ISO 8601 (``2026-01-15T01:00:00Z``, naive means UTC) or an integer ns timestamp."""
    t = text.strip()
    if t.lstrip("-").isdigit():
        return _in_range(int(t), text)
    try:
        dt = datetime.fromisoformat(t.replace("Z", "+00:00"))
    except ValueError as exc:
        raise UsageError(f"not a time: {text!r} (use ISO 8601, e.g. 2026-01-15T01:00:00Z)") from exc
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=UTC)
    delta = dt - datetime(1970, 1, 1, tzinfo=UTC)
    return _in_range((delta.days * 86_400 + delta.seconds) * 1_000_000_000
                     + delta.microseconds * 1000, text)  # fmt: skip


def _in_range(t_ns: int, text: str) -> int:
    """``t_ns`` if it is a time the warehouse can hold (int64 ns since 1970), else a
    :class:`UsageError` (``--to 9999-01-01``: exit 2, not a traceback)."""
    if not 0 <= t_ns <= 2**63 - 1:
        raise UsageError(f"time {text!r} is outside 1970-01-01 .. 2262-04-11 UTC (int64 ns)")
    return t_ns


_DURATION = re.compile(
    r"^(?:(?P<h>\d+(?:\.\d+)?)h)?(?:(?P<m>\d+(?:\.\d+)?)m)?(?:(?P<s>\d+(?:\.\d+)?)s)?$")


def parse_duration(text: str) -> float:
    """``"1h"``, ``"30m"``, ``"90s"``, ``"2h30m"``, ``"1.5h"`` or plain seconds
    (``"600"``) -> seconds. Raises ValueError for anything else or a zero duration."""
    t = text.strip().lower()
    try:
        seconds = float(t)
    except ValueError:
        m = _DURATION.match(t)
        if not t or m is None:
            raise ValueError(
                f"invalid duration {text!r}: use e.g. 1h, 30m, 90s, 2h30m or seconds"
            ) from None
        seconds = (float(m["h"] or 0) * 3600.0 + float(m["m"] or 0) * 60.0
                   + float(m["s"] or 0))
    if not seconds > 0 or seconds == float("inf"):
        raise ValueError(f"invalid duration {text!r}: must be positive and finite")
    return seconds


def parse_origin(text: str) -> tuple[float, float]:
    """``LAT,LON`` in degrees (``--origin 41.297,2.083``); :class:`UsageError` otherwise."""
    try:
        lat, lon = (float(x) for x in text.replace(" ", "").split(","))
    except ValueError:
        raise UsageError(f"{text!r}: give LAT,LON in degrees, e.g. 41.297,2.083") from None
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise UsageError(f"{text!r}: latitude in [-90, 90], longitude in [-180, 180]")
    return lat, lon
