"""Write a converter's messages to MCAP, with the messages that cannot be wrapped diverted
to the rejects channel instead of crashing the writer.

A converter collects :class:`Message` rows (topic, log time, payload, and optionally a
reason why the piece cannot be used as a message of its topic). :func:`write_converted`
writes them in the given order with :func:`pipeline.io.mcap_write.write_messages`; every
message whose log time is outside the representable range (``TIME_MIN_NS`` ..
``TIME_MAX_NS``, 1970-01-01 .. 2262-04-11: a uint64 MCAP log time and an int64 warehouse
time both hold it) or that carries a reason goes to ``/import/rejects`` instead
(``surveil.ImportReject`` JSON: original topic, reason code and reason, raw bytes), with
the log time of the nearest preceding wrapped message (the next one before the first, 0
when there is none). Ingest turns each into a ``rejects`` row
(:mod:`pipeline.decode.import_reject`): rejected per message, with a reason, never a
traceback and never dropped.
"""

from __future__ import annotations

import base64
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from pipeline.io.mcap_site import METADATA_KEY
from pipeline.io.mcap_write import ChannelSpec, write_messages
from pipeline.resources import resource_path
from pipeline.units import TIME_MAX_NS, TIME_MIN_NS, describe_time

REJECTS_TOPIC = "/import/rejects"
REJECT_SCHEMA = "surveil.ImportReject"
MCAP_LIBRARY = "surveil-pipeline/import"


@dataclass(frozen=True)
class Message:
    """One piece of the source: ``reject`` is ``(reason_code, reason)`` when the piece
    cannot be used as a message of ``topic`` (it then goes to the rejects channel)."""

    topic: str
    log_time_ns: int
    payload: bytes
    reject: tuple[str, str] | None = None


def time_problem(t_ns: int) -> tuple[str, str] | None:
    """``("out_of_range", why)`` when ``t_ns`` is not a representable log time."""
    if TIME_MIN_NS <= t_ns <= TIME_MAX_NS:
        return None
    return (
        "out_of_range",
        f"log time {t_ns} ns ({describe_time(t_ns)}) is outside the representable range "
        "1970-01-01 .. 2262-04-11 UTC",
    )


def site_metadata(site: str | None) -> dict[str, str]:
    """``{"site": site}`` for the ``surveil.import`` metadata record (empty without one):
    ingest stamps it on the file's rows (:mod:`pipeline.io.mcap_site`)."""
    return {METADATA_KEY: site} if site else {}


def write_converted(
    path: Path,
    channels: Sequence[ChannelSpec],
    messages: Sequence[Message],
    *,
    metadata: Mapping[str, Mapping[str, str]],
    library: str = MCAP_LIBRARY,
) -> dict[str, int]:
    """Write ``messages`` (topics among ``channels``) in order, rejects diverted (module
    docstring). Returns the message count per topic, ``/import/rejects`` included."""
    index = {c.topic: i for i, c in enumerate(channels)}
    problems = [m.reject or time_problem(m.log_time_ns) for m in messages]
    good = [m.log_time_ns for m, p in zip(messages, problems, strict=True) if p is None]
    fill = good[0] if good else 0
    chans = list(channels)
    if any(p is not None for p in problems):
        schema = (resource_path("schemas") / "import_reject.schema.json").read_bytes()
        chans.append(ChannelSpec(REJECTS_TOPIC, "json", REJECT_SCHEMA, schema_data=schema))
    out_index, out_times, out_payloads = [], [], []
    for m, p in zip(messages, problems, strict=True):
        if p is None:
            fill = m.log_time_ns
            out_index.append(index[m.topic])
            out_times.append(m.log_time_ns)
            out_payloads.append(m.payload)
        else:
            doc = {"topic": m.topic, "reason_code": p[0], "reason": p[1],
                   "raw_base64": base64.b64encode(m.payload).decode("ascii")}  # fmt: skip
            out_index.append(len(chans) - 1)
            out_times.append(fill)
            out_payloads.append(json.dumps(doc, separators=(",", ":")).encode())
    return write_messages(path, chans, out_index, out_times, out_payloads,
                          metadata=metadata, library=library)  # fmt: skip
