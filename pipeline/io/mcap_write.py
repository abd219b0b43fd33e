"""Write zstd-chunked MCAP files: one file atomically (temporary name, fsync, rename),
from a frame of (log time, channel, payload) rows, deterministically (no wall clock).

The scenario writers (``pipeline.simulate``) and the legacy converters
(``pipeline.convert``) build those frames; this module only writes them.
"""

from __future__ import annotations

import os
import tempfile
from datetime import UTC, datetime
from pathlib import Path

import polars as pl
from mcap.writer import CompressionType, Writer

from pipeline.units import NS

MCAP_PROFILE = ""
MCAP_LIBRARY = "surveil-pipeline/mcap_write"
"""Fixed header strings (the mcap default embeds the library version)."""

def json_payloads(df: pl.DataFrame, fields: list[str]) -> pl.Series:
    """Compact JSON object per row with exactly ``fields``, as bytes."""
    return df.select(
        pl.struct([pl.col(f) for f in fields]).struct.json_encode().cast(pl.Binary).alias("p")
    )["p"]


def archive_file_name(scenario_name: str, period_start_ns: int) -> str:
    """``<scenario>_<YYYYMMDDTHHMMSSZ>.mcap`` for the file period starting at the given ns."""
    stamp = datetime.fromtimestamp(period_start_ns // NS, tz=UTC).strftime("%Y%m%dT%H%M%SZ")
    return f"{scenario_name}_{stamp}.mcap"


def write_mcap_file(
    path: Path,
    channels: list[tuple],
    schemas: dict[str, bytes],
    metadata: dict[str, str],
    df: pl.DataFrame,
    *,
    library: str = MCAP_LIBRARY,
) -> None:
    """Write one zstd-chunked MCAP file atomically (temp file, fsync, rename).

    ``channels``: (topic, message encoding, JSON-schema name or None[, channel metadata])
    per channel id; ``df``: log_time_ns, channel (index into ``channels``), payload (bytes),
    in log-time order. Deterministic for the same inputs (no wall-clock anywhere).
    """
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            writer = Writer(f, compression=CompressionType.ZSTD)
            writer.start(profile=MCAP_PROFILE, library=library)
            schema_ids: dict[str, int] = {}
            channel_ids = []
            for topic, encoding, schema_name, *channel_meta in channels:
                sid = 0
                if schema_name is not None:
                    if schema_name not in schema_ids:
                        schema_ids[schema_name] = writer.register_schema(
                            schema_name, "jsonschema", schemas[schema_name]
                        )
                    sid = schema_ids[schema_name]
                meta = channel_meta[0] if channel_meta else {}
                channel_ids.append(writer.register_channel(topic, encoding, sid, metadata=meta))
            writer.add_metadata("surveil.scenario", metadata)
            sequence = [0] * len(channels)
            add = writer.add_message
            # one call per message: the mcap writer has no bulk API
            for t, ch, payload in zip(
                df["log_time_ns"].to_list(),
                df["channel"].to_list(),
                df["payload"].to_list(),
                strict=True,
            ):
                add(channel_ids[ch], t, payload, t, sequence[ch])
                sequence[ch] += 1
            writer.finish()
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp_name, path)
    except BaseException:
        if os.path.exists(tmp_name):
            os.unlink(tmp_name)
        raise
