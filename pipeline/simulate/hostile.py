"""Writers of hostile and damaged inputs (issue 18): the classes ``bench/hostile.py`` runs
and the tests of per-message isolation and salvage build on.

Every writer is deterministic (no RNG without a seed) and returns what a loss-free import
would keep, so that a caller can compare "rows kept" with "rows expected":

- raw ASTERIX (CAT010 data blocks back to back) and the same blocks in pcap / pcapng
  captures (one UDP datagram per block), with :func:`damage_length` to break one LEN /
  record length octet;
- NMEA 0183 text with sentences whose date cannot be represented.

Only the bytes: no file of the pipeline is read or written here but the output.
"""

from __future__ import annotations

import struct
from pathlib import Path

from pipeline.units import NS


def _fspec(frns: list[int]) -> bytes:
    """ASTERIX FSPEC octets for the given field reference numbers (1-based)."""
    n_oct = (max(frns) + 6) // 7
    octs = bytearray(n_oct)
    for frn in frns:
        i, bit = divmod(frn - 1, 7)
        octs[i] |= 0x80 >> bit
    for i in range(n_oct - 1):
        octs[i] |= 1  # FX: another octet follows
    return bytes(octs)


def cat010_record(tod_s: float, x_m: float, y_m: float, track: int) -> bytes:
    """One CAT010 (ed. 1.1) target report: I010/010 SAC/SIC, /000 type, /020 descriptor,
    /140 time of day (1/128 s), /042 Cartesian position (1 m), /161 track number."""
    items = {
        1: bytes([1, 2]),
        2: bytes([1]),
        3: bytes([3 << 5]),
        4: round(tod_s * 128).to_bytes(3, "big"),
        7: struct.pack(">hh", round(x_m), round(y_m)),
        10: struct.pack(">H", track & 0x0FFF),
    }
    return _fspec(sorted(items)) + b"".join(items[k] for k in sorted(items))


def cat010_blocks(n: int, *, tod0_s: float = 36_000.0, step_s: float = 1.0) -> list[bytes]:
    """Data blocks holding ``n`` CAT010 records in all, one per ``step_s``: 1, 2, 3, 1, ...
    records per block (blocks of one length would make the file periodic enough to pass
    for a framed recording)."""
    out, i, k = [], 0, 0
    while i < n:
        m = min(n - i, 1 + k % 3)
        body = b"".join(
            cat010_record(tod0_s + j * step_s, 100.0 + j % 500, -50.0 - j % 300, 1 + j % 50)
            for j in range(i, i + m)
        )
        out.append(bytes([10]) + (len(body) + 3).to_bytes(2, "big") + body)
        i, k = i + m, k + 1
    return out


def damage_length(data: bytes, offset: int, value: int) -> bytes:
    """``data`` with the 2-octet big-endian length field at ``offset`` set to ``value``."""
    return data[:offset] + value.to_bytes(2, "big") + data[offset + 2 :]


def udp_frame(payload: bytes, *, sport: int = 4000, dport: int = 8600) -> bytes:
    """An Ethernet + IPv4 + UDP frame carrying ``payload`` (10.0.0.1 -> 239.1.2.3)."""
    udp = struct.pack(">HHHH", sport, dport, 8 + len(payload), 0) + payload
    ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), 0, 0x4000, 64, 17, 0,
                     bytes([10, 0, 0, 1]), bytes([239, 1, 2, 3])) + udp  # fmt: skip
    return b"\x01\x00\x5e\x01\x02\x03" + b"\x02" * 6 + b"\x08\x00" + ip


