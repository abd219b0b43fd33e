"""Choose a decoder per MCAP channel and turn a whole file's batches into table rows.

A channel is decoded by (message encoding, schema encoding, schema name):

================  ===============  ==========================  =========================
message encoding  schema encoding  schema name                 decoder -> tables
================  ===============  ==========================  =========================
``json``          ``jsonschema``   ``surveil.RadarTrackReport``  radar -> radar_tracks
``json``          ``jsonschema``   ``surveil.TruthState``        truth -> truth
``nmea0183``      (none)           (none)                      ais -> ais_reports, ais_static
================  ===============  ==========================  =========================

Any other channel is not decoded: it produces ONE rejects row per channel (reason_code
``unknown_schema``) with the message count, not a row per message.

``make_rejects`` builds rows of the ``rejects`` table for every decoder. Reason codes used
at ingest: ``undecodable``, ``out_of_range``, ``bad_checksum``, ``truncated_multipart``,
``unsupported_type``, ``no_position``, ``unknown_schema``, ``not_mcap``, ``corrupt_chunk``,
``truncated``.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pyarrow as pa

from pipeline.config import ValidationConfig
from pipeline.io.mcap_read import ChannelBatch
from pipeline.tables import conform, empty

RAW_TABLES = ("radar_tracks", "ais_reports", "ais_static", "truth", "rejects")

RADAR = ("json", "jsonschema", "surveil.RadarTrackReport")
TRUTH = ("json", "jsonschema", "surveil.TruthState")
AIS = ("nmea0183", "", "")
_KINDS = {RADAR: "radar", TRUTH: "truth", AIS: "ais"}
JSON_BATCH = 50_000  # JSON messages per bulk parse (~15 MB of payload)


def decoder_kind(message_encoding: str, schema_encoding: str, schema_name: str) -> str | None:
    """``radar`` | ``truth`` | ``ais``, or ``None`` for a channel we cannot decode."""
    return _KINDS.get((message_encoding, schema_encoding, schema_name))


def make_rejects(
    log_time_ns: Sequence[int] | np.ndarray,
    *,
    source_file: str,
    topic: str | None,
    reason_code: str | Sequence[str],
    reason: str | Sequence[str],
    raw: Sequence[bytes | None] | None = None,
    stage: str = "ingest",
) -> pa.Table:
    """Rows of the ``rejects`` table (conformed); scalars are broadcast to every row."""
    times = np.asarray(log_time_ns, dtype=np.int64)
    n = len(times)

    def col(v: str | Sequence[str] | None) -> list:
        return [v] * n if v is None or isinstance(v, str) else list(v)

    data = {
        "log_time_ns": pa.array(times, pa.int64()),
        "source_file": pa.array([source_file] * n, pa.string()),
        "topic": pa.array(col(topic), pa.string()),
        "stage": pa.array([stage] * n, pa.string()),
        "reason_code": pa.array(col(reason_code), pa.string()),
        "reason": pa.array(col(reason), pa.string()),
        "raw": pa.array(list(raw) if raw is not None else [None] * n, pa.binary()),
    }
    return conform("rejects", pa.table(data))


@dataclass
class _UnknownChannel:
    topic: str
    description: str
    count: int = 0
    first_log_time_ns: int = 0


@dataclass
class FileDecoder:
    """Decode every batch of one file; ``finish()`` returns the rows per raw table.

    Holds the decoded rows of the file (Arrow columns, not Python objects), up to
    ``JSON_BATCH`` undecoded JSON payloads per channel, and per AIS topic at most a few
    trailing fragments of a multi-part message that continues in the next chunk.
    ``not_stored`` counts valid AIS messages of types we do not keep.
    """

    source_file: str
    validation: ValidationConfig
    parts: dict[str, list[pa.Table]] = field(default_factory=dict)
    not_stored: Counter = field(default_factory=Counter)
    _unknown: dict[int, _UnknownChannel] = field(default_factory=dict)
    _ais_carry: dict[str, tuple[list[bytes], np.ndarray]] = field(default_factory=dict)
    _json: dict[int, list[ChannelBatch]] = field(default_factory=dict)

    def _add(self, name: str, table: pa.Table) -> None:
        if table.num_rows:
            self.parts.setdefault(name, []).append(table)

    def feed(self, batch: ChannelBatch) -> None:
        """Take one batch. JSON channels are buffered per channel up to ``JSON_BATCH``
        messages so that each bulk parse is large (a chunk holds only ~4k messages)."""
        kind = decoder_kind(batch.message_encoding, batch.schema_encoding, batch.schema_name)
        if kind in ("radar", "truth"):
            buf = self._json.setdefault(batch.channel_id, [])
            buf.append(batch)
            if sum(len(b) for b in buf) >= JSON_BATCH:
                self._flush_json(batch.channel_id)
        elif kind == "ais":
            self._feed_ais(batch.topic, batch.payloads, batch.log_time_ns, final=False)
        else:
            self._note_unknown(batch)

    def _flush_json(self, channel_id: int) -> None:
        from pipeline.decode.radar import decode_radar_reports
        from pipeline.decode.truth import decode_truth_states

        batches = self._json.pop(channel_id, [])
        if not batches:
            return
        first = batches[0]
        payloads = [p for b in batches for p in b.payloads]
        times = np.concatenate([b.log_time_ns for b in batches])
        kind = decoder_kind(first.message_encoding, first.schema_encoding, first.schema_name)
        if kind == "radar":
            rows, rejects = decode_radar_reports(
                payloads,
                times,
                source_file=self.source_file,
                topic=first.topic,
                validation=self.validation,
            )
            self._add("radar_tracks", rows)
        else:
            rows, rejects = decode_truth_states(
                payloads, times, source_file=self.source_file, topic=first.topic
            )
            self._add("truth", rows)
        self._add("rejects", rejects)

    def _feed_ais(
        self, topic: str, sentences: list[bytes], log_time_ns: np.ndarray, *, final: bool
    ) -> None:
        from pipeline.decode.ais import decode_ais

        carried, carried_t = self._ais_carry.pop(topic, ([], np.empty(0, np.int64)))
        if carried:
            sentences = carried + list(sentences)
            log_time_ns = np.concatenate([carried_t, log_time_ns])
        out = decode_ais(
            sentences, log_time_ns, source_file=self.source_file, topic=topic, final=final
        )
        self._add("ais_reports", out.reports)
        self._add("ais_static", out.static)
        self._add("rejects", out.rejects)
        self.not_stored.update(out.not_stored)
        if out.carry:
            k = len(sentences) - out.carry
            self._ais_carry[topic] = (list(sentences[k:]), np.asarray(log_time_ns[k:]))

    def _note_unknown(self, batch: ChannelBatch) -> None:
        u = self._unknown.get(batch.channel_id)
        if u is None:
            desc = (
                f"message encoding {batch.message_encoding!r}, schema "
                f"{batch.schema_name!r} ({batch.schema_encoding!r})"
            )
            u = self._unknown[batch.channel_id] = _UnknownChannel(
                batch.topic, desc, first_log_time_ns=int(batch.log_time_ns[0])
            )
        u.count += len(batch)

    def add_rejects(self, rejects: pa.Table) -> None:
        """Keep extra rejects rows (file-level problems found by the reader)."""
        self._add("rejects", rejects)

    def finish(self) -> dict[str, pa.Table]:
        """Rows per raw table (every table of ``RAW_TABLES``, possibly empty), conformed."""
        for channel_id in list(self._json):
            self._flush_json(channel_id)
        for topic in list(self._ais_carry):
            self._feed_ais(topic, [], np.empty(0, np.int64), final=True)
        for u in self._unknown.values():
            self._add(
                "rejects",
                make_rejects(
                    [u.first_log_time_ns],
                    source_file=self.source_file,
                    topic=u.topic,
                    reason_code="unknown_schema",
                    reason=f"{u.count} messages not decoded: no decoder for {u.description}",
                ),
            )
        self._unknown.clear()
        out = {}
        for name in RAW_TABLES:
            parts = self.parts.get(name, [])
            out[name] = conform(name, pa.concat_tables(parts)) if parts else empty(name)
        return out
