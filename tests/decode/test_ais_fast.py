"""The vectorised AIS position-report path against the pyais path: identical tables
(reports, static, rejects, not-stored counts, carry) on simulated traffic, the test
samples, the real sample file and fuzzed batches."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from mcap_fixtures import AIS_EMPTY, AIS_TYPE1, AIS_TYPE3, AIS_TYPE18, T0_NS, TYPE5_FRAGMENTS

from pipeline.decode import ais
from pipeline.simulate.region import RegionSimulation
from pipeline.simulate.region_layout import region_layout

SRC, TOPIC = "/arch/f.mcap", "/ais/nmea"


def both(sentences: list[bytes], final: bool = True) -> tuple[ais.AisDecoded, ais.AisDecoded]:
    t = T0_NS + np.arange(len(sentences), dtype=np.int64) * 10**6
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


@pytest.fixture(scope="module")
def region_sentences() -> list[bytes]:
    sim = RegionSimulation(region_layout(2), n_ships=150, seed=4, start_ns=T0_NS,
                           duration_s=600.0)
    return [s for sl in sim.slices() for s in sl.ais_sentences["sentence"].to_list()]


def test_region_traffic(region_sentences) -> None:
    fast, ref = both(region_sentences)
    assert fast.reports.num_rows > 3000 and fast.static.num_rows > 50
    assert ais.fast_positions(region_sentences).index.size > 0.9 * fast.reports.num_rows
    same(fast, ref)


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


def test_real_sample_file() -> None:
    from mcap_fixtures import real_data_root

    path = real_data_root() / "ais" / "pyais_nmea_data_sample.txt"
    if not path.is_file():
        pytest.skip(f"real data absent: {path}")
    lines = [ln for ln in path.read_bytes().splitlines() if ln.strip()]
    same(*both(lines))


def test_empty() -> None:
    fast, ref = both([])
    assert fast.reports.num_rows == 0 and isinstance(fast.reports, pa.Table)
    same(fast, ref)
