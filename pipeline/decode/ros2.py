"""ROS 2 channels (message encoding ``cdr``, schema encoding ``ros2msg``) -> nav tables.

Messages are deserialised with ``mcap-ros2-support`` (``mcap_ros2.decoder.DecoderFactory``,
one dynamic class per channel schema); the library returns one Python object per message,
so the field extraction below is per message, and the table building is vectorised.

====================================  ===========  ===========================================
schema                                table        mapping
====================================  ===========  ===========================================
``sensor_msgs/msg/NavSatFix``         nav_gnss     :mod:`pipeline.decode.foxglove` fix rules;
                                                   status -> fix_quality below
``foxglove_msgs/msg/LocationFix``     nav_gnss     same, no fix status
``sensor_msgs/msg/Imu``               nav_heading  yaw of the orientation -> heading_rad;
                                                   angular_velocity.z -> rate_of_turn_radps
``nmea_msgs/msg/Sentence``            (NMEA)       the ``sentence`` strings go through
                                                   :func:`pipeline.decode.nmea.decode_nmea`
====================================  ===========  ===========================================

NavSatFix ``status.status`` -> ``fix_quality`` (GGA codes, design brief: 0 none, 1 fix, 2
differential) and ``fix_valid``: STATUS_NO_FIX (-1) -> 0 / false; STATUS_FIX (0) -> 1 /
true; STATUS_SBAS_FIX (1) -> 2 / true (satellite-based augmentation is a differential
correction); STATUS_GBAS_FIX (2) -> 2 / true (ground-based augmentation; drivers also use
it for RTK, which GGA would call 4/5: we do not guess). Any other value -> null. Position
covariance -> ``sigma_lon_m`` = sqrt(C[0]) (east), ``sigma_lat_m`` = sqrt(C[4]) (north)
unless ``position_covariance_type`` is COVARIANCE_TYPE_UNKNOWN (0). ``time_ns`` =
``header.stamp`` (else log time).

Imu (REP-103: ENU world frame, x east, z up; REP-145 element 0 of a covariance = -1 means
"no estimate"): when ``orientation_covariance[0] != -1`` the yaw of the orientation
quaternion (rotation about z, counter-clockwise from east),

.. math:: \\psi = \\operatorname{atan2}(2(wz + xy),\\; w^2 + x^2 - y^2 - z^2)

(the unnormalised form, so a quaternion of any norm gives the same angle) becomes the
heading clockwise from north, :math:`h = (\\pi/2 - \\psi) \\bmod 2\\pi`. When
``angular_velocity_covariance[0] != -1``, ``rate_of_turn_radps`` = -ω_z (z up, positive
counter-clockwise = to port; ours is positive to starboard). ``is_magnetic`` stays null:
the message does not say whether its yaw is referenced to true north, magnetic north or an
arbitrary start heading (IMUs without a magnetometer); it is only a true heading when the
IMU's world frame is ENU as REP-145 asks. A message with neither orientation nor angular
velocity -> rejects ``no_data``; a zero quaternion -> ``out_of_range``.

nmea_msgs Sentence: the batch's ``sentence`` strings (with the MCAP log times) go to the
NMEA 0183 decoder with a carry per channel, so multi-part AIS and dated time references
continue across batches; ``header.stamp`` is not used (the log time is the reception time).

Undecodable CDR payloads -> rejects ``undecodable`` with the raw bytes. A channel whose
schema text cannot be compiled -> one ``undecodable`` row per batch with the count.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa
from mcap.records import Schema

from pipeline.decode.foxglove import FixColumns, FixContext, fix_table, platform_of
from pipeline.decode.registry import make_rejects
from pipeline.io.mcap_read import ChannelBatch
from pipeline.tables import conform, empty
from pipeline.units import NS

NAVSATFIX = "sensor_msgs/msg/NavSatFix"
IMU = "sensor_msgs/msg/Imu"
SENTENCE = "nmea_msgs/msg/Sentence"
ROS1_SENTENCE = "nmea_msgs/Sentence"
LOCATIONFIX = "foxglove_msgs/msg/LocationFix"
NAVSAT_STATUS = {-1: (0, 0), 0: (1, 1), 1: (2, 1), 2: (2, 1)}  # status -> (quality, valid)


def ros2_decoder(schema_name: str, schema_data: bytes) -> Callable[[bytes], Any]:
    """The ``mcap_ros2`` deserialiser of one ``ros2msg`` schema (raises if it does not
    compile)."""
    from mcap_ros2.decoder import DecoderFactory

    schema = Schema(id=1, name=schema_name, encoding="ros2msg", data=schema_data)
    fn = DecoderFactory().decoder_for("cdr", schema)
    if fn is None:
        raise ValueError(f"no CDR decoder for schema {schema_name!r}")
    return fn


# -- fixed layouts, unpacked for a whole batch at once ----------------------------------
# NavSatFix and Imu are a Header (stamp + frame_id string) followed by fixed-size fields,
# so all messages of a batch whose frame_id has the same length share one byte layout:
# they are unpacked together as an (n, L) byte matrix with numpy views (no Python object
# per message). ROS 1: packed little-endian, header = seq u32, stamp u32 u32, string =
# u32 length + bytes. CDR (XCDR1, little-endian encapsulation 00 01): 4-byte
# encapsulation header, stamp i32 u32, string = u32 length (with the NUL) + bytes + NUL,
# each primitive aligned to its size relative to the end of the encapsulation header.

BODIES: dict[str, tuple[tuple[str, str, int], ...]] = {
    "navsatfix": (
        ("status", "i1", 1), ("service", "u2", 1), ("latitude", "f8", 1),
        ("longitude", "f8", 1), ("altitude", "f8", 1), ("cov", "f8", 9), ("cov_type", "u1", 1),
    ),
    "imu": (
        ("q", "f8", 4), ("q_cov", "f8", 9), ("w", "f8", 3), ("w_cov", "f8", 9),
        ("a", "f8", 3), ("a_cov", "f8", 9),
    ),
}  # fmt: skip
_STRLEN_AT = 12  # offset of the frame_id length in both dialects


def layout(body: str, frame_len: int, dialect: str) -> tuple[dict[str, tuple[int, str, int]], int]:
    """Byte offsets ``{field: (offset, dtype, count)}`` and the message size for a
    frame_id length field of ``frame_len`` (``dialect``: ``ros1`` | ``cdr``)."""
    if dialect == "ros1":
        out = {"sec": (4, "u4", 1), "nsec": (8, "u4", 1)}
        pos, base = 16 + frame_len, 0
    else:
        out = {"sec": (4, "i4", 1), "nsec": (8, "u4", 1)}
        # positions relative to the end of the encapsulation header: stamp 0..8, string
        # length 8..12, characters (with the NUL) from 12
        pos, base = 12 + frame_len, 4
    for name, dt, count in BODIES[body]:
        size = int(dt[1])
        if dialect == "cdr":
            pos += -pos % size
        out[name] = (base + pos, dt, count)
        pos += size * count
    return out, base + pos


def _gather(big: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """(n, width) bytes: ``width`` bytes from each start offset of ``big``."""
    return big[starts[:, None] + np.arange(width)[None, :]]


def _field(rows: np.ndarray, where: tuple[int, str, int]) -> np.ndarray:
    off, dt, count = where
    width = int(dt[1]) * count
    out = np.ascontiguousarray(rows[:, off : off + width]).view("<" + dt)
    return out.reshape(len(rows), count) if count > 1 else out.reshape(len(rows))


_ROWS_PER_GATHER = 16_384  # bounds the (rows, size) index array of one gather


def unpack_fixed(
    buf: np.ndarray, start: np.ndarray, end: np.ndarray, body: str, dialect: str
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Unpack every payload ``buf[start[i]:end[i]]`` (``buf``: uint8 array, e.g. the
    decompressed chunk, so no bytes object per message) that matches its layout:
    ``(fields, index)`` with one array per field (rows in ``index`` order, ``sec`` and
    ``nsec`` included). Payloads that do not match (other encapsulation, size off) are
    left out of ``index``."""
    start = np.asarray(start, dtype=np.int64)
    lengths = np.asarray(end, dtype=np.int64) - start
    n = len(start)
    long_enough = lengths >= _STRLEN_AT + 4
    frame_len = np.full(n, -1, dtype=np.int64)
    if long_enough.any():
        raw = _gather(buf, start[long_enough] + _STRLEN_AT, 4)
        frame_len[long_enough] = np.ascontiguousarray(raw).view("<u4").ravel()
        if dialect == "cdr":
            head = _gather(buf, start[long_enough], 2)
            le = (head[:, 0] == 0) & (head[:, 1] == 1)
            frame_len[np.flatnonzero(long_enough)[~le]] = -1  # big-endian etc.: fallback
    parts: dict[str, list[np.ndarray]] = {}
    index: list[np.ndarray] = []
    ok = frame_len >= 0
    # one group per (frame_id length, payload length): one layout, equal-size rows
    keys = np.unique(frame_len[ok] * (1 << 32) + lengths[ok]) if ok.any() else []
    for flen, length in zip((keys >> 32).tolist(), (keys & 0xFFFFFFFF).tolist(), strict=True):
        where, size = layout(body, flen, dialect)
        if not size <= length < size + 8:
            continue
        sel = np.flatnonzero((frame_len == flen) & (lengths == length))
        for k in range(0, len(sel), _ROWS_PER_GATHER):
            part = sel[k : k + _ROWS_PER_GATHER]
            rows = _gather(buf, start[part], size)
            index.append(part)
            for name, w in where.items():
                parts.setdefault(name, []).append(_field(rows, w))
    if not index:
        return {}, np.empty(0, np.int64)
    all_idx = np.concatenate(index)
    order = np.argsort(all_idx, kind="stable")
    fields = {k: np.concatenate(v)[order] for k, v in parts.items()}
    return fields, all_idx[order]


