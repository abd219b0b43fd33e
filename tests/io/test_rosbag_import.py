"""ROS 1 ``.bag`` files (written here with ``rosbags``' own writer, messages serialised by
its ROS 1 serialiser) -> MCAP with the original message definitions -> the existing ROS
decoders (pipeline/convert/rosbag.py, pipeline/decode/ros2.py)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "decode"))
from nmea_builders import sentence

from pipeline.convert.importer import run_import
from pipeline.convert.legacy import detect_format
from pipeline.families import load_config
from pipeline.ingest.driver import run_ingest
from pipeline.io.mcap_read import read_mcap_batches
from pipeline.units import NS
from pipeline.warehouse.delta import read_table

T0 = 1_432_235_460 * NS  # 2015-05-21T19:11:00Z
SENTENCE_MSG = "std_msgs/Header header\nstring sentence\n"


def _store():
    ts = get_typestore(Stores.ROS1_NOETIC)
    ts.register(get_types_from_msg(SENTENCE_MSG, "nmea_msgs/msg/Sentence"))
    return ts


def _header(ts, t_ns: int, frame: str):
    Time = ts.types["builtin_interfaces/msg/Time"]
    return ts.types["std_msgs/msg/Header"](seq=1, stamp=Time(sec=t_ns // NS,
                                           nanosec=t_ns % NS), frame_id=frame)  # fmt: skip


def write_bag(path: Path, n: int = 5) -> Path:
    ts = _store()
    T = ts.types
    with Writer(path) as w:
        fix_c = w.add_connection("/fix", "sensor_msgs/msg/NavSatFix", typestore=ts)
        imu_c = w.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=ts)
        nmea_c = w.add_connection("/nmea_sentence", "nmea_msgs/msg/Sentence", typestore=ts)
        odom_c = w.add_connection("/odom", "std_msgs/msg/String", typestore=ts)
        for k in range(n):
            t = T0 + k * NS
            fix = T["sensor_msgs/msg/NavSatFix"](
                header=_header(ts, t, "/gps"),
                status=T["sensor_msgs/msg/NavSatStatus"](status=1, service=1),
                latitude=42.3758 + k * 1e-5, longitude=-71.1473, altitude=10.0,
                position_covariance=np.array([4.0, 0, 0, 0, 9.0, 0, 0, 0, 16.0]),
                position_covariance_type=2,
            )  # fmt: skip
            w.write(fix_c, t, ts.serialize_ros1(fix, "sensor_msgs/msg/NavSatFix"))
            yaw = math.radians(30.0)  # ENU yaw 30 deg -> heading 60 deg
            imu = T["sensor_msgs/msg/Imu"](
                header=_header(ts, t, "imu_link"),
                orientation=T["geometry_msgs/msg/Quaternion"](
                    x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
                orientation_covariance=np.zeros(9),
                angular_velocity=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.01),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=9.8),
                linear_acceleration_covariance=np.zeros(9),
            )  # fmt: skip
            w.write(imu_c, t + 1000, ts.serialize_ros1(imu, "sensor_msgs/msg/Imu"))
            s = sentence(f"GPHDT,{100 + k}.0,T").decode()
            msg = T["nmea_msgs/msg/Sentence"](header=_header(ts, t, "gps"), sentence=s)
            w.write(nmea_c, t + 2000, ts.serialize_ros1(msg, "nmea_msgs/msg/Sentence"))
            w.write(odom_c, t + 3000,
                    ts.serialize_ros1(T["std_msgs/msg/String"](data="x"), "std_msgs/msg/String"))
    return path


def test_bag_becomes_mcap_with_the_original_definitions(tmp_path):
    (tmp_path / "in").mkdir()
    bag = write_bag(tmp_path / "in" / "husky.bag")
    assert detect_format(bag) == "ros1_bag"
    summary = run_import([bag], tmp_path / "out")
    assert summary.exit_code == 0, summary.render()
    (f,) = summary.imported
    assert f.format == "ros1_bag"
    assert f.messages == {"/fix": 5, "/imu/data": 5, "/nmea_sentence": 5, "/odom": 5}
    batches = list(read_mcap_batches(Path(f.output)))
    by_topic = {b.topic: b for b in batches}
    fix = by_topic["/fix"]
    assert (fix.message_encoding, fix.schema_encoding, fix.schema_name) == (
        "ros1", "ros1msg", "sensor_msgs/NavSatFix")
    assert b"float64 latitude" in fix.schema_data and b"MSG: std_msgs/Header" in fix.schema_data
    assert fix.log_time_ns.tolist() == [T0 + k * NS for k in range(5)]
    assert fix.metadata["log_time_source"] == "rosbag:record_time"


def test_known_types_decode_and_unknown_ones_are_one_reject_per_channel(tmp_path):
    (tmp_path / "in").mkdir()
    bag = write_bag(tmp_path / "in" / "husky.bag")
    summary = run_import([bag], tmp_path / "out")
    ingest = run_ingest([summary.imported[0].output], load_config(), tmp_path / "wh",
                        executor="serial")  # fmt: skip
    assert ingest.exit_code == 1, ingest.render()  # unknown channels: rejects rows
    gnss = read_table(tmp_path / "wh", "nav_gnss").to_pylist()
    assert len(gnss) == 5 and gnss[0]["lat_deg"] == pytest.approx(42.3758)
    assert gnss[0]["fix_quality"] == 2 and gnss[0]["time_ns"] == T0
    assert gnss[0]["sigma_lat_m"] == pytest.approx(3.0)
    heading = read_table(tmp_path / "wh", "nav_heading").to_pylist()
    imu = [r for r in heading if r["sentence"] != "HDT"]
    hdt = [r for r in heading if r["sentence"] == "HDT"]
    assert len(imu) == 5 and imu[0]["heading_rad"] == pytest.approx(math.radians(60.0))
    assert [round(math.degrees(r["heading_rad"])) for r in hdt] == [100, 101, 102, 103, 104]
    (rej,) = read_table(tmp_path / "wh", "rejects").to_pylist()
    assert rej["reason_code"] == "unknown_schema" and rej["topic"] == "/odom"


def test_damaged_bags_are_refused_with_a_reason_and_exit_1(tmp_path):
    (tmp_path / "in").mkdir()
    bag = write_bag(tmp_path / "in" / "good.bag")
    cut = tmp_path / "in" / "cut.bag"
    cut.write_bytes(bag.read_bytes()[: bag.stat().st_size // 2])  # index lost
    summary = run_import([cut], tmp_path / "out")
    assert summary.exit_code == 1
    ((name, err),) = summary.failed
    assert name.endswith("cut.bag") and "ROS 1 bag cannot be read" in err
