"""Every real NMEA / AIS text log and AIS CSV in ../shared/data/real/{ais,ais/csv,nav,radar}
is wrapped by ``surveil import`` and ingested into a Delta warehouse; per file, rows per
table and rejects per reason must equal counts established here by reading the files
with a separate, deliberately plain reader (line splitting, XOR checksums, a 6-bit AIS
bit reader, the csv module), plus facts from SOURCES.md. ``gpsd_sample.aivdm`` is checked
against the decoded values its ``#`` comments document; tag-block files against ``c:``.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from collections import Counter
from pathlib import Path

import polars as pl
import pytest

from pipeline.convert.importer import run_import
from pipeline.ingest.driver import run_ingest

pytestmark = pytest.mark.realdata

KN = 1852.0 / 3600.0
DIRS = ("ais", "ais/csv", "nav", "radar")
NAV = {  # formatter -> (table, measurement field indices: all empty means "no_data")
    "GGA": ("nav_gnss", (1, 3, 5, 6, 7, 8)), "RMC": ("nav_gnss", (1, 2, 4, 6, 7)),
    "VTG": ("nav_gnss", (0, 4, 6)), "GSA": ("nav_gnss", (1, 15)), "GLL": ("nav_gnss", (0, 2)),
    "ZDA": ("nav_gnss", (0,)), "HDT": ("nav_heading", (0,)), "HDM": ("nav_heading", (0,)),
    "HDG": ("nav_heading", (0,)), "THS": ("nav_heading", (0,)), "ROT": ("nav_heading", (0,)),
    "VHW": ("nav_speed_log", (0, 4, 6)), "VBW": ("nav_speed_log", (0, 1, 3, 4)),
    "TTM": ("arpa_targets", (1, 2, 4, 5)), "TLL": ("arpa_targets", (1, 3)),
    "OSD": ("arpa_own_ship", (0, 2, 4, 6, 7)),
}  # fmt: skip
TABLES = ("nav_gnss", "nav_heading", "nav_speed_log", "arpa_targets", "arpa_own_ship",
          "ais_reports", "ais_static", "ais_other_messages")  # fmt: skip


def _real() -> Path:
    from tests.real_data import real_data_dir

    return real_data_dir()


def _inputs(root: Path) -> list[Path]:
    return sorted(p for d in DIRS for p in (root / d).glob("*") if p.is_file())


@pytest.fixture(scope="module")
def warehouse(tmp_path_factory) -> tuple[Path, dict[str, dict[str, int]], dict]:
    from pipeline.families import load_config
    from pipeline.warehouse.delta import read_table

    root = _real()
    tmp = tmp_path_factory.mktemp("real_nmea")
    summary = run_import(_inputs(root), tmp / "mcap")
    assert summary.exit_code == 0 and not summary.skipped, summary.render()
    ingest = run_ingest(sorted((tmp / "mcap").glob("*.mcap")), load_config(), tmp / "wh",
                        executor="serial")  # fmt: skip
    # real logs hold damaged sentences: rejects rows, hence exit 1 (issue 18), no failure
    assert not ingest.failed and ingest.exit_code == (1 if ingest.rejected else 0)
    got: dict[str, Counter] = {}
    frames = {}
    for name in (*TABLES, "rejects"):
        df = pl.from_arrow(read_table(tmp / "wh", name))
        df = df.with_columns(file=pl.col("source_file").str.extract(r"([^/]+)\.mcap$", 1))
        frames[name] = df
        key = [pl.col("file"), pl.lit(name) if name != "rejects" else pl.col("reason_code")]
        for f, k, n in df.group_by(key).len().iter_rows():
            got.setdefault(f, Counter())[k if name == "rejects" else name] += n
    index = pl.from_arrow(read_table(tmp / "wh", "mcap_index"))
    per_file: dict[str, Counter] = {}
    for f, j in index.select("source_file", "not_stored_json").iter_rows():
        per_file.setdefault(Path(f).name.removesuffix(".mcap"), Counter()).update(
            json.loads(j) if j else {}
        )
    got["__index__"] = per_file  # type: ignore[assignment]
    ledger = pl.from_arrow(read_table(tmp / "wh", "ingest_ledger"))
    got["__ledger__"] = {  # type: ignore[assignment]
        Path(f).name.removesuffix(".mcap"): json.loads(j)
        for f, j in ledger.select("source_file", "not_stored_json").iter_rows()
    }
    return root, got, frames


# -- the plain reader --------------------------------------------------------------------


def _lines(path: Path) -> list[str]:
    text = path.read_bytes().decode("latin-1")
    out = [ln.strip() for ln in re.split(r"\r\n|\n|\r", text)]
    return [ln for ln in out if ln and not ln.startswith("#")]


def _xor(s: str) -> int:
    v = 0
    for ch in s:
        v ^= ord(ch)
    return v


def _sentences(path: Path) -> tuple[list[tuple[str, str, list[str]]], Counter]:
    """Good sentences ``(start+address, formatter, fields)`` and reject counts."""
    good, rej = [], Counter()
    for ln in _lines(path):
        if ln.startswith("\\"):
            tag, ln = ln[1:].split("\\", 1)
            body, hh = tag.rsplit("*", 1)
            if _xor(body) != int(hh, 16):
                rej["bad_checksum"] += 1
                continue
        if ln[:1] not in "$!":
            rej["undecodable"] += 1
            continue
        star = ln.find("*")
        body, rest = ln[1:star], ln[star + 1 :]
        hh = re.match(r"[0-9A-Fa-f]{1,2}", rest).group(0)
        trailer = rest[len(hh) :]
        if trailer and not trailer.startswith(","):
            rej["undecodable"] += 1  # text after the checksum (e.g. a literal "\x0d\x0a")
        if _xor(body) != int(hh, 16):
            rej["bad_checksum"] += 1
            continue
        address, *fields = body.split(",")
        good.append((ln[0] + address, address[2:] if address[0] != "P" else address, fields))
    return good, rej


def _bits(payload: str, fill: int) -> str:
    b = "".join(f"{(ord(c) - 48) - 8 * (ord(c) - 48 > 40):06b}" for c in payload)
    return b[: len(b) - fill] if fill else b


def _signed(bits: str) -> int:
    v = int(bits, 2)
    return v - (1 << len(bits)) if bits[0] == "1" else v


_T123 = (61, 28, 89, 27, 600_000)  # lon at, lon bits, lat at, lat bits, units per degree
_T18 = (57, 28, 85, 27, 600_000)
POS = {1: _T123, 2: _T123, 3: _T123, 18: _T18, 19: _T18, 27: (44, 18, 62, 17, 600)}


def _ais_unit(bits: str) -> tuple[set[str], str | None, int | None]:
    """(tables, reject reason, not-stored type) of one complete AIS message."""
    if not bits:
        return set(), "undecodable", None
    t = int(bits[:6], 2)
    if t == 0 or t > 27:
        return set(), "unsupported_type", None
    if t in (5,):
        return {"ais_static"}, None, None
    if t == 24:
        return (
            ({"ais_static"}, None, None)
            if int(bits[38:40], 2) < 2
            else (set(), "undecodable", None)
        )
    if t not in POS:  # every other message: its own table (its MMSI is bits 8-37)
        return ({"ais_other_messages"}, None, None) if len(bits) >= 38 else (
            set(), "undecodable", None)
    lon_at, lon_n, lat_at, lat_n, scale = POS[t]
    lon, lat = _signed(bits[lon_at : lon_at + lon_n]), _signed(bits[lat_at : lat_at + lat_n])
    static = {"ais_static"} if t == 19 else set()
    if lon == 181 * scale or lat == 91 * scale:
        return static, "no_position", None
    if abs(lat) > 90 * scale or abs(lon) > 180 * scale:
        return static, "out_of_range", None
    return {"ais_reports"} | static, None, None


def _ais_counts(sentences: list[tuple[str, str, list[str]]]) -> Counter:
    out: Counter = Counter()
    open_: dict[tuple, list] = {}
    ais = [f for a, fmt, f in sentences if fmt in ("VDM", "VDO")]
    for i, f in enumerate(ais):
        for key in [k for k, g in open_.items() if i - g[0] > 8]:
            out["truncated_multipart"] += 1
            del open_[key]
        n, k, seq, ch, payload, fill = int(f[0]), int(f[1]), f[2], f[3], f[4], int(f[5][:1])
        if n == 1:
            units = [payload]
        else:
            key = (seq, ch, n)
            if k == 1:
                if key in open_:
                    out["truncated_multipart"] += 1
                open_[key] = [i, [payload]]
                continue
            if key not in open_ or len(open_[key][1]) != k - 1:
                out["truncated_multipart"] += 1 + (key in open_)
                open_.pop(key, None)
                continue
            open_[key][0] = i
            open_[key][1].append(payload)
            if k < n:
                continue
            units = ["".join(open_.pop(key)[1])]
        tables, reason, not_stored = _ais_unit(_bits(units[0], fill))
        out.update(tables)
        if reason:
            out[reason] += 1
        if not_stored:
            out[f"not_stored_{not_stored}"] += 1
    out["truncated_multipart"] += len(open_)
    return out


def expected_nmea(path: Path) -> Counter:
    good, want = _sentences(path)
    for _, fmt, fields in good:
        if fmt in NAV:
            table, data = NAV[fmt]
            empty = all((fields[i].strip() if i < len(fields) else "") == "" for i in data)
            want["no_data" if empty else table] += 1
        elif fmt not in ("VDM", "VDO"):  # valid, not decoded: counted in the ledger
            want[f"nmea_{fmt}"] += 1
    want.update(_ais_counts(good))
    return want


def split_not_stored(want: Counter) -> tuple[Counter, Counter]:
    """``(rows and rejects, valid messages not stored)`` of an expectation."""
    rest, not_stored = Counter(), Counter()
    for k, v in want.items():
        if k.startswith("nmea_"):
            not_stored[k] = v
        elif k.startswith("not_stored_"):
            not_stored[f"ais_type_{k.removeprefix('not_stored_')}"] = v
        else:
            rest[k] = v
    return rest, not_stored


def expected_csv(path: Path) -> Counter:
    rows = list(csv.reader(io.StringIO(path.read_text())))
    head = [h.strip().lstrip("#").strip().lower() for h in rows[0]]
    want: Counter = Counter()
    for r in rows[1:]:
        d = dict(zip(head, (c.strip() for c in r), strict=True))
        if d.get("type of mobile") in ("Base Station", "AtoN", "SAR Airborne"):
            want["ais_other_messages"] += 1
            continue
        lat = d.get("latitude_degrees") or d.get("lat") or d.get("latitude")
        lon = d.get("longitude_degrees") or d.get("lon") or d.get("longitude")
        no_pos = not lat or not lon or float(lat) == 91 or float(lon) == 181
        want["no_position" if no_pos else "ais_reports"] += 1
        imo = re.sub(r"\D", "", d.get("imo", "")) or "0"
        texts = [d.get(k, "") for k in ("vesselname", "name", "callsign", "destination")]
        if int(imo) > 0 or any(texts) or float(d.get("vesseltype") or 0) > 0:
            want["ais_static"] += 1
    return want


# -- tests -------------------------------------------------------------------------------


def _files() -> list[str]:
    try:
        return [p.name for p in _inputs(_real())]
    except pytest.skip.Exception:
        return ["(real data absent)"]


@pytest.mark.parametrize("name", _files())
def test_counts_per_file_match_a_plain_reading(warehouse, name):
    root, got, _ = warehouse
    (path,) = [p for p in _inputs(root) if p.name == name]
    want = expected_csv(path) if path.suffix == ".csv" else expected_nmea(path)
    want, not_stored = split_not_stored(want)
    assert dict(got.get(name, Counter())) == dict(+want)
    if path.suffix != ".csv":  # valid but unused sentences: counted per type, not rejected
        assert got["__ledger__"][name] == dict(not_stored)
        assert dict(got["__index__"][name]) == dict(not_stored)  # the channels' sum


def test_sources_md_facts(warehouse):
    root, got, _ = warehouse
    good, rej = _sentences(root / "ais" / "gpsd_ais-nmea.log")
    assert len(good) == 1496 and rej == Counter()  # "all 1 496 checksums ok"
    plaka = got["signalk_plaka_first20000lines.log"]
    assert plaka["no_data"] == 3750  # $IIHDT,,T x2 and $IIHDM,,M per 1 Hz cycle: 1250 cycles
    assert got["opencpn_Hakefjord_L1-120_with_RATTM.log"]["arpa_targets"] == 2
    assert got["stonesoup_SolentAIS_20160112_130211.csv"]["ais_reports"] == 18_623
    assert got["gpsd_nmea-rtk.log"]["nav_gnss"] == 244


def test_rtk_fix_quality_counts(warehouse):
    _, _, frames = warehouse
    gga = frames["nav_gnss"].filter((pl.col("file") == "gpsd_nmea-rtk.log")
                                    & (pl.col("sentence") == "GGA"))  # fmt: skip
    assert dict(Counter(gga["fix_quality"].to_list())) == {2: 104, 4: 18}  # SOURCES.md
    assert set(gga["talker"].to_list()) == {"GP", "GN"}


def test_tag_block_files_use_tag_block_times(warehouse):
    _, _, frames = warehouse
    for name in ("aisdb_test_data_20211101.nm4", "libais_tagblock.nmea"):
        for table in ("ais_reports", "ais_static"):
            df = frames[table].filter(pl.col("file") == name)
            assert df.height > 0
            tags = df["nmea"].str.extract_all(r"\\[^\\]*\\").list.last()  # last fragment's
            c = tags.str.extract(r"[\\,]c:(\d+)", 1).cast(pl.Int64)
            assert (df["time_ns"] == c * 1_000_000_000).all(), (name, table)


def test_nav_times_from_the_sentences(warehouse):
    _, _, frames = warehouse
    rmc = frames["nav_gnss"].filter((pl.col("file") == "gpsd_ais-nmea.log")
                                    & (pl.col("sentence") == "RMC")).sort("time_ns")  # fmt: skip
    assert rmc["time_ns"][0] == 1_586_295_590 * 10**9  # 2020-04-07T21:39:50Z (SOURCES.md)
    assert rmc["time_ns"][-1] == 1_586_295_753 * 10**9  # 21:42:33
    ttm = frames["arpa_targets"].filter(pl.col("file") == "opencpn_Hakefjord_L1-120_with_RATTM.log")
    hours = ((ttm["time_ns"] - ttm["log_time_ns"]) / 3.6e12).to_list()
    assert all(6.3 < h < 6.4 for h in hours)  # the radar clock's 15:41 vs the ship's 09:22


def _oracle(path: Path) -> list[dict]:
    """Each documented single-sentence position report: the sentence and its fields."""
    out, cur = [], None
    for ln in path.read_text(encoding="latin-1").splitlines():
        if ln.startswith("!AIVDM,1,1,"):
            cur = {"nmea": ln.strip()}
            out.append(cur)
        elif ln.startswith("#") and cur is not None and ":" in ln:
            k, v = ln[1:].split(":", 1)
            cur.setdefault(re.sub(r"\s", "", k).lower(), v.strip())
        elif not ln.startswith("#"):
            cur = None
    keep = []
    for d in out:
        mtype = d.get("messageid") or d.get("messagetype")
        if mtype in ("1", "2", "3", "18", "19") and ("latitude" in d):
            keep.append(d)
    return keep


def test_gpsd_sample_decodes_to_its_documented_values(warehouse):
    root, _, frames = warehouse
    docs = _oracle(root / "ais" / "gpsd_sample.aivdm")
    assert len(docs) == 8
    rep = frames["ais_reports"].filter(pl.col("file") == "gpsd_sample.aivdm")
    by_nmea = {r["nmea"]: r for r in rep.to_dicts()}
    for d in docs:
        r = by_nmea[d["nmea"]]
        assert r["mmsi"] == int(d.get("userid") or d["mmsi"])
        assert r["lat_deg"] == pytest.approx(float(d["latitude"]), abs=1e-5)
        assert r["lon_deg"] == pytest.approx(float(d["longitude"]), abs=1e-5)
        sog_kn = float(d["sog"]) if "sog" in d else float(d["speedoverground"]) / 10
        assert r["sog_mps"] == pytest.approx(sog_kn * KN, abs=1e-9)
        cog = float(d["cog"]) if "cog" in d else float(d["courseoverground"]) / 10
        assert r["cog_rad"] == pytest.approx(math.radians(cog), abs=1e-9)
        hdg = int(d.get("trueheading", "511"))
        assert r["heading_rad"] == (None if hdg == 511 else pytest.approx(math.radians(hdg)))
