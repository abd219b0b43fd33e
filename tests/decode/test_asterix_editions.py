"""ASTERIX editions other than the shipped ones (pipeline/decode/asterix_editions.py):
records encoded here by hand in CAT010 0.24, CAT021 0.26 and CAT062 0.17 (FSPEC by FRN
of each edition's UAP, items in their octet layouts), detected from the data or chosen
by config / channel metadata."""

from __future__ import annotations

import math
import os
import struct

import numpy as np
import pytest

pytest.importorskip("asterix")
from test_asterix import block, fspec

from pipeline.config import ConfigError
from pipeline.convert.config import parse_editions
from pipeline.decode.asterix import (
    AsterixChannelDecoder,
    decode_asterix,
    restore_default_editions,
)
from pipeline.decode.asterix_editions import EDITIONS, known_editions
from pipeline.io.mcap_read import ChannelBatch
from pipeline.units import NS

T0 = 1_772_359_200 * NS  # 2026-03-01T10:00:00Z
DAY0 = T0 - T0 % (86_400 * NS)


@pytest.fixture(autouse=True)
def _default_editions_after_each_test():
    yield
    restore_default_editions()  # asterix_decoder's definitions are process-wide


def record(uap: tuple[str, ...], items: dict[str, bytes]) -> bytes:
    """FSPEC from the FRN of each item in ``uap`` + the items in FRN order."""
    frns = sorted(uap.index(k) + 1 for k in items)
    return fspec(frns) + b"".join(items[uap[f - 1]] for f in frns)


def s24(v: int) -> bytes:
    return (v & 0xFFFFFF).to_bytes(3, "big")


def cat010_024(tod: float, lat: float, lon: float, x: int, y: int, vx: int, vy: int,
               track: int) -> bytes:  # fmt: skip
    uap = EDITIONS[10]["0.24"].uap
    k = 2**31 / 180
    v = ((vx & 0xFFF) << 12) | (vy & 0xFFF)
    return record(uap, {
        "010": b"\x00\x07", "000": b"\x01", "020": bytes([0x00]),
        "140": round(tod * 128).to_bytes(3, "big"),
        "041": struct.pack(">ii", round(lat * k), round(lon * k)),
        "042": struct.pack(">hh", x, y), "202": v.to_bytes(3, "big"),
        "161": track.to_bytes(2, "big"), "500": bytes([10, 13]) + struct.pack(">h", -4),
    })  # fmt: skip


def cat021_026(tod: float, lat: float, lon: float, address: int) -> bytes:
    uap = EDITIONS[21]["0.26"].uap
    k = 2**25 / 180
    return record(uap, {
        "010": b"\x00\x05", "040": b"\x01\x20", "030": round(tod * 128).to_bytes(3, "big"),
        "130": struct.pack(">ii", round(lat * k), round(lon * k)),
        "080": address.to_bytes(3, "big"), "090": b"\x00\x08", "095": b"\x02",
        "131": b"\xf0",
    })  # fmt: skip


def cat062_017(tod: float, lat: float, lon: float, x_nm: float, y_nm: float, spd_mps: float,
               hdg_deg: float, track: int) -> bytes:  # fmt: skip
    uap = EDITIONS[62]["0.17"].uap
    k = 2**23 / 180
    spd = round(spd_mps / 1852 * 2**14)
    return record(uap, {
        "010": bytes([25, 100]), "070": round(tod * 128).to_bytes(3, "big"),
        "040": track.to_bytes(2, "big"),
        "105": s24(round(lat * k)) + s24(round(lon * k)),
        "100": struct.pack(">hh", round(x_nm * 64), round(y_nm * 64)),
        "180": struct.pack(">HH", spd, round(hdg_deg / 360 * 2**16)),
        "080": b"\x40",  # one octet of track status
        "380": b"\x40" + (0x3C4A12).to_bytes(3, "big"),  # I380 subfield 2: address
        "290": b"\x81\x40" + b"\x05\x06",  # I290 subfields 1 (PSR) and 9 (MD2)
    })  # fmt: skip


def decode(payloads, **kw):
    return decode_asterix(payloads, [T0] * len(payloads), source_file="f", topic="/t", **kw)


def test_cat010_024_detected_and_decoded():
    rec = cat010_024(36_000.5, 25.6226, 22.1755, -1423, 1368, -8, 1, 922)
    out = decode([block(10, rec)])
    assert out.rejects.num_rows == 0
    (r,) = out.obs.to_pylist()
    assert (r["sac"], r["sic"], r["track_number"]) == (0, 7, 922)
    assert r["lat_deg"] == pytest.approx(25.6226, abs=1e-7)
    assert r["lon_deg"] == pytest.approx(22.1755, abs=1e-7)
    assert (r["x_m"], r["y_m"], r["vx_mps"], r["vy_mps"]) == (-1423.0, 1368.0, -8.0, 1.0)
    assert (r["sigma_x_m"], r["sigma_y_m"]) == (2.5, 3.25)
    assert r["time_ns"] == DAY0 + round(36_000.5 * NS)


