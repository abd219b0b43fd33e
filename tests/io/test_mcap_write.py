"""The batched MCAP writer writes the same bytes as the mcap package's Writer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest
from mcap.reader import make_reader

from pipeline.io.mcap_write import (
    CHUNK_SIZE,
    McapFileWriter,
    write_mcap_file,
    write_mcap_file_reference,
)
from pipeline.messages import RADAR_REPORT, message_layout

CHANNELS = [("/radar/R1/tracks", "json", "S"), ("/ais/nmea", "nmea0183", None),
            ("/truth", "json", "S", {"k": "v"})]


def _messages(n: int, seed: int, max_len: int = 900) -> pl.DataFrame:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(1_700_000_000 * 10**9, 1_700_000_100 * 10**9, n))
    payload = [bytes(rng.integers(32, 127, int(rng.integers(0, max_len))).astype(np.uint8))
               for _ in range(n)]
    return pl.DataFrame({"log_time_ns": t, "channel": rng.integers(0, 3, n),
                         "payload": pl.Series(payload, dtype=pl.Binary)})


@pytest.mark.parametrize(("n", "max_len"), [(0, 10), (1, 10), (7, 10), (3000, 900),
                                            (5000, 2 * CHUNK_SIZE // 1000)])
def test_same_bytes_as_reference(tmp_path: Path, n: int, max_len: int) -> None:
    schema = message_layout(RADAR_REPORT).data
    df = _messages(n, n, max_len)
    fast, ref = tmp_path / "fast.mcap", tmp_path / "ref.mcap"
    write_mcap_file(fast, CHANNELS, {"S": schema}, {"name": "t"}, df)
    write_mcap_file_reference(ref, CHANNELS, {"S": schema}, {"name": "t"}, df)
    assert fast.read_bytes() == ref.read_bytes()


def test_batches_stream_to_the_same_file(tmp_path: Path) -> None:
    """Adding messages in several batches gives the file of one batch (and of the
    reference), including a message larger than a whole chunk."""
    schema = message_layout(RADAR_REPORT).data
    df = _messages(4000, 3)
    big = pl.DataFrame({"log_time_ns": [df["log_time_ns"][-1]], "channel": [1],
                        "payload": pl.Series([b"x" * (CHUNK_SIZE + 17)], dtype=pl.Binary)})
    df = pl.concat([df, big])
    ref = tmp_path / "ref.mcap"
    write_mcap_file_reference(ref, CHANNELS, {"S": schema}, {"name": "t"}, df)
    out = tmp_path / "batched.mcap"
    with McapFileWriter(out, CHANNELS, {"S": schema}, {"name": "t"}) as w:
        for a in range(0, df.height, 777):
            part = df.slice(a, 777)
            w.add(part["log_time_ns"], part["channel"], part["payload"])
    assert out.read_bytes() == ref.read_bytes()
    with out.open("rb") as f:
        got = [(m.log_time, m.data) for _, _, m in make_reader(f).iter_messages()]
    assert len(got) == df.height


def test_failed_write_leaves_no_file(tmp_path: Path) -> None:
    out = tmp_path / "x.mcap"
    with pytest.raises(RuntimeError), McapFileWriter(out, CHANNELS, {"S": b"{}"}, {}) as w:
        w.add(np.array([1]), np.array([0]), [b"a"])
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
