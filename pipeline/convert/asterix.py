"""Wrap raw ASTERIX recordings and pcap/pcapng captures into MCAP (one channel per source).

``wrap_asterix_file(path, out_dir)`` writes ``<out_dir>/<file name>.mcap`` whose channels
follow the ASTERIX channel convention of :mod:`pipeline.decode.asterix`: message encoding
``asterix``, no schema, one ASTERIX data block per message. Every later stage reads MCAP
only. The output bytes depend only on the input (fixed header strings, no wall clock); the
file is written to a temporary name and renamed into place.

Inputs, recognised by their first bytes:

- **pcap** (libpcap, magic ``a1b2c3d4`` µs or ``a1b23c4d`` ns, either byte order) and
  **pcapng** (Section Header Block ``0a0d0d0a``; Enhanced, Simple and obsolete Packet
  Blocks; per-interface ``if_tsresol``). Link types: Ethernet (with 802.1Q/802.1ad VLAN
  tags), Linux cooked SLL/SLL2, BSD loopback, raw IPv4/IPv6. Each UDP datagram's payload
  is split into data blocks by their LEN fields (a datagram often carries several, e.g.
  CAT062 + CAT065); bytes that do not frame become one message of their own, which the
  decoder rejects as ``undecodable``. **log time = the capture timestamp** of the packet
  (``log_time_source`` = ``pcap``). One channel per UDP flow
  ``/asterix/<src ip>:<src port>/<dst ip>:<dst port>``; a flow of NMEA 0183 text (an AIS
  receiver's ``!AIVDM`` lines over UDP, :func:`is_nmea_text`) is one ``nmea0183``
  channel ``/nmea/<src ip>:<src port>/<dst ip>:<dst port>``, one message per line (a
  tag block or N-AIS fields in a line still give its time at ingest), with metadata ``src_ip``,
  ``src_port``, ``dst_ip``, ``dst_port``. Packets that are not UDP over IPv4/IPv6, and IP
  fragments (not reassembled), are counted in the file metadata record
  ``surveil.import`` (``packets_skipped``, by reason), not written.
- **raw ASTERIX** (``.raw``, ``.ast``, ...: data blocks back to back, no framing, no
  capture time): one channel ``/asterix/raw``. The file carries no time, so the log time
  is derived (``log_time_source`` = ``asterix_time_of_day``): ``day`` (default
  1970-01-01, i.e. unknown) + the time of day of the block's first timed record (see
  :func:`pipeline.decode.asterix.tod_to_time_ns` for the items), plus one day for each
  backward jump of the time of day by more than 12 h (midnight crossed); a block without
  a decodable time takes the previous block's log time (noon of ``day`` before the first
  timed block). A tail that does not frame becomes one last message (rejected as
  ``undecodable`` at ingest). The metadata key ``log_date`` records the day used.

Anything else raises ``ValueError`` with the reason (not pcap/pcapng, and the first bytes
do not frame as an ASTERIX data block, or the file looks like text).
"""

from __future__ import annotations

import re
import struct
from collections import Counter
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from datetime import UTC, date, datetime
from pathlib import Path

from pipeline.convert.asterix_framing import (
    RESYNC_RECORDS,
    Tail,
    blocks_fill,
    detect_framing,
    oradis_time,
    oradis_time_unit,
    split_blocks_resync,
    walk,
    walk_hdlc,
    walk_resync,
)
from pipeline.convert.output import Message, site_metadata, write_converted
from pipeline.decode.asterix import (
    EXTRACTORS,
    INSTALL_HINT,
    candidate_editions,
    decoder_available,
    extract_block,
    split_blocks,
)
from pipeline.io.mcap_write import ChannelSpec
from pipeline.units import NS

