"""Write a simulated scenario as an archive of zstd-chunked MCAP files, one per hour.

Channels (one per topic; every file registers all of them):

========================  ==================  ============================  ============
topic                     message encoding    schema                        payload
========================  ==================  ============================  ============
``/radar/<site_id>/tracks``  ``json``          ``surveil.RadarTrackReport``   compact JSON
``/ais/nmea``             ``nmea0183``        none (schema id 0)            one sentence
``/truth/vessels``        ``json``            ``surveil.TruthState``         compact JSON
========================  ==================  ============================  ============

JSON payloads carry exactly the fields of the channel's JSON schema (``schemas/``), in
the schema's order; AIS payloads are the ASCII sentence without CR/LF. Messages are
written in non-decreasing log time across channels (ties: radar, AIS, truth, then row
order); ``publish_time`` = ``log_time``. A file covers [k·P, (k+1)·P) of log time
(P = ``file_period_s``, aligned to the Unix epoch, so 3600 s gives UTC hours) and is
named ``<scenario>_<YYYYMMDDTHHMMSSZ of its period start>.mcap``. Each file holds a
metadata record ``surveil.scenario`` (name, seed, start, duration, the file's period).

The bytes depend only on the inputs: no wall-clock time, fixed header strings. Each file
is written to a temporary name in ``out_dir`` and renamed into place (``os.replace``).
"""

from __future__ import annotations

import json
import os
import tempfile
from datetime import UTC, datetime
from pathlib import Path

import polars as pl
from mcap.writer import CompressionType, Writer

from pipeline.resources import resource_path
from pipeline.simulate.channel import ChannelScenario

NS = 1_000_000_000
MCAP_PROFILE = ""
MCAP_LIBRARY = "surveil-pipeline/mcap_write"
"""Fixed header strings (the mcap default embeds the library version)."""

RADAR_SCHEMA_NAME = "surveil.RadarTrackReport"
TRUTH_SCHEMA_NAME = "surveil.TruthState"
AIS_TOPIC = "/ais/nmea"
TRUTH_TOPIC = "/truth/vessels"


def radar_topic(site_id: str) -> str:
    """MCAP topic of a radar site's track reports."""
    return f"/radar/{site_id}/tracks"


def _schema_bytes(file_name: str) -> tuple[bytes, list[str]]:
    data = (resource_path("schemas") / file_name).read_bytes()
    return data, list(json.loads(data)["properties"])


def _json_payloads(df: pl.DataFrame, fields: list[str]) -> pl.Series:
    """Compact JSON object per row with exactly ``fields``, as bytes."""
    return df.select(
        pl.struct([pl.col(f) for f in fields]).struct.json_encode().cast(pl.Binary).alias("p")
    )["p"]


def archive_file_name(scenario_name: str, period_start_ns: int) -> str:
    """``<scenario>_<YYYYMMDDTHHMMSSZ>.mcap`` for the file period starting at the given ns."""
    stamp = datetime.fromtimestamp(period_start_ns // NS, tz=UTC).strftime("%Y%m%dT%H%M%SZ")
    return f"{scenario_name}_{stamp}.mcap"


def write_channel_archive(
    scenario: ChannelScenario,
    out_dir: Path,
    *,
    file_period_s: float = 3600.0,
    scenario_name: str = "channel",
) -> list[Path]:
    """Write ``scenario`` as MCAP files under ``out_dir``; return their paths in time order.

    ``file_period_s``: length of the log-time period of one file, s (3600: one file per
    UTC hour). Files of periods without messages are not written.
    """
    period_ns = round(file_period_s * NS)
    if period_ns <= 0:
        raise ValueError(f"file_period_s must be positive, got {file_period_s}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    radar_schema, radar_fields = _schema_bytes("radar_track_report.schema.json")
    truth_schema, truth_fields = _schema_bytes("truth_state.schema.json")

    # (topic, message encoding, schema name or None) in channel-id order
    site_ids = list(scenario.site_ids)
    channels: list[tuple[str, str, str | None]] = [
        *((radar_topic(s), "json", RADAR_SCHEMA_NAME) for s in site_ids),
        (AIS_TOPIC, "nmea0183", None),
        (TRUTH_TOPIC, "json", TRUTH_SCHEMA_NAME),
    ]
    rank = {topic: i for i, (topic, _, _) in enumerate(channels)}

    parts = []
    for s in site_ids:
        df = scenario.radar_reports.filter(pl.col("site_id") == s)
        parts.append(
            pl.DataFrame(
                {
                    "log_time_ns": df["log_time_ns"],
                    "channel": rank[radar_topic(s)],
                    "payload": _json_payloads(df, radar_fields),
                }
            )
        )
    ais = scenario.ais_sentences
    parts.append(
        pl.DataFrame(
            {
                "log_time_ns": ais["log_time_ns"],
                "channel": rank[AIS_TOPIC],
                "payload": ais["sentence"].cast(pl.Binary),
            }
        )
    )
    truth = scenario.truth
    parts.append(
        pl.DataFrame(
            {
                "log_time_ns": truth["time_ns"],
                "channel": rank[TRUTH_TOPIC],
                "payload": _json_payloads(truth, truth_fields),
            }
        )
    )
    messages = (
        pl.concat(
            [
                p.with_columns(
                    pl.col("channel").cast(pl.Int32),
                    pl.int_range(pl.len(), dtype=pl.Int64).alias("row"),
                )
                for p in parts
            ]
        )
        .sort(["log_time_ns", "channel", "row"])
        .with_columns((pl.col("log_time_ns") // period_ns).alias("file_index"))
    )

    metadata = {
        "name": scenario_name,
        "seed": str(scenario.seed),
        "start_ns": str(scenario.start_ns),
        "duration_s": repr(float(scenario.duration_s)),
        "start_utc": datetime.fromtimestamp(scenario.start_ns / NS, tz=UTC).isoformat(),
    }
    schemas = {RADAR_SCHEMA_NAME: radar_schema, TRUTH_SCHEMA_NAME: truth_schema}
    paths: list[Path] = []
    for (file_index,), df in messages.group_by(["file_index"], maintain_order=True):
        period_start = int(file_index) * period_ns
        path = out_dir / archive_file_name(scenario_name, period_start)
        meta = {
            **metadata,
            "file_start_ns": str(period_start),
            "file_end_ns": str(period_start + period_ns),
        }
        write_mcap_file(path, channels, schemas, meta, df)
        paths.append(path)
    return paths


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
