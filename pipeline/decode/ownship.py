"""Own-ship JSON channels -> raw tables: gyrocompass signals (``surveil.GyroSignals`` ->
``nav_gyro_signals``) and simulated truth (``surveil.OwnshipTruth`` -> ``ownship_truth``).

Parsed in bulk per batch (:func:`pipeline.decode.json_bulk.parse_json_payloads`) and
validated with vectorised checks (reason_code ``out_of_range``): a missing required
field, NaN/inf, an interval <= 0, |signals| > 1 rad (a tilt-equivalent signal of a
gyrocompass that large is a fault), latitude/longitude out of range, negative speeds.
``platform_id`` is the channel metadata's ``platform_id`` when present, else the
payload's, else the topic. Units: rad, m/s, m/s^2, ns.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import polars as pl
import pyarrow as pa

from pipeline.decode.json_bulk import (
    missing,
    nonfinite,
    outside,
    parse_json_payloads,
    split_valid,
    with_provenance,
)
from pipeline.decode.vasn import rejects_for
from pipeline.io.mcap_read import ChannelBatch
from pipeline.messages import message_layout
from pipeline.tables import conform

GYRO_SIGNALS_SCHEMA = "surveil.GyroSignals"
OWNSHIP_TRUTH_SCHEMA = "surveil.OwnshipTruth"

GYRO_LAYOUT = message_layout("gyro_signals.schema.json")
GYRO_FIELDS: dict[str, pl.DataType] = GYRO_LAYOUT.polars_schema()
_GYRO_NUMERIC = GYRO_LAYOUT.required_numbers

TRUTH_LAYOUT = message_layout("ownship_truth.schema.json")
TRUTH_FIELDS: dict[str, pl.DataType] = TRUTH_LAYOUT.polars_schema()
_TRUTH_NUMERIC = TRUTH_LAYOUT.required_numbers


def _platform(rows: pl.DataFrame, platform_id: str | None, topic: str) -> pl.DataFrame:
    given = pl.lit(platform_id, dtype=pl.String) if platform_id else pl.col("platform_id")
    return rows.with_columns(given.fill_null(topic).alias("platform_id"))


def decode_gyro_signals(
    payloads: list[bytes], log_time_ns: np.ndarray, *, source_file: str, topic: str,
    platform_id: str | None = None,
) -> tuple[pa.Table, pa.Table]:
    """``(nav_gyro_signals rows, rejects rows)`` of a batch of gyro-signal payloads."""
    parsed = parse_json_payloads(payloads, GYRO_FIELDS)
    checks = [
        *missing(GYRO_LAYOUT.required),
        *nonfinite(_GYRO_NUMERIC),
        outside("interval_s", 0.0, None, lo_open=True),
        outside("accel_signal_rad", -1.0, 1.0),
        outside("amplifier_rad", -1.0, 1.0),
    ]
    good, bad = split_valid(parsed.frame, checks)
    rows = _platform(with_provenance(good, log_time_ns, source_file=source_file, topic=topic),
                     platform_id, topic)
    rejects = rejects_for(parsed, bad, payloads, log_time_ns, source_file=source_file, topic=topic)
    return conform("nav_gyro_signals", rows.to_arrow()), rejects


def decode_ownship_truth(
    payloads: list[bytes], log_time_ns: np.ndarray, *, source_file: str, topic: str,
    platform_id: str | None = None,
) -> tuple[pa.Table, pa.Table]:
    """``(ownship_truth rows, rejects rows)`` of a batch of truth payloads."""
    parsed = parse_json_payloads(payloads, TRUTH_FIELDS)
    checks = [
        *missing(TRUTH_LAYOUT.required),
        *nonfinite(_TRUTH_NUMERIC),
        outside("lat_deg", -90.0, 90.0),
        outside("lon_deg", -180.0, 180.0),
        outside("speed_water_mps", 0.0, None),
        outside("sog_mps", 0.0, None),
    ]
    good, bad = split_valid(parsed.frame, checks)
    rows = _platform(with_provenance(good, log_time_ns, source_file=source_file, topic=topic),
                     platform_id, topic)
    rejects = rejects_for(parsed, bad, payloads, log_time_ns, source_file=source_file, topic=topic)
    return conform("ownship_truth", rows.to_arrow()), rejects


@dataclass
class _OwnshipJsonDecoder:
    """Stateless per batch (registry ``CHANNEL_DECODERS`` protocol)."""

    source_file: str
    topic: str
    metadata: Mapping[str, str] = field(default_factory=dict)

    @classmethod
    def for_channel(cls, batch: ChannelBatch, source_file: str) -> _OwnshipJsonDecoder:
        return cls(source_file, batch.topic, dict(batch.metadata))

    def finish(self) -> dict[str, pa.Table]:
        return {}


class GyroSignalsChannelDecoder(_OwnshipJsonDecoder):
    def feed(self, batch: ChannelBatch) -> dict[str, pa.Table]:
        rows, rejects = decode_gyro_signals(
            list(batch.payloads), batch.log_time_ns, source_file=self.source_file,
            topic=self.topic, platform_id=self.metadata.get("platform_id"))
        return {"nav_gyro_signals": rows, "rejects": rejects}


class OwnshipTruthChannelDecoder(_OwnshipJsonDecoder):
    def feed(self, batch: ChannelBatch) -> dict[str, pa.Table]:
        rows, rejects = decode_ownship_truth(
            list(batch.payloads), batch.log_time_ns, source_file=self.source_file,
            topic=self.topic, platform_id=self.metadata.get("platform_id"))
        return {"ownship_truth": rows, "rejects": rejects}