DAY_NS = 86_400 * NS
MCAP_LIBRARY = "surveil-pipeline/asterix_import"
RAW_TOPIC = "/asterix/raw"
PCAP_MAGICS = {
    b"\xd4\xc3\xb2\xa1": ("<", 1_000), b"\xa1\xb2\xc3\xd4": (">", 1_000),
    b"\x4d\x3c\xb2\xa1": ("<", 1), b"\xa1\xb2\x3c\x4d": (">", 1),
}  # fmt: skip  # magic -> (byte order, ns per timestamp fraction unit)
PCAPNG_SHB = b"\x0a\x0d\x0d\x0a"
ETH_IPV4, ETH_IPV6, ETH_VLAN = 0x0800, 0x86DD, (0x8100, 0x88A8)
TAIL_RAW_BYTES = 4096  # octets of a skipped stretch kept in its rejects row
PCAP_MAX_RECORD = 262_144  # libpcap's largest snapshot length
PCAP_RESYNC_WINDOW_S = 86_400  # a record after damage is within a day of the last good one
CAPTURE_TOPIC = "/asterix/capture"  # topic named in the rejects rows of capture damage


@dataclass(frozen=True)
class Packet:
    """One captured frame: capture time (ns since the epoch), link type, frame bytes."""

    time_ns: int
    link_type: int
    data: bytes


@dataclass
class _Messages:
    """Messages per channel topic, in capture order, plus channel metadata."""

    topics: dict[str, dict[str, str]] = field(default_factory=dict)
    rows: list[Message] = field(default_factory=list)
    skipped: Counter = field(default_factory=Counter)
    encodings: dict[str, str] = field(default_factory=dict)  # topic -> not "asterix"

    def add_nmea(self, topic: str, meta: dict[str, str], t: int, payload: bytes) -> None:
        """One ``nmea0183`` message per line of a UDP payload of NMEA text (AIS receivers
        send ``!AIVDM`` lines over UDP), log time = the packet's capture time."""
        self.topics.setdefault(topic, meta)
        self.encodings[topic] = "nmea0183"
        for line in re.split(rb"\r\n|\n|\r", payload):
            if line.strip():
                self.rows.append(Message(topic, t, line.strip()))

    def reject_tail(self, topic: str, t: int, tail: Tail) -> None:
        """A damaged stretch of the file: one rejects message (its first
        ``TAIL_RAW_BYTES`` octets; the reason gives its offset and length)."""
        self.rows.append(Message(topic, t, tail.data[:TAIL_RAW_BYTES],
                                 ("undecodable", tail.reason)))  # fmt: skip

    def add(
        self, topic: str, meta: dict[str, str], t: int, payload: bytes,
        reject: tuple[str, str] | None = None,
    ) -> None:  # fmt: skip
        """One message per data block of ``payload``; a tail that does not frame is kept
        as one message of its own (the decoder rejects it). ``reject``: why the payload
        cannot be a message (it then goes to the rejects channel whole)."""
        self.topics.setdefault(topic, meta)
        if reject is not None:
            self.rows.append(Message(topic, t, payload, reject))
            return
        blocks, rest = split_blocks(payload)
        self.rows.extend(Message(topic, t, b) for b in blocks)
        if rest:
            self.rows.append(Message(topic, t, rest))


@dataclass(frozen=True)
class WrappedAsterix:
    """One wrapped file: output path, input format, messages per topic, log-time source
    per topic."""

    output: Path
    kind: str
    messages: dict[str, int]
    log_time_source: dict[str, str]


def wrap_asterix_file(path: Path, out_dir: Path, *, day: date | None = None) -> Path:
    """Wrap an ASTERIX recording into ``out_dir/<name>.mcap`` (:func:`wrap_asterix`)."""
    return wrap_asterix(path, out_dir, day=day).output


