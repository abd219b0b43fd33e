"""Injected-fault truth (JSON ``surveil.FaultTruth`` on ``/truth/faults``) -> ``fault_truth``.

Parsed in bulk per batch (:func:`pipeline.decode.json_bulk.parse_json_payloads`) and
validated with vectorised checks (reason_code ``out_of_range``): a missing required
field, or an end before the start.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl
import pyarrow as pa

from pipeline.decode.json_bulk import (
    Check,
    missing,
    parse_json_payloads,
    split_valid,
    with_provenance,
)
from pipeline.decode.vasn import rejects_for
from pipeline.io.mcap_read import ChannelBatch
from pipeline.messages import message_layout
from pipeline.tables import conform

FAULT_TRUTH_SCHEMA = "surveil.FaultTruth"

FAULT_TRUTH_LAYOUT = message_layout("fault_truth.schema.json")
FIELDS: dict[str, pl.DataType] = FAULT_TRUTH_LAYOUT.polars_schema()
REQUIRED = FAULT_TRUTH_LAYOUT.required


def decode_fault_truth(
    payloads: list[bytes], log_time_ns: np.ndarray, *, source_file: str, topic: str
) -> tuple[pa.Table, pa.Table]:
    """``(fault_truth rows, rejects rows)`` of a batch of payloads."""
    parsed = parse_json_payloads(payloads, FIELDS)
    checks = [
        *missing(REQUIRED),
        Check(
            (pl.col("end_ns") < pl.col("start_ns")).fill_null(False),
            pl.lit("end_ns before start_ns"),
        ),
    ]
    good, bad = split_valid(parsed.frame, checks)
    rows = with_provenance(good, log_time_ns, source_file=source_file, topic=topic)
    rejects = rejects_for(parsed, bad, payloads, log_time_ns, source_file=source_file, topic=topic)
    return conform("fault_truth", rows.to_arrow()), rejects


@dataclass
class FaultTruthChannelDecoder:
    """Stateless per batch (registry ``CHANNEL_DECODERS`` protocol)."""

    source_file: str
    topic: str

    @classmethod
    def for_channel(cls, batch: ChannelBatch, source_file: str) -> FaultTruthChannelDecoder:
        return cls(source_file, batch.topic)

    def feed(self, batch: ChannelBatch) -> dict[str, pa.Table]:
        rows, rejects = decode_fault_truth(
            list(batch.payloads), batch.log_time_ns, source_file=self.source_file,
            topic=self.topic)
        return {"fault_truth": rows, "rejects": rejects}

    def finish(self) -> dict[str, pa.Table]:
        return {}
