"""AIS ``!AIVDM``/``!AIVDO`` sentences -> ``ais_reports``, ``ais_static`` + rejects (pyais).

Each MCAP message of the ``nmea0183`` channel is one raw sentence (an IEC 62320-1 tag
block ``\\...\\`` in front is accepted; time is the MCAP log time, or the reception time
the caller read from the sentence, see :mod:`pipeline.decode.nmea` and
:mod:`pipeline.time_sources`; each row's ``time_source`` says which).

Two vectorised paths (numpy over whole columns) decode the common messages; pyais, one
message per call, decodes the rest and is the reference both are tested against
(``tests/decode/test_ais_fast.py``: identical tables; ``FAST = False`` turns both off):

- canonical single-sentence position reports 1, 2, 3, 18 (:func:`fast_positions`) are
  taken before pyais sees them: framing, checksum and payload in numpy;
- static data 5 and 24 (parts A and B; :func:`fast_static`): pyais still parses each
  sentence and the fragment grouping stays a Python step per sentence (it is sequential,
  and its reject rules are pyais's), but the payloads of the complete units are decoded
  together: fields, 6-bit text, conversions.

Everything unusual (tag blocks and other framing for positions, types 19 and 27, type 24
part numbers 2 and 3, payloads too short or longer than the standard message, invalid
armour characters) goes to pyais. There, unit conversion and not-available codes work on
the decoded values as they are appended to column lists; no table is built row by row.

What goes where (ITU-R M.1371 message ids):

- position reports 1, 2, 3, 18, 19, 27 -> ``ais_reports``
- static/voyage data 5, 19, 24 (each part of 24 is a row) -> ``ais_static``
  (19 carries both and yields a row in each table)
- every other valid type (4, 6-17, 20-23, 25, 26) -> ``ais_other_messages``
  (``AisDecoded.other``: the sender's MMSI and, for base stations 4/11, SAR aircraft 9 and
  AtoN 21, their class, position and time fields; :func:`_other_row`).

Rejects (reason_code): ``bad_checksum`` (NMEA XOR checksum missing or wrong),
``truncated_multipart`` (a fragment group that never completes: missing, out-of-order
or interrupted fragments), ``unsupported_type`` (not an AIS sentence, or message id 0 /
28-63), ``undecodable`` (malformed sentence, empty payload, payload too short),
``no_position`` (latitude 91 / longitude 181: "not available"), ``out_of_range``
(latitude beyond ±90 or longitude beyond ±180 other than those codes). ``raw`` holds the
sentence(s), newline-joined for a group.

Conversions to SI: SOG knots -> m/s (``× 1852/3600``; 102.3 kn, or 63 kn for type 27, is
"not available" -> null); COG and heading degrees -> rad (COG ≥ 360, heading 511 or
> 359 -> null); UTC second 60-63 -> null; dimensions and ship type 0 -> null (message
5's ship type goes through pyais's ``ShipType``: codes it does not name become 0, or the
reserved code of their decade); IMO 0 -> null; text: '@' padding and spaces trimmed as
pyais and :func:`_text` do, empty -> null.

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
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from pyais.constants import ShipType
from pyais.exceptions import UnknownMessageException
from pyais.messages import MSG_CLASS, AISSentence, NMEASentenceFactory

from pipeline import time_sources as ts
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
    other: pa.Table = field(default_factory=lambda: empty("ais_other_messages"))


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
    time_source: Sequence[str] | None = None,
    refine_gap_s: float | None = None,
) -> AisDecoded:
    """Decode a batch of raw AIS sentences (see module docstring).

    ``log_time_ns``: int64 MCAP log times of the sentences, ns. ``time_ns``: reception
    times of the sentences (the time each carries, see :mod:`pipeline.decode.nmea` and
    :mod:`pipeline.time_sources`), ns; ``None`` means the log times.
    ``time_source``: what gave each sentence's time (default ``mcap_log_time``); a row
    keeps its last sentence's, or, when that one has no time of its own, the first
    sentence's of its message that has (:func:`_unit_times`). Position reports whose
    time was interpolated are moved to the second they state
    (:func:`pipeline.time_sources.refine_by_utc_second`, bracket ``refine_gap_s``).
    """
    times = np.asarray(log_time_ns, dtype=np.int64)
    recv = (times if time_ns is None else np.asarray(time_ns, dtype=np.int64)).copy()
    sentences = list(sentences)
    clock = _Sources.of(time_source, len(sentences))
    fast = fast_positions(sentences) if FAST else None
    dec = _Decoder(sentences, final, skip=None if fast is None else fast.index)
    carry_at = dec.run()
    _unit_times(dec, carry_at, recv, clock)
    # before the pyais path: its assembly rewrites a group's first fragment's payload
    statics = fast_static(dec, carry_at) if FAST else None
    rows = _decode_units(dec, carry_at, set() if statics is None else set(statics.unit.tolist()),
                         sentences, times, recv)
    if fast is not None and fast.index.size:
        table = _merge_fast(rows.reports, rows.report_key, fast, fast.index < carry_at,
                            sentences, times, recv, source_file, topic, clock)
    else:
        table = _table("ais_reports", rows.reports, rows.report_key, source_file, topic, clock)
    table = _refined(table, clock, refine_gap_s)
    if statics is not None:
        static = _merge("ais_static", rows.static, rows.static_key,
                        _fast_static_table(statics, dec, sentences, times, recv),
                        statics.index, source_file, topic, clock)
    else:
        static = _table("ais_static", rows.static, rows.static_key, source_file, topic, clock)
    static = _overall_dimensions(static)
    other = _table("ais_other_messages", rows.other, rows.other_key, source_file, topic, clock)
    return AisDecoded(
        reports=table,
        static=static,
        rejects=_rejects(rows.rejects, sentences, times, source_file, topic),
        not_stored=dict(rows.not_stored),
        carry=len(sentences) - carry_at,
        other=other,
    )


@dataclass(frozen=True)
class _Sources:
    """What gave each sentence's time: ``code`` (int32 per sentence) into ``labels``."""

    code: np.ndarray
    labels: tuple[str, ...]

    @classmethod
    def of(cls, time_source: Sequence[str] | None, n: int) -> _Sources:
        if time_source is None:
            return cls(np.zeros(n, np.int32), (ts.MCAP_LOG_TIME,))
        if len(time_source) != n:
            raise ValueError(f"{n} sentences but {len(time_source)} time sources")
        labels = tuple(sorted(set(time_source)))
        index = {lab: i for i, lab in enumerate(labels)}
        return cls(np.fromiter((index[t] for t in time_source), np.int32, n), labels)

    def column(self, keys: np.ndarray) -> pa.Array:
        """The ``time_source`` of rows whose last sentences are ``keys``."""
        codes = pa.array(self.code[np.asarray(keys, np.int64)], pa.int32())
        return pa.DictionaryArray.from_arrays(codes, pa.array(self.labels, pa.string())
                                              ).cast(pa.string())

    def own(self) -> np.ndarray:
        """Per label: is it a time the sentence carries itself (not its log time)?"""
        return np.array([lab in ts.OWN_ORDER for lab in self.labels], bool)


