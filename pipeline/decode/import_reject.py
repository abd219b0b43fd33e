"""``/import/rejects`` channels (``surveil.ImportReject`` JSON, written by
:mod:`pipeline.convert.output`) -> ``rejects`` rows.

Each message is one piece of a legacy capture that ``surveil import`` could not wrap (a log
time outside the representable range, ...): it becomes ONE ``rejects`` row with stage
``import``, the original channel as ``topic``, the reason code and reason written by the
converter, the original bytes as ``raw`` and the message's log time. A payload that is not
such a document is itself a reject (``undecodable``).
"""

from __future__ import annotations

import base64
import binascii
import json
from typing import Any

import pyarrow as pa

from pipeline.decode.registry import make_rejects


def decode_import_rejects(
    payloads: list[bytes], log_time_ns: Any, *, source_file: str, topic: str
) -> pa.Table:
    """One rejects row per message (see the module docstring)."""
    topics, codes, reasons, raws = [], [], [], []
    # per message: import rejects are rare (a few per file at most)
    for p in payloads:
        try:
            doc = json.loads(p)
            row = (str(doc["topic"]), str(doc["reason_code"]), str(doc["reason"]),
                   base64.b64decode(doc["raw_base64"], validate=True))  # fmt: skip
        except (ValueError, KeyError, TypeError, binascii.Error) as exc:
            row = (topic, "undecodable", f"not a surveil.ImportReject document: {exc}", bytes(p))
        for col, v in zip((topics, codes, reasons, raws), row, strict=True):
            col.append(v)
    return make_rejects(log_time_ns, source_file=source_file, topic=topics, reason_code=codes,
                        reason=reasons, raw=raws, stage="import")  # fmt: skip


class ImportRejectChannelDecoder:
    """Registry adapter: every batch is decoded as it comes (rows are independent)."""

    def __init__(self, source_file: str, topic: str):
        self.source_file = source_file
        self.topic = topic

    @classmethod
    def for_channel(cls, batch: Any, source_file: str) -> ImportRejectChannelDecoder:
        return cls(source_file, batch.topic)

    def feed(self, batch: Any) -> dict[str, pa.Table]:
        return {
            "rejects": decode_import_rejects(
                list(batch.payloads),
                batch.log_time_ns,
                source_file=self.source_file,
                topic=self.topic,
            )
        }

    def finish(self) -> dict[str, pa.Table]:
        return {}
