"""AIS ``!AIVDM``/``!AIVDO`` sentences -> ``ais_reports``, ``ais_static`` + rejects (pyais).

Each MCAP message of the ``nmea0183`` channel is one raw sentence (an IEC 62320-1 tag
block ``\\...\\`` in front is accepted; time is the MCAP log time, or the reception time
the caller read from the tag block's ``c:``, see :mod:`pipeline.decode.nmea`). A Python
step per sentence is unavoidable here: NMEA framing, fragment assembly and the 6-bit
payload decode are inherently sequential, and pyais decodes one message per call. The
rest (unit conversion, not-available codes) works on the decoded values as they are
appended to column lists; no table is built row by row.

What goes where (ITU-R M.1371 message ids):

- position reports 1, 2, 3, 18, 19, 27 -> ``ais_reports``
- static/voyage data 5, 19, 24 (each part of 24 is a row) -> ``ais_static``
  (19 carries both and yields a row in each table)
- every other valid type (4, 6-17, 20-23, 25, 26) is not stored and NOT rejected: it is
  counted in ``AisDecoded.not_stored`` (message id -> count).

Rejects (reason_code): ``bad_checksum`` (NMEA XOR checksum missing or wrong),
``truncated_multipart`` (a fragment group that never completes: missing, out-of-order
or interrupted fragments), ``unsupported_type`` (not an AIS sentence, or message id 0 /
28-63), ``undecodable`` (malformed sentence, empty payload, payload too short),
``no_position`` (latitude 91 / longitude 181: "not available"), ``out_of_range``
(latitude beyond ±90 or longitude beyond ±180 other than those codes). ``raw`` holds the
sentence(s), newline-joined for a group.

Conversions to SI: SOG knots -> m/s (``× 1852/3600``; 102.3 kn, or 63 kn for type 27, is
"not available" -> null); COG and heading degrees -> rad (COG ≥ 360, heading 511 or
> 359 -> null); UTC second 60-63 -> null; dimensions and ship type 0 -> null; IMO 0 ->
null; empty text -> null.

Multi-part messages: fragments are matched by (sequential id, radio channel, fragment
count) and must arrive in order; a group is abandoned after ``MAX_FRAGMENT_GAP`` other
sentences. ``time_ns`` and ``log_time_ns`` are the log time of the LAST fragment. With
``final=False`` a group still open at the end of the batch is not rejected: its
sentences (and everything after the first of them) are returned uncounted as
``carry`` so the caller can prepend them to the next batch of the same topic.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa
from pyais.exceptions import UnknownMessageException
from pyais.messages import MSG_CLASS, AISSentence, NMEASentenceFactory

from pipeline.decode.registry import make_rejects
from pipeline.tables import conform, empty, schema
from pipeline.units import KNOT_MPS

DEG = math.pi / 180.0
POSITION_TYPES = frozenset({1, 2, 3, 18, 19, 27})
STATIC_TYPES = frozenset({5, 19, 24})
CLASS_B_TYPES = frozenset({18, 19, 24})
LAT_NA_DEG, LON_NA_DEG = 91.0, 181.0
MAX_FRAGMENT_GAP = 8


@dataclass(frozen=True)
class AisDecoded:
    """Rows per table, counts of valid-but-unstored message ids, and how many trailing
    sentences were not consumed (``carry``, only when decoding with ``final=False``)."""

    reports: pa.Table
    static: pa.Table
    rejects: pa.Table
    not_stored: dict[int, int]
    carry: int = 0


@dataclass
class _Group:
    first: int
    idx: list[int]


def _append(cols: dict[str, list], row: dict) -> None:
    for k, v in row.items():
        cols.setdefault(k, []).append(v)


def _text(s: object) -> str | None:
    t = str(s).strip().rstrip("@").strip() if s is not None else ""
    return t or None


def _nonzero(v: Any) -> int | None:
    return int(v) if v else None


def _sog_mps(msg_type: int, speed: float | None) -> float | None:
    if speed is None:
        return None
    na = 63.0 if msg_type == 27 else 102.3
    return None if speed >= na - 1e-6 else speed * KNOT_MPS


def _cog_rad(course: float | None) -> float | None:
    if course is None or course >= 360.0 or course < 0.0:
        return None  # 360 (3600 in 1/10 deg) and type 27's 511 mean "not available"
    return course * DEG


def _heading_rad(heading: int | None) -> float | None:
    return None if heading is None or heading > 359 else heading * DEG


def _position_row(msg_type: int, d: object) -> dict:
    def get(k: str) -> Any:
        return getattr(d, k, None)

    second, status, accuracy = get("second"), get("status"), get("accuracy")
    return {
        "mmsi": int(get("mmsi")),
        "msg_type": msg_type,
        "ais_class": "B" if msg_type in CLASS_B_TYPES else "A",
        "lat_deg": float(get("lat")),
        "lon_deg": float(get("lon")),
        "sog_mps": _sog_mps(msg_type, get("speed")),
        "cog_rad": _cog_rad(get("course")),
        "heading_rad": _heading_rad(get("heading")),
        "nav_status": int(status) if status is not None and msg_type in (1, 2, 3, 27) else None,
        "position_accuracy": None if accuracy is None else bool(accuracy),
        "utc_second": None if second is None or second >= 60 else int(second),
    }


def _static_row(msg_type: int, d: object) -> dict:
    def get(k: str) -> Any:
        return getattr(d, k, None)

    return {
        "mmsi": int(get("mmsi")),
        "msg_type": msg_type,
        "ais_class": "B" if msg_type in CLASS_B_TYPES else "A",
        "imo": _nonzero(get("imo")),
        "callsign": _text(get("callsign")),
        "shipname": _text(get("shipname")),
        "ship_type": _nonzero(get("ship_type")),
        "to_bow_m": _nonzero(get("to_bow")),
        "to_stern_m": _nonzero(get("to_stern")),
        "to_port_m": _nonzero(get("to_port")),
        "to_starboard_m": _nonzero(get("to_starboard")),
        "destination": _text(get("destination")),
    }


def _position_problem(lat: float | None, lon: float | None) -> tuple[str, str] | None:
    if lat is None or lon is None:
        return "undecodable", "payload too short for a position"
    if lat == LAT_NA_DEG or lon == LON_NA_DEG:
        return "no_position", f"position not available (lat {lat:g}, lon {lon:g})"
    if abs(lat) > 90.0:
        return "out_of_range", f"lat_deg={lat:g} outside [-90, 90]"
    if abs(lon) > 180.0:
        return "out_of_range", f"lon_deg={lon:g} outside [-180, 180]"
    return None


class _Decoder:
    """One pass over a batch of sentences (see module docstring)."""

    def __init__(self, sentences: list[bytes], final: bool, skip: np.ndarray | None = None):
        self.sentences = sentences
        self.final = final
        # sentences decoded by the vectorised path: single-sentence position reports,
        # which never join or break a fragment group; the others keep their indices, so
        # fragment gaps count every sentence as before
        self.skip = np.zeros(len(sentences), bool)
        if skip is not None and skip.size:
            self.skip[skip] = True
        self.parsed: list[AISSentence | None] = [None] * len(sentences)
        self.units: list[list[int]] = []
        self.rejects: list[tuple[list[int], str, str]] = []
        self.open: dict[tuple, _Group] = {}

    def run(self) -> int:
        """Parse and group every sentence; returns the index where the carry starts."""
        n = len(self.sentences)
        for i in np.flatnonzero(~self.skip).tolist():
            self._expire(i)
            s = self._parse(i, self.sentences[i])
            if s is not None:
                self._group(i, s)
        if n:
            self._expire(n - 1)  # skipped sentences at the end count as gap too
        if self.final or not self.open:
            for g in self.open.values():
                self._reject_group(g, "group never completed")
            self.open.clear()
            return n
        return min(g.first for g in self.open.values())

    def _parse(self, i: int, raw: bytes) -> AISSentence | None:
        try:
            s = NMEASentenceFactory.produce(raw)
        except UnknownMessageException:
            self.rejects.append(([i], "unsupported_type", "not an AIS VDM/VDO sentence"))
            return None
        except Exception as exc:  # pyais raises several types for malformed input
            self.rejects.append(([i], "undecodable", f"malformed sentence: {exc}"[:200]))
            return None
        if not isinstance(s, AISSentence):
            self.rejects.append(([i], "unsupported_type", f"{s.TYPE} sentence, not AIS"))
            return None
        if not s.is_valid:
            self.rejects.append(([i], "bad_checksum", f"NMEA checksum {s.checksum} is wrong"))
            return None
        self.parsed[i] = s
        return s

    def _group(self, i: int, s: AISSentence) -> None:
        if s.frag_cnt == 1:
            self.units.append([i])
            return
        key = (s.seq_id, s.channel, s.frag_cnt)
        g = self.open.get(key)
        if s.frag_num == 1:
            if g is not None:
                self._reject_group(g, "next group started before it completed")
            g = self.open[key] = _Group(first=i, idx=[i])
        elif g is not None and s.frag_num == len(g.idx) + 1:
            g.idx.append(i)
        else:
            if g is not None:
                self._reject_group(g, f"fragment {s.frag_num}/{s.frag_cnt} out of order")
                del self.open[key]
            self.rejects.append(
                (
                    [i],
                    "truncated_multipart",
                    f"fragment {s.frag_num}/{s.frag_cnt} without its preceding fragments",
                )
            )
            return
        if len(g.idx) == s.frag_cnt:
            self.units.append(g.idx)
            del self.open[key]

    def _expire(self, i: int) -> None:
        for key, g in list(self.open.items()):
            if i - g.idx[-1] > MAX_FRAGMENT_GAP:
                self._reject_group(g, f"no next fragment within {MAX_FRAGMENT_GAP} sentences")
                del self.open[key]

    def _reject_group(self, g: _Group, why: str) -> None:
        s = self.parsed[g.idx[0]]
        n = s.frag_cnt if s is not None else "?"
        self.rejects.append(
            (list(g.idx), "truncated_multipart", f"{len(g.idx)} of {n} fragments: {why}")
        )


def _assemble(parts: list[AISSentence]) -> AISSentence:
    return parts[0] if len(parts) == 1 else AISSentence.assemble_from_iterable(parts)


def decode_ais(
    sentences: list[bytes],
    log_time_ns: np.ndarray,
    *,
    source_file: str,
    topic: str,
    final: bool = True,
    time_ns: np.ndarray | None = None,
) -> AisDecoded:
    """Decode a batch of raw AIS sentences (see module docstring).

    ``log_time_ns``: int64 MCAP log times of the sentences, ns. ``time_ns``: reception
    times of the sentences (IEC 62320-1 tag block ``c:``, see
    :mod:`pipeline.decode.nmea`), ns; ``None`` means the log times.
    """
    times = np.asarray(log_time_ns, dtype=np.int64)
    recv = times if time_ns is None else np.asarray(time_ns, dtype=np.int64)
    sentences = list(sentences)
    fast = fast_positions(sentences) if FAST else None
    dec = _Decoder(sentences, final, skip=None if fast is None else fast.index)
    carry_at = dec.run()
    reports: dict[str, list] = {}
    static: dict[str, list] = {}
    rejects = [r for r in dec.rejects if max(r[0]) < carry_at]
    not_stored: Counter = Counter()
    report_key: list[int] = []  # index of the last sentence of each report row
    for idx in dec.units:
        if max(idx) >= carry_at:
            continue
        out = _decode_unit([dec.parsed[j] for j in idx])  # type: ignore[misc]
        if isinstance(out, int):
            not_stored[out] += 1
            continue
        position, static_row, problem = out
        if problem is not None:
            rejects.append((idx, *problem))
        prov = _provenance(idx, sentences, times, recv)
        if position is not None:
            _append(reports, {**position, **prov})
            report_key.append(max(idx))
        if static_row is not None:
            _append(static, {**static_row, **prov})
    if fast is not None and fast.index.size:
        table = _merge_fast(reports, report_key, fast, fast.index < carry_at, sentences,
                            times, recv, source_file, topic)
    else:
        table = _table("ais_reports", reports, source_file, topic)
    return AisDecoded(
        reports=table,
        static=_table("ais_static", static, source_file, topic),
        rejects=_rejects(rejects, sentences, times, source_file, topic),
        not_stored=dict(not_stored),
        carry=len(sentences) - carry_at,
    )


_Unit = tuple[dict | None, dict | None, tuple[str, str] | None]


def _decode_unit(parts: list[AISSentence]) -> _Unit | int:
    """Decode one complete message: ``(position row, static row, problem)``, or the
    message id when it is a valid type we do not store."""
    msg = _assemble(parts)
    if not msg.payload:
        return None, None, ("undecodable", "empty payload")
    ais_id = msg.ais_id
    if ais_id not in MSG_CLASS:
        return None, None, ("unsupported_type", f"message id {ais_id} is not defined")
    if ais_id not in POSITION_TYPES and ais_id not in STATIC_TYPES:
        return ais_id
    try:
        d = msg.decode()
    except Exception as exc:  # pyais: bad bit lengths, unknown part numbers, ...
        return None, None, ("undecodable", f"type {ais_id}: {type(exc).__name__}: {exc}"[:200])
    if getattr(d, "mmsi", None) is None:
        return None, None, ("undecodable", f"type {ais_id}: payload too short")
    position = problem = None
    if ais_id in POSITION_TYPES:
        problem = _position_problem(getattr(d, "lat", None), getattr(d, "lon", None))
        if problem is None:
            position = {**_position_row(ais_id, d), "radio_channel": msg.channel or None}
    static_row = _static_row(ais_id, d) if ais_id in STATIC_TYPES else None
    return position, static_row, problem


def _provenance(
    idx: list[int], sentences: list[bytes], times: np.ndarray, recv: np.ndarray
) -> dict:
    """log_time_ns = log time of the last fragment, time_ns = its reception time (the
    tag-block time when given, else the log time); nmea = the sentence(s)."""
    last = max(idx)
    return {"time_ns": int(recv[last]), "log_time_ns": int(times[last]),
            "nmea": _nmea_text(idx, sentences)}


def _nmea_text(idx: list[int], sentences: list[bytes]) -> str:
    """The ``nmea`` column: the message's sentence(s), stripped, newline-joined."""
    return "\n".join(sentences[j].decode("ascii", "replace").strip() for j in idx)