def _unit_times(dec: _Decoder, carry_at: int, recv: np.ndarray, clock: _Sources) -> None:
    """A multi-sentence message whose last sentence has no time of its own takes the
    first own time among its sentences (in place, at its last sentence). Per unit in
    Python: multi-sentence units only, a few per cent of a recording."""
    own = clock.own()
    if not own.any():
        return
    for idx in dec.units:
        if len(idx) < 2 or max(idx) >= carry_at:
            continue
        last = idx[-1]
        if own[clock.code[last]]:
            continue
        first = next((j for j in idx if own[clock.code[j]]), None)
        if first is not None:
            recv[last] = recv[first]
            clock.code[last] = clock.code[first]


def _overall_dimensions(static: pa.Table) -> pa.Table:
    """``length_m`` = A + B and ``width_m`` = C + D where both dimensions are given
    (ITU-R M.1371-5 Annex 8, message 5 Fig. 42: the reference point's distances)."""
    if not static.num_rows:
        return static
    i = static.schema.get_field_index
    length = pc.add(static["to_bow_m"], static["to_stern_m"])
    width = pc.add(static["to_port_m"], static["to_starboard_m"])
    static = static.set_column(i("length_m"), "length_m", length)
    return static.set_column(i("width_m"), "width_m", width)


def _refined(table: pa.Table, clock: _Sources, gap_s: float | None) -> pa.Table:
    """Position reports whose time was interpolated at the second they state, where it
    agrees (:func:`pipeline.time_sources.refine_by_utc_second`); their
    ``time_source`` gains ``+utc_second``."""
    if not table.num_rows or not any(ts.is_interpolated(lab) for lab in clock.labels):
        return table
    source = table["time_source"]
    interp = pc.fill_null(pc.starts_with(source, ts.INTERPOLATED), False).to_numpy()
    second = table["utc_second"].fill_null(-1).to_numpy()
    t, hit = ts.refine_by_utc_second(table["time_ns"].to_numpy(), second, interp, gap_s)
    if not hit.any():
        return table
    refined = pc.if_else(pa.array(hit), pc.binary_join_element_wise(source, ts.REFINED, ""),
                         source)
    i = table.schema.get_field_index
    table = table.set_column(i("time_ns"), "time_ns", pa.array(t, pa.int64()))
    table = table.set_column(i("time_source"), "time_source", refined)
    return conform("ais_reports", table.drop(["date"]) if "date" in table.column_names
                   else table)


