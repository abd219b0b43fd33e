"""Scenario writers: simulated logs of every sensor family, written as MCAP archives."""

from pipeline.units import NS

DEFAULT_START_NS = 1_768_435_200 * NS
"""Default scenario start: 2026-01-15T00:00:00Z."""
