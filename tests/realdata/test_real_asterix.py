"""Every real ASTERIX file of ``../shared/data/real/asterix`` imported and ingested.

Expected counts are established without the decoder under test:

- data blocks per file: counted here from the LEN fields (raw files) and from the UDP
  payloads of the captures (a minimal Ethernet/IPv4/UDP walk written below);
- records per block: the jASTERIX unit tests of every ``jasterix_single_records`` file
  assert ``num_records == 1`` (hpuhr/jASTERIX ``src/test/test_cat*.cpp``); the
  CroatiaControl ``cat_062_065.pcap`` holds 2 CAT062 + 1 CAT065 records (its reference
  decode); ``croatiacontrol_cat062cat065.raw`` holds 2 CAT062 records (the second
  record's FSPEC ``bf df ff 02`` and SAC/SIC ``19 64`` start at byte 0x43 of the file) and
  1 CAT065 record; the other CroatiaControl raw files hold one record per block;
- editions: SOURCES.md and the jASTERIX file names give each block's edition; the blocks
  of editions the shipped decoder does not read (CAT010 0.24 Sensis, CAT021 0.26, the
  2008 CAT062 capture, pre-1.0) are decoded with the editions we declare
  (``pipeline/decode/asterix_editions.py``) and checked against jASTERIX's tests.
"""

from __future__ import annotations

import json
import math
import struct
from collections import Counter
from datetime import UTC, datetime
from pathlib import Path

import pytest

from pipeline.families import load_config
from pipeline.units import NS
from tests.real_data import real_data_dir

pytestmark = pytest.mark.realdata
SERVICE = {2, 19, 23, 25, 31, 34, 63, 65, 247, 252}
SUPPORTED = {10, 20, 21, 48, 62} | SERVICE
OTHER_EDITION: set[str] = set()  # every edition of the samples is decoded now
# records per block where a file's blocks hold more than one (see the module docstring)
RECORDS = {
    "croatiacontrol_cat_062_065.pcap": {62: 2, 65: 1},
    "croatiacontrol_cat062cat065.raw": {62: 2, 65: 1},
}


def asterix_files(root: Path) -> list[Path]:
    base = root / "asterix"
    files = [p for p in sorted(base.iterdir()) if p.is_file()]
    return files + sorted((base / "jasterix_single_records").glob("*.bin"))


def _frame(data: bytes) -> list[int]:
    """Categories of the consecutive data blocks of ``data`` (must frame exactly)."""
    cats, pos = [], 0
    while pos < len(data):
        n = int.from_bytes(data[pos + 1 : pos + 3], "big")
        assert n >= 3 and pos + n <= len(data), "real sample does not frame"
        cats.append(data[pos])
        pos += n
    return cats


def block_categories(path: Path) -> list[int]:
    """Independent count: categories of every data block in a raw file or a capture."""
    data = path.read_bytes()
    if path.suffix != ".pcap":
        return _frame(data)
    assert data[:4] == b"\xd4\xc3\xb2\xa1"  # little-endian libpcap, Ethernet (checked below)
    assert struct.unpack_from("<I", data, 20)[0] == 1
    cats, pos = [], 24
    while pos < len(data):
        incl = struct.unpack_from("<I", data, pos + 8)[0]
        frame = data[pos + 16 : pos + 16 + incl]
        assert frame[12:14] == b"\x08\x00" and frame[14] == 0x45 and frame[23] == 17
        cats += _frame(frame[14 + 20 + 8 :])
        pos += 16 + incl
    return cats


def expected(path: Path) -> tuple[int, int, Counter, Counter]:
    """(airfield_obs rows, asterix_service rows, rejects per reason, not stored per type)
    for one file: categories we do not decode are counted in the ledger, not rejected."""
    cats = block_categories(path)
    per = RECORDS.get(path.name, {})
    obs = svc = 0
    rejects: Counter = Counter()
    not_stored = Counter(f"asterix_cat{c:03d}" for c in cats if c not in SUPPORTED)
    for c in cats:
        if c not in SUPPORTED:
            continue
        if path.name in OTHER_EDITION:
            rejects["other_edition"] += 1
        elif c in SERVICE:
            svc += per.get(c, 1)
        else:
            obs += per.get(c, 1)
    return obs, svc, +rejects, not_stored


