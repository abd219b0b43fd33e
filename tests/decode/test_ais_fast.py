"""The vectorised AIS paths (position reports; static messages 5 and 24) against the pyais
path: identical tables (reports, static, rejects, not-stored counts, carry) on simulated
traffic, the test samples, the real AIS files, fuzzed batches and fuzzed static payloads.
``ais.FAST = False`` turns both vectorised paths off (checked below), so ``both()``
compares them with pyais."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest
from mcap_fixtures import (
    AIS_EMPTY,
    AIS_TYPE1,
    AIS_TYPE3,
    AIS_TYPE18,
    T0_NS,
    TYPE5_FRAGMENTS,
    real_data_root,
)
from nmea_builders import sentence

from pipeline.decode import ais
from pipeline.simulate.region import RegionSimulation
from pipeline.simulate.region_layout import region_layout

SRC, TOPIC = "/arch/f.mcap", "/ais/nmea"


def both(sentences: list[bytes], final: bool = True, step_ns: int = 10**6
         ) -> tuple[ais.AisDecoded, ais.AisDecoded]:
    """Vectorised and reference decode; log times ``step_ns`` apart (0: all equal, so the
    tables' (time, mmsi) sort leaves the row order to the decoders)."""
    t = T0_NS + np.arange(len(sentences), dtype=np.int64) * step_ns
    fast = ais.decode_ais(sentences, t, source_file=SRC, topic=TOPIC, final=final)
    ais.FAST = False
    try:
        ref = ais.decode_ais(sentences, t, source_file=SRC, topic=TOPIC, final=final)
    finally:
        ais.FAST = True
    return fast, ref


def same(a: ais.AisDecoded, b: ais.AisDecoded) -> None:
    assert a.reports.equals(b.reports)
    assert a.static.equals(b.static)
    assert a.rejects.sort_by([("log_time_ns", "ascending"), ("reason", "ascending")]).equals(
        b.rejects.sort_by([("log_time_ns", "ascending"), ("reason", "ascending")]))
    assert a.not_stored == b.not_stored and a.carry == b.carry


def static_taken(sentences: list[bytes], final: bool = True) -> np.ndarray:
    """Batch index (last sentence) of each static message the vectorised path decodes,
    set up as ``decode_ais`` does."""
    fast = ais.fast_positions(sentences)
    dec = ais._Decoder(sentences, final, skip=None if fast is None else fast.index)
    taken = ais.fast_static(dec, dec.run())
    return np.zeros(0, np.int64) if taken is None else taken.index


def static_rows_5_24(d: ais.AisDecoded) -> int:
    """ais_static rows of messages 5 and 24."""
    return int(pc.sum(pc.is_in(d.static["msg_type"], pa.array([5, 24], pa.int16()))).as_py()
               or 0)


@pytest.fixture(scope="module")
def region_sentences() -> list[bytes]:
    sim = RegionSimulation(region_layout(2), n_ships=150, seed=4, start_ns=T0_NS,
                           duration_s=600.0)
    return [s for sl in sim.slices() for s in sl.ais_sentences["sentence"].to_list()]


def test_region_traffic(region_sentences) -> None:
    fast, ref = both(region_sentences)
    assert fast.reports.num_rows > 3000 and fast.static.num_rows > 50
    assert ais.fast_positions(region_sentences).index.size > 0.9 * fast.reports.num_rows
    # the simulator sends canonical 5 (two sentences) and 24 A / B: all vectorised
    assert static_taken(region_sentences).size == fast.static.num_rows
    same(fast, ref)
    same(*both(region_sentences, step_ns=0))  # row order within equal (time, mmsi)


def test_fast_switch_turns_both_paths_off(region_sentences, monkeypatch) -> None:
    def used(*args: object) -> None:
        raise AssertionError("a vectorised path ran with ais.FAST off")

    batch = region_sentences[:3000]
    t = T0_NS + np.arange(len(batch), dtype=np.int64)
    monkeypatch.setattr(ais, "fast_positions", used)
    monkeypatch.setattr(ais, "fast_static", used)
    monkeypatch.setattr(ais, "FAST", False)
    assert ais.decode_ais(batch, t, source_file=SRC, topic=TOPIC).static.num_rows > 0
    monkeypatch.setattr(ais, "FAST", True)
    with pytest.raises(AssertionError, match="vectorised path ran"):
        ais.decode_ais(batch, t, source_file=SRC, topic=TOPIC)


def test_samples_and_edge_cases() -> None:
    f1, f2 = TYPE5_FRAGMENTS
    batch = [AIS_TYPE1, AIS_TYPE3, f1, AIS_TYPE18, f2, AIS_EMPTY, AIS_TYPE1.lower(),
             AIS_TYPE1 + b" ", b"\\c:1635731889*6A\\" + AIS_TYPE1, AIS_TYPE1[:-2] + b"00"]
    same(*both(batch))


@pytest.mark.parametrize("seed", range(4))
def test_fuzzed_batches(region_sentences, seed: int) -> None:
    """Corrupted characters, checksums, fill bits, channels; multi-part groups broken by
    runs of single sentences (fragment gaps count every sentence on both paths)."""
    rng = np.random.default_rng(seed)
    picked = [region_sentences[i] for i in rng.integers(0, len(region_sentences), 600)]
    out = []
    f1, f2 = TYPE5_FRAGMENTS
    for k, s in enumerate(picked):
        b = bytearray(s)
        u = rng.random()
        if u < 0.1 and len(b) > 42:
            b[int(rng.integers(14, 42))] = int(rng.integers(32, 127))  # payload char
        elif u < 0.15:
            b[-1] = ord("0") if b[-1] != ord("0") else ord("1")  # checksum
        elif u < 0.18 and len(b) == 47:
            b[43] = ord("2")  # fill bits
        elif u < 0.2:
            b[12] = ord("1")  # channel written as a digit
        out.append(bytes(b))
        if k % 50 == 0:
            out.append(f1)
        if k % 50 == int(rng.integers(1, 12)):
            out.append(f2)
    fast, ref = both(out)
    same(fast, ref)
    fast, ref = both(out, final=False)
    same(fast, ref)


def _real_ais_files() -> list[str]:
    folder = real_data_root() / "ais"
    return sorted(p.name for p in folder.glob("*") if p.is_file()) or ["(none)"]


@pytest.mark.realdata
@pytest.mark.parametrize("name", _real_ais_files())
def test_real_ais_files(name: str) -> None:
    """Every real AIS log: same tables, and every message 5 / 24 row from the vectorised
    path (type 19 rows and type 24 part numbers 2, 3 stay with pyais)."""
    path = real_data_root() / "ais" / name
    if not path.is_file():
        pytest.skip(f"real AIS recordings absent: no files in {path.parent} "
                    "(not part of the repository; set SURVEIL_REAL_DATA)")
    lines = [ln for ln in path.read_bytes().splitlines() if ln.strip()]
    fast, ref = both(lines)
    same(fast, ref)
    assert static_taken(lines).size == static_rows_5_24(fast)


def test_empty() -> None:
    fast, ref = both([])
    assert fast.reports.num_rows == 0 and isinstance(fast.reports, pa.Table)
    same(fast, ref)


# -- fuzzed static messages: ITU-R M.1371-5 message 5 and message 24 parts A / B, built bit
# by bit, then damaged (lengths, fill bits, part numbers, text, fragments, characters)

SIXBIT = "@ABCDEFGHIJKLMNOPQRSTUVWXYZ[\\]^_ !\"#$%&'()*+,-./0123456789:;<=>?"
NAMES = ["", "@@@@", "    ", "A", " A", "A ", "A@", "@A", "A @ @", "A @ @ @", " @ A@ ",
         "NORDIC STAR", "NORDIC STAR@@@@", "NORDIC STAR  @@", "@@ @", "A B  C@ @@ ", "?!,.-"]


def _uint(value: int, width: int) -> str:
    return format(value & ((1 << width) - 1), f"0{width}b")


def _text(rng: np.random.Generator, n_chars: int) -> str:
    """6-bit text bits: a known tricky name, or characters with many '@' and spaces."""
    if rng.random() < 0.4:
        text = NAMES[int(rng.integers(len(NAMES)))]
    else:
        pick = rng.choice(3, n_chars, p=[0.3, 0.3, 0.4])
        text = "".join("@" if k == 0 else " " if k == 1 else SIXBIT[int(rng.integers(64))]
                       for k in pick)
    text = (text + "@" * n_chars)[:n_chars]
    return "".join(_uint(SIXBIT.index(c), 6) for c in text)


def _mmsi(rng: np.random.Generator) -> int:
    u = rng.random()
    if u < 0.2:
        return int(rng.integers(980_000_000, 990_000_000))  # auxiliary craft
    return int(rng.integers(0, 1 << 30)) if u < 0.3 else int(rng.integers(2 * 10**8, 8 * 10**8))


def _message_5(rng: np.random.Generator) -> str:
    small = lambda w: _uint(int(rng.integers(0, 1 << w)) if rng.random() < 0.8 else 0, w)  # noqa: E731
    return (_uint(5, 6) + small(2) + _uint(_mmsi(rng), 30) + small(2) + small(30)
            + _text(rng, 7) + _text(rng, 20) + small(8) + small(9) + small(9) + small(6)
            + small(6) + small(4) + small(4) + small(5) + small(5) + small(6) + small(8)
            + _text(rng, 20) + small(1) + small(1))  # 424 bits


def _message_24(rng: np.random.Generator) -> str:
    part = int(rng.choice(4, p=[0.4, 0.4, 0.1, 0.1]))
    head = _uint(24, 6) + _uint(int(rng.integers(4)), 2) + _uint(_mmsi(rng), 30) + _uint(part, 2)
    if part == 0 or (part > 1 and rng.random() < 0.5):
        return head + _text(rng, 20) + ("" if rng.random() < 0.5 else "0" * 8)  # 160 / 168
    dims = "".join(_uint(int(rng.integers(0, 1 << w)) if rng.random() < 0.8 else 0, w)
                   for w in (9, 9, 6, 6))
    return (head + _uint(int(rng.integers(256)), 8) + _uint(int(rng.integers(1 << 42)), 42)
            + _text(rng, 7) + dims + "0" * 6)  # 168 bits


def _damaged_length(rng: np.random.Generator, bits: str) -> str:
    if rng.random() < 0.6:
        return bits
    d = int(rng.choice([-30, -12, -7, -6, -4, -2, -1, 1, 2, 4, 6, 8, 12, 30]))
    return bits[:d] if d < 0 else bits + "".join(rng.choice(["0", "1"], d))


def _armour(bits: str) -> tuple[str, int]:
    """Payload characters and the true fill bits."""
    fill = -len(bits) % 6
    bits += "0" * fill
    values = [int(bits[i:i + 6], 2) for i in range(0, len(bits), 6)]
    return "".join(chr(v + 48 if v < 40 else v + 56) for v in values), fill


def _fragments(rng: np.random.Generator, bits: str, seq: int) -> list[bytes]:
    """The message as 1-3 VDM sentences; the fill bits are the true ones or (sometimes)
    any of 0-5; sometimes an invalid armour character."""
    payload, fill = _armour(bits)
    if rng.random() < 0.3:
        fill = int(rng.integers(6))
    if rng.random() < 0.03:
        k = int(rng.integers(len(payload)))
        payload = payload[:k] + "X^~x"[int(rng.integers(4))] + payload[k + 1:]
    n = 1 if len(payload) < 40 and rng.random() < 0.8 else int(rng.choice([1, 2, 2, 2, 3]))
    cuts = sorted(int(c) for c in rng.choice(np.arange(1, len(payload)), n - 1, replace=False))
    if n > 1 and rng.random() < 0.1:
        cuts[0] = 1  # a one-character first fragment: with fill bits, another message id
    parts = [payload[a:b] for a, b in zip([0, *cuts], [*cuts, len(payload)], strict=True)]
    channel = "AB"[int(rng.integers(2))]
    seq_field = str(seq % 10) if n > 1 else ""
    out = []
    for i, part in enumerate(parts, 1):
        f = fill if i == n else (int(rng.integers(6)) if rng.random() < 0.2 else 0)
        out.append(sentence(f"AIVDM,{n},{i},{seq_field},{channel},{part},{f}", start="!"))
    return out


def fuzzed_static_batch(rng: np.random.Generator, others: list[bytes], n: int) -> list[bytes]:
    """``n`` static messages between position reports, some fragments lost, repeated or
    far apart (truncated groups)."""
    out: list[bytes] = []
    for seq in range(n):
        bits = _message_5(rng) if rng.random() < 0.5 else _message_24(rng)
        frags = _fragments(rng, _damaged_length(rng, bits), seq)
        u = rng.random()
        if len(frags) > 1 and u < 0.05:
            del frags[int(rng.integers(len(frags)))]  # a lost fragment
        elif len(frags) > 1 and u < 0.08:
            frags.insert(1, frags[0])  # a repeated first fragment
        for k, frag in enumerate(frags):
            if k and rng.random() < 0.1:  # other traffic between the fragments, >8 sometimes
                out.extend(others[i] for i in rng.integers(0, len(others),
                                                           int(rng.integers(1, 12))))
            out.append(frag)
        out.extend(others[i] for i in rng.integers(0, len(others), int(rng.integers(0, 3))))
    return out


@pytest.mark.parametrize("seed", range(6))
def test_fuzzed_static_payloads(region_sentences, seed: int) -> None:
    """Random 6-bit text ('@' and spaces anywhere), all 256 ship types, auxiliary-craft
    MMSIs, payloads shorter and longer than standard, fill bits 0-5, part numbers 0-3,
    1-3 fragments, lost and repeated fragments, invalid characters."""
    rng = np.random.default_rng(100 + seed)
    reports = [s for s in region_sentences[:4000] if s.startswith(b"!AIVDM,1,1,")]
    batch = fuzzed_static_batch(rng, reports, 400)
    fast, ref = both(batch)
    same(fast, ref)
    taken = static_taken(batch).size
    assert 0.4 * fast.static.num_rows < taken < fast.static.num_rows  # both paths used
    assert (pc.match_substring(fast.rejects["reason"], "Partno").to_numpy(zero_copy_only=False)
            .any())  # part numbers 2 and 3 stay with pyais: rejected there
    fast, ref = both(batch, final=False)
    same(fast, ref)
    same(*both(batch, step_ns=0))


def test_static_text_trimming() -> None:
    """Each tricky name as message 24 part A and as message 5 call sign / name /
    destination, one batch: pyais's '@' and space rules, exactly."""
    rng = np.random.default_rng(0)
    batch = []
    for k, name in enumerate(NAMES):
        text = "".join(_uint(SIXBIT.index(c), 6) for c in (name + "@" * 20)[:20])
        head = _uint(24, 6) + "00" + _uint(300_000_000 + k, 30) + "00"
        batch.append(_fragments_exact(head + text, seq=k))
        five = (_uint(5, 6) + "00" + _uint(300_000_000 + k, 30) + "00" + _uint(k, 30)
                + text[:42] + text + _message_5(rng)[232:302] + text + "00")
        batch.append(_fragments_exact(five, seq=k))
    lines = [s for frags in batch for s in frags]
    fast, ref = both(lines)
    same(fast, ref)
    assert static_taken(lines).size == fast.static.num_rows == 2 * len(NAMES)
    names = fast.static.filter(pc.equal(fast.static["msg_type"], 24))["shipname"].to_pylist()
    assert {"": None, "A @ @ @": "A @", " @ A@ ": "@ A", "@@ @": None}.items() <= dict(
        zip(NAMES, names, strict=True)).items()


def _fragments_exact(bits: str, seq: int) -> list[bytes]:
    """The message with its true fill bits: one sentence, or two (60 characters first)."""
    payload, fill = _armour(bits)
    if len(payload) <= 60:
        return [sentence(f"AIVDM,1,1,,A,{payload},{fill}", start="!")]
    return [sentence(f"AIVDM,2,1,{seq % 10},A,{payload[:60]},0", start="!"),
            sentence(f"AIVDM,2,2,{seq % 10},A,{payload[60:]},{fill}", start="!")]
