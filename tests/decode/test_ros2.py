"""ROS 2 (CDR) and ROS 1 channels: NavSatFix, Imu, nmea_msgs Sentence, LocationFix.

MCAP files are written with the official ``mcap_ros2.writer`` (ROS 2) or, for ROS 1, with
``mcap.writer`` and payloads packed here by hand in the ROS 1 wire format (little-endian,
no alignment). The vectorised fixed-layout unpack is checked against ``mcap_ros2``'s own
per-message deserialiser.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import CompressionType, Writer
from mcap_fixtures import TYPE5_FRAGMENTS
from mcap_ros2.writer import Writer as Ros2Writer

from pipeline.config import ValidationConfig
from pipeline.decode.registry import FileDecoder, decoder_kind
from pipeline.decode.ros2 import (
    decode_fixed,
    ros2_decoder,
    unpack_payloads,
    yaw_to_heading_rad,
)
from pipeline.io.mcap_read import ChannelBatch, read_mcap_batches
from pipeline.units import NS

T0 = 1_772_359_200 * NS  # 2026-03-01T10:00:00Z
SEP = "\n" + "=" * 80 + "\n"
HEADER = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id"
TIME = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec"
VEC3 = "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z"
QUAT = "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w"
NAVSATFIX = SEP.join([
    "std_msgs/Header header\nNavSatStatus status\nfloat64 latitude\nfloat64 longitude\n"
    "float64 altitude\nfloat64[9] position_covariance\nuint8 COVARIANCE_TYPE_UNKNOWN = 0\n"
    "uint8 COVARIANCE_TYPE_DIAGONAL_KNOWN = 2\nuint8 position_covariance_type",
    HEADER, TIME,
    "MSG: sensor_msgs/NavSatStatus\nint8 STATUS_NO_FIX = -1\nint8 STATUS_FIX = 0\n"
    "int8 status\nuint16 SERVICE_GPS = 1\nuint16 service",
])  # fmt: skip
IMU = SEP.join([
    "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\n"
    "float64[9] orientation_covariance\ngeometry_msgs/Vector3 angular_velocity\n"
    "float64[9] angular_velocity_covariance\ngeometry_msgs/Vector3 linear_acceleration\n"
    "float64[9] linear_acceleration_covariance",
    HEADER, TIME, QUAT, VEC3,
])  # fmt: skip
SENTENCE = SEP.join(["std_msgs/Header header\nstring sentence", HEADER, TIME])
LOCATIONFIX = SEP.join([
    "builtin_interfaces/Time timestamp\nstring frame_id\nfloat64 latitude\n"
    "float64 longitude\nfloat64 altitude\nfloat64[9] position_covariance\n"
    "uint8 position_covariance_type\nfoxglove_msgs/Color color",
    TIME, "MSG: foxglove_msgs/Color\nfloat64 r\nfloat64 g\nfloat64 b\nfloat64 a",
])  # fmt: skip
STRING = "string data"


def stamp(t_ns: int) -> dict:
    return {"sec": t_ns // NS, "nanosec": t_ns % NS}


def navsatfix(t_ns: int, lat: float, lon: float, *, status: int = 0, frame: str = "gps",
              cov=(4.0, 0, 0, 0, 9.0, 0, 0, 0, 16.0), cov_type: int = 2) -> dict:  # fmt: skip
    return {"header": {"stamp": stamp(t_ns), "frame_id": frame},
            "status": {"status": status, "service": 1}, "latitude": lat, "longitude": lon,
            "altitude": 12.5, "position_covariance": list(cov),
            "position_covariance_type": cov_type}  # fmt: skip


def quat_from_ypr(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> dict:
    """ZYX Euler angles (ENU yaw about z) -> quaternion."""
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    return {"w": cr * cp * cy + sr * sp * sy, "x": sr * cp * cy - cr * sp * sy,
            "y": cr * sp * cy + sr * cp * sy, "z": cr * cp * sy - sr * sp * cy}  # fmt: skip


def imu(t_ns: int, yaw: float | None, wz: float | None, *, pitch=0.0, roll=0.0,
        frame="imu_link") -> dict:  # fmt: skip
    q = quat_from_ypr(yaw, pitch, roll) if yaw is not None else {"x": 0, "y": 0, "z": 0, "w": 1}
    return {"header": {"stamp": stamp(t_ns), "frame_id": frame}, "orientation": q,
            "orientation_covariance": [0.01] * 9 if yaw is not None else [-1.0] + [0.0] * 8,
            "angular_velocity": {"x": 0.0, "y": 0.0, "z": wz or 0.0},
            "angular_velocity_covariance": [0.0] * 9 if wz is not None else [-1.0] + [0.0] * 8,
            "linear_acceleration": {"x": 0.0, "y": 0.0, "z": 9.8},
            "linear_acceleration_covariance": [0.0] * 9}  # fmt: skip


def write_ros2(path: Path, messages: list[tuple[str, str, str, int, dict]],
               chunk_size: int = 1024 * 1024) -> Path:  # fmt: skip
    """(topic, schema name, msgdef, log time, message dict) -> MCAP via mcap_ros2."""
    with open(path, "wb") as f:
        w = Ros2Writer(f, chunk_size=chunk_size)
        schemas = {}
        for topic, name, msgdef, t, msg in messages:
            if name not in schemas:
                schemas[name] = w.register_msgdef(name, msgdef)
            w.write_message(topic, schemas[name], msg, log_time=t)
        w.finish()
    return path


def decode_file(path: Path) -> dict:
    dec = FileDecoder(source_file=str(path), validation=ValidationConfig())
    for b in read_mcap_batches(path):
        dec.feed(b)
    return dec.finish()


def test_registry_kinds():
    assert decoder_kind("cdr", "ros2msg", "sensor_msgs/msg/NavSatFix") == "ros2"
    assert decoder_kind("cdr", "ros2msg", "sensor_msgs/msg/Imu") == "ros2"
    assert decoder_kind("cdr", "ros2msg", "nmea_msgs/msg/Sentence") == "ros2"
    assert decoder_kind("cdr", "ros2msg", "foxglove_msgs/msg/LocationFix") == "ros2"
    assert decoder_kind("cdr", "ros2msg", "std_msgs/msg/String") is None
    assert decoder_kind("ros1", "ros1msg", "sensor_msgs/NavSatFix") == "ros1"


def test_navsatfix_status_covariance_and_times(tmp_path):
    msgs = [
        ("/fix", "sensor_msgs/msg/NavSatFix", NAVSATFIX, T0 + k * NS + 7,
         navsatfix(T0 + k * NS, 50.0 + k * 1e-5, 30.0, status=s))
        for k, s in enumerate([-1, 0, 1, 2, 5])
    ]  # fmt: skip
    msgs.append(("/fix", "sensor_msgs/msg/NavSatFix", NAVSATFIX, T0 + 9 * NS,
                 navsatfix(0, math.nan, math.nan, status=-1, cov_type=0)))  # fmt: skip
    msgs.append(("/fix", "sensor_msgs/msg/NavSatFix", NAVSATFIX, T0 + 10 * NS,
                 navsatfix(T0, 123.0, 30.0)))  # fmt: skip
    out = decode_file(write_ros2(tmp_path / "fix.mcap", msgs))
    rows = out["nav_gnss"].to_pylist()
    assert [(r["fix_quality"], r["fix_valid"]) for r in rows] == [
        (0, False), (1, True), (2, True), (2, True), (None, None), (0, False)
    ]
    assert [r["time_ns"] for r in rows[:5]] == [T0 + k * NS for k in range(5)]
    assert rows[5]["time_ns"] == T0 + 9 * NS  # zero stamp -> log time
    assert rows[5]["lat_deg"] is None and rows[5]["sigma_lat_m"] is None
    assert (rows[0]["sigma_lon_m"], rows[0]["sigma_lat_m"]) == (2.0, 3.0)  # sqrt(C0), sqrt(C4)
    assert rows[1]["lat_deg"] == 50.00001 and rows[1]["altitude_m"] == 12.5
    assert {r["sentence"] for r in rows} == {"NavSatFix"}
    assert {r["platform_id"] for r in rows} == {"/fix"}
    (rej,) = out["rejects"].to_pylist()
    assert rej["reason_code"] == "out_of_range" and rej["log_time_ns"] == T0 + 10 * NS
    assert rej["raw"] is not None and len(rej["raw"]) > 100


@pytest.mark.parametrize("body", ["navsatfix", "imu"])
def test_fixed_layout_unpack_agrees_with_mcap_ros2(body):
    """Two paths: the vectorised numpy unpack vs mcap_ros2's per-message deserialiser,
    frame_id lengths 0..12 (every CDR alignment case)."""
    from mcap_ros2._dynamic import serialize_dynamic

    name, msgdef = (("sensor_msgs/msg/NavSatFix", NAVSATFIX) if body == "navsatfix"
                    else ("sensor_msgs/msg/Imu", IMU))  # fmt: skip
    encode = serialize_dynamic(name, msgdef)[name]
    decode = ros2_decoder(name, msgdef.encode())
    rng = np.random.default_rng(3)
    payloads = []
    for k in range(60):
        frame = "f" * (k % 13)
        t = T0 + int(rng.integers(0, 10**12))
        if body == "navsatfix":
            m = navsatfix(t, rng.uniform(-90, 90), rng.uniform(-180, 180),
                          status=int(rng.integers(-1, 3)), frame=frame,
                          cov=rng.uniform(0, 9, 9))  # fmt: skip
        else:
            m = imu(t, rng.uniform(-3, 3), rng.uniform(-1, 1), pitch=0.1, roll=-0.2,
                    frame=frame)  # fmt: skip
        payloads.append(encode(m))
    fields, index = unpack_payloads(payloads, body, "cdr")
    assert index.tolist() == list(range(60))
    objs = [decode(p) for p in payloads]
    assert fields["sec"].tolist() == [o.header.stamp.sec for o in objs]
    assert fields["nsec"].tolist() == [o.header.stamp.nanosec for o in objs]
    if body == "navsatfix":
        assert fields["status"].tolist() == [o.status.status for o in objs]
        assert fields["latitude"].tolist() == [o.latitude for o in objs]
        assert fields["cov"].tolist() == [list(o.position_covariance) for o in objs]
    else:
        q = [[o.orientation.x, o.orientation.y, o.orientation.z, o.orientation.w] for o in objs]
        assert fields["q"].tolist() == q
        assert fields["w"][:, 2].tolist() == [o.angular_velocity.z for o in objs]


def test_payloads_outside_the_layout_fall_back_or_are_rejected():
    from mcap_ros2._dynamic import serialize_dynamic

    name = "sensor_msgs/msg/NavSatFix"
    good = serialize_dynamic(name, NAVSATFIX)[name](navsatfix(T0, 1.0, 2.0))
    batch = ChannelBatch(1, "/fix", "cdr", name, "ros2msg", NAVSATFIX.encode(),
                         np.array([T0, T0 + 1, T0 + 2]), [good, good[:40], good + b"\0" * 9])
    fields, index, rejects = decode_fixed(batch, "navsatfix", "cdr",
                                          ros2_decoder(name, NAVSATFIX.encode()), "f")
    # the padded payload is read by mcap_ros2 (it ignores trailing bytes); the cut one is not
    assert index.tolist() == [0, 2]
    assert fields["latitude"].tolist() == [1.0, 1.0]
    assert rejects["reason_code"].to_pylist() == ["undecodable"]
    assert rejects["raw"].to_pylist() == [good[:40]]


@pytest.mark.parametrize(
    ("yaw_deg", "heading_deg"), [(0, 90), (90, 0), (180, 270), (-90, 180), (45, 45), (10, 80)]
)
def test_enu_yaw_to_heading(yaw_deg, heading_deg):
    q = quat_from_ypr(math.radians(yaw_deg), pitch=0.2, roll=-0.3)
    h = yaw_to_heading_rad(*(np.array([q[k]]) for k in "wxyz"))[0]
    assert math.degrees(h) == pytest.approx(heading_deg % 360, abs=1e-9)
    # an unnormalised quaternion gives the same heading
    h2 = yaw_to_heading_rad(*(np.array([3.0 * q[k]]) for k in "wxyz"))[0]
    assert h2 == pytest.approx(h, abs=1e-12)


def test_imu_heading_rate_and_missing_estimates(tmp_path):
    msgs = [("/imu", "sensor_msgs/msg/Imu", IMU, T0 + k, m) for k, m in enumerate([
        imu(T0, math.radians(30), 0.2),       # heading 60 deg, turning to port
        imu(T0 + 1, None, -0.1),              # no orientation estimate
        imu(T0 + 2, math.radians(-60), None),  # no rate estimate
        imu(T0 + 3, None, None),              # nothing: rejected
    ])]  # fmt: skip
    zero = imu(T0 + 4, 0.0, 0.0)
    zero["orientation"] = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 0.0}
    msgs.append(("/imu", "sensor_msgs/msg/Imu", IMU, T0 + 4, zero))
    out = decode_file(write_ros2(tmp_path / "imu.mcap", msgs))
    rows = out["nav_heading"].to_pylist()
    assert len(rows) == 3
    assert math.degrees(rows[0]["heading_rad"]) == pytest.approx(60.0)
    assert rows[0]["rate_of_turn_radps"] == pytest.approx(-0.2)  # CCW (port) is negative
    assert rows[1]["heading_rad"] is None and rows[1]["rate_of_turn_radps"] == 0.1
    assert math.degrees(rows[2]["heading_rad"]) == pytest.approx(150.0)
    assert rows[2]["rate_of_turn_radps"] is None
    assert [r["time_ns"] for r in rows] == [T0, T0 + 1, T0 + 2]
    assert {r["sentence"] for r in rows} == {"Imu"} and rows[0]["is_magnetic"] is None
    assert sorted(out["rejects"]["reason_code"].to_pylist()) == ["no_data", "out_of_range"]


def test_nmea_sentence_channel_goes_through_the_nmea_decoder(tmp_path):
    pytest.importorskip("pipeline.decode.nmea")
    gga = "$GPGGA,101500.00,5230.0000,N,01320.0000,E,2,09,0.9,40.0,M,45.0,M,,*"
    gga += f"{_xor(gga[1:-1]):02X}"
    hdt = "$HEHDT,123.4,T*" + f"{_xor('HEHDT,123.4,T'):02X}"
    sentences = [gga, hdt, TYPE5_FRAGMENTS[0].decode()] + ["$GPGSV,garbage"] * 60
    sentences.append(TYPE5_FRAGMENTS[1].decode())  # second AIS part in a later chunk
    msgs = [("/nmea", "nmea_msgs/msg/Sentence", SENTENCE, T0 + k * NS,
             {"header": {"stamp": stamp(T0 + k * NS), "frame_id": "gps"}, "sentence": s})
            for k, s in enumerate(sentences)]  # fmt: skip
    path = write_ros2(tmp_path / "nmea.mcap", msgs, chunk_size=512)
    out = decode_file(path)
    assert out["nav_gnss"].num_rows == 1 and out["nav_gnss"]["fix_quality"][0].as_py() == 2
    assert out["nav_heading"]["heading_rad"][0].as_py() == pytest.approx(math.radians(123.4))
    assert out["ais_static"].num_rows == 1  # the two parts were joined across chunks
    assert out["rejects"].num_rows == 60


def _xor(s: str) -> int:
    ck = 0
    for c in s.encode():
        ck ^= c
    return ck


def test_locationfix_ros2_and_unknown_schema(tmp_path):
    fix = {"timestamp": stamp(T0 + 5), "frame_id": "antenna", "latitude": 59.9,
           "longitude": 10.7, "altitude": 3.0, "position_covariance": [1.0] + [0.0] * 3 +
           [0.25] + [0.0] * 4, "position_covariance_type": 3,
           "color": {"r": 0.0, "g": 0.0, "b": 0.0, "a": 1.0}}  # fmt: skip
    msgs = [("/loc", "foxglove_msgs/msg/LocationFix", LOCATIONFIX, T0 + k, fix) for k in range(3)]
    msgs += [("/chatter", "std_msgs/msg/String", STRING, T0 + k, {"data": "hi"})
             for k in range(4)]  # fmt: skip
    out = decode_file(write_ros2(tmp_path / "loc.mcap", msgs))
    rows = out["nav_gnss"].to_pylist()
    assert len(rows) == 3 and rows[0]["sentence"] == "LocationFix"
    assert rows[0]["time_ns"] == T0 + 5 and rows[0]["fix_quality"] is None
    assert (rows[0]["sigma_lon_m"], rows[0]["sigma_lat_m"]) == (1.0, 0.5)
    (rej,) = out["rejects"].to_pylist()
    assert rej["reason_code"] == "unknown_schema" and rej["reason"].startswith("4 messages")


# -- ROS 1 -------------------------------------------------------------------------------


def ros1_header(seq: int, t_ns: int, frame: str) -> bytes:
    return struct.pack("<III", seq, t_ns // NS, t_ns % NS) + struct.pack("<I", len(frame)) + (
        frame.encode()
    )


def ros1_navsatfix(seq, t_ns, lat, lon, status=0, frame="/gps") -> bytes:
    cov = [0.64, 0, 0, 0, 0.81, 0, 0, 0, 4.0]
    return ros1_header(seq, t_ns, frame) + struct.pack("<bH3d9dB", status, 1, lat, lon, 20.0,
                                                        *cov, 1)  # fmt: skip


def ros1_imu(seq, t_ns, q, wz, frame="imu_link") -> bytes:
    x, y, z, w = q
    return ros1_header(seq, t_ns, frame) + struct.pack(
        "<4d9d3d9d3d9d", x, y, z, w, *([0.1] * 9), 0.0, 0.0, wz, *([0.1] * 9),
        0.0, 0.0, 9.8, *([0.1] * 9),
    )  # fmt: skip


def test_ros1_navsatfix_and_imu(tmp_path):
    path = tmp_path / "ros1.mcap"
    q = quat_from_ypr(math.radians(-30))
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="ros1", library="surveil-tests")
        s_fix = w.register_schema("sensor_msgs/NavSatFix", "ros1msg", b"# ros1 definition")
        s_imu = w.register_schema("sensor_msgs/Imu", "ros1msg", b"# ros1 definition")
        c_fix = w.register_channel("/fix", "ros1", s_fix, metadata={"platform_id": "husky"})
        c_imu = w.register_channel("/imu/data", "ros1", s_imu)
        for k in range(20):
            w.add_message(c_fix, T0 + k, ros1_navsatfix(k, T0 + k * NS, 42.3 + k * 1e-6,
                                                        -71.1, frame="/gps" + "x" * (k % 3)),
                          T0 + k)  # fmt: skip
            w.add_message(c_imu, T0 + k, ros1_imu(k, T0 + k * NS,
                                                  (q["x"], q["y"], q["z"], q["w"]), 0.05),
                          T0 + k)  # fmt: skip
        w.add_message(c_fix, T0 + 99, b"\x00" * 10, T0 + 99)
        w.finish()
    out = decode_file(path)
    gnss = out["nav_gnss"].to_pylist()
    assert len(gnss) == 20 and {r["platform_id"] for r in gnss} == {"husky"}
    assert [r["time_ns"] for r in gnss] == [T0 + k * NS for k in range(20)]
    assert gnss[3]["lat_deg"] == 42.3 + 3e-6 and gnss[0]["fix_quality"] == 1
    assert (gnss[0]["sigma_lon_m"], gnss[0]["sigma_lat_m"]) == pytest.approx((0.8, 0.9))
    head = out["nav_heading"].to_pylist()
    assert len(head) == 20
    assert math.degrees(head[0]["heading_rad"]) == pytest.approx(120.0)
    assert head[0]["rate_of_turn_radps"] == pytest.approx(-0.05)
    (rej,) = out["rejects"].to_pylist()
    assert rej["reason_code"] == "undecodable" and rej["raw"] == b"\x00" * 10


@pytest.mark.slow
def test_navsatfix_decode_rates(tmp_path):
    """Vectorised unpack vs mcap_ros2 per message (printed with ``-s``), and a 200,000
    message NavSatFix MCAP ingested end to end into a warehouse."""
    import time

    from mcap_ros2._dynamic import serialize_dynamic

    from pipeline.decode.ros2 import Ros2ChannelDecoder
    from pipeline.families import load_config
    from pipeline.ingest.driver import run_ingest

    name = "sensor_msgs/msg/NavSatFix"
    encode = serialize_dynamic(name, NAVSATFIX)[name]
    n = 200_000
    payloads = [encode(navsatfix(T0 + i * 10**8, 50 + i * 1e-7, 30.0)) for i in range(n)]
    batch = ChannelBatch(1, "/fix", "cdr", name, "ros2msg", NAVSATFIX.encode(),
                         T0 + np.arange(n, dtype=np.int64) * 10**8, payloads)  # fmt: skip
    dec = Ros2ChannelDecoder.for_channel(batch, "f")
    t = time.perf_counter()
    out = dec.feed(batch)
    vec = n / (time.perf_counter() - t)
    assert out["nav_gnss"].num_rows == n
    k = 20_000
    t = time.perf_counter()
    for p in payloads[:k]:
        dec.decode(p)
    per_msg = k / (time.perf_counter() - t)
    print(f"\nNavSatFix -> nav_gnss rows, vectorised: {vec:,.0f} msg/s; "
          f"mcap_ros2 deserialise only, per message: {per_msg:,.0f} msg/s")  # fmt: skip
    assert vec > 3 * per_msg
    path = tmp_path / "fix.mcap"
    with open(path, "wb") as f:
        w = Ros2Writer(f)
        s = w.register_msgdef(name, NAVSATFIX)
        for i in range(n):
            w.write_message("/fix", s, navsatfix(T0 + i * 10**8, 50 + i * 1e-7, 30.0),
                            log_time=T0 + i * 10**8)  # fmt: skip
        w.finish()
    t = time.perf_counter()
    summary = run_ingest([path], load_config(), tmp_path / "wh", executor="serial")
    dt = time.perf_counter() - t
    assert summary.rows["nav_gnss"] == n
    print(f"ingest of a {n:,} message NavSatFix MCAP ({path.stat().st_size / 1e6:.1f} MB): "
          f"{n / dt:,.0f} msg/s end to end ({dt:.2f} s)")  # fmt: skip
