"""ROS 1 ``.bag`` files -> MCAP with the original message definitions (``ros1msg``).

Read through ``rosbags`` (pure Python, Apache-2.0, PyPI: ``rosbags.rosbag1.Reader``,
bag format 2.0, chunks uncompressed / bz2 / lz4). One MCAP channel per (topic, message
type) of the bag's connections: message encoding ``ros1``, schema encoding ``ros1msg``,
schema name = the ROS 1 type (``sensor_msgs/NavSatFix``), schema data = the connection's
full message definition as the bag stores it (dependencies after ``===`` separators),
channel metadata ``md5sum``, ``callerid``, ``latching`` (first connection's),
``source_file``, ``platform_id`` (file name up to its first dot) and
``log_time_source`` = ``rosbag:record_time``. Payloads are the serialised messages,
unchanged; log time = the bag record's time (ns). Ingest then decodes the types it knows
(``sensor_msgs/NavSatFix``, ``sensor_msgs/Imu``, ``nmea_msgs/Sentence``:
:mod:`pipeline.decode.ros2`); any other type is one ``unknown_schema`` reject per channel.

A bag ``rosbags`` cannot open (not indexed: a recording cut off before ``rosbag
reindex``; an unsupported version; a damaged header) is refused with its reason
(``ValueError``: ``surveil import`` lists it as failed, exit 1). A bag that fails half-way
(a damaged chunk) keeps the messages read so far and one reject (``/import/rejects``)
saying where it stopped.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.convert.legacy import ImportedFile, output_path
from pipeline.convert.output import Message, site_metadata, write_converted
from pipeline.io.mcap_write import ChannelSpec

BAG_MAGIC = b"#ROSBAG V2.0\n"
LOG_TIME_SOURCE = "rosbag:record_time"


def is_ros1_bag(head: bytes) -> bool:
    """The file starts with the ROS 1 bag 2.0 version line."""
    return head.startswith(BAG_MAGIC)


def wrap_ros1_bag(path: Path, out_dir: Path, *, site: str | None = None) -> ImportedFile:
    """Wrap a ROS 1 bag into ``<out_dir>/<name>.mcap`` (module docstring)."""
    from rosbags.rosbag1 import Reader, ReaderError

    path = Path(path)
    platform = path.name.split(".")[0] or path.name
    channels: list[ChannelSpec] = []
    topic_of: dict[int, str] = {}
    messages: list[Message] = []
    try:
        reader = Reader(path)
        reader.open()
    except (ReaderError, OSError, ValueError, KeyError) as exc:
        raise ValueError(f"{path}: ROS 1 bag cannot be read: {exc}") from None
    try:
        keys: dict[tuple[str, str], str] = {}
        for conn in reader.connections:
            msgtype = conn.msgtype.replace("/msg/", "/")  # rosbags says pkg/msg/Type
            key = (conn.topic, msgtype)
            if key not in keys:
                topic = conn.topic if conn.topic not in {k[0] for k in keys} else (
                    f"{conn.topic}#{msgtype}")  # fmt: skip
                keys[key] = topic
                ext = conn.ext
                meta = {
                    "md5sum": conn.digest,
                    "callerid": str(getattr(ext, "callerid", "") or ""),
                    "latching": str(getattr(ext, "latching", "") or 0),
                    "source_file": path.name,
                    "platform_id": platform,
                    "log_time_source": LOG_TIME_SOURCE,
                }
                channels.append(ChannelSpec(topic, "ros1", msgtype, "ros1msg",
                                            conn.msgdef.data.encode(), meta))  # fmt: skip
            topic_of[conn.id] = keys[key]
        last = 0
        try:
            # per message: rosbags yields one (connection, time, bytes) tuple each
            for conn, t, raw in reader.messages():
                messages.append(Message(topic_of[conn.id], t, bytes(raw)))
                last = t
        except (ReaderError, OSError, ValueError, KeyError) as exc:
            topic = channels[0].topic if channels else "/rosbag"
            why = f"ROS 1 bag unreadable after {len(messages)} messages: {exc}"
            messages.append(Message(topic, last, b"", ("truncated", why)))
    finally:
        reader.close()
    if not channels:
        raise ValueError(f"{path}: ROS 1 bag holds no connection (no messages to wrap)")
    out = output_path(path, out_dir)
    file_meta = {**site_metadata(site), "format": "ros1_bag", "source_file": path.name,
                 "log_time_source": LOG_TIME_SOURCE, "messages": str(len(messages))}  # fmt: skip
    counts = write_converted(out, channels, messages, metadata={"surveil.import": file_meta})
    return ImportedFile(str(path), str(out), "ros1_bag", counts,
                        dict.fromkeys(counts, LOG_TIME_SOURCE))  # fmt: skip
