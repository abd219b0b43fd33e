"""Protobuf channels (message and schema encoding ``protobuf``) -> ``nav_gnss``.

``foxglove.LocationFix`` only (the schema carries its ``FileDescriptorSet``): classes are
built once per channel by ``mcap-protobuf-support``
(``mcap_protobuf.decoder.DecoderFactory``); each payload is parsed into one message object
by the protobuf runtime (per message by construction), its fields go to
:class:`pipeline.decode.foxglove.FixColumns` and the table is built vectorised by
:func:`pipeline.decode.foxglove.fix_table` (mapping and rejects documented there).
``timestamp`` is a ``google.protobuf.Timestamp``; an unset one counts as zero, and the log
time is used. A payload that does not parse -> rejects ``undecodable``; a channel whose
descriptor set does not load -> one ``undecodable`` row per batch with the count.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa
from mcap.records import Schema

from pipeline.decode.foxglove import FixColumns, FixContext, fix_table, platform_of
from pipeline.decode.registry import make_rejects
from pipeline.io.mcap_read import ChannelBatch
from pipeline.units import NS


def protobuf_decoder(schema_name: str, schema_data: bytes) -> Callable[[bytes], Any]:
    """The ``mcap_protobuf`` parser of one schema (raises if the descriptors do not load)."""
    from mcap_protobuf.decoder import DecoderFactory

    schema = Schema(id=1, name=schema_name, encoding="protobuf", data=schema_data)
    fn = DecoderFactory().decoder_for("protobuf", schema)
    if fn is None:
        raise ValueError(f"no protobuf decoder for schema {schema_name!r}")
    return fn


def location_fix_columns(
    decode: Callable[[bytes], Any], payloads: list[bytes]
) -> tuple[FixColumns, list[tuple[int, str]]]:
    """Fix columns of the payloads that parse, and ``(index, reason)`` of the others."""
    fixes = FixColumns()
    bad: list[tuple[int, str]] = []
    # one protobuf parse per message: the runtime builds one message object each
    for i, payload in enumerate(payloads):
        try:
            m = decode(payload)
        except Exception as exc:  # DecodeError and friends: this message only
            bad.append((i, f"foxglove.LocationFix does not parse ({type(exc).__name__})"))
            continue
        stamp = m.timestamp.seconds * NS + m.timestamp.nanos if m.HasField("timestamp") else 0
        fixes.add(
            i, stamp, m.latitude, m.longitude, m.altitude, m.position_covariance,
            m.position_covariance_type,
        )  # fmt: skip
    return fixes, bad


@dataclass
class ProtobufChannelDecoder:
    """Channel decoder (registry protocol) for protobuf ``foxglove.LocationFix``."""

    ctx: FixContext
    decode: Callable[[bytes], Any] | None
    error: str | None = None

    @classmethod
    def for_channel(cls, batch: ChannelBatch, source_file: str) -> ProtobufChannelDecoder:
        ctx = FixContext(source_file, batch.topic, platform_of(batch), "LocationFix")
        try:
            return cls(ctx, protobuf_decoder(batch.schema_name, batch.schema_data))
        except Exception as exc:  # descriptors that do not load: reject the messages
            return cls(ctx, None, f"{type(exc).__name__}: {exc}")

    def feed(self, batch: ChannelBatch) -> Mapping[str, pa.Table]:
        if self.decode is None:
            return {"rejects": make_rejects(
                [batch.log_time_ns[0]], source_file=self.ctx.source_file, topic=self.ctx.topic,
                reason_code="undecodable",
                reason=f"{len(batch)} messages not decoded: descriptor set of "
                       f"{batch.schema_name!r} does not load ({self.error})",
            )}  # fmt: skip
        fixes, bad = location_fix_columns(self.decode, batch.payloads)
        table, rejects = fix_table(fixes, batch.log_time_ns, batch.payloads, self.ctx)
        log_t = np.asarray(batch.log_time_ns, dtype=np.int64)
        more = make_rejects(
            [log_t[i] for i, _ in bad], source_file=self.ctx.source_file, topic=self.ctx.topic,
            reason_code="undecodable", reason=[w for _, w in bad],
            raw=[batch.payloads[i] for i, _ in bad],
        )  # fmt: skip
        return {"nav_gnss": table, "rejects": pa.concat_tables([rejects, more])}

    def finish(self) -> Mapping[str, pa.Table]:
        return {}