@dataclass
class _Rows:
    """What the pyais path made of a batch's units: column lists per table, the index of
    the last sentence of each row (``*_key``), rejects, valid-but-unstored counts."""

    reports: dict[str, list] = field(default_factory=dict)
    report_key: list[int] = field(default_factory=list)
    static: dict[str, list] = field(default_factory=dict)
    static_key: list[int] = field(default_factory=list)
    other: dict[str, list] = field(default_factory=dict)
    other_key: list[int] = field(default_factory=list)
    rejects: list[tuple[list[int], str, str]] = field(default_factory=list)
    not_stored: Counter = field(default_factory=Counter)


def _decode_units(dec: _Decoder, carry_at: int, skip: set[int], sentences: list[bytes],
                  times: np.ndarray, recv: np.ndarray) -> _Rows:
    """The pyais path over the complete units before ``carry_at``, except the positions
    in ``skip`` (units the vectorised static path took)."""
    rows = _Rows(rejects=[r for r in dec.rejects if max(r[0]) < carry_at])
    for k, idx in enumerate(dec.units):
        if max(idx) >= carry_at or k in skip:
            continue
        out = _decode_unit([dec.parsed[j] for j in idx])  # type: ignore[misc]
        position, static_row, problem = out[:3]
        if problem is not None:
            rows.rejects.append((idx, *problem))
        prov = _provenance(idx, sentences, times, recv)
        if position is not None:
            _append(rows.reports, {**position, **prov})
            rows.report_key.append(max(idx))
        if static_row is not None:
            _append(rows.static, {**static_row, **prov})
            rows.static_key.append(max(idx))
        if len(out) > 3 and out[3] is not None:
            _append(rows.other, {**out[3], **prov})
            rows.other_key.append(max(idx))
    return rows


_Unit = tuple[dict | None, dict | None, tuple[str, str] | None] | tuple[
    dict | None, dict | None, tuple[str, str] | None, dict | None]


def _decode_unit(parts: list[AISSentence]) -> _Unit:
    """Decode one complete message: ``(position row, static row, problem)``, or, for a
    message of another type, ``(None, None, problem, ais_other_messages row)``."""
    msg = _assemble(parts)
    if not msg.payload:
        return None, None, ("undecodable", "empty payload")
    ais_id = msg.ais_id
    if ais_id not in MSG_CLASS:
        return None, None, ("unsupported_type", f"message id {ais_id} is not defined")
    if ais_id not in POSITION_TYPES and ais_id not in STATIC_TYPES:
        other = _other_row(ais_id, msg)
        if other is None:
            return None, None, ("undecodable", f"type {ais_id}: payload too short for an MMSI")
        return None, None, None, other
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


OTHER_CLASS = {4: "base_station", 11: "base_station", 21: "aton", 9: "sar_aircraft"}
"""The station kind a message id says (ITU-R M.1371-5 Annex 8: base station report 4,
UTC/date response 11, aids-to-navigation report 21, standard SAR aircraft position
report 9); every other id of ``ais_other_messages`` may come from any station."""


