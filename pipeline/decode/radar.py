"""Radar track reports (JSON, ``surveil.RadarTrackReport``) -> ``radar_tracks`` + rejects.

Decoded in bulk by :mod:`pipeline.decode.json_bulk`: the payloads of many chunks (and of
every radar and truth channel in them) go through ONE ``polars.read_ndjson`` call with the
declared types, built without a Python object per message; validation is a few
vectorised expressions whose reason strings are only formatted for failing rows. Only
when the bulk parse fails does the group fall back to one ``json.loads`` per payload to
find the bad ones (reason_code ``undecodable``).

Validation (reason_code ``out_of_range``, the reason names every failed check):
missing required field; NaN/inf in any numeric field (JSON ``NaN``/``Infinity`` tokens
included); ``range_m`` < 0 or > ``validation.max_range_m``; ``azimuth_rad`` outside
[0, 2π]; ``speed_mps`` < 0 or > ``validation.max_speed_mps``; a sigma or
``scan_period_s`` ≤ 0.

Column mapping: ``track_id`` -> ``local_track_id``, ``x_m`` -> ``x_site_m``,
``y_m`` -> ``y_site_m``; every other field keeps its name (units in the names: m, rad,
m/s, s, ns). Rejected rows keep their raw payload in ``raw``.
"""

from __future__ import annotations

import math

import numpy as np
import polars as pl
import pyarrow as pa

from pipeline.config import ValidationConfig
from pipeline.decode.json_bulk import (
    Check,
    JsonKind,
    JsonParse,
    decode_payloads,
    missing,
    nonfinite,
    outside,
    parse_json_payloads,
)
from pipeline.messages import RADAR_REPORT, message_layout

__all__ = [
    "RADAR",
    "RADAR_FIELDS",
    "RADAR_LAYOUT",
    "RADAR_RENAME",
    "JsonParse",
    "decode_radar_reports",
    "parse_json_payloads",
    "radar_checks",
]

RADAR_LAYOUT = message_layout(RADAR_REPORT)
"""``schemas/radar_track_report.schema.json``: the report's one declaration."""
RADAR_FIELDS: dict[str, pl.DataType] = RADAR_LAYOUT.polars_schema(omit=("status",))
"""The fields decoded into ``radar_tracks``: every field of the schema but ``status``
(the site tracker's status is not stored)."""
RADAR_RENAME = {"track_id": "local_track_id", "x_m": "x_site_m", "y_m": "y_site_m"}
_POSITIVE = (
    "sigma_range_m",
    "sigma_azimuth_rad",
    "sigma_course_rad",
    "sigma_speed_mps",
    "scan_period_s",
)


def radar_checks(validation: ValidationConfig) -> list[Check]:
    """Validation checks of a radar report (see module docstring)."""
    numeric = [c for c, t in RADAR_FIELDS.items() if t == pl.Float64()]
    return [
        *missing(RADAR_LAYOUT.required),
        *nonfinite(numeric),
        outside("range_m", 0.0, validation.max_range_m),
        outside("azimuth_rad", 0.0, 2 * math.pi),
        outside("speed_mps", 0.0, validation.max_speed_mps),
        *(outside(c, 0.0, None, lo_open=True) for c in _POSITIVE),
    ]


RADAR = JsonKind("radar_tracks", RADAR_FIELDS, radar_checks, RADAR_RENAME)
"""Radar reports as a JSON kind of :mod:`pipeline.decode.json_bulk`."""


def decode_radar_reports(
    payloads: list[bytes],
    log_time_ns: np.ndarray,
    *,
    source_file: str,
    topic: str,
    validation: ValidationConfig,
) -> tuple[pa.Table, pa.Table]:
    """``(radar_tracks rows, rejects rows)`` of a list of radar report payloads.

    ``log_time_ns``: int64 MCAP log times of the payloads, ns. Output rows carry the
    provenance columns and are conformed to the canonical schemas. (The ingest feeds
    whole chunks to :func:`pipeline.decode.json_bulk.decode_json_batches` instead.)
    """
    return decode_payloads(
        RADAR, payloads, log_time_ns, source_file=source_file, topic=topic, validation=validation
    )
