"""Shared builders for tests: real MCAP files written with ``mcap.writer.Writer``.

Imported by tests under tests/io, tests/decode, tests/warehouse and tests/jobs (no
conftest.py on purpose). Everything is deterministic: no RNG without a seed.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pyarrow as pa
from mcap.writer import CompressionType, Writer

from pipeline.resources import resource_path
from pipeline.tables import conform
from pipeline.units import NS

T0_NS = 1_767_225_600 * 10**9  # 2026-01-01T00:00:00Z
T0 = T0_NS

DAY = 86_400 * NS
RADAR_SCHEMA = "surveil.RadarTrackReport"
TRUTH_SCHEMA = "surveil.TruthState"

# Real sentences (pyais test sample, MIT) used as known-good AIS input.
AIS_TYPE1 = b"!AIVDM,1,1,,A,13RlIW?04F1beOVEFLB9bRvH0L0L,0*6C"
AIS_TYPE3 = b"!AIVDM,1,1,,A,33P;Tw0tjBQO22:E7dm66DrB20UP,0*2E"
AIS_TYPE18 = b"!AIVDM,1,1,,B,B39H9GP0;@H136UI3ijEowU5oP06,0*14"
AIS_EMPTY = b"!AIVDM,1,1,,B,,0*25"


def real_data_root() -> Path:
    """``$SURVEIL_REAL_DATA`` or ``/work/shared/data/real`` (``../shared/data/real`` of the
    repository); tests using it skip when the file they need is absent."""
    env = os.environ.get("SURVEIL_REAL_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "real"


def radar_report(i: int, *, site: str = "R1", t_ns: int | None = None, **over: object) -> dict:
    """A valid radar track report (schema fields), number ``i``; ``over`` overrides."""
    t = T0_NS + i * 10**9 if t_ns is None else t_ns
    az = (0.1 + 0.01 * i) % (2 * math.pi)
    rng = 1000.0 + i
    rep = {
        "site_id": site,
        "track_id": 100 + i % 7,
        "time_ns": t,
        "range_m": rng,
        "azimuth_rad": az,
        "x_m": rng * math.sin(az),
        "y_m": rng * math.cos(az),
        "course_rad": 1.0,
        "speed_mps": 5.0,
        "sigma_range_m": 15.0,
        "sigma_azimuth_rad": 0.0079,
        "sigma_course_rad": 0.035,
        "sigma_speed_mps": 0.25,
        "scan_period_s": 3.0,
        "scan_end_azimuth_rad": 6.0,
        "status": "confirmed",
    }
    rep.update(over)
    return rep


def dumps(obj: dict) -> bytes:
    """Compact JSON as the simulator writes it (NaN allowed, as Python emits it)."""
    return json.dumps(obj, separators=(",", ":")).encode()


def truth_state(i: int, *, vessel: int = 1, **over: object) -> dict:
    st = {
        "vessel_id": vessel,
        "mmsi": 273000000 + vessel,
        "time_ns": T0_NS + i * 10**9,
        "lat_deg": 46.4 + 1e-4 * i,
        "lon_deg": 30.9,
        "course_rad": 0.5,
        "speed_mps": 6.0,
    }
    st.update(over)
    return st


def nmea(body: str) -> bytes:
    """``!<body>*hh`` with a correct NMEA XOR checksum."""
    ck = 0
    for c in body.encode():
        ck ^= c
    return f"!{body}*{ck:02X}".encode()


def write_mcap(
    path: Path,
    messages: list[tuple[str, int, bytes]],
    *,
    chunk_size: int = 4096,
    compression: CompressionType = CompressionType.ZSTD,
    finish: bool = True,
    extra_channels: dict[str, tuple[str, str, str]] | None = None,
    metadata: dict[str, dict[str, str]] | None = None,
) -> Path:
    """Write ``messages`` to ``path`` with the real channel layout of the simulator.

    Topics ``/radar/*`` -> json + surveil.RadarTrackReport, ``/truth/vessels`` -> json +
    surveil.TruthState, ``/ais/nmea`` -> nmea0183 without schema. ``extra_channels`` maps a
    topic to (message_encoding, schema_name, schema_encoding) for unknown channels.
    ``finish=False`` leaves the file as a crashed writer would (no summary, no footer).
    ``metadata``: metadata records (name -> key/values), written ahead of the messages.
    """
    schemas_dir = resource_path("schemas")
    f = open(path, "wb")  # noqa: SIM115 - kept open on purpose when finish=False
    w = Writer(f, chunk_size=chunk_size, compression=compression)
    w.start(profile="", library="surveil-tests")
    radar_sid = w.register_schema(
        RADAR_SCHEMA, "jsonschema", (schemas_dir / "radar_track_report.schema.json").read_bytes()
    )
    truth_sid = w.register_schema(
        TRUTH_SCHEMA, "jsonschema", (schemas_dir / "truth_state.schema.json").read_bytes()
    )
    channels: dict[str, int] = {}
    for name, values in (metadata or {}).items():
        w.add_metadata(name, values)

    def channel(topic: str) -> int:
        if topic in channels:
            return channels[topic]
        if extra_channels and topic in extra_channels:
            enc, sname, senc = extra_channels[topic]
            sid = w.register_schema(sname, senc, b"{}") if sname else 0
            channels[topic] = w.register_channel(topic, enc, sid)
        elif topic.startswith("/radar/"):
            channels[topic] = w.register_channel(topic, "json", radar_sid)
        elif topic == "/truth/vessels":
            channels[topic] = w.register_channel(topic, "json", truth_sid)
        elif topic.startswith("/ais/"):
            channels[topic] = w.register_channel(topic, "nmea0183", 0)
        else:
            raise ValueError(topic)
        return channels[topic]

    for seq, (topic, t, payload) in enumerate(messages):
        w.add_message(channel(topic), log_time=t, data=payload, publish_time=t, sequence=seq)
    if finish:
        w.finish()
        f.close()
    else:
        f.flush()
        f.close()
    return path


def radar_messages(n: int, *, site: str = "R1", t0_ns: int = T0_NS) -> list:
    """``n`` valid radar reports on ``/radar/<site>/tracks``, one per second."""
    out = []
    for i in range(n):
        t = t0_ns + i * 10**9
        out.append((f"/radar/{site}/tracks", t, dumps(radar_report(i, site=site, t_ns=t))))
    return out


def mixed_file(path: Path, n_radar: int = 300, *, chunk_size: int = 4096) -> Path:
    """A healthy file with radar, truth and AIS (incl. a two-part type 5) messages."""
    msgs = radar_messages(n_radar)
    for i in range(0, n_radar, 10):
        t = T0_NS + i * 10**9 + 1
        msgs.append(("/truth/vessels", t, dumps(truth_state(i, time_ns=t))))
    ais_t = T0_NS + 5 * 10**9
    msgs.append(("/ais/nmea", ais_t, AIS_TYPE1))
    msgs.append(("/ais/nmea", ais_t + 1, AIS_TYPE18))
    for k, frag in enumerate(TYPE5_FRAGMENTS):
        msgs.append(("/ais/nmea", ais_t + 2 + k, frag))
    msgs.sort(key=lambda m: m[1])
    return write_mcap(path, msgs, chunk_size=chunk_size)


# A real two-part type 5 (pyais test sample).
TYPE5_FRAGMENTS = [
    b"!AIVDM,2,1,1,A,55?MbV02;H;s<HtKR20EHE:0@T4@Dn2222222216L961O5Gf0NSQEp6ClRp8,0*1C",
    b"!AIVDM,2,2,1,A,88888888880,2*25",
]


# -- warehouse rows ---------------------------------------------------------------------


def truth_rows(t_ns: np.ndarray, *, speed: float = 5.0, source: str = "/a.mcap",
               site: str = "harbour") -> pa.Table:
    n = len(t_ns)
    return conform(
        "truth",
        pa.table(
            {
                "time_ns": pa.array(t_ns, pa.int64()),
                "vessel_id": pa.array(np.arange(n) % 3, pa.int64()),
                "mmsi": pa.nulls(n, pa.int64()),
                "lat_deg": np.full(n, 46.0),
                "lon_deg": np.full(n, 30.0),
                "course_rad": np.zeros(n),
                "speed_mps": np.full(n, speed),
                "source_file": [source] * n,
                "topic": ["/truth/vessels"] * n,
                "log_time_ns": pa.array(t_ns, pa.int64()),
            }
        ),
        site=site,
    )


def hours(h0: float, h1: float, step_s: int = 60) -> np.ndarray:
    return np.arange(T0 + int(h0 * 3600) * NS, T0 + int(h1 * 3600) * NS, step_s * NS)
