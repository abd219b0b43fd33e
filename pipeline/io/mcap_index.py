"""Rows of the ``mcap_index`` table: what an archived MCAP file holds, per channel.

From the summary section when the file has one (no chunk is read for it): the channel
records, ``Statistics.channel_message_counts`` and the chunk indexes, whose
``message_index_offsets`` tell which chunks hold a channel, hence the channel's chunk count
and time span (the span of those chunks: an outer bound of the channel's own log times).
A file without a readable summary gets the channels and counts its scan actually read
(``source = "scan"``). The table is declared in ``schemas/tables.d/ingest.toml``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping

import pyarrow as pa

from pipeline.io.mcap_read import ChannelInfo, McapSummary, ReadStatus
from pipeline.tables import conform, empty


def _channel_row(source_file: str, ch_id: int, info: ChannelInfo) -> dict:
    return {
        "source_file": source_file,
        "channel_id": ch_id,
        "topic": info.topic,
        "message_encoding": info.message_encoding,
        "schema_name": info.schema_name,
        "schema_encoding": info.schema_encoding,
        "metadata_json": json.dumps(info.metadata, sort_keys=True),
    }


def summary_rows(source_file: str, summary: McapSummary) -> list[dict]:
    """One row per channel declared in the summary."""
    st = summary.statistics
    spans: dict[int, tuple[int, int, int]] = {}
    any_index = False
    for ci in summary.chunk_indexes:
        for ch in ci.message_index_offsets:
            any_index = True
            lo, hi, n = spans.get(ch, (ci.message_start_time, ci.message_end_time, 0))
            spans[ch] = (min(lo, ci.message_start_time), max(hi, ci.message_end_time), n + 1)
    rows = []
    for ch_id, info in sorted(summary.channels.items()):
        lo, hi, n = spans.get(ch_id, (None, None, 0))
        rows.append(
            {
                **_channel_row(source_file, ch_id, info),
                "message_count": None if st is None else st.channel_message_counts.get(ch_id, 0),
                "start_time_ns": lo,
                "end_time_ns": hi,
                "chunk_count": n if any_index else None,
                "file_message_count": None if st is None else st.message_count,
                "file_start_time_ns": None if st is None else st.message_start_time,
                "file_end_time_ns": None if st is None else st.message_end_time,
                "file_chunk_count": len(summary.chunk_indexes),
                "file_size_bytes": summary.size_bytes,
                "source": "summary",
            }
        )
    return rows


def scan_rows(
    source_file: str, size_bytes: int, channels: dict[int, ChannelInfo], status: ReadStatus
) -> list[dict]:
    """One row per channel met while scanning a file without a usable summary."""
    rows = []
    for ch_id, info in sorted(channels.items()):
        lo, hi = status.channel_spans.get(ch_id, (None, None))
        rows.append(
            {
                **_channel_row(source_file, ch_id, info),
                "message_count": status.channel_counts.get(ch_id, 0),
                "start_time_ns": lo,
                "end_time_ns": hi,
                "chunk_count": None,
                "file_message_count": status.messages_read,
                "file_start_time_ns": status.start_time_ns,
                "file_end_time_ns": status.end_time_ns,
                "file_chunk_count": None,
                "file_size_bytes": size_bytes,
                "source": "scan",
            }
        )
    return rows


def mcap_index_rows(
    source_file: str,
    size_bytes: int,
    summary: McapSummary | None,
    channels: dict[int, ChannelInfo],
    status: ReadStatus,
    not_stored: Mapping[int, Mapping[str, int]] | None = None,
) -> pa.Table:
    """The ``mcap_index`` rows of one file (empty for a file that is not MCAP);
    ``not_stored``: per channel id, the valid messages the decoder did not keep, per type
    (column ``not_stored_json``, null for channels without any)."""
    if status.not_mcap:
        return empty("mcap_index")
    if summary is not None:
        rows = summary_rows(source_file, summary)
    else:
        rows = scan_rows(source_file, size_bytes, channels, status)
    if not rows:
        return empty("mcap_index")
    for row in rows:
        counts = (not_stored or {}).get(row["channel_id"])
        row["not_stored_json"] = json.dumps(dict(counts), sort_keys=True) if counts else None
    return conform("mcap_index", pa.Table.from_pylist(rows))