# -- vectorised path: single-sentence position reports (types 1, 2, 3, 18) ----------------

FAST = True
"""Decode canonical single-sentence position reports without pyais (tests switch it off
to compare with the reference path)."""
_SENTENCE_LEN = 47  # "!AIVDM,1,1,,A," + 28 payload characters + ",0*HH"
_HEX = np.frombuffer(b"0123456789ABCDEF", np.uint8)


@dataclass(frozen=True)
class FastPositions:
    """Decoded fields of the sentences the vectorised path took (``index``: their
    positions in the batch), one entry per sentence."""

    index: np.ndarray
    msg_type: np.ndarray
    mmsi: np.ndarray
    status: np.ndarray
    speed: np.ndarray  # 0.1 kn units
    accuracy: np.ndarray
    lon: np.ndarray  # 1/10000 min units
    lat: np.ndarray
    course: np.ndarray  # 0.1 deg units
    heading: np.ndarray
    second: np.ndarray
    channel: np.ndarray  # the channel byte


def _bits(six: np.ndarray, start: int, width: int, signed: bool = False) -> np.ndarray:
    """Bit field [start, start + width) of 6-bit rows (n, 28), as int64."""
    first, last = start // 6, (start + width - 1) // 6
    v = np.zeros(six.shape[0], np.int64)
    for c in range(first, last + 1):
        v = (v << 6) | six[:, c].astype(np.int64)
    v >>= (last + 1) * 6 - (start + width)
    v &= (1 << width) - 1
    if signed:
        v = np.where(v >= 1 << (width - 1), v - (1 << width), v)
    return v