_OTHER_EMPTY: dict[str, Any] = dict.fromkeys((
    "lat_deg", "lon_deg", "sog_mps", "cog_rad", "altitude_m", "utc_second", "station_utc_ns",
    "name", "aton_type", "virtual_aton", "off_position"))  # every row has every column


def _other_row(ais_id: int, msg: AISSentence) -> dict | None:
    """The ``ais_other_messages`` row of a message of another type: MMSI (bits 8-37 of
    every message), the station kind, and for 4/11, 9 and 21 their position, time and
    identity fields; None when the payload is too short for an MMSI. A field pyais
    cannot read stays null (the message still counts)."""
    bits = msg.bv
    if len(bits) < 38:
        return None
    row: dict[str, Any] = {**_OTHER_EMPTY, "mmsi": int(bits.get(8, 30)), "msg_type": ais_id,
                           "ais_class": OTHER_CLASS.get(ais_id),
                           "radio_channel": msg.channel or None}
    if ais_id not in OTHER_CLASS:
        return row
    try:
        d = msg.decode()
    except Exception:  # pyais: bad bit lengths; the row keeps its MMSI and kind
        return row

    def get(k: str) -> Any:
        return getattr(d, k, None)

    lat, lon = get("lat"), get("lon")
    if lat is not None and lon is not None and abs(lat) <= 90 and abs(lon) <= 180:
        row.update(lat_deg=float(lat), lon_deg=float(lon))
    second = get("second")
    if ais_id in (4, 11):
        row["station_utc_ns"] = station_utc_ns(d)
    else:
        row["utc_second"] = int(second) if second is not None and second < 60 else None
    if ais_id == 9:
        speed, course, alt = get("speed"), get("course"), get("alt")
        row["sog_mps"] = speed * KNOT_MPS if speed is not None and speed < 1023 else None
        row["cog_rad"] = _cog_rad(course)
        row["altitude_m"] = float(alt) if alt is not None and alt < 4095 else None
    if ais_id == 21:
        name = "".join(t for t in (_text(get("name")), _text(get("name_ext"))) if t)
        row.update(name=name or None, aton_type=_nonzero(get("aid_type")),
                   virtual_aton=_flag(get("virtual_aid")), off_position=_flag(get("off_position")))
    return row


def _flag(v: Any) -> bool | None:
    return None if v is None else bool(v)


def station_utc_ns(d: object) -> int | None:
    """The UTC a base station (message 4, 11) transmitted, ns; None when any field is
    "not available" (year 0, month 0, day 0, hour 24, minute 60, second 60) or the date
    does not exist."""
    from datetime import UTC, datetime

    f = [getattr(d, k, None) for k in ("year", "month", "day", "hour", "minute", "second")]
    if any(v is None for v in f) or not (1970 <= f[0] <= 2261) or f[3] > 23 or f[4] > 59 \
            or f[5] > 59:
        return None
    try:
        t = datetime(f[0], f[1], f[2], f[3], f[4], f[5], tzinfo=UTC)
    except ValueError:
        return None
    return int(t.timestamp()) * 1_000_000_000


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
"""Decode canonical single-sentence position reports and static messages 5 and 24 with
numpy (tests switch it off to compare with the reference path)."""
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
    """Bit field [start, start + width) of 6-bit rows (n, characters), as int64."""
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


# -- vectorised path: static data (message 5, message 24 parts A and B) -------------------

