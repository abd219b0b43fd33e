"""Write the ``airfield`` scenario as zstd-chunked MCAP files, one per hour.

========================  ================  ========================  ===========================
topic                     message encoding  schema                    payload
========================  ================  ========================  ===========================
``/airfield/<id>/cat010``  ``asterix``       none (schema id 0)        one CAT010 data block per
                                                                      update (SMR, MLAT)
``/airfield/<id>/vasn``   ``json``          ``surveil.VasnReport``    one report
``/airfield/truth``       ``json``          ``surveil.AirfieldTruth``  one target state
========================  ================  ========================  ===========================

Sensor channels carry MCAP channel metadata ``sensor_id`` and ``sensor_kind``. A CAT010
block holds every report of one sensor update (time of applicability = the update
second); its log time is that second plus the sensor's latency. Messages are written in
non-decreasing log time (ties in channel order); each file covers [k·P, (k+1)·P) of log
time and is named like the channel scenario's (``airfield_<YYYYMMDDTHHMMSSZ>.mcap``);
temp file + ``os.replace``; the bytes depend only on the inputs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl

from pipeline.airfield.config import AirfieldConfig, airfield_config
from pipeline.config import Config
from pipeline.decode import asterix_encode as cat010
from pipeline.io.mcap_write import archive_file_name, write_mcap_file
from pipeline.messages import message_layout
from pipeline.simulate.airfield import AirfieldScenario, simulate_airfield
from pipeline.units import NS

TRUTH_TOPIC = "/airfield/truth"
VASN_SCHEMA = "surveil.VasnReport"
TRUTH_SCHEMA = "surveil.AirfieldTruth"


def sensor_topic(sensor_id: str, kind: str) -> str:
    return f"/airfield/{sensor_id}/{'vasn' if kind == 'vasn' else 'cat010'}"


def _schema(file_name: str) -> tuple[bytes, list[str]]:
    """The schema's bytes (the channel's MCAP schema) and its fields in order."""
    layout = message_layout(file_name)
    return layout.data, layout.names


def _json(df: pl.DataFrame, fields: list[str]) -> pl.Series:
    return df.select(
        pl.struct([pl.col(f) for f in fields if f in df.columns])
        .struct.json_encode()
        .cast(pl.Binary)
        .alias("p")
    )["p"]


def cat010_messages(reports: pl.DataFrame, kind: str, sac: int, sic: int) -> pl.DataFrame:
    """(log_time_ns, payload) of one sensor's reports packed as CAT010 blocks."""
    r = reports.sort(["time_ns", "track_number"])
    get = (lambda c: r[c].to_numpy()) if r.height else (lambda c: np.empty(0))
    rep = cat010.Cat010Reports(
        kind=kind,
        sac=sac,
        sic=sic,
        time_ns=get("time_ns"),
        track_number=get("track_number"),
        sigma_x_m=get("sigma_x_m"),
        sigma_y_m=get("sigma_y_m"),
        cov_xy_m2=get("cov_xy_m2"),
        last=get("last"),
        **(
            {
                "range_m": get("range_m"),
                "azimuth_rad": get("azimuth_rad"),
                "speed_mps": get("speed_mps"),
                "course_rad": get("course_rad"),
            }
            if kind == "smr"
            else {
                "x_m": get("x_m"),
                "y_m": get("y_m"),
                "vx_mps": get("vx_mps"),
                "vy_mps": get("vy_mps"),
                "target_address": get("target_address"),
                "callsign": get("callsign"),
                "target_type": get("target_type"),
            }
        ),
    )
    keys, blocks = cat010.encode_blocks(rep, get("time_ns"))
    latency = (r["log_time_ns"] - r["time_ns"]).first() if r.height else 0
    return pl.DataFrame(
        {
            "log_time_ns": np.asarray(keys, np.int64) + latency,
            "payload": pl.Series(blocks, dtype=pl.Binary),
        }
    )


def write_airfield_archive(
    scenario: AirfieldScenario, cfg: AirfieldConfig, out_dir: Path, *, file_period_s: float = 3600.0
) -> list[Path]:
    """Write ``scenario`` under ``out_dir``; return the files in time order."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    period_ns = round(file_period_s * NS)
    vasn_schema, vasn_fields = _schema("vasn_report.schema.json")
    truth_schema, truth_fields = _schema("airfield_truth.schema.json")
    channels, parts = [], []
    for s in cfg.sensors:  # one pass per sensor
        rows = scenario.reports.filter(pl.col("sensor_id") == s.sensor_id)
        meta = {"sensor_id": s.sensor_id, "sensor_kind": s.kind}
        if s.kind == "vasn":
            msgs = pl.DataFrame(
                {
                    "log_time_ns": rows["log_time_ns"],
                    "payload": _json(rows.rename({"track_number": "track_id"}), vasn_fields),
                }
            )
            channels.append((sensor_topic(s.sensor_id, s.kind), "json", VASN_SCHEMA, meta))
        else:
            msgs = cat010_messages(rows, s.kind, s.sac, s.sic)
            channels.append((sensor_topic(s.sensor_id, s.kind), "asterix", None, meta))
        parts.append(msgs.with_columns(pl.lit(len(channels) - 1, pl.Int32).alias("channel")))
    channels.append((TRUTH_TOPIC, "json", TRUTH_SCHEMA, {}))
    parts.append(
        pl.DataFrame(
            {
                "log_time_ns": scenario.truth["time_ns"],
                "payload": _json(scenario.truth, truth_fields),
            }
        ).with_columns(pl.lit(len(channels) - 1, pl.Int32).alias("channel"))
    )
    messages = (
        pl.concat(
            [p.with_columns(pl.int_range(pl.len(), dtype=pl.Int64).alias("row")) for p in parts]
        )
        .sort(["log_time_ns", "channel", "row"])
        .with_columns((pl.col("log_time_ns") // period_ns).alias("file_index"))
    )
    schemas = {VASN_SCHEMA: vasn_schema, TRUTH_SCHEMA: truth_schema}
    meta = {
        "name": "airfield",
        "site": "airfield",  # each scenario its own site (pipeline.io.mcap_site)
        "seed": str(scenario.seed),
        "start_ns": str(scenario.start_ns),
        "duration_s": repr(float(scenario.duration_s)),
    }
    paths = []
    for (file_index,), df in messages.group_by(["file_index"], maintain_order=True):
        path = out_dir / archive_file_name("airfield", int(file_index) * period_ns)
        write_mcap_file(path, channels, schemas, meta, df)
        paths.append(path)
    return paths


def simulate_airfield_archive(
    cfg: Config, start_ns: int, duration_s: float, seed: int, out_dir: Path
) -> list[Path]:
    """The ``airfield`` entry of ``surveil simulate`` (jobs/simulate.py SCENARIOS)."""
    acfg = airfield_config(cfg)
    scenario = simulate_airfield(acfg, start_ns=start_ns, duration_s=duration_s, seed=seed)
    return write_airfield_archive(scenario, acfg, out_dir)