@pytest.fixture(scope="module")
def ingested(tmp_path_factory):
    from pipeline.convert.asterix import wrap_asterix_file
    from pipeline.ingest.driver import run_ingest
    from pipeline.warehouse.delta import read_table

    root = real_data_dir()
    tmp = tmp_path_factory.mktemp("real_asterix")
    files = asterix_files(root)
    wrapped = {wrap_asterix_file(p, tmp / "mcap"): p for p in files}
    summary = run_ingest(list(wrapped), load_config(), tmp / "wh", executor="serial")
    tables = {n: read_table(tmp / "wh", n) for n in ("airfield_obs", "asterix_service",
                                                     "rejects", "ingest_ledger")}  # fmt: skip
    by_source = {str(k.resolve()): v for k, v in wrapped.items()}
    return files, summary, tables, by_source


def _rows_of(table, by_source) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for r in table.to_pylist():
        out.setdefault(by_source[r["source_file"]].name, []).append(r)
    return out


def test_every_file_ingests_with_the_expected_counts(ingested):
    files, summary, tables, by_source = ingested
    assert summary.files_ok == len(files) == 25 and not summary.failed
    obs = _rows_of(tables["airfield_obs"], by_source)
    svc = _rows_of(tables["asterix_service"], by_source)
    rej = _rows_of(tables["rejects"], by_source)
    ledger = _rows_of(tables["ingest_ledger"], by_source)
    for path in files:
        n_obs, n_svc, reasons, not_stored = expected(path)
        assert json.loads(ledger[path.name][0]["not_stored_json"]) == dict(not_stored)
        got = Counter(r["reason_code"] for r in rej.get(path.name, []))
        other = got.pop("undecodable", 0) + got.pop("out_of_range", 0)
        assert len(obs.get(path.name, [])) == n_obs, path.name
        assert len(svc.get(path.name, [])) == n_svc, path.name
        assert other == reasons.pop("other_edition", 0), path.name
        assert got == reasons, path.name


def test_unsupported_categories_are_counted_per_block_in_the_ledger(ingested):
    _, _, tables, by_source = ingested
    assert "cat004ed1.4.bin" not in _rows_of(tables["rejects"], by_source)
    (led,) = _rows_of(tables["ingest_ledger"], by_source)["cat004ed1.4.bin"]
    assert json.loads(led["not_stored_json"]) == {"asterix_cat004": 3}  # three blocks


@pytest.mark.parametrize("name", ["cat002ed1.0.bin", "cat019ed1.3.bin", "cat063ed1.0.bin",
                                  "cat247ed1.2.bin", "cat252ed7.0.bin"])  # fmt: skip
def test_service_categories_land_in_asterix_service(ingested, name):
    _, _, tables, by_source = ingested
    (row,) = _rows_of(tables["asterix_service"], by_source)[name]
    assert row["asterix_category"] == int(name[3:6])


def test_croatiacontrol_reference_decode_matches_field_by_field(ingested):
    root = real_data_dir()
    _, _, tables, by_source = ingested
    ref = [json.loads(line) for line in
           (root / "asterix" / "reference_decodes" / "croatiacontrol_cat_062_065_json.txt")
           .read_text().splitlines() if line.strip()]  # fmt: skip
    obs = {r["track_number"]: r for r in
           _rows_of(tables["airfield_obs"], by_source)["croatiacontrol_cat_062_065.pcap"]}
    day = int(datetime(2014, 2, 25, tzinfo=UTC).timestamp()) * NS  # capture date
    cat062 = [r["CAT062"] for r in ref if r["cat"] == 62]
    assert len(cat062) == len(obs) == 2
    for item in cat062:
        r = obs[item["I040"]["TrkN"]]
        assert (r["sac"], r["sic"]) == (item["I010"]["SAC"], item["I010"]["SIC"])
        assert r["time_ns"] == day + round(item["I070"]["ToT"] * NS)
        assert r["lat_deg"] == pytest.approx(item["I105"]["Lat"], abs=1e-7)  # 7 decimals
        assert r["lon_deg"] == pytest.approx(item["I105"]["Lon"], abs=1e-7)
        assert (r["x_m"], r["y_m"]) == (item["I100"]["X"], item["I100"]["Y"])
        assert (r["vx_mps"], r["vy_mps"]) == (item["I185"]["Vx"], item["I185"]["Vy"])
        assert r["target_address"] == int(item["I380"]["ADR"]["ADR"], 16)
        assert r["callsign"] == item["I380"]["ID"]["ACID"].strip()
        assert r["sensor_kind"] == "system_track" and r["asterix_category"] == 62
    (svc,) = _rows_of(tables["asterix_service"], by_source)["croatiacontrol_cat_062_065.pcap"]
    (item,) = [r["CAT065"] for r in ref if r["cat"] == 65]
    assert (svc["sac"], svc["sic"]) == (item["I010"]["SAC"], item["I010"]["SIC"])
    assert svc["message_type"] == {1: "sdps status", 2: "end of batch"}[item["I000"]["Typ"]]
    assert svc["service_id"] == item["I015"]["SID"]
    assert svc["batch_number"] == item["I020"]["BTN"]
    assert svc["time_ns"] == day + round(item["I030"]["ToD"] * NS)


