"""Write zstd-chunked MCAP files: one file atomically (temporary name, fsync, rename),
from (log time, channel, payload) rows, deterministically (no wall clock).

The scenario writers (``pipeline.simulate``) build frames for :func:`write_mcap_file`;
the legacy converters (``pipeline.convert``) call :func:`write_messages`. This module
only writes them.

Log times: an MCAP log time is a uint64 and the warehouse keeps int64 ns, so a log time
is representable when it lies in ``[TIME_MIN_NS, TIME_MAX_NS]`` (1970-01-01 to
2262-04-11, :mod:`pipeline.units`). Both writers check every log time BEFORE they create
the file and raise :class:`LogTimeError` (a ``ValueError`` naming the first bad message)
instead of the ``struct.error`` the mcap writer would raise half-way through; the
converters divert such messages to rejects beforehand (:mod:`pipeline.convert.output`).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import polars as pl
from mcap.writer import CompressionType, Writer

from pipeline.units import NS, TIME_MAX_NS, TIME_MIN_NS, describe_time

MCAP_PROFILE = ""
MCAP_LIBRARY = "surveil-pipeline/mcap_write"
"""Fixed header strings (the mcap default embeds the library version)."""


class LogTimeError(ValueError):
    """A log time outside the representable range (see the module docstring)."""


def first_bad_log_time(log_times: Sequence[int]) -> tuple[int, int] | None:
    """``(index, value)`` of the first log time outside ``[TIME_MIN_NS, TIME_MAX_NS]``,
    else ``None``. ``log_times``: Python ints (exact) or an int64 array."""
    for i, t in enumerate(log_times):
        if not TIME_MIN_NS <= t <= TIME_MAX_NS:
            return i, int(t)
    return None


def check_log_times(log_times: Sequence[int], what: str = "message") -> None:
    """Raise :class:`LogTimeError` when a log time is not representable."""
    bad = first_bad_log_time(log_times)
    if bad is not None:
        i, t = bad
        raise LogTimeError(
            f"{what} {i}: log time {t} ns ({describe_time(t)}) is outside the representable "
            f"range [{TIME_MIN_NS}, {TIME_MAX_NS}] ns (1970-01-01 .. 2262-04-11 UTC)"
        )


@dataclass(frozen=True)
class ChannelSpec:
    """One channel to write: topic, message encoding, optional schema, metadata."""

    topic: str
    message_encoding: str
    schema_name: str | None = None
    schema_encoding: str = "jsonschema"
    schema_data: bytes = b""
    metadata: Mapping[str, str] = field(default_factory=dict)


def write_messages(
    path: Path,
    channels: Sequence[ChannelSpec],
    channel_index: Sequence[int],
    log_times: Sequence[int],
    payloads: Sequence[bytes],
    *,
    metadata: Mapping[str, Mapping[str, str]] | None = None,
    library: str = MCAP_LIBRARY,
) -> dict[str, int]:
    """Write messages in the given order (a source file's order), atomically; returns the
    message count per topic. ``channel_index[i]`` indexes ``channels``; ``metadata``:
    name -> key/value metadata records. Raises :class:`LogTimeError` (nothing written)
    when a log time is not representable."""
    check_log_times(log_times)
    if not len(channel_index) == len(log_times) == len(payloads):
        raise ValueError("channel_index, log_times and payloads differ in length")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            w = Writer(f, compression=CompressionType.ZSTD)
            w.start(profile=MCAP_PROFILE, library=library)
            schema_ids: dict[tuple[str, str, bytes], int] = {}
            ids = []
            for c in channels:
                sid = 0
                if c.schema_name is not None:
                    key = (c.schema_name, c.schema_encoding, c.schema_data)
                    if key not in schema_ids:
                        schema_ids[key] = w.register_schema(*key)
                    sid = schema_ids[key]
                ids.append(w.register_channel(c.topic, c.message_encoding, sid,
                                              metadata=dict(c.metadata)))  # fmt: skip
            for name, record in (metadata or {}).items():
                w.add_metadata(name, dict(record))
            seq = [0] * len(ids)
            # one add_message call per message: the mcap writer has no bulk API
            for ch, t, p in zip(channel_index, log_times, payloads, strict=True):
                w.add_message(ids[ch], int(t), p, int(t), seq[ch])
                seq[ch] += 1
            w.finish()
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return {c.topic: n for c, n in zip(channels, seq, strict=True) if n}


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
    in log-time order. Deterministic for the same inputs (no wall-clock anywhere). Raises
    :class:`LogTimeError` (no file written) when a log time is not representable.
    """
    check_log_times(df["log_time_ns"].to_list())
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