def wrap_asterix(
    path: Path,
    out_dir: Path,
    *,
    day: date | None = None,
    editions: Mapping[int, str] | None = None,
    site: str | None = None,
    day_source: str = "",
) -> WrappedAsterix:
    """Wrap a raw ASTERIX file, a framed recording (GPS, FINAL, IOSS, HDLC, ORADIS) or a
    pcap/pcapng capture into ``out_dir/<name>.mcap``.

    ``day``: UTC date of a recording whose records carry only the time of day (raw and
    framed files; None: 1970-01-01, unknown); ignored for captures, which carry their own
    timestamps. ``day_source``: where ``day`` came from (``base_time``, ``file_name``),
    written as the channels' ``log_date_source``. ``editions``:
    the config's ``[asterix] editions``, written to every channel's metadata
    (``asterix_editions``) for ingest. Raises ``ValueError`` when the file is none of
    these, or holds nothing to write.
    """
    path = Path(path)
    data = path.read_bytes()
    head = data[:4]
    capture = head in PCAP_MAGICS or head == PCAPNG_SHB
    if not capture:
        _check_binary(data, path)
    framing = None if capture else detect_framing(data)
    if head in PCAP_MAGICS or head == PCAPNG_SHB:
        msgs = _from_capture(data, path)
        kind = "pcapng" if head == PCAPNG_SHB else "pcap"
    elif framing is not None:
        msgs = _from_framed(data, framing, day or date(1970, 1, 1), path)
        kind = framing
    else:
        _check_raw(data, path)
        msgs = _from_raw(data, day or date(1970, 1, 1), path)
        kind = "raw"
    if not msgs.rows:
        raise ValueError(f"{path}: {kind} file holds no UDP payload to wrap as ASTERIX")
    out = Path(out_dir) / f"{path.name}.mcap"
    meta = {"source": path.name, "input_format": kind, "messages": str(len(msgs.rows)),
            **site_metadata(site)}
    meta |= {f"packets_skipped_{k}": str(v) for k, v in sorted(msgs.skipped.items())}
    if editions:
        text = ",".join(f"{c:03d}={e}" for c, e in sorted(editions.items()))
        for m in msgs.topics.values():
            m["asterix_editions"] = text
    for m in msgs.topics.values():  # where the day of a time-of-day recording came from
        if "log_date" in m:
            m["log_date_source"] = day_source or ("unknown" if day is None else "given")
    counts = _write_mcap(out, msgs, meta)
    sources = {t: m.get("log_time_source", "") for t, m in msgs.topics.items()}
    return WrappedAsterix(out, kind, counts, sources)


# -- raw ---------------------------------------------------------------------------------


def _check_binary(data: bytes, path: Path) -> None:
    if not data:
        raise ValueError(f"{path}: empty file, neither pcap/pcapng nor raw ASTERIX")
    sample = data[:64]
    if all(32 <= b < 127 or b in (9, 10, 13) for b in sample):
        raise ValueError(
            f"{path}: looks like a text file, neither pcap/pcapng nor raw ASTERIX "
            "(NMEA text logs are imported by the NMEA importer)"
        )


def _check_raw(data: bytes, path: Path) -> None:
    blocks, _rest = split_blocks(data)
    if not blocks:
        n = int.from_bytes(data[1:3], "big") if len(data) >= 3 else None
        raise ValueError(
            f"{path}: neither pcap/pcapng nor raw ASTERIX: the first bytes do not frame as "
            f"an ASTERIX data block (CAT {data[0]}, LEN {n}, file size {len(data)} B)"
        )


def block_time_of_day(block: bytes) -> float | None:
    """Time of day (s) of the first timed record of a supported-category block (needs
    the ``asterix`` extra: ``None`` without it)."""
    if not decoder_available():
        return None
    if block[0] not in EXTRACTORS:
        return None
    for ed in candidate_editions(block[0], {}, {}) or [None]:
        rows = extract_block(block, ed)
        if isinstance(rows, tuple):
            continue
        for row in rows:
            tod = row.get("tod_s")
            if tod is not None and 0 <= tod < 86_400:
                return float(tod)
        return None
    return None


def _need_decoder(path: Path, kind: str) -> None:
    if not decoder_available():
        raise ValueError(
            f"{path}: {kind} ASTERIX carries no time outside its records, and reading their "
            f"time of day needs the ASTERIX decoder: {INSTALL_HINT}"
        )


