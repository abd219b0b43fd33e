"""Every real MCAP file of ``../shared/data/real/mcap`` ingested into a warehouse.

Expected counts come from each file's own summary (channel message counts, read with
the ``mcap`` package's reader) and its schemas: NavSatFix and Imu channels (ROS 1 in the
converted Husky bag) must give one row per message, every other channel with messages
exactly one ``unknown_schema`` rejects row carrying its count. The decoded values of the
Husky file are checked against a second, per-message decode written here with
``struct`` from the ROS 1 wire format (sensor_msgs/NavSatFix, sensor_msgs/Imu).
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from pipeline.families import load_config
from pipeline.units import NS
from tests.real_data import real_data_dir

pytestmark = pytest.mark.realdata
DECODED = {
    "sensor_msgs/NavSatFix": "nav_gnss", "sensor_msgs/Imu": "nav_heading",
    "sensor_msgs/msg/NavSatFix": "nav_gnss", "sensor_msgs/msg/Imu": "nav_heading",
}  # fmt: skip
HUSKY = "robot_localization_test1_husky_gps_imu_odom.CONVERTED_FROM_ROS1BAG.mcap"


def summary_counts(path: Path) -> tuple[Counter, dict[str, int]]:
    """(rows expected per table, messages per undecoded topic) from the file's summary."""
    with open(path, "rb") as f:
        s = make_reader(f).get_summary()
    rows: Counter = Counter()
    unknown: dict[str, int] = {}
    for cid, ch in s.channels.items():
        n = s.statistics.channel_message_counts.get(cid, 0)
        name = s.schemas[ch.schema_id].name if ch.schema_id else ""
        if name in DECODED:
            rows[DECODED[name]] += n
        elif n:
            unknown[ch.topic] = n
    return rows, unknown


@pytest.fixture(scope="module")
def ingested(tmp_path_factory):
    from pipeline.ingest.driver import run_ingest
    from pipeline.warehouse.delta import read_table

    files = sorted((real_data_dir() / "mcap").glob("*.mcap"))
    wh = tmp_path_factory.mktemp("real_mcap") / "wh"
    summary = run_ingest(files, load_config(), wh, executor="serial")
    tables = {n: read_table(wh, n) for n in ("nav_gnss", "nav_heading", "rejects")}
    return files, summary, tables


def test_every_file_rows_and_rejects_per_summary(ingested):
    files, summary, tables = ingested
    assert len(files) == 5 and summary.files_ok == 5 and not summary.failed
    for path in files:
        rows, unknown = summary_counts(path)
        src = str(path.resolve())
        for name in ("nav_gnss", "nav_heading"):
            got = sum(1 for s in tables[name]["source_file"].to_pylist() if s == src)
            assert got == rows[name], (path.name, name)
        rej = [r for r in tables["rejects"].to_pylist() if r["source_file"] == src]
        assert {r["topic"]: r["reason_code"] for r in rej} == dict.fromkeys(
            unknown, "unknown_schema"), path.name  # fmt: skip
        for r in rej:
            assert r["reason"].startswith(f"{unknown[r['topic']]} messages not decoded")


def _ros1_reference(path: Path, topic: str) -> list[tuple]:
    """Per-message struct decode of a ROS 1 NavSatFix or Imu topic (second path)."""
    out = []
    with open(path, "rb") as f:
        for _, ch, m in make_reader(f).iter_messages(topics=[topic]):
            d = m.data
            _seq, sec, nsec, flen = struct.unpack_from("<IIII", d, 0)
            p = 16 + flen
            if ch.topic == "/fix":
                status, _svc, lat, lon, alt = struct.unpack_from("<bH3d", d, p)
                cov = struct.unpack_from("<9d", d, p + 27)
                out.append((sec * NS + nsec, status, lat, lon, alt, cov[0], cov[4]))
            else:
                x, y, z, w = struct.unpack_from("<4d", d, p)
                q_cov0 = struct.unpack_from("<d", d, p + 32)[0]
                wz = struct.unpack_from("<d", d, p + 32 + 72 + 16)[0]
                out.append((sec * NS + nsec, x, y, z, w, q_cov0, wz))
    return out


def test_husky_navsatfix_values_match_a_second_decode(ingested):
    root = real_data_dir() / "mcap"
    _, _, tables = ingested
    src = str((root / HUSKY).resolve())
    got = sorted((r for r in tables["nav_gnss"].to_pylist() if r["source_file"] == src),
                 key=lambda r: (r["time_ns"], r["log_time_ns"]))  # fmt: skip
    ref = sorted(_ros1_reference(root / HUSKY, "/fix"))
    assert len(got) == len(ref) == 989
    for r, (t, status, lat, lon, alt, c0, c4) in zip(got, ref, strict=True):
        assert r["time_ns"] == t and r["lat_deg"] == lat and r["lon_deg"] == lon
        assert r["altitude_m"] == alt
        assert status == 1 and r["fix_quality"] == 2 and r["fix_valid"]  # SBAS fix
        assert r["sigma_lon_m"] == pytest.approx(math.sqrt(c0))
        assert r["sigma_lat_m"] == pytest.approx(math.sqrt(c4))
    lats = np.array([r["lat_deg"] for r in got])
    assert lats.min() > 42.3757 and lats.max() < 42.3772  # SOURCES.md: 42.3758-42.3771 N


def test_husky_imu_heading_and_rate_match_a_second_decode(ingested):
    root = real_data_dir() / "mcap"
    _, _, tables = ingested
    src = str((root / HUSKY).resolve())
    got = sorted((r for r in tables["nav_heading"].to_pylist() if r["source_file"] == src),
                 key=lambda r: (r["time_ns"], r["log_time_ns"]))  # fmt: skip
    ref = sorted(_ros1_reference(root / HUSKY, "/imu/data"))
    assert len(got) == len(ref) == 11865
    for r, (t, x, y, z, w, q_cov0, wz) in zip(got, ref, strict=True):
        assert r["time_ns"] == t
        assert q_cov0 != -1
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))  # unit quaternion
        expect = (math.pi / 2 - yaw) % (2 * math.pi)
        diff = (r["heading_rad"] - expect + math.pi) % (2 * math.pi) - math.pi
        assert abs(diff) < 1e-6
        assert r["rate_of_turn_radps"] == -wz
