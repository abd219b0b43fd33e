"""Issue 18, item 2: framed captures resynchronise after a bad record. One damaged length
field costs the block / packet it is in, is a rejects row with its byte offset, and
marks the file partial (import exit 1); everything after it is kept."""

from __future__ import annotations

import base64
import json

import pytest
from mcap.reader import make_reader

from pipeline.convert.asterix_framing import split_blocks_resync, walk_resync
from pipeline.convert.importer import run_import
from pipeline.decode.asterix import decoder_available
from pipeline.simulate import hostile as h

T0 = 1_768_435_200 * 10**9 + 36_000 * 10**9
N_RECORDS = 1500

needs_decoder = pytest.mark.skipif(not decoder_available(), reason="asterix extra missing")


def _topic_counts(mcap_path):
    counts: dict[str, int] = {}
    rejects = []
    with open(mcap_path, "rb") as f:
        for _, ch, msg in make_reader(f).iter_messages():
            counts[ch.topic] = counts.get(ch.topic, 0) + 1
            if ch.topic == "/import/rejects":
                rejects.append(json.loads(msg.data))
    return counts, rejects


def _blocks():
    return h.cat010_blocks(N_RECORDS)


def test_raw_blocks_resync_after_a_bad_len():
    blocks = _blocks()
    data = b"".join(blocks)
    k = 100
    off = sum(len(b) for b in blocks[:k])
    damaged = h.damage_length(data, off + 1, 60_000)
    good, tails = split_blocks_resync(damaged)
    assert [b for _, b in good] == blocks[:k] + blocks[k + 1 :]
    [tail] = tails
    assert tail.offset == off and tail.data == damaged[off : off + len(blocks[k])]
    assert f"at octet {off}" in tail.reason


def test_raw_garbage_in_the_middle_and_at_the_end():
    blocks = _blocks()
    junk = bytes(range(200, 256)) * 3
    data = b"".join(blocks[:50]) + junk + b"".join(blocks[50:]) + b"\x0a\x00"
    good, tails = split_blocks_resync(data)
    assert [b for _, b in good] == blocks
    assert [t.data for t in tails] == [junk, b"\x0a\x00"]


def test_final_framing_resyncs():
    recs = []
    for i, b in enumerate(_blocks()[:60]):
        n = 8 + len(b) + 4
        head = n.to_bytes(2, "big") + bytes([1, 1, 0]) + (i * 100).to_bytes(3, "big")
        recs.append(head + b + b"\xa5" * 4)
    data = b"".join(recs)
    off = sum(len(r) for r in recs[:20])
    damaged = h.damage_length(data, off, 3)  # byte count shorter than a record
    records, tails = walk_resync(damaged, "final")
    assert len(records) == 59
    assert [t.offset for t in tails] == [off] and len(tails[0].data) == len(recs[20])


@needs_decoder
@pytest.mark.parametrize("kind", ["ast", "pcap", "pcapng"])
def test_import_salvages_and_reports_partial(tmp_path, kind):
    blocks = _blocks()
    k = 100
    if kind == "ast":
        data = b"".join(blocks)
        off = sum(len(b) for b in blocks[:k])
        data = h.damage_length(data, off + 1, 60_000)
        lost = 1
    else:
        frames = [(T0 + i * 10**8, h.udp_frame(b)) for i, b in enumerate(blocks)]
        if kind == "pcap":
            data, offs = h.pcap_bytes(frames)
            off = offs[k]
            data = h.damage_length(data, off + 8, 60_000)  # included length
        else:
            data, offs = h.pcapng_bytes(frames)
            off = offs[k]
            data = data[: off + 4] + (123_457).to_bytes(4, "little") + data[off + 8 :]
        lost = 1
    src = h.write(tmp_path / "in" / f"damaged.{kind}", data)
    summary = run_import([src], tmp_path / "out")
    assert summary.exit_code == 1 and not summary.failed, summary.render()
    [imp] = summary.imported
    assert imp.status == "partial" and imp.rejected == 1
    assert "PARTIAL" in summary.render() and "1 pieces rejected" in summary.render()
    counts, rejects = _topic_counts(imp.output)
    kept = sum(n for t, n in counts.items() if t != "/import/rejects")
    assert kept == len(blocks) - lost
    [rej] = rejects
    assert f"at octet {off}" in rej["reason"]
    assert base64.b64decode(rej["raw_base64"])  # the skipped octets (capped)


def test_raw_bad_len_inside_the_file_does_not_swallow_good_blocks():
    """A broken LEN that still ends inside the file (60000 in a 300 KB file) is not
    taken: the blocks after it would not frame. Only the broken block is lost."""
    blocks = h.cat010_blocks(9832)
    data = b"".join(blocks)
    k = 61
    off = sum(len(b) for b in blocks[:k])
    assert len(data) - off > 60_000
    good, tails = split_blocks_resync(h.damage_length(data, off + 1, 60_000))
    assert [b for _, b in good] == blocks[:k] + blocks[k + 1 :]
    assert [t.offset for t in tails] == [off]


def test_pcap_bad_length_inside_the_file():
    from pipeline.convert.asterix import _pcap_packets

    blocks = _blocks()
    frames = [(T0 + i * 10**8, h.udp_frame(b)) for i, b in enumerate(blocks)]
    data, offs = h.pcap_bytes(frames)
    k = 100
    # included = original = 3000: plausible alone, inside the file; the next header is not
    bad = data[: offs[k] + 8] + (3000).to_bytes(4, "little") * 2 + data[offs[k] + 16 :]
    tails: list = []
    from collections import Counter

    packets = list(_pcap_packets(bad, Counter(), tails))
    assert len(packets) == len(frames) - 1
    assert [t.offset for t in tails] == [offs[k]]