class _DayClock:
    """Times of day -> log times on ``day``: one day added at each backward jump of more
    than 12 h (midnight crossed); before the first time of day: noon of ``day``."""

    def __init__(self, day: date):
        self.offset = _day_ns(day)
        self.t = self.offset + DAY_NS // 2
        self.prev: float | None = None

    def at(self, tod: float | None) -> int:
        if tod is not None:
            if self.prev is not None and tod < self.prev - 43_200:
                self.offset += DAY_NS
            self.prev = tod
            self.t = self.offset + round(tod * NS)
        return self.t


def _day_ns(day: date) -> int:
    return int(datetime(day.year, day.month, day.day, tzinfo=UTC).timestamp()) * NS


def _from_raw(data: bytes, day: date, path: Path) -> _Messages:
    """Blocks of a raw file with log times from their time of day (module docstring)."""
    _need_decoder(path, "raw")
    meta = {"log_time_source": "asterix_time_of_day", "log_date": day.isoformat()}
    msgs = _Messages()
    blocks, tails = split_blocks_resync(data)
    clock = _DayClock(day)
    pending = sorted(tails, key=lambda t: t.offset, reverse=True)
    # per block: the time of day comes from the decoded records of each block
    for offset, block in blocks:
        while pending and pending[-1].offset < offset:  # damage before this block
            msgs.reject_tail(RAW_TOPIC, clock.t, pending.pop())
        msgs.add(RAW_TOPIC, meta, clock.at(block_time_of_day(block)), block)
    for tail in reversed(pending):
        msgs.reject_tail(RAW_TOPIC, clock.t, tail)
    return msgs


def _from_framed(data: bytes, framing: str, day: date, path: Path) -> _Messages:
    """Records of a framed recording (:mod:`pipeline.convert.asterix_framing`), log time
    from the record headers (time of day on ``day``, midnight rollover handled; ORADIS:
    its calibrated unit; HDLC: the records' own time of day)."""
    topic = f"/asterix/{framing}"
    msgs = _Messages()
    if framing == "hdlc":
        _need_decoder(path, "HDLC-framed")
        records, tails = walk_hdlc(data)
    else:
        records, tails = walk_resync(data, framing)
    meta = {"log_date": day.isoformat()}
    tods: list[float | None] = [r.tod_s for r in records]
    abs_ns: list[int | None] = [None] * len(records)
    if framing in ("gps", "final", "ioss_seq"):
        meta["log_time_source"] = f"{framing}_header:time_of_day"
    elif framing == "hdlc":
        meta["log_time_source"] = "asterix_time_of_day"
        tods = [_content_tod(r.content) for r in records]
    else:  # oradis: calibrate the header time's unit against the records
        own = [_content_tod(r.content) for r in records] if decoder_available() else []
        unit = oradis_time_unit([r.raw_time or 0 for r in records],
                                own or [None] * len(records))  # fmt: skip
        if unit is None:
            _need_decoder(path, "ORADIS (header time of no known unit)")
            meta["log_time_source"] = "asterix_time_of_day"
            tods = own
        else:
            meta["log_time_source"] = f"oradis_header:{unit}"
            pairs = [oradis_time(r.raw_time or 0, unit) for r in records]
            tods = [p[0] for p in pairs]
            abs_ns = [p[1] for p in pairs]
    clock = _DayClock(day)
    # per record: each header carries its own time
    for r, tod, t_abs in zip(records, tods, abs_ns, strict=True):
        t = t_abs if t_abs is not None else clock.at(tod)
        msgs.add(topic, meta, t, r.content)
    for tail in tails:
        msgs.reject_tail(topic, clock.t, tail)
    return msgs


def _content_tod(content: bytes) -> float | None:
    """Time of day of the first timed record among the blocks of ``content``."""
    blocks, _ = split_blocks(content)
    for b in blocks:
        tod = block_time_of_day(b)
        if tod is not None:
            return tod
    return None


# -- captures ----------------------------------------------------------------------------