# ITU-R M.1371-5 message 5, static and voyage related data (bit offset, width): message id
# 0/6, repeat indicator 6/2, user ID (MMSI) 8/30, AIS version 38/2, IMO number 40/30, call
# sign 70/42 (7 characters), name 112/120 (20 characters), type of ship and cargo 232/8,
# overall dimension A (to bow) 240/9, B (to stern) 249/9, C (to port) 258/6, D (to
# starboard) 264/6, EPFD type 270/4, ETA 274/20, maximum draught 294/8, destination
# 302/120 (20 characters), DTE 422/1, spare 423/1: 424 bits, 71 characters + 2 fill bits.
# Message 24 part A (part number 0): message id, repeat, MMSI as above, part number
# 38/2, name 40/120: 160 bits (pyais and some transmitters add 8 spare bits: 168).
# Message 24 part B (part number 1): part number 38/2, type of ship and cargo 40/8, vendor
# ID 48/42, call sign 90/42, dimensions A-D 132/30 as in message 5 (for an auxiliary
# craft, MMSI 98XXXYYYY, the mothership's MMSI instead), spare 162/6: 168 bits.
_MSG5, _MSG24 = 5, 24
_PART_A, _PART_B = 0, 1
# a unit is taken when every field read lies inside its bits (pyais reads any field from
# the front of the payload: fill bits and further bits do not change it) and its payload
# is no longer than the standard message
_MSG5_BITS, _PART_A_BITS, _PART_B_BITS = 422, 160, 162  # end of destination / name / D
_MSG5_CHARS, _MSG24_CHARS = 71, 28  # the standard messages' armour characters
# dimensions to the reference point: column, bit offset from dimension A, width
_DIMENSIONS = (("to_bow_m", 0, 9), ("to_stern_m", 9, 9), ("to_port_m", 18, 6),
               ("to_starboard_m", 24, 6))
_AUXILIARY_MMSI = (980_000_000, 989_999_999)  # pyais is_auxiliary_craft: no dimensions
# pyais _SIXBIT_CHAR: 6-bit value -> ASCII (0-31 -> '@', 'A'..'Z', '[\\]^_'; 32-63 as is)
_SIXBIT_ASCII = np.array([v + 64 if v < 32 else v for v in range(64)], np.uint8)
_AT, _SPACE = ord("@"), ord(" ")
# pyais decodes message 5's type of ship and cargo through ShipType.from_value: codes it
# does not name become 0 ("not available": 1-19, 38, 39, 100-255) or the reserved code of
# their decade (26-28 -> 25, ...); message 24 part B keeps the raw code
_SHIP_TYPE_5 = np.array([int(ShipType.from_value(v)) for v in range(256)], np.int64)


@dataclass(frozen=True)
class FastStatic:
    """The static messages the vectorised path decoded: ``unit`` their positions in
    ``_Decoder.units``, ``index`` the batch index of each one's last sentence (the
    reference's row order), ``table`` their ais_static field columns, row for row."""

    unit: np.ndarray
    index: np.ndarray
    table: pa.Table


def fast_static(dec: _Decoder, carry_at: int) -> FastStatic | None:
    """Message 5 and message 24 (part A or B) units of a decoded batch, decoded with
    numpy over whole columns.

    Taken: a complete unit (any number of fragments) before ``carry_at`` whose assembled
    payload has valid armour characters, message id 5 or 24 (as pyais read it from the
    first fragment), part number 0 or 1 for 24, and every field read inside its bits and
    no more characters than the standard message (see ``_MSG5_BITS``). Everything else
    (type 19, part numbers 2 and 3, short or long payloads, bad characters) is left to the
    pyais path, which gives the exact rows and reject reasons. For a taken unit the row is
    the one :func:`_static_row` writes from pyais's decode.
    """
    unit, payload, fill, ais_id = _static_candidates(dec, carry_at)
    if not unit:
        return None
    taken, table = _static_fields(payload, np.asarray(fill, np.int64),
                                  np.asarray(ais_id, np.int64))
    if taken.size == 0:
        return None
    unit_taken = np.asarray(unit, np.int64)[taken]
    last = np.fromiter((max(dec.units[u]) for u in unit_taken.tolist()), np.int64,
                       unit_taken.size)
    return FastStatic(unit=unit_taken, index=last, table=table)


def _static_candidates(dec: _Decoder, carry_at: int
                       ) -> tuple[list[int], list[bytes], list[int], list[int]]:
    """Units whose first fragment says message 5 or 24: positions, assembled payloads, fill
    bits of the last fragment, message ids. Per unit in Python: units and payloads exist
    only as the pyais sentences of the sequential fragment grouping (~1 us a unit)."""
    unit: list[int] = []
    payload: list[bytes] = []
    fill: list[int] = []
    ais_id: list[int] = []
    parsed: list[AISSentence] = dec.parsed  # type: ignore[assignment]  # units: parsed only
    for k, idx in enumerate(dec.units):
        first = parsed[idx[0]]
        if first.ais_id not in (_MSG5, _MSG24) or max(idx) >= carry_at:
            continue
        unit.append(k)
        payload.append(b"".join(parsed[j].payload for j in idx))
        fill.append(parsed[idx[-1]].fill_bits)
        ais_id.append(first.ais_id)
    return unit, payload, fill, ais_id