def pcap_bytes(frames: list[tuple[int, bytes]]) -> tuple[bytes, list[int]]:
    """A libpcap file (µs, little-endian, Ethernet) of ``(time_ns, frame)``; also the
    offset of each record header."""
    out = bytearray(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1))
    offsets = []
    for t_ns, frame in frames:
        offsets.append(len(out))
        out += struct.pack("<IIII", t_ns // NS, (t_ns % NS) // 1000, len(frame), len(frame))
        out += frame
    return bytes(out), offsets


def pcapng_bytes(frames: list[tuple[int, bytes]]) -> tuple[bytes, list[int]]:
    """A pcapng file (one section, one Ethernet interface in ns) of ``(time_ns, frame)``
    as Enhanced Packet Blocks; also the offset of each packet block."""

    def blk(btype: int, body: bytes) -> bytes:
        body += b"\x00" * (-len(body) % 4)
        n = len(body) + 12
        return struct.pack("<II", btype, n) + body + struct.pack("<I", n)

    out = bytearray(blk(0x0A0D0D0A, struct.pack("<IHHq", 0x1A2B3C4D, 1, 0, -1)))
    tsresol = struct.pack("<HHB3x", 9, 1, 9) + struct.pack("<HH", 0, 0)
    out += blk(1, struct.pack("<HHI", 1, 0, 65535) + tsresol)
    offsets = []
    for t_ns, frame in frames:
        offsets.append(len(out))
        out += blk(6, struct.pack("<IIIII", 0, t_ns >> 32, t_ns & 0xFFFFFFFF, len(frame),
                                  len(frame)) + frame)  # fmt: skip
    return bytes(out), offsets


def nmea_sentence(body: str, start: str = "$") -> str:
    """``<start><body>*hh`` with a correct XOR checksum."""
    ck = 0
    for c in body.encode():
        ck ^= c
    return f"{start}{body}*{ck:02X}"


def nmea_fixes(n: int, *, day: str = "150126", year: int = 2026) -> list[str]:
    """``n`` seconds of a GNSS log: RMC + GGA each second and a ZDA every 10 s."""
    lines = []
    for i in range(n):
        hh, mm, ss = 12, (i // 60) % 60, i % 60
        t = f"{hh:02d}{mm:02d}{ss:02d}.00"
        lat = f"4623.{1000 + i:04d}"
        lines.append(nmea_sentence(f"GPRMC,{t},A,{lat},N,03054.0000,E,5.0,90.0,{day},,,A"))
        lines.append(nmea_sentence(f"GPGGA,{t},{lat},N,03054.0000,E,1,08,1.0,10.0,M,0.0,M,,"))
        if i % 10 == 0:
            lines.append(nmea_sentence(f"GPZDA,{t},{day[:2]},{day[2:4]},{year},00,00"))
    return lines


def write(path: Path, data: bytes | str) -> Path:
    """Write ``data`` (text as ASCII with CRLF endings already in it) to ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data.encode("ascii") if isinstance(data, str) else data)
    return path


# -- MCAP with hostile messages ------------------------------------------------------------

T0_NS = 1_767_225_600 * NS  # 2026-01-01T00:00:00Z


def radar_report(i: int, *, site: str = "R1", t_ns: int | None = None, **over: object) -> bytes:
    """A valid radar track report as the simulator writes it (JSON), number ``i``, one per
    second from :data:`T0_NS`; ``over`` replaces fields."""
    import json
    import math

    t = T0_NS + i * NS if t_ns is None else t_ns
    az = (0.1 + 0.01 * i) % (2 * math.pi)
    rng = 1000.0 + i
    rep = {
        "site_id": site, "track_id": 100 + i % 7, "time_ns": t, "range_m": rng,
        "azimuth_rad": az, "x_m": rng * math.sin(az), "y_m": rng * math.cos(az),
        "course_rad": 1.0, "speed_mps": 5.0, "sigma_range_m": 15.0,
        "sigma_azimuth_rad": 0.0079, "sigma_course_rad": 0.035, "sigma_speed_mps": 0.25,
        "scan_period_s": 3.0, "scan_end_azimuth_rad": 6.0, "status": "confirmed",
    }  # fmt: skip
    rep.update(over)
    return json.dumps(rep, separators=(",", ":")).encode()


def write_radar_mcap(path: Path, messages: list[tuple[int, bytes]], *,
                     topic: str = "/radar/R1/tracks", site: str | None = None) -> Path:  # fmt: skip
    """``(log_time_ns, payload)`` on one radar channel (json, surveil.RadarTrackReport),
    zstd chunks, written with the ``mcap`` writer (log times up to 2^64 - 1 allowed, as
    MCAP allows them); ``site``: the file's ``surveil.scenario`` metadata names it."""
    from mcap.writer import CompressionType, Writer

    from pipeline.resources import resource_path

    schema = (resource_path("schemas") / "radar_track_report.schema.json").read_bytes()
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD, chunk_size=1 << 16)
        w.start(profile="", library="surveil-hostile")
        sid = w.register_schema("surveil.RadarTrackReport", "jsonschema", schema)
        ch = w.register_channel(topic, "json", sid)
        for seq, (t, payload) in enumerate(messages):
            w.add_message(ch, log_time=t, data=payload, publish_time=t, sequence=seq)
        if site is not None:
            w.add_metadata("surveil.scenario", {"site": site})
        w.finish()
    return path