def _from_capture(data: bytes, path: Path) -> _Messages:
    msgs = _Messages()
    tails: list[Tail] = []
    packets = (
        _pcapng_packets(data, msgs.skipped, tails)
        if data[:4] == PCAPNG_SHB
        else (_pcap_packets(data, msgs.skipped, tails))
    )
    # per packet: each frame has its own link/IP/UDP headers to strip
    last_t = 0
    for pkt in packets:
        while tails:  # damage found before this packet: rejected at the last good time
            msgs.reject_tail(CAPTURE_TOPIC, last_t or pkt.time_ns, tails.pop(0))
        last_t = pkt.time_ns
        udp = _udp_payload(pkt, msgs.skipped)
        if udp is None:
            continue
        (src, sport, dst, dport), payload = udp
        flow = f"{src}:{sport}/{dst}:{dport}"
        meta = {
            "log_time_source": "pcap",
            "src_ip": src, "src_port": str(sport), "dst_ip": dst, "dst_port": str(dport),
        }  # fmt: skip
        if is_nmea_text(payload):
            msgs.add_nmea(f"/nmea/{flow}", {**meta, "time_source_fallback": "pcap",
                                            "platform_id": flow}, pkt.time_ns, payload)
            continue
        for content in _oradis_unwrapped(payload):
            msgs.add(f"/asterix/{flow}", meta, pkt.time_ns, content)
    for tail in tails:
        msgs.reject_tail(CAPTURE_TOPIC, last_t, tail)
    return msgs


_NMEA_START = re.compile(rb"^\s*(?:\\[^\\]*\\)?[!$][A-Z0-9]{2}[A-Z0-9]{3,}[,*]")


def is_nmea_text(payload: bytes) -> bool:
    """A UDP payload of NMEA 0183 text: printable, its first line a sentence (``!AIVDM``,
    ``$GPRMC``, with or without a tag block). An ASTERIX block starts with a category
    octet and its length, never with ``!``/``$``/``\\`` followed by an address."""
    if not payload or not _NMEA_START.match(payload):
        return False
    return all(b >= 32 or b in (9, 10, 13) for b in payload[:512])


def _oradis_unwrapped(payload: bytes) -> list[bytes]:
    """The ASTERIX content of a UDP payload: itself, or, when it is a run of ORADIS
    packets (CroatiaControl's ``--oradispcap``: 6-octet header before the blocks), their
    contents (the capture time stays the log time)."""
    if blocks_fill(payload) or not payload:
        return [payload]
    records, tail = walk(payload, "oradis")
    return [r.content for r in records] if records and tail is None else [payload]


def _pcap_packets(data: bytes, skipped: Counter, tails: list[Tail]) -> Iterator[Packet]:
    """Frames of a libpcap file. A record header that is not plausible (length beyond the
    snapshot length, fraction beyond a second, record past the end of the file) is
    damage: the walk resumes at the next offset where :data:`RESYNC_RECORDS` record
    headers in a row are plausible (or the records reach the end of the file exactly),
    and the octets skipped are a :class:`Tail` in ``tails``."""
    order, frac_ns = PCAP_MAGICS[data[:4]]
    if len(data) < 24:
        skipped["truncated_header"] += 1
        tails.append(Tail(0, data, f"pcap: {len(data)} octets, shorter than its header"))
        return
    (snaplen, link_type) = struct.unpack_from(order + "II", data, 16)
    limit = min(snaplen, PCAP_MAX_RECORD) if snaplen else PCAP_MAX_RECORD
    frac_max = NS // frac_ns
    rec = struct.Struct(order + "IIII")
    n = len(data)

    last_sec: list[int] = []  # seconds of the last good record (none yet: any)

    def record_at(q: int) -> int:  # end of a plausible record at q, else 0
        if q + 16 > n:
            return 0
        sec, frac, incl, orig = rec.unpack_from(data, q)
        if frac >= frac_max or incl > limit or incl > orig or q + 16 + incl > n:
            return 0
        if last_sec and abs(sec - last_sec[0]) > PCAP_RESYNC_WINDOW_S:
            return 0  # a misaligned header reads some other field as its time
        return q + 16 + incl

    def chain(q: int) -> bool:
        for _ in range(RESYNC_RECORDS):
            if q == n:
                return True
            q = record_at(q)
            if not q:
                return False
        return True

    pos = 24
    while pos < n:
        end = record_at(pos)
        # taken: the next header checks too, or, where it does not, no run of good records
        # starts inside this one (a broken length inside the file swallows what it spans)
        if end and (end == n or record_at(end) or not any(map(chain, range(pos + 1, end)))):
            sec, frac, _incl, _orig = rec.unpack_from(data, pos)
            last_sec[:] = [sec]
            yield Packet(sec * NS + frac * frac_ns, link_type & 0x0FFFFFFF, data[pos + 16 : end])
            pos = end
            continue
        skipped["damaged_record"] += 1
        nxt = next((q for q in range(pos + 1, n) if chain(q)), n)
        where = f"resumed at octet {nxt}" if nxt < n else "to the end of the file (cut off?)"
        tails.append(Tail(pos, data[pos:nxt], f"pcap: record header at octet {pos} is not "
                          f"plausible; {nxt - pos} octets skipped, {where}"))  # fmt: skip
        pos = nxt


