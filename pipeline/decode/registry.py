"""Choose a decoder per MCAP channel and turn a whole file's batches into table rows.

A channel is decoded by (message encoding, schema encoding, schema name):

================  ===============  ==========================  =========================
message encoding  schema encoding  schema name                 decoder -> tables
================  ===============  ==========================  =========================
``json``          ``jsonschema``   ``surveil.RadarTrackReport``  radar -> radar_tracks
``json``          ``jsonschema``   ``surveil.TruthState``        truth -> truth
``nmea0183``      (any)            (any)                       nmea -> ais_reports, ais_static,
                                                               nav_gnss, nav_heading,
                                                               nav_speed_log, arpa_targets,
                                                               arpa_own_ship
``json``          ``jsonschema``   ``surveil.AisReport``       ais_json -> ais_reports,
                                                               ais_static (AIS CSV imports)
``asterix``       any / (none)     ``asterix`` / (none)        asterix -> airfield_obs,
                                                               asterix_service
``cdr``           ``ros2msg``      ``sensor_msgs/msg/NavSatFix``  ros2 -> nav_gnss
``cdr``           ``ros2msg``      ``sensor_msgs/msg/Imu``     ros2 -> nav_heading
``cdr``           ``ros2msg``      ``nmea_msgs/msg/Sentence``  ros2 -> (NMEA tables)
``cdr``           ``ros2msg``      ``foxglove_msgs/msg/LocationFix``  ros2 -> nav_gnss
``protobuf``      ``protobuf``     ``foxglove.LocationFix``    protobuf -> nav_gnss
``json``          ``jsonschema``   ``foxglove.LocationFix``    foxglove_json -> nav_gnss
``ros1``          ``ros1msg``      ``sensor_msgs/NavSatFix``   ros1 -> nav_gnss
``ros1``          ``ros1msg``      ``sensor_msgs/Imu``         ros1 -> nav_heading
``ros1``          ``ros1msg``      ``nmea_msgs/Sentence``      ros1 -> (NMEA tables)
``json``          ``jsonschema``   ``surveil.VasnReport``      vasn -> airfield_obs
``json``          ``jsonschema``   ``surveil.AirfieldTruth``   airfield_truth -> airfield_truth
``json``          ``jsonschema``   ``surveil.GyroSignals``     ownship -> nav_gyro_signals
``json``          ``jsonschema``   ``surveil.OwnshipTruth``    ownship -> ownship_truth
``json``          ``jsonschema``   ``surveil.FaultTruth``      fault_truth -> fault_truth
``json``          ``jsonschema``   ``surveil.ImportReject``    import_reject -> rejects
``protobuf``      ``protobuf``     ``surveil.RadarTrackReport``  radar_binary -> radar_tracks
``cdr``           ``ros2msg``      ``surveil_msgs/msg/RadarTrackReport``  radar_binary ->
                                                               radar_tracks
================  ===============  ==========================  =========================

Kinds in ``CHANNEL_DECODERS`` are stateful per channel: ``Class.for_channel(batch,
source_file)`` (``for_channel(batch, source_file, validation)`` when the class sets
``takes_validation = True``) is built at the channel's first batch, ``feed(batch)`` and
``finish()`` return ``{table: rows}``.

Any other channel is not decoded: it produces ONE rejects row per channel (reason_code
``unknown_schema``) with the message count, not a row per message.

``make_rejects`` builds rows of the ``rejects`` table for every decoder. Reason codes used
at ingest: ``undecodable``, ``out_of_range``, ``bad_checksum``, ``truncated_multipart``,
``unsupported_type``, ``no_position``, ``unknown_schema``, ``not_mcap``, ``corrupt_chunk``,
``truncated``, ``decode_error``, ``too_large``.

**No message loses more than itself** (:class:`FileDecoder`): before decoding, a message
whose log time does not fit int64 (MCAP's is uint64) or whose payload is longer than
``MAX_MESSAGE_BYTES`` is a rejects row (``out_of_range`` / ``too_large``); any exception
a decoder raises on a batch (``RecursionError`` from deep JSON, ``OverflowError``,
``struct.error``, ...) makes the batch decode again message by message, and each message
that still raises is a rejects row (``decode_error``: the exception, the channel's topic,
the first ``REJECT_RAW_BYTES`` of the payload); a channel whose decoder cannot be built or
finished loses that channel's pending messages only. Every decoded row of a raw table is
checked against ``schemas/tables.toml [valid]`` (time and coordinate ranges, string
lengths) before it is kept; a row that breaks it is an ``out_of_range`` rejects row.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline.config import ValidationConfig

# our own JSON reports, the bulk of an archive: imported with the registry (~30 ms, paid
# once per process) rather than inside the first file's decode
from pipeline.decode.json_bulk import decode_json_batches
from pipeline.decode.radar import RADAR as RADAR_KIND
from pipeline.decode.truth import TRUTH as TRUTH_KIND
from pipeline.io.mcap_read import ChannelBatch
from pipeline.tables import ConstantStrings, conform, empty, invalid_rows

RAW_TABLES = (
    "radar_tracks", "ais_reports", "ais_static", "ais_other_messages", "truth", "rejects",
    "airfield_obs", "asterix_service", "nav_gnss", "nav_heading",
    "nav_speed_log", "arpa_targets", "arpa_own_ship", "airfield_truth",
    "nav_gyro_signals", "ownship_truth", "fault_truth",
)  # fmt: skip

RADAR = ("json", "jsonschema", "surveil.RadarTrackReport")
TRUTH = ("json", "jsonschema", "surveil.TruthState")
AIS = ("nmea0183", "", "")  # any channel with message encoding nmea0183 is "nmea"
NMEA_ENCODING = "nmea0183"
_KINDS = {RADAR: "radar", TRUTH: "truth", ("json", "jsonschema", "surveil.AisReport"): "ais_json"}
ROS2_SCHEMAS = (
    "sensor_msgs/msg/NavSatFix", "sensor_msgs/msg/Imu", "nmea_msgs/msg/Sentence",
    "foxglove_msgs/msg/LocationFix",
)  # fmt: skip
_KINDS.update({("cdr", "ros2msg", name): "ros2" for name in ROS2_SCHEMAS})
_KINDS[("protobuf", "protobuf", "foxglove.LocationFix")] = "protobuf"
_KINDS[("json", "jsonschema", "foxglove.LocationFix")] = "foxglove_json"
_KINDS[("json", "jsonschema", "surveil.VasnReport")] = "vasn"
_KINDS[("json", "jsonschema", "surveil.AirfieldTruth")] = "airfield_truth"
_KINDS.update({("ros1", "ros1msg", n): "ros1" for n in ("sensor_msgs/NavSatFix",
                                                        "sensor_msgs/Imu",
                                                        "nmea_msgs/Sentence")})  # fmt: skip
CHANNEL_DECODERS = {
    "nmea": "pipeline.decode.nmea:NmeaChannelDecoder",
    "ais_json": "pipeline.decode.ais_json:AisJsonChannelDecoder",
    "asterix": "pipeline.decode.asterix:AsterixChannelDecoder",
    "ros2": "pipeline.decode.ros2:Ros2ChannelDecoder",
    "protobuf": "pipeline.decode.protobuf:ProtobufChannelDecoder",
    "foxglove_json": "pipeline.decode.foxglove:FoxgloveJsonChannelDecoder",
    "ros1": "pipeline.decode.ros2:Ros1ChannelDecoder",
    "vasn": "pipeline.decode.vasn:VasnChannelDecoder",
    "airfield_truth": "pipeline.decode.vasn:AirfieldTruthChannelDecoder",
    "radar_binary": "pipeline.decode.radar_binary:RadarBinaryChannelDecoder",
}
_KINDS[("protobuf", "protobuf", "surveil.RadarTrackReport")] = "radar_binary"
_KINDS[("cdr", "ros2msg", "surveil_msgs/msg/RadarTrackReport")] = "radar_binary"
CHANNEL_DECODERS["gyro_signals"] = "pipeline.decode.ownship:GyroSignalsChannelDecoder"
CHANNEL_DECODERS["ownship_truth"] = "pipeline.decode.ownship:OwnshipTruthChannelDecoder"
_KINDS[("json", "jsonschema", "surveil.GyroSignals")] = "gyro_signals"
_KINDS[("json", "jsonschema", "surveil.OwnshipTruth")] = "ownship_truth"
CHANNEL_DECODERS["fault_truth"] = "pipeline.decode.fault_truth:FaultTruthChannelDecoder"
_KINDS[("json", "jsonschema", "surveil.FaultTruth")] = "fault_truth"
CHANNEL_DECODERS["import_reject"] = "pipeline.decode.import_reject:ImportRejectChannelDecoder"
_KINDS[("json", "jsonschema", "surveil.ImportReject")] = "import_reject"
MAX_MESSAGE_BYTES = 1 << 20  # a decoded message longer than this is a rejects row
REJECT_RAW_BYTES = 1024  # payload bytes kept in a decode_error / too_large rejects row
JSON_BATCH = 100_000  # JSON messages per bulk parse (~44 MB of radar payload)
JSON_MAX_CHUNKS = 64  # chunks a pending JSON parse may hold (bounds memory: ~64 MiB)
JSON_RAMP_STEPS = 3  # the first parses take 1/8, 1/4, 1/2 of these limits
JSON_RAMP_DOWN_STEPS = 4  # the last parses shrink down to 1/16 of JSON_BATCH


def decoder_kind(message_encoding: str, schema_encoding: str, schema_name: str) -> str | None:
    """``radar`` | ``truth`` | ``ais`` | a key of ``CHANNEL_DECODERS``, or ``None`` for a
    channel we cannot decode."""
    if message_encoding == "asterix" and schema_name in ("", "asterix"):
        return "asterix"
    if message_encoding == NMEA_ENCODING:
        return "nmea"
    return _KINDS.get((message_encoding, schema_encoding, schema_name))


def _open_channel_decoder(
    kind: str,
    batch: ChannelBatch,
    source_file: str,
    validation: ValidationConfig | None = None,
    asterix_editions: Mapping[int, str] | None = None,
) -> Any:
    """The stateful decoder of ``CHANNEL_DECODERS[kind]`` for ``batch``'s channel."""
    import importlib

    module, cls = CHANNEL_DECODERS[kind].split(":")
    factory = getattr(importlib.import_module(module), cls)
    if getattr(factory, "takes_validation", False):
        return factory.for_channel(batch, source_file, validation)
    if getattr(factory, "takes_editions", False):
        return factory.for_channel(batch, source_file, asterix_editions)
    return factory.for_channel(batch, source_file)


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

    Holds the decoded rows not yet taken by :meth:`drain` (Arrow columns, not Python
    objects), up to ``JSON_BATCH`` undecoded radar/truth JSON messages (of at most
    ``JSON_MAX_CHUNKS`` chunks: memory does not grow with the file), and per AIS topic at
    most a few trailing fragments of a multi-part message that continues in the next
    chunk. ``not_stored`` counts valid messages we do not keep, per type (``ais_type_4``,
    ``nmea_GSV``, ``asterix_cat004``): the ledger's ``not_stored_json``.
    ``missing_decoders``: optional decoders the file needed but this installation lacks
    (its channels got a ``decoder_missing`` reject; ingest marks the file partial).

    ``parse_pool``, ``strings``: what the bulk JSON decoding reuses across groups and
    files (the ingest context's parser threads and provenance columns; ``None``: made
    per group).
    """

    source_file: str
    validation: ValidationConfig
    asterix_editions: Mapping[int, str] = field(default_factory=dict)
    parse_pool: Executor | None = None
    strings: ConstantStrings | None = None
    parts: dict[str, list[pa.Table]] = field(default_factory=dict)
    not_stored: Counter = field(default_factory=Counter)
    missing_decoders: set[str] = field(default_factory=set)
    not_stored_by_channel: dict[int, Counter] = field(default_factory=dict)
    _unknown: dict[int, _UnknownChannel] = field(default_factory=dict)
    _json: list[ChannelBatch] = field(default_factory=list)
    _json_count: int = 0
    _json_flushes: int = 0
    _channels: dict[int, Any] = field(default_factory=dict)

    def _add(self, name: str, table: pa.Table) -> None:
        if not table.num_rows:
            return
        if name != "rejects":
            bad = invalid_rows(name, table)
            if bad is not None:
                idx, why = bad
                keep = np.ones(table.num_rows, dtype=bool)
                keep[idx] = False
                take = pa.array(idx)
                self._add("rejects", make_rejects(
                    table["log_time_ns"].take(take).to_numpy(zero_copy_only=False),
                    source_file=self.source_file,
                    topic=table["topic"].take(take).to_pylist(),
                    reason_code="out_of_range",
                    reason=[f"{name}: {w}" for w in why],
                ))  # fmt: skip
                table = table.filter(pa.array(keep))
                if not table.num_rows:
                    return
        self.parts.setdefault(name, []).append(table)

    def _reject_messages(self, batch: ChannelBatch, code: str, reason: str) -> None:
        """Every message of ``batch`` as a rejects row (payload kept up to a cap)."""
        self._add("rejects", make_rejects(
            batch.log_time_ns,
            source_file=self.source_file,
            topic=batch.topic,
            reason_code=code,
            reason=reason,
            raw=[p[:REJECT_RAW_BYTES] for p in batch.payloads],
        ))  # fmt: skip

    def _screen(self, batch: ChannelBatch) -> ChannelBatch:
        """``batch`` without the messages no decoder is given: log time beyond int64
        (reads negative), payload over ``MAX_MESSAGE_BYTES`` (each a rejects row)."""
        t_bad = batch.log_time_ns < 0
        big = batch.payload_lengths() > MAX_MESSAGE_BYTES
        if not (t_bad.any() or big.any()):
            return batch
        for mask, code, reason in (
            (t_bad, "out_of_range", "MCAP log_time beyond 2^63-1 ns (year 2262)"),
            (big & ~t_bad, "too_large", f"payload over {MAX_MESSAGE_BYTES} bytes"),
        ):
            if mask.any():
                bad = batch.take(np.flatnonzero(mask))
                self._add("rejects", make_rejects(
                    np.zeros(len(bad), dtype=np.int64) if code == "out_of_range"
                    else bad.log_time_ns,
                    source_file=self.source_file, topic=batch.topic, reason_code=code,
                    reason=reason, raw=[p[:REJECT_RAW_BYTES] for p in bad.payloads],
                ))  # fmt: skip
        return batch.take(np.flatnonzero(~(t_bad | big)))

    def _isolated(self, batch: ChannelBatch, decode: Any) -> list[dict[str, pa.Table]]:
        """``decode(batch)``; when it raises, ``decode`` of each message alone, and a
        ``decode_error`` rejects row for each message that still raises."""
        try:
            return [decode(batch)]
        except Exception as exc:  # any decoder failure: isolate the message(s) at fault
            if len(batch) == 1:
                self._reject_messages(batch, "decode_error", _why(exc))
                return []
        out = []
        for i in range(len(batch)):
            one = batch.take([i])
            try:
                out.append(decode(one))
            except Exception as exc:  # this message alone fails: it is the bad one
                self._reject_messages(one, "decode_error", _why(exc))
        return out

    def feed(self, batch: ChannelBatch, chunks_left: int | None = None) -> None:
        """Take one batch. JSON channels are buffered per channel up to ``JSON_BATCH``
        messages so that each bulk parse is large (a chunk holds only ~4k messages).

        ``chunks_left``: chunks of the file still to come after this batch's, if known;
        the last parses then shrink (see below)."""
        kind = decoder_kind(batch.message_encoding, batch.schema_encoding, batch.schema_name)
        if kind in ("radar", "truth") or kind in CHANNEL_DECODERS:
            batch = self._screen(batch)
            if not len(batch):
                return
        if kind in ("radar", "truth"):
            self._json.append(batch)
            self._json_count += len(batch)
            # the first parses are smaller (1/8, 1/4, 1/2 of the batch): decoding starts
            # while the reader still fetches, instead of after a whole batch of chunks
            ramp = max(0, JSON_RAMP_STEPS - self._json_flushes)
            chunks = len({id(b.chunk) for b in self._json})
            # ... and the last ones too: once more chunks are pending than are still to
            # come, parse them now, so that what is left to parse after the file's last
            # chunk halves on the way to the end instead of being up to a whole batch
            ending = chunks_left is not None and chunks > chunks_left
            if (
                self._json_count >= JSON_BATCH >> ramp
                or chunks > JSON_MAX_CHUNKS >> ramp
                or (ending and self._json_count >= JSON_BATCH >> JSON_RAMP_DOWN_STEPS)
            ):
                self._flush_json()
        elif kind in CHANNEL_DECODERS:
            dec = self._channels.get(batch.channel_id)
            if dec is None:
                try:
                    dec = _open_channel_decoder(
                        kind, batch, self.source_file, self.validation, self.asterix_editions
                    )
                except Exception as exc:  # e.g. a schema that does not parse
                    self._reject_messages(batch, "decode_error", "no decoder: " + _why(exc))
                    return
                self._channels[batch.channel_id] = dec
            for tables in self._isolated(batch, dec.feed):
                for name, table in tables.items():
                    self._add(name, table)
        else:
            self._note_unknown(batch)

    def _flush_json(self) -> None:
        """Decode every pending radar/truth batch in one bulk parse (json_bulk)."""
        batches, self._json, self._json_count = self._json, [], 0
        if not batches:
            return
        self._json_flushes += 1
        kinds = {}
        for b in batches:
            kind = decoder_kind(b.message_encoding, b.schema_encoding, b.schema_name)
            kinds[b.channel_id] = RADAR_KIND if kind == "radar" else TRUTH_KIND

        def decode(group: list[ChannelBatch]) -> dict[str, pa.Table]:
            return decode_json_batches(
                group,
                kinds,
                source_file=self.source_file,
                validation=self.validation,
                parse_pool=self.parse_pool,
                strings=self.strings,
            )

        try:
            results = [decode(batches)]
        except Exception:  # one message at fault: find it batch by batch, then alone
            results = []
            for b in batches:
                results += self._isolated(b, lambda one: decode([one]))
        for tables in results:
            for name, table in tables.items():
                self._add(name, table)

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

    def drain(self) -> dict[str, list[pa.Table]]:
        """Take the rows decoded so far (per table, in parts): the ingest stages them as
        it goes, so that the file's rows never sit in memory all at once."""
        parts, self.parts = self.parts, {}
        return parts

    def finish(self) -> dict[str, pa.Table]:
        """Rows per raw table not yet drained (every table of ``RAW_TABLES``, possibly
        empty), conformed."""
        self._flush_json()
        for channel_id, dec in self._channels.items():
            try:
                finished = dec.finish()
            except Exception as exc:  # what the decoder still held is lost, nothing more
                finished = {"rejects": make_rejects(
                    [0], source_file=self.source_file, topic=None, reason_code="decode_error",
                    reason=f"channel {channel_id}: decoder failed at the end: {_why(exc)}",
                )}  # fmt: skip
            for name, table in finished.items():
                self._add(name, table)
            counts = getattr(dec, "not_stored", {})
            self.not_stored.update(counts)
            if counts:
                self.not_stored_by_channel[channel_id] = Counter(counts)
            if getattr(dec, "missing_decoder", None):
                self.missing_decoders.add(dec.missing_decoder)
        self._channels.clear()
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


def _why(exc: BaseException) -> str:
    """One line naming an exception (its message capped)."""
    text = str(exc).splitlines()[0][:200] if str(exc) else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
