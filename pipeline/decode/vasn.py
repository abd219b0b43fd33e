"""Vibro-acoustic surveillance network reports (JSON, ``surveil.VasnReport``) ->
``airfield_obs`` + rejects; and airfield reference states (JSON,
``surveil.AirfieldTruth``) -> ``airfield_truth`` + rejects.

Both are parsed in bulk per batch with :func:`pipeline.decode.json_bulk.parse_json_payloads`
(one ndjson parse, per-payload fallback only on failure) and validated with vectorised
expressions (reason_code ``out_of_range``): a missing required field, NaN/inf, and for
the truth latitude outside [-90, 90] deg, longitude outside [-180, 180] deg.

VASN rows: ``sensor_kind`` = ``vasn``, ``track_number`` = ``track_id``, x/y/velocity
east/north of the network's reference point (m, m/s); ``sensor_id`` = the channel
metadata's ``sensor_id`` when present, else the payload's. ASTERIX fields stay null.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import polars as pl
import pyarrow as pa

from pipeline.decode.json_bulk import (
    JsonParse,
    missing,
    nonfinite,
    outside,
    parse_json_payloads,
    split_valid,
    with_provenance,
)
from pipeline.decode.registry import make_rejects
from pipeline.io.mcap_read import ChannelBatch
from pipeline.messages import message_layout
from pipeline.tables import conform, empty

VASN_SCHEMA_NAME = "surveil.VasnReport"
TRUTH_SCHEMA_NAME = "surveil.AirfieldTruth"

# fields from the schemas (pipeline.messages); a VASN report's "last" flag is not decoded
VASN_LAYOUT = message_layout("vasn_report.schema.json")
VASN_FIELDS: dict[str, pl.DataType] = VASN_LAYOUT.polars_schema(omit=("last",))
_VASN_REQUIRED = VASN_LAYOUT.required
_VASN_NUMERIC = VASN_LAYOUT.required_numbers

TRUTH_LAYOUT = message_layout("airfield_truth.schema.json")
TRUTH_FIELDS: dict[str, pl.DataType] = TRUTH_LAYOUT.polars_schema()
_TRUTH_REQUIRED = TRUTH_LAYOUT.required
_TRUTH_NUMERIC = TRUTH_LAYOUT.required_numbers


def rejects_for(parsed: JsonParse, bad: pl.DataFrame, payloads: list[bytes],
                log_time_ns: np.ndarray, *, source_file: str, topic: str) -> pa.Table:
    """Rejects rows for the payloads that did not parse and the rows that failed a check."""
    if not parsed.bad_idx and bad.height == 0:
        return empty("rejects")
    idx = [*parsed.bad_idx, *bad["_idx"].to_list()]
    return make_rejects(
        np.asarray(log_time_ns, np.int64)[np.asarray(idx, np.int64)], source_file=source_file,
        topic=topic, reason_code=[*parsed.bad_code, *["out_of_range"] * bad.height],
        reason=[*parsed.bad_reason, *bad["_reason"].to_list()], raw=[payloads[i] for i in idx])


def decode_vasn_reports(
    payloads: list[bytes],
    log_time_ns: np.ndarray,
    *,
    source_file: str,
    topic: str,
    sensor_id: str | None = None,
) -> tuple[pa.Table, pa.Table]:
    """``(airfield_obs rows, rejects rows)`` of a batch of VASN report payloads."""
    parsed = parse_json_payloads(payloads, VASN_FIELDS)
    reasons = [
        *missing(_VASN_REQUIRED),
        *nonfinite(_VASN_NUMERIC),
        outside("sigma_x_m", 0.0, None, lo_open=True),
        outside("sigma_y_m", 0.0, None, lo_open=True),
    ]
    good, bad = split_valid(parsed.frame, reasons)
    rows = with_provenance(good, log_time_ns, source_file=source_file, topic=topic)
    rows = rows.with_columns(
        (pl.lit(sensor_id) if sensor_id else pl.col("sensor_id")).alias("sensor_id"),
        pl.lit("vasn").alias("sensor_kind"),
        pl.lit("target report").alias("message_type"),
        pl.col("track_id").alias("track_number"),
    )
    rejects = rejects_for(parsed, bad, payloads, log_time_ns, source_file=source_file, topic=topic)
    return conform("airfield_obs", rows.to_arrow()), rejects


def decode_airfield_truth(
    payloads: list[bytes], log_time_ns: np.ndarray, *, source_file: str, topic: str
) -> tuple[pa.Table, pa.Table]:
    """``(airfield_truth rows, rejects rows)`` of a batch of reference-state payloads."""
    parsed = parse_json_payloads(payloads, TRUTH_FIELDS)
    reasons = [
        *missing(_TRUTH_REQUIRED),
        *nonfinite(_TRUTH_NUMERIC),
        outside("lat_deg", -90.0, 90.0),
        outside("lon_deg", -180.0, 180.0),
    ]
    good, bad = split_valid(parsed.frame, reasons)
    rows = with_provenance(good, log_time_ns, source_file=source_file, topic=topic)
    rejects = rejects_for(parsed, bad, payloads, log_time_ns, source_file=source_file, topic=topic)
    return conform("airfield_truth", rows.to_arrow()), rejects


@dataclass
class VasnChannelDecoder:
    """Stateless per batch (registry ``CHANNEL_DECODERS`` protocol)."""

    source_file: str
    topic: str
    metadata: Mapping[str, str] = field(default_factory=dict)

    @classmethod
    def for_channel(cls, batch: ChannelBatch, source_file: str) -> VasnChannelDecoder:
        return cls(source_file, batch.topic, dict(batch.metadata))

    def feed(self, batch: ChannelBatch) -> dict[str, pa.Table]:
        rows, rejects = decode_vasn_reports(
            list(batch.payloads),
            batch.log_time_ns,
            source_file=self.source_file,
            topic=self.topic,
            sensor_id=self.metadata.get("sensor_id"),
        )
        return {"airfield_obs": rows, "rejects": rejects}

    def finish(self) -> dict[str, pa.Table]:
        return {}


@dataclass
class AirfieldTruthChannelDecoder:
    """Stateless per batch (registry ``CHANNEL_DECODERS`` protocol)."""

    source_file: str
    topic: str

    @classmethod
    def for_channel(cls, batch: ChannelBatch, source_file: str) -> AirfieldTruthChannelDecoder:
        return cls(source_file, batch.topic)

    def feed(self, batch: ChannelBatch) -> dict[str, pa.Table]:
        rows, rejects = decode_airfield_truth(
            list(batch.payloads), batch.log_time_ns, source_file=self.source_file, topic=self.topic
        )
        return {"airfield_truth": rows, "rejects": rejects}

    def finish(self) -> dict[str, pa.Table]:
        return {}