def _static_fields(payload: list[bytes], fill: np.ndarray, ais_id: np.ndarray
                   ) -> tuple[np.ndarray, pa.Table]:
    """Which candidates are taken (positions in the candidate lists: message 5 first,
    then 24 part A, then part B) and their ais_static field columns in that order."""
    n_chars = np.fromiter(map(len, payload), np.int64, len(payload))
    rows = np.flatnonzero((n_chars >= 1) & (n_chars <= _MSG5_CHARS))
    six, valid = _six_bit_rows([payload[i] for i in rows.tolist()], n_chars[rows], _MSG5_CHARS)
    n_bits = 6 * n_chars[rows] - fill[rows]
    msg = six[:, 0].astype(np.int64)
    ok = valid & (msg == ais_id[rows])  # pyais decodes by the first fragment's id
    part = _bits(six, 38, 2)
    kinds = (
        (ok & (msg == _MSG5) & (n_bits >= _MSG5_BITS), _message_5),
        (ok & (msg == _MSG24) & (part == _PART_A) & (n_bits >= _PART_A_BITS)
         & (n_chars[rows] <= _MSG24_CHARS), _message_24_part_a),
        (ok & (msg == _MSG24) & (part == _PART_B) & (n_bits >= _PART_B_BITS)
         & (n_chars[rows] <= _MSG24_CHARS), _message_24_part_b),
    )
    taken = [rows[mask] for mask, _ in kinds]
    tables = [pa.table(decode(six[mask])) for mask, decode in kinds]
    return np.concatenate(taken), pa.concat_tables(tables)


