"""Simulated ground truth (JSON, ``surveil.TruthState``) -> ``truth`` table + rejects.

Parsed in bulk like the radar reports (:mod:`pipeline.decode.json_bulk`; radar and truth
channels of the same chunks share one parse). Validation (reason_code ``out_of_range``):
a missing required field, NaN/inf, latitude outside [-90, 90] deg, longitude outside
[-180, 180] deg, speed < 0. ``mmsi`` may be null (the vessel carries no AIS). Units: deg,
rad, m/s, ns.
"""

from __future__ import annotations

import numpy as np
import polars as pl
import pyarrow as pa

from pipeline.config import ValidationConfig
from pipeline.decode.json_bulk import Check, JsonKind, decode_payloads, missing, nonfinite, outside
from pipeline.messages import message_layout

TRUTH_LAYOUT = message_layout("truth_state.schema.json")
TRUTH_FIELDS: dict[str, pl.DataType] = TRUTH_LAYOUT.polars_schema()
_REQUIRED = TRUTH_LAYOUT.required
_NUMERIC = TRUTH_LAYOUT.required_numbers


def truth_checks(_validation: ValidationConfig) -> list[Check]:
    """Validation checks of a truth state (see module docstring)."""
    return [
        *missing(_REQUIRED),
        *nonfinite(_NUMERIC),
        outside("lat_deg", -90.0, 90.0),
        outside("lon_deg", -180.0, 180.0),
        outside("speed_mps", 0.0, None),
    ]


TRUTH = JsonKind("truth", TRUTH_FIELDS, truth_checks, {})
"""Truth states as a JSON kind of :mod:`pipeline.decode.json_bulk`."""


def decode_truth_states(
    payloads: list[bytes], log_time_ns: np.ndarray, *, source_file: str, topic: str
) -> tuple[pa.Table, pa.Table]:
    """``(truth rows, rejects rows)`` of a list of truth-state payloads.

    ``log_time_ns``: int64 MCAP log times of the payloads, ns.
    """
    return decode_payloads(
        TRUTH,
        payloads,
        log_time_ns,
        source_file=source_file,
        topic=topic,
        validation=ValidationConfig(),
    )
