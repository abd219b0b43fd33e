"""Fuzz targets: untrusted bytes into the MCAP reader, the ingest decoders (the compiled
JSON column parser among them), and the NMEA / AIS / ASTERIX / pcap importers.

Each target takes ``bytes`` and must return without an exception, except the ones the
API documents for bad input (an importer's ``ValueError`` "not an importable file").
Anything else is a finding: ``fuzz/run.py`` saves the input, and
``tests/fuzz/test_regressions.py`` replays every saved input through the same target.
Used by ``fuzz/run.py`` (atheris, coverage-guided) and the regression tests.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

_TMP = Path(tempfile.mkdtemp(prefix=f"surveil-fuzz-{os.getpid()}-"))
T0_NS = 1_767_225_600 * 10**9


def _decoder():
    from pipeline.config import ValidationConfig
    from pipeline.decode.registry import FileDecoder

    return FileDecoder(source_file="/fuzz.mcap", validation=ValidationConfig())


def _drive(batches):
    dec = _decoder()
    for b in batches:
        dec.feed(b)
        dec.drain()
    dec.finish()
    return dec


def _batch(payloads: list[bytes], encoding: str, schema: str, schema_enc: str, topic: str):
    from pipeline.io.mcap_read import ChannelBatch

    times = T0_NS + np.arange(len(payloads), dtype=np.int64) * 10**6
    return ChannelBatch(1, topic, encoding, schema, schema_enc, b"", times, payloads)


def mcap(data: bytes) -> None:
    """The reader never raises on damaged content; the decoders isolate bad messages."""
    from pipeline.io.mcap_read import read_mcap_batches

    path = _TMP / "in.mcap"
    path.write_bytes(data)
    from pipeline.io.mcap_index import mcap_index_rows

    scan = read_mcap_batches(path, prefetch=False)
    dec = _drive(scan)
    _ = scan.status.status, scan.status.error
    # what the ingest worker then builds from the summary and status (ledger, mcap_index)
    mcap_index_rows("/fuzz.mcap", len(data), scan.summary, scan.channels, scan.status,
                    dec.not_stored_by_channel)  # fmt: skip


def json_radar(data: bytes) -> None:
    """Radar JSON payloads (one per line) through the bulk parser (C extension when
    built) and its fallbacks."""
    payloads = data.split(b"\n")[:256]
    _drive([_batch(payloads, "json", "surveil.RadarTrackReport", "jsonschema",
                   "/radar/R1/tracks")])  # fmt: skip


def nmea(data: bytes) -> None:
    """NMEA / AIS sentences as MCAP messages (one per line), then as a text log import."""
    lines = data.splitlines()[:256]
    _drive([_batch(lines, "nmea0183", "", "", "/ais/nmea")])
    _import(data, "log.nmea")


def asterix(data: bytes) -> None:
    """ASTERIX data blocks as MCAP messages, then the file importer (raw, framed
    recordings, pcap/pcapng by their first bytes)."""
    from pipeline.decode.asterix import split_blocks

    blocks, rest = split_blocks(data)
    _drive([_batch([*blocks[:256], rest], "asterix", "", "", "/asterix/raw")])
    _import(data, "rec.ast")


def _import(data: bytes, name: str) -> None:
    from pipeline.convert.legacy import import_file

    src = _TMP / name
    src.write_bytes(data)
    out = _TMP / "out"
    try:
        import_file(src, out)
    except ValueError:  # documented: not an importable file / nothing to wrap
        pass
    finally:
        shutil.rmtree(out, ignore_errors=True)


TARGETS = {"mcap": mcap, "json": json_radar, "nmea": nmea, "asterix": asterix}