def _pcapng_packets(data: bytes, skipped: Counter, tails: list[Tail]) -> Iterator[Packet]:
    """Frames of a pcapng file (EPB, SPB, obsolete PB); SHB/IDB set order and units. A
    block whose length does not check (the trailing copy of the length must match) is
    damage: the walk resumes at the next block that checks, the octets skipped are a
    :class:`Tail` in ``tails``."""
    order = "<"
    ifaces: list[tuple[int, tuple[int, int]]] = []  # (link type, if_tsresol (base, exp))
    pos, n = 0, len(data)

    def block_ok(q: int) -> bool:
        if q + 12 > n:
            return False
        blen = struct.unpack_from(order + "I", data, q + 4)[0]
        if blen < 12 or blen % 4 or q + blen > n:
            return False
        return struct.unpack_from(order + "I", data, q + blen - 4)[0] == blen

    while pos < n:
        if data[pos : pos + 4] == PCAPNG_SHB and pos + 12 <= n:
            order = "<" if data[pos + 8 : pos + 12] == b"\x4d\x3c\x2b\x1a" else ">"
            ifaces = []
        if not block_ok(pos):
            skipped["damaged_block"] += 1
            nxt = next((q for q in range(pos + 4, n, 4) if block_ok(q)), n)
            where = f"resumed at octet {nxt}" if nxt < n else "to the end of the file"
            tails.append(Tail(pos, data[pos:nxt], f"pcapng: block at octet {pos} does not "
                              f"check; {nxt - pos} octets skipped, {where}"))  # fmt: skip
            pos = nxt
            continue
        btype, blen = struct.unpack_from(order + "II", data, pos)
        body = data[pos + 8 : pos + blen - 4]
        if btype == 1 and len(body) >= 8:  # Interface Description Block
            link, _res, _snap = struct.unpack_from(order + "HHI", body, 0)
            ifaces.append((link, _tsresol_ns(body[8:], order)))
        elif btype in (6, 2) and len(body) >= 20 and ifaces:  # Enhanced / obsolete PB
            iface, hi, lo, cap, _orig = struct.unpack_from(order + "IIIII", body, 0)
            if btype == 2:
                iface &= 0xFFFF
            if iface < len(ifaces):
                link, resol = ifaces[iface]
                yield Packet(_ticks_ns((hi << 32) | lo, resol), link, body[20 : 20 + cap])
        elif btype == 3:  # Simple Packet Block: no timestamp
            skipped["no_timestamp"] += 1
        pos += blen