def test_cat010_edition_024_matches_the_jasterix_expectations(ingested):
    """hpuhr/jASTERIX src/test/test_cat010_0.24_sensis.cpp."""
    _, _, tables, by_source = ingested
    (r,) = _rows_of(tables["airfield_obs"], by_source)["cat010ed0.24_sensis.bin"]
    assert (r["sac"], r["sic"], r["track_number"]) == (0, 0, 922)
    assert r["lat_deg"] == pytest.approx(25.62264827080070972443, abs=1e-10)
    assert r["lon_deg"] == pytest.approx(22.1754983067512512207, abs=1e-10)
    assert (r["x_m"], r["y_m"]) == (-1423.0, 1368.0)
    assert (r["vx_mps"], r["vy_mps"]) == (-8.0, 1.0)
    assert r["target_address"] == 4672673
    assert (r["sigma_x_m"], r["sigma_y_m"]) == (2.5, 3.25)
    assert r["time_ns"] == round(84080.484375 * NS)


def test_cat021_edition_026_matches_the_jasterix_expectations(ingested):
    """hpuhr/jASTERIX src/test/test_cat021_0.26.cpp."""
    _, _, tables, by_source = ingested
    (r,) = _rows_of(tables["airfield_obs"], by_source)["cat021ed0.26.bin"]
    assert (r["sac"], r["sic"], r["target_address"]) == (0, 5, 4811822)
    assert r["lat_deg"] == pytest.approx(38.77732336521148681641, abs=1e-12)
    assert r["lon_deg"] == pytest.approx(-9.131237268447875976563, abs=1e-12)
    assert r["time_ns"] == round(14418.484375 * NS)


def test_2008_cat062_capture_decodes_with_the_pre_1_0_edition(ingested):
    """The 2008 CroatiaControl capture: 100 system tracks of SAC/SIC 25/100, each within
    a second of its capture time, over the Adriatic / Balkans, at airliner speeds."""
    _, _, tables, by_source = ingested
    rows = _rows_of(tables["airfield_obs"], by_source)["croatiacontrol_asterix.pcap"]
    assert len(rows) == 100 and {(r["sac"], r["sic"]) for r in rows} == {(25, 100)}
    assert all(abs(r["time_ns"] - r["log_time_ns"]) < NS for r in rows)
    assert all(40 < r["lat_deg"] < 48 and 12 < r["lon_deg"] < 22 for r in rows)
    speeds = [math.hypot(r["vx_mps"], r["vy_mps"]) for r in rows if r["vx_mps"] is not None]
    assert len(speeds) > 50 and 50 < sorted(speeds)[len(speeds) // 2] < 300


def test_cat010_matches_the_jasterix_expectations(ingested):
    """hpuhr/jASTERIX src/test/test_cat010_0.31.cpp: the record's documented values."""
    _, _, tables, by_source = ingested
    (r,) = _rows_of(tables["airfield_obs"], by_source)["cat010ed0.31.bin"]
    assert (r["sac"], r["sic"], r["track_number"]) == (0, 1, 4)
    assert r["sensor_kind"] == "smr"  # I020 TYP = 3 (PSR)
    assert r["range_m"] == 1588.0
    # I040 THETA = 34499 LSB of 360/2^16 deg; jASTERIX prints 189.50866690594 (its factor
    # is rounded, 1e-7 deg off), we keep the exact LSB
    assert r["azimuth_rad"] == pytest.approx(math.radians(189.50866690594), abs=1e-8)
    assert r["azimuth_rad"] == math.radians(34499 * 360 / 65536)
    assert (r["x_m"], r["y_m"]) == (-267.0, -1566.0)
    assert (r["vx_mps"], r["vy_mps"]) == (-0.5, 0.0)
    # raw file: no capture date, log time = 1970-01-01 + time of day (log_time_source)
    assert r["time_ns"] == round(24693.140625 * NS) == r["log_time_ns"]