def test_cat021_026_detected_and_decoded():
    out = decode([block(21, cat021_026(14_418.484375, 38.7773, -9.1312, 4811822))])
    assert out.rejects.num_rows == 0
    (r,) = out.obs.to_pylist()
    assert (r["sac"], r["sic"], r["target_address"]) == (0, 5, 4811822)
    assert r["lat_deg"] == pytest.approx(38.7773, abs=1e-5)
    assert r["lon_deg"] == pytest.approx(-9.1312, abs=1e-5)
    assert r["time_ns"] == DAY0 + round(14_418.484375 * NS)


def test_cat062_017_detected_and_decoded():
    rec = cat062_017(36_001.0, 44.2689, 18.2299, -12.5, 30.25, 212.0, 285.0, 894)
    out = decode([block(62, rec, rec)])
    assert out.rejects.num_rows == 0
    r = out.obs.to_pylist()[0]
    assert (r["sac"], r["sic"], r["track_number"]) == (25, 100, 894)
    assert r["lat_deg"] == pytest.approx(44.2689, abs=3e-5)  # LSB 180/2^23 deg
    assert r["lon_deg"] == pytest.approx(18.2299, abs=3e-5)
    assert (r["x_m"], r["y_m"]) == (-12.5 * 1852, 30.25 * 1852)
    assert math.hypot(r["vx_mps"], r["vy_mps"]) == pytest.approx(212.0, abs=0.12)
    assert math.degrees(math.atan2(r["vx_mps"], r["vy_mps"])) % 360 == pytest.approx(285.0,
                                                                                     abs=0.01)
    assert r["time_ns"] == DAY0 + 36_001 * NS


def test_shipped_editions_still_come_first():
    assert known_editions(62) == ["1.18", "0.17"] and known_editions(10) == ["1.1", "0.24"]
    assert known_editions(48) == ["1.21"]


def test_a_forced_edition_is_the_only_one_tried():
    rec = cat062_017(36_001.0, 44.2689, 18.2299, -12.5, 30.25, 212.0, 285.0, 894)
    out = decode([block(62, rec)], editions={62: "1.18"})
    assert out.obs.num_rows == 0
    (reason,) = out.rejects["reason"].to_pylist()
    assert "editions tried" not in reason  # one edition, no detection
    meta = {"asterix_editions": "062=0.17"}
    assert decode([block(62, rec)], metadata=meta).obs.num_rows == 1


def test_the_channel_learns_its_edition_and_mixed_editions_decode():
    new = block(10, bytes.fromhex("f0") + b"\x00\x07" + b"\x01" + b"\x60" +
                round(36_000.0 * 128).to_bytes(3, "big"))  # fmt: skip  # ed 1.1 status-less
    old = block(10, cat010_024(36_000.5, 25.6, 22.1, 1, 2, 3, 4, 5))
    dec = AsterixChannelDecoder("f", "/t")
    batch = ChannelBatch(1, "/t", "asterix", "", "", b"", np.array([T0, T0]), [old, old])
    out = dec.feed(batch)
    assert out["airfield_obs"].num_rows == 2 and dec.learned == {10: "0.24"}
    batch = ChannelBatch(1, "/t", "asterix", "", "", b"", np.array([T0]), [new])
    dec.feed(batch)  # another edition on the same channel still decodes
    assert dec.learned[10] in ("1.1", "0.24")


def test_config_editions_are_validated():
    assert parse_editions({"editions": {"010": "0.24", "62": "0.17"}}) == {10: "0.24", 62: "0.17"}
    with pytest.raises(ConfigError, match=r"CAT021 edition '9\.9' is not one we decode"):
        parse_editions({"editions": {"021": "9.9"}})


def test_a_process_leaves_no_definition_file_behind(tmp_path):
    """The definition files handed to asterix_decoder live while the process does: a
    nightly run must not leave its CAT048/065 and edition files in the temporary folder."""
    import subprocess
    import sys

    code = ("import os, tempfile\n"
            "from pipeline.decode.asterix import use_edition\n"
            "use_edition(10, '0.24')\n"
            "print(len(os.listdir(tempfile.gettempdir())))\n")
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, check=True)
    assert int(done.stdout.strip().splitlines()[-1]) >= 1  # the folder while it ran
    assert list(tmp_path.iterdir()) == []
