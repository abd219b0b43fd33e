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