def unpack_payloads(
    payloads: list[bytes], body: str, dialect: str
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """:func:`unpack_fixed` over a list of payloads (joined into one buffer)."""
    lengths = np.fromiter(map(len, payloads), dtype=np.int64, count=len(payloads))
    start = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    buf = np.frombuffer(b"".join(payloads), dtype=np.uint8)
    return unpack_fixed(buf, start, start + lengths, body, dialect)


def _stamp_ns(t: Any) -> int:
    return int(t.sec) * NS + int(getattr(t, "nanosec", 0))


def _objects_to_fields(body: str, messages: list[Any]) -> dict[str, np.ndarray]:
    """The arrays of :func:`unpack_fixed` from ``mcap_ros2`` message objects (fallback)."""
    sec = np.array([m.header.stamp.sec for m in messages], dtype=np.int64)
    nsec = np.array([m.header.stamp.nanosec for m in messages], dtype=np.int64)
    if body == "navsatfix":
        return {
            "sec": sec, "nsec": nsec,
            "status": np.array([m.status.status for m in messages], dtype=np.int64),
            "latitude": np.array([m.latitude for m in messages], dtype=np.float64),
            "longitude": np.array([m.longitude for m in messages], dtype=np.float64),
            "altitude": np.array([m.altitude for m in messages], dtype=np.float64),
            "cov": np.array([list(m.position_covariance) for m in messages],
                            dtype=np.float64).reshape(-1, 9),
            "cov_type": np.array([m.position_covariance_type for m in messages]),
        }  # fmt: skip
    o = [m.orientation for m in messages]
    return {
        "sec": sec, "nsec": nsec,
        "q": np.array([(q.x, q.y, q.z, q.w) for q in o], dtype=np.float64).reshape(-1, 4),
        "q_cov": np.array([[m.orientation_covariance[0]] + [0.0] * 8 for m in messages]),
        "w": np.array([(0.0, 0.0, m.angular_velocity.z) for m in messages]).reshape(-1, 3),
        "w_cov": np.array([[m.angular_velocity_covariance[0]] + [0.0] * 8 for m in messages]),
    }  # fmt: skip


def decode_fixed(
    batch: ChannelBatch, body: str, dialect: str, fallback: Callable[[bytes], Any] | None,
    source_file: str,
) -> tuple[dict[str, np.ndarray], np.ndarray, pa.Table]:  # fmt: skip
    """``(fields, index, rejects)``: the vectorised unpack, then ``fallback`` (the
    ``mcap_ros2`` deserialiser) per message for the payloads it left; what neither
    decodes is rejected ``undecodable``."""
    chunk, start, end = batch.spans()
    fields, index = unpack_fixed(chunk.arr, start, end, body, dialect)
    covered = np.zeros(len(batch), dtype=bool)
    covered[index] = True
    rest = np.flatnonzero(~covered)
    objects: list[Any] = []
    bad: list[tuple[int, str]] = []
    kept: list[int] = []
    # per message only for payloads outside the fixed layout (big-endian CDR, ...)
    for i in rest.tolist():
        try:
            if fallback is None:
                raise ValueError("size does not match the message layout")
            objects.append(fallback(batch.payloads[i]))
            kept.append(i)
        except Exception as exc:  # any deserialisation error rejects that message only
            bad.append((i, f"{batch.schema_name}: payload does not deserialise "
                           f"({type(exc).__name__}: {exc})"))  # fmt: skip
    if objects:
        more = _objects_to_fields(body, objects)
        all_idx = np.concatenate([index, np.asarray(kept, np.int64)])
        order = np.argsort(all_idx, kind="stable")
        fields = {k: np.concatenate([fields[k], more[k]])[order] if k in fields else more[k]
                  for k in more}  # fmt: skip
        index = all_idx[order]
    rejects = make_rejects(
        [batch.log_time_ns[i] for i, _ in bad], source_file=source_file, topic=batch.topic,
        reason_code="undecodable", reason=[w for _, w in bad],
        raw=[batch.payloads[i] for i, _ in bad],
    )  # fmt: skip
    return fields, index, rejects


def _stamps(fields: dict[str, np.ndarray]) -> np.ndarray:
    return fields["sec"].astype(np.int64) * NS + fields["nsec"].astype(np.int64)


def navsatfix_columns(fields: dict[str, np.ndarray], index: np.ndarray) -> FixColumns:
    """Fix columns of unpacked ``NavSatFix`` messages (status mapped, module docstring)."""
    status = fields["status"].astype(np.int64)
    quality = np.full(len(index), -1, dtype=np.int64)
    valid = np.full(len(index), -1, dtype=np.int64)
    for code, (q, v) in NAVSAT_STATUS.items():
        quality[status == code] = q
        valid[status == code] = v
    return FixColumns(
        stamp_ns=_stamps(fields), lat=fields["latitude"], lon=fields["longitude"],
        alt=fields["altitude"], cov=fields["cov"].reshape(-1, 9), cov_type=fields["cov_type"],
        fix_quality=quality, fix_valid=valid, index=index,
    )  # fmt: skip


def locationfix_columns(messages: list[tuple[int, Any]]) -> FixColumns:
    """Fix columns of decoded ``foxglove_msgs/msg/LocationFix`` (ROS 2) messages."""
    fixes = FixColumns()
    for i, m in messages:
        stamp = _stamp_ns(m.timestamp) if hasattr(m, "timestamp") else 0
        fixes.add(
            i, stamp, m.latitude, m.longitude, m.altitude, m.position_covariance,
            m.position_covariance_type,
        )  # fmt: skip
    return fixes


def yaw_to_heading_rad(w: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Heading clockwise from north (rad, [0, 2π)) of ENU orientation quaternions.

    .. math:: \\psi = \\operatorname{atan2}(2(wz + xy), w^2 + x^2 - y^2 - z^2),\\quad
              h = (\\pi/2 - \\psi) \\bmod 2\\pi
    """
    psi = np.arctan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)
    return np.mod(np.pi / 2 - psi, 2 * np.pi)


def imu_table(
    fields: dict[str, np.ndarray], index: np.ndarray, batch: ChannelBatch, source_file: str,
    platform_id: str,
) -> tuple[pa.Table, pa.Table]:  # fmt: skip
    """``(nav_heading rows, rejects)`` of unpacked ``sensor_msgs/Imu`` messages."""
    if not len(index):
        return empty("nav_heading"), empty("rejects")
    x, y, z, w = fields["q"].reshape(-1, 4).T
    has_q = fields["q_cov"].reshape(len(index), -1)[:, 0] != -1
    has_w = fields["w_cov"].reshape(len(index), -1)[:, 0] != -1
    wz = fields["w"].reshape(-1, 3)[:, 2]
    stamp = _stamps(fields)
    log_t = batch.log_time_ns[index]
    zero_q = has_q & ~((np.abs(x) + np.abs(y) + np.abs(z) + np.abs(w)) > 0)
    no_data = ~has_q & ~has_w
    bad = zero_q | no_data
    rejects = make_rejects(
        log_t[bad], source_file=source_file, topic=batch.topic,
        reason_code=np.where(zero_q[bad], "out_of_range", "no_data").tolist(),
        reason=np.where(zero_q[bad], "Imu: zero orientation quaternion",
                        "Imu: neither orientation nor angular velocity (covariance[0] = -1)"
                        ).tolist(),
        raw=[batch.payloads[i] for i in index[bad]],
    )  # fmt: skip
    k = ~bad
    n = int(k.sum())
    table = pa.table({
        "time_ns": np.where(stamp > 0, stamp, log_t)[k],
        "platform_id": [platform_id] * n,
        "sentence": ["Imu"] * n,
        "heading_rad": pa.array(yaw_to_heading_rad(w[k], x[k], y[k], z[k]), pa.float64(),
                                mask=~has_q[k]),
        "rate_of_turn_radps": pa.array(-wz[k], pa.float64(), mask=~has_w[k]),
        "source_file": [source_file] * n,
        "topic": [batch.topic] * n,
        "log_time_ns": log_t[k],
    })  # fmt: skip
    return conform("nav_heading", table), rejects


def _decode_objects(
    decode: Callable[[bytes], Any], batch: ChannelBatch, source_file: str
) -> tuple[list[tuple[int, Any]], pa.Table]:
    """``[(index, message)]`` of the payloads that deserialise, and the rejects of the
    others (one library call per message: the CDR decoder builds one object each)."""
    ok: list[tuple[int, Any]] = []
    bad: list[tuple[int, str]] = []
    for i, payload in enumerate(batch.payloads):
        try:
            ok.append((i, decode(payload)))
        except Exception as exc:  # any deserialisation error rejects that message only
            bad.append((i, f"{batch.schema_name}: CDR payload does not deserialise "
                           f"({type(exc).__name__})"))  # fmt: skip
    rejects = make_rejects(
        [batch.log_time_ns[i] for i, _ in bad], source_file=source_file, topic=batch.topic,
        reason_code="undecodable", reason=[w for _, w in bad],
        raw=[batch.payloads[i] for i, _ in bad],
    )  # fmt: skip
    return ok, rejects


@dataclass
class Ros2ChannelDecoder:
    """Channel decoder (registry protocol) for the ROS 2 schemas of the module docstring;
    with ``dialect="ros1"`` for ROS 1 NavSatFix/Imu (see :class:`Ros1ChannelDecoder`)."""

    source_file: str
    topic: str
    schema_name: str
    platform_id: str
    decode: Callable[[bytes], Any] | None
    error: str | None = None
    dialect: str = "cdr"
    nmea_carry: Any = None
    _nmea_open: bool = field(default=False)
    not_stored: Counter = field(default_factory=Counter)

    @classmethod
    def for_channel(cls, batch: ChannelBatch, source_file: str) -> Ros2ChannelDecoder:
        try:
            fn, err = ros2_decoder(batch.schema_name, batch.schema_data), None
        except Exception as exc:  # a schema that does not compile: reject its messages
            fn, err = None, f"{type(exc).__name__}: {exc}"
        return cls(source_file, batch.topic, batch.schema_name, platform_of(batch), fn, err)

    @property
    def is_sentence(self) -> bool:
        return self.schema_name in (SENTENCE, ROS1_SENTENCE)

    @property
    def body(self) -> str | None:
        """Fixed-layout body of the schema (``navsatfix`` | ``imu``), else ``None``."""
        short = self.schema_name.replace("/msg/", "/")
        return {"sensor_msgs/NavSatFix": "navsatfix", "sensor_msgs/Imu": "imu"}.get(short)

    def feed(self, batch: ChannelBatch) -> Mapping[str, pa.Table]:
        if self.decode is None and self.dialect == "cdr":
            return {"rejects": make_rejects(
                [batch.log_time_ns[0]], source_file=self.source_file, topic=self.topic,
                reason_code="undecodable",
                reason=f"{len(batch)} messages not decoded: schema {self.schema_name!r} "
                       f"does not compile ({self.error})",
            )}  # fmt: skip
        body = self.body
        if body is not None:
            fields, index, rejects = decode_fixed(
                batch, body, self.dialect, self.decode, self.source_file
            )
            if body == "imu":
                table, more = imu_table(fields, index, batch, self.source_file,
                                        self.platform_id)  # fmt: skip
                return {"nav_heading": table, "rejects": pa.concat_tables([rejects, more])}
            fixes = navsatfix_columns(fields, index) if len(index) else FixColumns()
            sentence = "NavSatFix"
        else:
            messages, rejects = _decode_objects(self.decode, batch, self.source_file)
            if self.is_sentence:
                return self._sentences(messages, batch, rejects)
            fixes, sentence = locationfix_columns(messages), "LocationFix"
        ctx = FixContext(self.source_file, self.topic, self.platform_id, sentence)
        table, more = fix_table(fixes, batch.log_time_ns, batch.payloads, ctx)
        return {"nav_gnss": table, "rejects": pa.concat_tables([rejects, more])}

    def _sentences(
        self, messages: list[tuple[int, Any]], batch: ChannelBatch, rejects: pa.Table,
        *, final: bool = False,
    ) -> dict[str, pa.Table]:  # fmt: skip
        from pipeline.decode.nmea import decode_nmea

        idx = np.array([i for i, _ in messages], dtype=np.int64)
        text = [m.sentence.encode("latin-1", "replace") for _, m in messages]
        out = decode_nmea(
            text, batch.log_time_ns[idx] if len(idx) else np.empty(0, np.int64),
            source_file=self.source_file, topic=self.topic, platform_id=self.platform_id,
            carry=self.nmea_carry, final=final,
        )  # fmt: skip
        self.nmea_carry = out.carry
        self.not_stored.update(out.not_stored)
        self._nmea_open = True
        tables = dict(out.tables)
        tables["rejects"] = pa.concat_tables([tables.get("rejects", empty("rejects")), rejects])
        return tables

    def finish(self) -> Mapping[str, pa.Table]:
        """Flush an NMEA channel's open multi-part AIS message (rejected if incomplete)."""
        if not self.is_sentence or not self._nmea_open:
            return {}
        empty_batch = ChannelBatch(0, self.topic, "cdr", self.schema_name, "ros2msg", b"",
                                   np.empty(0, np.int64), [])  # fmt: skip
        return self._sentences([], empty_batch, empty("rejects"), final=True)


class Ros1ChannelDecoder(Ros2ChannelDecoder):
    """ROS 1 (``ros1`` / ``ros1msg``) ``sensor_msgs/NavSatFix`` and ``sensor_msgs/Imu``:
    the same mapping, unpacked from the packed ROS 1 layout (no per-message fallback);
    ``nmea_msgs/Sentence`` (``nmea_navsat_driver``): the sentence string read from the
    packed layout, then the NMEA decoder."""

    @classmethod
    def for_channel(cls, batch: ChannelBatch, source_file: str) -> Ros1ChannelDecoder:
        decode = ros1_sentence if batch.schema_name == ROS1_SENTENCE else None
        return cls(source_file, batch.topic, batch.schema_name, platform_of(batch), decode,
                   dialect="ros1")  # fmt: skip


def ros1_sentence(payload: bytes) -> Any:
    """ROS 1 ``nmea_msgs/Sentence``: Header (uint32 seq, time stamp = uint32 sec + uint32
    nsec, string frame_id) + string sentence; a ROS 1 string is a uint32 length + bytes."""
    import struct
    from types import SimpleNamespace

    (n_frame,) = struct.unpack_from("<I", payload, 12)
    at = 16 + n_frame
    (n,) = struct.unpack_from("<I", payload, at)
    if at + 4 + n != len(payload):
        raise ValueError(f"sentence length {n} does not fill the message")
    return SimpleNamespace(sentence=bytes(payload[at + 4 : at + 4 + n]).decode("latin-1"))
