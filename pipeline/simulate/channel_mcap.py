"""Write the ``channel`` scenario (and the ``gaps`` scenario, which has the same channels)
as an archive of zstd-chunked MCAP files, one per hour.

Channels (one per topic; every file registers all of them):

========================  ==================  ============================  ============
topic                     message encoding    schema                        payload
========================  ==================  ============================  ============
``/radar/<site_id>/tracks``  ``json``          ``surveil.RadarTrackReport``   compact JSON
``/ais/nmea``             ``nmea0183``        none (schema id 0)            one sentence
``/truth/vessels``        ``json``            ``surveil.TruthState``         compact JSON
``/truth/faults``         ``json``            ``surveil.FaultTruth``         compact JSON
========================  ==================  ============================  ============

``/truth/faults`` only when the scene has faults: a fault-free scene (``channel-clean``,
``gaps``) has the channels and bytes it had before the fault schedule existed.

JSON payloads carry exactly the fields of the channel's JSON schema (``schemas/``), in
the schema's order; AIS payloads are the ASCII sentence without CR/LF. Messages are
written in non-decreasing log time across channels (ties: radar, AIS, truth, faults,
then row order); ``publish_time`` = ``log_time``. A file covers [k·P, (k+1)·P) of log time
(P = ``file_period_s``, aligned to the Unix epoch, so 3600 s gives UTC hours) and is
named ``<scenario>_<YYYYMMDDTHHMMSSZ of its period start>.mcap``. Each file holds a
metadata record ``surveil.scenario`` (name, seed, start, duration, the file's period).
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import polars as pl

from pipeline.config import Config
from pipeline.io.mcap_write import archive_file_name, json_payloads, write_mcap_file
from pipeline.maritime.config import without_faults
from pipeline.messages import RADAR_REPORT, message_layout
from pipeline.simulate.channel import ChannelScenario, simulate_channel
from pipeline.units import NS

RADAR_SCHEMA_NAME = "surveil.RadarTrackReport"
TRUTH_SCHEMA_NAME = "surveil.TruthState"
FAULT_SCHEMA_NAME = "surveil.FaultTruth"
AIS_TOPIC = "/ais/nmea"
TRUTH_TOPIC = "/truth/vessels"
FAULT_TOPIC = "/truth/faults"


def radar_topic(site_id: str) -> str:
    """MCAP topic of a radar site's track reports."""
    return f"/radar/{site_id}/tracks"


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
    radar, truth_layout = message_layout(RADAR_REPORT), message_layout("truth_state.schema.json")
    radar_schema, radar_fields = radar.data, radar.names
    truth_schema, truth_fields = truth_layout.data, truth_layout.names
    fault_layout = message_layout("fault_truth.schema.json")
    fault_schema, fault_fields = fault_layout.data, fault_layout.names

    # (topic, message encoding, schema name or None) in channel-id order
    site_ids = list(scenario.site_ids)
    channels: list[tuple[str, str, str | None]] = [
        *((radar_topic(s), "json", RADAR_SCHEMA_NAME) for s in site_ids),
        (AIS_TOPIC, "nmea0183", None),
        (TRUTH_TOPIC, "json", TRUTH_SCHEMA_NAME),
    ]
    faults = scenario.fault_truth
    if faults.height:  # a fault-free scene's archive has the channels it had before faults
        channels.append((FAULT_TOPIC, "json", FAULT_SCHEMA_NAME))
    rank = {topic: i for i, (topic, _, _) in enumerate(channels)}

    parts = []
    for s in site_ids:
        df = scenario.radar_reports.filter(pl.col("site_id") == s)
        parts.append(
            pl.DataFrame(
                {
                    "log_time_ns": df["log_time_ns"],
                    "channel": rank[radar_topic(s)],
                    "payload": json_payloads(df, radar_fields),
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
                "payload": json_payloads(truth, truth_fields),
            }
        )
    )
    if faults.height:
        parts.append(
            pl.DataFrame(
                {
                    "log_time_ns": faults["start_ns"],
                    "channel": rank[FAULT_TOPIC],
                    "payload": json_payloads(faults, fault_fields),
                },
                schema={"log_time_ns": pl.Int64, "channel": pl.Int64, "payload": pl.Binary},
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
        "site": scenario_name,  # each scenario its own site (pipeline.io.mcap_site)
        "seed": str(scenario.seed),
        "start_ns": str(scenario.start_ns),
        "duration_s": repr(float(scenario.duration_s)),
        "start_utc": datetime.fromtimestamp(scenario.start_ns / NS, tz=UTC).isoformat(),
    }
    schemas = {
        RADAR_SCHEMA_NAME: radar_schema,
        TRUTH_SCHEMA_NAME: truth_schema,
    }
    if faults.height:
        schemas[FAULT_SCHEMA_NAME] = fault_schema
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


def simulate_channel_archive(
    cfg: Config, start_ns: int, duration_s: float, seed: int, out_dir: Path
) -> list[Path]:
    """Simulate the ``channel`` scenario (with the config's ``[[channel_faults]]``) and
    write it under ``out_dir``; return the files."""
    scenario = simulate_channel(cfg, start_ns=start_ns, duration_s=duration_s, seed=seed)
    return write_channel_archive(scenario, out_dir, scenario_name="channel")


def simulate_channel_clean_archive(
    cfg: Config, start_ns: int, duration_s: float, seed: int, out_dir: Path
) -> list[Path]:
    """The ``channel-clean`` scenario: ``channel`` without the fault schedule (the same
    ships, reports and noise where no fault acts)."""
    scenario = simulate_channel(
        without_faults(cfg), start_ns=start_ns, duration_s=duration_s, seed=seed
    )
    return write_channel_archive(scenario, out_dir, scenario_name="channel-clean")