def _six_bit_rows(payload: list[bytes], n_chars: np.ndarray, width: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """De-armoured payloads as (n, width) 6-bit values, zero-padded on the right, and
    whether every character is valid armour ('0'-'W', '`'-'w')."""
    armour = np.full((len(payload), width), ord("0"), np.uint8)
    flat = np.frombuffer(b"".join(payload), np.uint8)
    row = np.repeat(np.arange(len(payload)), n_chars)
    col = np.arange(flat.size) - np.repeat(np.cumsum(n_chars) - n_chars, n_chars)
    armour[row, col] = flat
    valid = (((armour >= 48) & (armour <= 87)) | ((armour >= 96) & (armour <= 119))).all(axis=1)
    six = armour.astype(np.int16) - 48
    return np.where(six > 40, six - 8, six), valid


def _message_5(six: np.ndarray) -> dict[str, pa.Array]:
    """ais_static fields of message 5 rows (layout above)."""
    callsign, shipname, destination = _text_columns(six, (70, 7), (112, 20), (302, 20))
    return _static_columns(
        six, _MSG5, ais_class="A",
        imo=_nonzero_column(_bits(six, 40, 30), pa.int64()),
        callsign=callsign,
        shipname=shipname,
        ship_type=_nonzero_column(_SHIP_TYPE_5[_bits(six, 232, 8)], pa.int16()),
        dimensions=_dimensions(six, 240, np.ones(six.shape[0], bool)),
        destination=destination,
    )


def _message_24_part_a(six: np.ndarray) -> dict[str, pa.Array]:
    """ais_static fields of message 24 part A rows: the name only."""
    n = six.shape[0]
    return _static_columns(
        six, _MSG24, ais_class="B",
        imo=pa.nulls(n, pa.int64()),
        callsign=pa.nulls(n, pa.string()),
        shipname=_text_columns(six, (40, 20))[0],
        ship_type=pa.nulls(n, pa.int16()),
        dimensions={name: pa.nulls(n, pa.float64()) for name, _, _ in _DIMENSIONS},
        destination=pa.nulls(n, pa.string()),
    )


def _message_24_part_b(six: np.ndarray) -> dict[str, pa.Array]:
    """ais_static fields of message 24 part B rows: type, call sign, dimensions (none for
    an auxiliary craft)."""
    n = six.shape[0]
    mmsi = _bits(six, 8, 30)
    auxiliary = (mmsi >= _AUXILIARY_MMSI[0]) & (mmsi <= _AUXILIARY_MMSI[1])
    return _static_columns(
        six, _MSG24, ais_class="B",
        imo=pa.nulls(n, pa.int64()),
        callsign=_text_columns(six, (90, 7))[0],
        shipname=pa.nulls(n, pa.string()),
        ship_type=_nonzero_column(_bits(six, 40, 8), pa.int16()),
        dimensions=_dimensions(six, 132, ~auxiliary),
        destination=pa.nulls(n, pa.string()),
    )


def _static_columns(six: np.ndarray, msg_type: int, *, ais_class: str, imo: pa.Array,
                    callsign: pa.Array, shipname: pa.Array, ship_type: pa.Array,
                    dimensions: dict[str, pa.Array], destination: pa.Array
                    ) -> dict[str, pa.Array]:
    """The ais_static field columns in :func:`_static_row`'s order."""
    n = six.shape[0]
    return {
        "mmsi": pa.array(_bits(six, 8, 30), pa.int64()),
        "msg_type": pa.array(np.full(n, msg_type, np.int16), pa.int16()),
        "ais_class": pa.array([ais_class] * n, pa.string()),
        "imo": imo,
        "callsign": callsign,
        "shipname": shipname,
        "ship_type": ship_type,
        **dimensions,
        "destination": destination,
    }


def _dimensions(six: np.ndarray, start: int, present: np.ndarray) -> dict[str, pa.Array]:
    """Dimensions A (to bow, 9 bits), B (to stern, 9), C (to port, 6), D (to starboard, 6)
    from bit ``start`` (240 in message 5, 132 in message 24 part B), m; 0 or not
    ``present`` -> null."""
    out = {}
    for name, offset, width in _DIMENSIONS:
        v = _bits(six, start + offset, width)
        out[name] = pa.array(v.astype(np.float64), pa.float64(), mask=(v == 0) | ~present)
    return out


def _nonzero_column(v: np.ndarray, kind: pa.DataType) -> pa.Array:
    """:func:`_nonzero` over a column: 0 -> null."""
    return pa.array(v, kind, mask=v == 0)


def _text_columns(six: np.ndarray, *fields: tuple[int, int]) -> list[pa.Array]:
    """6-bit ASCII text fields, each ``(start bit, characters)``, as the pyais path stores
    them: pyais ``get_str`` (``rstrip("@").strip()``), then :func:`_text`
    (``strip().rstrip("@").strip()``); empty -> null. The fields are trimmed together,
    side by side, right-padded with '@' to the longest (the first step strips it)."""
    n = six.shape[0]
    width = max(n_chars for _, n_chars in fields)
    # characters down the rows, texts across: the strips reduce over rows of n values
    codes = np.full((width, len(fields) * n), _AT, np.uint8)
    for k, (start, n_chars) in enumerate(fields):
        codes[:n_chars, k * n:(k + 1) * n] = _SIXBIT_ASCII[_characters(six, start, n_chars)].T
    lo = np.zeros(codes.shape[1], np.int16)
    hi = np.full(codes.shape[1], width, np.int16)
    hi = _rstrip(codes, _AT, lo, hi)
    hi = _rstrip(codes, _SPACE, lo, hi)
    lo = _lstrip(codes, _SPACE, lo, hi)
    # _text: strip() finds nothing more to strip at either end; rstrip("@") and strip()
    # on the right remain (codes[lo] is not a space, so nothing comes off the left)
    hi = _rstrip(codes, _AT, lo, hi)
    hi = _rstrip(codes, _SPACE, lo, hi)
    text = _string_column(codes, lo, hi)
    return [text.slice(k * n, n) for k in range(len(fields))]


def _characters(six: np.ndarray, start: int, n_chars: int) -> np.ndarray:
    """The (n, n_chars) 6-bit characters of a text field from bit ``start``: each one the
    low bits of an armour character and the high bits of the next (``start`` need not be
    a multiple of 6)."""
    first, shift = divmod(start, 6)
    if shift == 0:
        return six[:, first:first + n_chars]
    pairs = six[:, first:first + n_chars + 1].astype(np.int64)
    return ((pairs[:, :-1] << shift) | (pairs[:, 1:] >> (6 - shift))) & 63


def _inside(codes: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(width, texts) mask of the characters in [lo, hi) of each text (column)."""
    p = np.arange(codes.shape[0], dtype=np.int16)[:, None]
    inside = p >= lo
    inside &= p < hi
    return inside


def _rstrip(codes: np.ndarray, char: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """New right ends of the texts ``codes[lo:hi]`` (columns) after ``rstrip(char)``."""
    keep = _inside(codes, lo, hi)
    keep &= codes != char
    p1 = np.arange(1, codes.shape[0] + 1, dtype=np.int16)[:, None]
    return np.maximum((keep * p1).max(axis=0, initial=0), lo)


def _lstrip(codes: np.ndarray, char: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """New left ends of the texts ``codes[lo:hi]`` (columns) after ``lstrip(char)``."""
    keep = _inside(codes, lo, hi)
    keep &= codes != char
    width = codes.shape[0]
    from_end = np.arange(width, 0, -1, dtype=np.int16)[:, None]  # width - position
    return np.minimum(width - (keep * from_end).max(axis=0, initial=0), hi)


def _string_column(codes: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> pa.Array:
    """Texts ``codes[lo:hi]`` (columns, ASCII) as a string column, empty -> null, built
    from one data buffer and the offsets."""
    n = codes.shape[1]
    data = codes.T[_inside(codes, lo, hi).T]  # text by text, each in order
    length = (hi - lo).astype(np.int32)
    offsets = np.zeros(n + 1, np.int32)
    np.cumsum(length, out=offsets[1:])
    present = length > 0
    return pa.StringArray.from_buffers(
        n, pa.py_buffer(offsets), pa.py_buffer(data.tobytes()),
        pa.py_buffer(np.packbits(present, bitorder="little")), int(n - present.sum()))


def _fast_static_table(f: FastStatic, dec: _Decoder, sentences: list[bytes], times: np.ndarray,
                       recv: np.ndarray) -> pa.Table:
    """The taken rows' fields with :func:`_provenance`'s columns. ``nmea`` is joined per row
    in Python: a unit's sentences are a list of any length."""
    columns = dict(zip(f.table.column_names, f.table.columns, strict=True))
    columns["time_ns"] = pa.chunked_array([recv[f.index]], pa.int64())
    columns["log_time_ns"] = pa.chunked_array([times[f.index]], pa.int64())
    text = [_nmea_text(dec.units[u], sentences) for u in f.unit.tolist()]
    columns["nmea"] = pa.chunked_array([pa.array(text, pa.string())])
    return pa.table(columns)


def _merge_fast(cols: dict[str, list], keys: list[int], f: FastPositions, keep: np.ndarray,
                sentences: list[bytes], times: np.ndarray, recv: np.ndarray, source_file: str,
                topic: str, clock: _Sources) -> pa.Table:
    """Slow-path report rows and fast rows in the reference order (see :func:`_merge`)."""
    fast = _fast_table(f, keep, sentences, times, recv)
    return _merge("ais_reports", cols, keys, fast, f.index[keep], source_file, topic, clock)


def _merge(name: str, cols: dict[str, list], keys: list[int], fast: pa.Table,
           fast_keys: np.ndarray, source_file: str, topic: str, clock: _Sources) -> pa.Table:
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
    all_keys = np.concatenate(order)
    perm = np.argsort(all_keys, kind="stable")
    table = table.take(perm)
    n = table.num_rows
    if n == 0:
        return empty(name)
    table = table.append_column("source_file", pa.array([source_file] * n, pa.string()))
    table = table.append_column("topic", pa.array([topic] * n, pa.string()))
    table = table.append_column("time_source", clock.column(all_keys[perm]))
    return conform(name, table)


def _table(name: str, cols: dict[str, list], keys: list[int], source_file: str, topic: str,
           clock: _Sources) -> pa.Table:
    n = len(cols.get("mmsi", []))
    if not n:
        return empty(name)
    types = {f.name: f.type for f in schema(name)}
    arrays = {k: pa.array(v, type=types[k]) for k, v in cols.items()}
    arrays["source_file"] = pa.array([source_file] * n, pa.string())
    arrays["topic"] = pa.array([topic] * n, pa.string())
    arrays["time_source"] = clock.column(np.asarray(keys, np.int64))
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
