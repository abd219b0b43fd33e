"""Write the ``region`` scenario: its config as ``region.toml`` and the log as hourly
zstd-chunked MCAP files beside it, streamed slice by slice (at most one slice of ten
minutes of messages in memory, whatever the duration).

Channels and payloads are those of the ``channel`` scenario
(:mod:`pipeline.simulate.channel_mcap`): ``/radar/<site>/tracks`` (JSON
``surveil.RadarTrackReport``), ``/ais/nmea`` (one ``!AIVDM`` sentence per message),
``/truth/vessels`` (JSON ``surveil.TruthState``); messages in non-decreasing log time
(ties: radar sites, AIS, truth, then row order). A file covers one UTC hour of log time
and is named ``region_<YYYYMMDDTHHMMSSZ>.mcap``.

    surveil simulate --scenario region --ships 1000 --radars 6 --duration 24h --out A/
    surveil --config A/region.toml ingest A/
    surveil --config A/region.toml batch --from ... --to ...
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import polars as pl

from pipeline.config import Config
from pipeline.io.mcap_write import McapFileWriter, archive_file_name, json_payloads
from pipeline.messages import RADAR_REPORT, message_layout
from pipeline.simulate.channel_mcap import (
    AIS_TOPIC,
    RADAR_SCHEMA_NAME,
    TRUTH_SCHEMA_NAME,
    TRUTH_TOPIC,
    radar_topic,
)
from pipeline.simulate.region import RegionSimulation
from pipeline.simulate.region_layout import region_config, region_layout, toml_text
from pipeline.units import NS

SCENARIO = "region"
CONFIG_NAME = "region.toml"
DEFAULT_SHIPS = 1000
DEFAULT_RADARS = 6
DEFAULT_DURATION_S = 86400.0
FILE_PERIOD_S = 3600


def write_region_config(out_dir: Path, n_radars: int) -> Path:
    """Write ``region.toml`` (the region's sites, legs, sectors and defaults) into
    ``out_dir`` and return its path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / CONFIG_NAME
    text = toml_text(
        region_config(region_layout(n_radars)),
        header=(f"surveil config of the `region` scenario ({n_radars} radar sites), written by\n"
                "`surveil simulate --scenario region`. Angles in degrees, times in seconds."),
    )
    path.write_text(text)
    return path


def simulate_region_archive(
    cfg: Config,
    start_ns: int,
    duration_s: float,
    seed: int,
    out_dir: Path,
    *,
    ships: int = DEFAULT_SHIPS,
    radars: int = DEFAULT_RADARS,
) -> list[Path]:
    """Simulate the region (``ships`` on average, ``radars`` sites) and write its config
    and hourly MCAP files under ``out_dir``; return the MCAP paths in time order.

    ``cfg`` is not used: the region brings its own geography (``region.toml``)."""
    out_dir = Path(out_dir)
    write_region_config(out_dir, radars)
    layout = region_layout(radars)
    sim = RegionSimulation(layout, n_ships=ships, seed=seed, start_ns=start_ns,
                           duration_s=duration_s)
    radar, truth = message_layout(RADAR_REPORT), message_layout("truth_state.schema.json")
    radar_schema, radar_fields = radar.data, radar.names
    truth_schema, truth_fields = truth.data, truth.names
    site_ids = [s.site_id for s in layout.sites]
    channels: list[tuple] = [
        *((radar_topic(s), "json", RADAR_SCHEMA_NAME) for s in site_ids),
        (AIS_TOPIC, "nmea0183", None),
        (TRUTH_TOPIC, "json", TRUTH_SCHEMA_NAME),
    ]
    rank = {s: i for i, s in enumerate(site_ids)}
    schemas = {RADAR_SCHEMA_NAME: radar_schema, TRUTH_SCHEMA_NAME: truth_schema}
    metadata = {
        "name": SCENARIO,
        "site": SCENARIO,  # each scenario its own site (pipeline.io.mcap_site)
        "seed": str(seed),
        "start_ns": str(start_ns),
        "duration_s": repr(float(duration_s)),
        "start_utc": datetime.fromtimestamp(start_ns / NS, tz=UTC).isoformat(),
        "ships": str(ships),
        "radars": str(radars),
    }
    period_ns = FILE_PERIOD_S * NS
    paths: list[Path] = []
    writer: McapFileWriter | None = None
    current = None
    try:
        for sl in sim.slices():
            file_index = sl.start_ns // period_ns
            if file_index != current:
                if writer is not None:
                    writer.__exit__(None, None, None)
                current = file_index
                period_start = int(file_index) * period_ns
                path = out_dir / archive_file_name(SCENARIO, period_start)
                meta = {**metadata, "file_start_ns": str(period_start),
                        "file_end_ns": str(period_start + period_ns)}
                writer = McapFileWriter(path, channels, schemas, meta)
                paths.append(path)
            radar = sl.radar_reports
            parts = [
                pl.DataFrame({
                    "log_time_ns": radar["log_time_ns"],
                    "channel": radar["site_id"].replace_strict(rank, return_dtype=pl.Int32),
                    "payload": json_payloads(radar, radar_fields),
                }),
                pl.DataFrame({
                    "log_time_ns": sl.ais_sentences["log_time_ns"],
                    "channel": pl.repeat(len(site_ids), sl.ais_sentences.height, eager=True,
                                         dtype=pl.Int32),
                    "payload": sl.ais_sentences["sentence"],
                }),
                pl.DataFrame({
                    "log_time_ns": sl.truth["time_ns"],
                    "channel": pl.repeat(len(site_ids) + 1, sl.truth.height, eager=True,
                                         dtype=pl.Int32),
                    "payload": json_payloads(sl.truth, truth_fields),
                }),
            ]
            messages = pl.concat(
                [p.with_columns(pl.col("channel").cast(pl.Int32),
                                pl.int_range(pl.len(), dtype=pl.Int64).alias("row"))
                 for p in parts]
            ).sort(["log_time_ns", "channel", "row"])
            assert writer is not None
            writer.add(messages["log_time_ns"], messages["channel"], messages["payload"])
        if writer is not None:
            writer.__exit__(None, None, None)
            writer = None
    except BaseException as exc:
        if writer is not None:
            writer.__exit__(type(exc), exc, exc.__traceback__)
        raise
    return paths