def _tsresol_ns(options: bytes, order: str) -> tuple[int, int]:
    """An IDB's ``if_tsresol`` option as (base, exponent): a tick is base**-exponent s
    (default (10, 6), microseconds)."""
    pos = 0
    while pos + 4 <= len(options):
        code, length = struct.unpack_from(order + "HH", options, pos)
        if code == 0:
            break
        if code == 9 and length >= 1:
            v = options[pos + 4]
            return (2, v & 0x7F) if v & 0x80 else (10, v & 0x7F)
        pos += 4 + length + (-length % 4)
    return (10, 6)


def _ticks_ns(ticks: int, resol: tuple[int, int]) -> int:
    """Integer ns of a pcapng timestamp (exact: no float at 1e18 ns)."""
    base, exp = resol
    return ticks * NS // base**exp


def _udp_payload(pkt: Packet, skipped: Counter) -> tuple[tuple[str, int, str, int], bytes] | None:
    """``((src, sport, dst, dport), payload)`` of a UDP frame, else ``None`` (counted)."""
    ip = _ip_packet(pkt.link_type, pkt.data)
    if ip is None:
        skipped["not_ip"] += 1
        return None
    version = ip[0] >> 4 if ip else 0
    if version == 4 and len(ip) >= 20:
        ihl = (ip[0] & 0x0F) * 4
        frag = struct.unpack_from(">H", ip, 6)[0]
        if frag & 0x3FFF:  # MF flag or a fragment offset
            skipped["ip_fragment"] += 1
            return None
        if ip[9] != 17:
            skipped["not_udp"] += 1
            return None
        src, dst, udp = _ipv4(ip[12:16]), _ipv4(ip[16:20]), ip[ihl:]
    elif version == 6 and len(ip) >= 40:
        if ip[6] != 17:
            skipped["not_udp"] += 1
            return None
        src, dst, udp = _ipv6(ip[8:24]), _ipv6(ip[24:40]), ip[40:]
    else:
        skipped["not_ip"] += 1
        return None
    if len(udp) < 8:
        skipped["truncated_udp"] += 1
        return None
    sport, dport, ulen = struct.unpack_from(">HHH", udp, 0)
    end = ulen if 8 <= ulen <= len(udp) else len(udp)
    return (src, sport, dst, dport), udp[8:end]


def _ip_packet(link_type: int, frame: bytes) -> bytes | None:
    """The IP packet inside a link-layer frame, ``None`` when it holds no IP."""
    if link_type == 1:  # Ethernet
        pos, etype = 14, int.from_bytes(frame[12:14], "big") if len(frame) >= 14 else 0
        while etype in ETH_VLAN and len(frame) >= pos + 4:
            etype = int.from_bytes(frame[pos + 2 : pos + 4], "big")
            pos += 4
        return frame[pos:] if etype in (ETH_IPV4, ETH_IPV6) else None
    if link_type == 113:  # Linux cooked SLL
        etype = int.from_bytes(frame[14:16], "big") if len(frame) >= 16 else 0
        return frame[16:] if etype in (ETH_IPV4, ETH_IPV6) else None
    if link_type == 276:  # Linux cooked SLL2
        etype = int.from_bytes(frame[0:2], "big") if len(frame) >= 20 else 0
        return frame[20:] if etype in (ETH_IPV4, ETH_IPV6) else None
    if link_type in (0, 108):  # BSD loopback / OpenBSD loop: 4-byte family
        return frame[4:] if len(frame) > 4 else None
    if link_type in (101, 12, 14, 228, 229):  # raw IP
        return frame
    return None


def _ipv4(b: bytes) -> str:
    return ".".join(str(x) for x in b)


def _ipv6(b: bytes) -> str:
    import ipaddress

    return str(ipaddress.IPv6Address(b))


# -- writing ----------------------------------------------------------------------------


def _write_mcap(out: Path, msgs: _Messages, meta: dict[str, str]) -> dict[str, int]:
    channels = [
        ChannelSpec(topic, msgs.encodings.get(topic, "asterix"), metadata=m)
        for topic, m in sorted(msgs.topics.items())
    ]
    return write_converted(out, channels, msgs.rows, metadata={"surveil.import": meta},
                    library=MCAP_LIBRARY)  # fmt: skip