def fast_positions(sentences: list[bytes]) -> FastPositions | None:
    """The canonical single-sentence position reports of a batch, decoded with numpy.

    Taken: exactly ``!AIVDM,1,1,,<A|B>,<28 payload characters>,0*<checksum>`` (or
    ``!AIVDO``), checksum right, payload characters valid, message id 1, 2, 3 or 18,
    latitude and longitude available and in range. Everything else (tag blocks,
    multi-part, static data, anything unusual or faulty) is left to the pyais path,
    which gives the exact reject reasons. For a taken sentence the row is the one the
    pyais path writes: pyais's field layout and conversions (``to_lat_lon``,
    ``to_speed``, ``to_10th``), then the same unit conversions and not-available codes.
    ``tests/decode/test_ais_fast.py`` checks both paths give identical tables.
    """
    n = len(sentences)
    if n == 0:
        return None
    lens = np.fromiter(map(len, sentences), np.int64, n)
    cand = np.flatnonzero(lens == _SENTENCE_LEN)
    if cand.size == 0:
        return None
    raw = np.frombuffer(b"".join(sentences[i] for i in cand.tolist()), np.uint8).reshape(
        cand.size, _SENTENCE_LEN)
    prefix_ok = (raw[:, :5] == np.frombuffer(b"!AIVD", np.uint8)).all(axis=1)
    prefix_ok &= (raw[:, 5] == ord("M")) | (raw[:, 5] == ord("O"))
    prefix_ok &= (raw[:, 6:12] == np.frombuffer(b",1,1,,", np.uint8)).all(axis=1)
    prefix_ok &= (raw[:, 12] == ord("A")) | (raw[:, 12] == ord("B"))
    prefix_ok &= (raw[:, 13] == ord(",")) & (raw[:, 42:45] == np.frombuffer(b",0*", np.uint8)
                                             ).all(axis=1)
    cs = np.bitwise_xor.reduce(raw[:, 1:44], axis=1)
    prefix_ok &= (raw[:, 45] == _HEX[cs >> 4]) & (raw[:, 46] == _HEX[cs & 15])
    pay = raw[:, 14:42].astype(np.int16)
    valid = ((pay >= 48) & (pay <= 87)) | ((pay >= 96) & (pay <= 119))
    prefix_ok &= valid.all(axis=1)
    six = pay - 48
    six = np.where(six > 40, six - 8, six)
    msg = six[:, 0]
    prefix_ok &= (msg == 1) | (msg == 2) | (msg == 3) | (msg == 18)
    b18 = msg == 18
    # field offsets: types 1-3 / type 18 (ITU-R M.1371, pyais's layout)
    lon = np.where(b18, _bits(six, 57, 28, True), _bits(six, 61, 28, True))
    lat = np.where(b18, _bits(six, 85, 27, True), _bits(six, 89, 27, True))
    # pyais to_lat_lon: ((10 v + 3) // 6) / 1e6 (round(v / 600000, 6) exactly)
    lon_deg = ((10 * lon + 3) // 6) / 1e6
    lat_deg = ((10 * lat + 3) // 6) / 1e6
    prefix_ok &= (lat_deg != LAT_NA_DEG) & (lon_deg != LON_NA_DEG)
    prefix_ok &= (np.abs(lat_deg) <= 90.0) & (np.abs(lon_deg) <= 180.0)
    k = np.flatnonzero(prefix_ok)
    if k.size == 0:
        return None
    six, b18 = six[k], b18[k]
    return FastPositions(
        index=cand[k],
        msg_type=msg[k].astype(np.int16),
        mmsi=_bits(six, 8, 30),
        status=np.where(b18, -1, _bits(six, 38, 4)),
        speed=np.where(b18, _bits(six, 46, 10), _bits(six, 50, 10)),
        accuracy=np.where(b18, _bits(six, 56, 1), _bits(six, 60, 1)).astype(bool),
        lon=lon_deg[k],
        lat=lat_deg[k],
        course=np.where(b18, _bits(six, 112, 12), _bits(six, 116, 12)),
        heading=np.where(b18, _bits(six, 124, 9), _bits(six, 128, 9)),
        second=np.where(b18, _bits(six, 133, 6), _bits(six, 137, 6)),
        channel=raw[k, 12],
    )


def _fast_table(f: FastPositions, keep: np.ndarray, sentences: list[bytes], times: np.ndarray,
                recv: np.ndarray) -> pa.Table:
    """The ais_reports columns of the kept fast rows (the conversions of _position_row,
    vectorised)."""
    i = f.index[keep]
    speed = f.speed[keep] / 10.0  # pyais to_speed
    course = f.course[keep] / 10.0  # pyais to_10th
    heading = f.heading[keep]
    second = f.second[keep]
    status = f.status[keep]
    b18 = f.msg_type[keep] == 18
    sog = pa.array(speed * KNOT_MPS, pa.float64(), mask=speed >= 102.3 - 1e-6)
    cog = pa.array(course * DEG, pa.float64(), mask=(course >= 360.0) | (course < 0.0))
    hdg = pa.array(heading * DEG, pa.float64(), mask=heading > 359)
    text = [sentences[j].decode("ascii", "replace").strip() for j in i.tolist()]
    return pa.table({
        "mmsi": pa.array(f.mmsi[keep], pa.int64()),
        "msg_type": pa.array(f.msg_type[keep], pa.int16()),
        "ais_class": pa.array(np.where(b18, "B", "A"), pa.string()),
        "lat_deg": pa.array(f.lat[keep], pa.float64()),
        "lon_deg": pa.array(f.lon[keep], pa.float64()),
        "sog_mps": sog,
        "cog_rad": cog,
        "heading_rad": hdg,
        "nav_status": pa.array(status, pa.int16(), mask=b18),
        "position_accuracy": pa.array(f.accuracy[keep], pa.bool_()),
        "utc_second": pa.array(second, pa.int16(), mask=second >= 60),
        "radio_channel": pa.array(np.where(f.channel[keep] == ord("A"), "A", "B"), pa.string()),
        "time_ns": pa.array(recv[i], pa.int64()),
        "log_time_ns": pa.array(times[i], pa.int64()),
        "nmea": pa.array(text, pa.string()),
    })


def _merge_fast(cols: dict[str, list], keys: list[int], f: FastPositions, keep: np.ndarray,
                sentences: list[bytes], times: np.ndarray, recv: np.ndarray, source_file: str,
                topic: str) -> pa.Table:
    """Slow-path report rows and fast rows in the reference order (see :func:`_merge`)."""
    fast = _fast_table(f, keep, sentences, times, recv)
    return _merge("ais_reports", cols, keys, fast, f.index[keep], source_file, topic)


def _merge(name: str, cols: dict[str, list], keys: list[int], fast: pa.Table,
           fast_keys: np.ndarray, source_file: str, topic: str) -> pa.Table:
    """Slow-path rows (``cols``) and vectorised rows (``fast``) in the order the reference
    makes them (by the index of each message's last sentence: ``keys``, ``fast_keys``),
    then conformed like :func:`_table`."""
    parts, order = [fast], [np.asarray(fast_keys, np.int64)]
    if cols.get("mmsi"):
        types = {fd.name: fd.type for fd in schema(name)}
        slow = pa.table({k: pa.array(v, type=types[k]) for k, v in cols.items()})
        parts.append(slow.select(fast.column_names))
        order.append(np.asarray(keys, np.int64))
    table = pa.concat_tables(parts)
    table = table.take(np.argsort(np.concatenate(order), kind="stable"))
    n = table.num_rows
    if n == 0:
        return empty(name)
    table = table.append_column("source_file", pa.array([source_file] * n, pa.string()))
    table = table.append_column("topic", pa.array([topic] * n, pa.string()))
    return conform(name, table)


def _table(name: str, cols: dict[str, list], source_file: str, topic: str) -> pa.Table:
    n = len(cols.get("mmsi", []))
    if not n:
        return empty(name)
    types = {f.name: f.type for f in schema(name)}
    arrays = {k: pa.array(v, type=types[k]) for k, v in cols.items()}
    arrays["source_file"] = pa.array([source_file] * n, pa.string())
    arrays["topic"] = pa.array([topic] * n, pa.string())
    return conform(name, pa.table(arrays))


def _rejects(
    rejects: list[tuple[list[int], str, str]],
    sentences: list[bytes],
    times: np.ndarray,
    source_file: str,
    topic: str,
) -> pa.Table:
    last = np.asarray([max(idx) for idx, _, _ in rejects], dtype=np.int64)
    return make_rejects(
        times[last],
        source_file=source_file,
        topic=topic,
        reason_code=[c for _, c, _ in rejects],
        reason=[r for _, _, r in rejects],
        raw=[b"\n".join(sentences[j].strip() for j in idx) for idx, _, _ in rejects],
    )


def decode_ais_sentences(
    sentences: list[bytes], log_time_ns: np.ndarray, *, source_file: str, topic: str
) -> tuple[pa.Table, pa.Table, pa.Table]:
    """``(ais_reports, ais_static, rejects)`` of a complete batch of sentences.

    Same as :func:`decode_ais` with ``final=True``, without the ``not_stored`` counts.
    """
    out = decode_ais(sentences, log_time_ns, source_file=source_file, topic=topic)
    return out.reports, out.static, out.rejects
