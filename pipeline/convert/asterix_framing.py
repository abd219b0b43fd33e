"""ASTERIX recording formats with per-record framing: detect the framing, walk its records.

ASTERIX tools write recordings in framings of their own around the data blocks (ASTERIX
Part 1: ``CAT`` 1 octet, ``LEN`` 2 octets = the whole block). The layouts below are those
read by CroatiaControl's open-source decoder (``CroatiaControlLtd/asterix``,
``src/asterix/asterix{gps,final,hdlc,raw}subformat.cxx``, ``asterixhdlcparsing.c``) and
jASTERIX (``hpuhr/jASTERIX``, ``definitions/framings/ioss*.json``, whose ``ioss`` is the
FINAL layout); all integers are big-endian unless said otherwise.

=========  ====================================================================  ==============
framing    one record                                                            header time
=========  ====================================================================  ==============
``gps``    file header of 2 200 octets (skipped), then per record: one data      post-octets 6-8:
           block (CAT, LEN, ...) followed by 10 "GPS post" octets                time of day,
                                                                                 1/128 s
``final``  byte count (2, the whole record), board number (1), line number (1),  time of day,
           recording day (1), time (3), data blocks, padding (4, ``A5 A5 A5 A5``)  10 ms units
``ioss_seq``  byte count (2, whole record), sequence number (4), unknown (1),    time of day,
           board number (1), recording day (1), time (3), data blocks, padding   10 ms units
           (4)
``oradis`` byte count (2, the whole record incl. this header), time (4), data    unit not
           blocks                                                                published (see
                                                                                 below)
``hdlc``   HDLC frame: address ``01``, control ``03``, data blocks, FCS (2,     none: time of
           CRC-16/X.25 over address..FCS leaves the residue ``F0B8``)            day of the
                                                                                 records
=========  ====================================================================  ==============

Detection (:func:`detect_framing`): a framing is taken when its walk from offset 0 reads
complete records whose content frames exactly as data blocks (LEN by LEN), for the first
:data:`PROBE_RECORDS` records or up to the end of the file (a truncated last record is
allowed: the file is damaged, not of another kind). The FINAL padding is not checked
(``A5 A5 A5 A5`` in CroatiaControl's description; neither reader checks it). HDLC needs a
frame with a good FCS at offset 0 and good frames in at least half of the first 64 KiB (a
frame with a bad FCS is skipped, not the end of the file). Candidates are tried FINAL,
IOSS-seq, HDLC, ORADIS, GPS; raw data blocks (no framing) are recognised by the caller.

Walking (:func:`walk`): records in file order; a record that does not frame ends the walk
and the rest of the file is returned as one damaged tail (the importer rejects it with the
reason, it is not dropped). HDLC resynchronises at the next ``01 03`` whose frame checks.

ORADIS time: CroatiaControl's reader skips the 4 time octets and no public source states
their unit, so it is calibrated per file (:func:`oradis_time_unit`): with the records' own
ASTERIX time of day, the unit among milliseconds of the day, 1/128 s of the day, 10 ms of
the day and Unix seconds that best matches them; without (decoder missing, records
without time), milliseconds of the day when every value fits a day, else Unix seconds
when every value is a plausible one (1990 .. 2106), else the records' time of day.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

from pipeline.units import NS

GPS_HEADER = 2200
GPS_POST = 10
FINAL_HEADER, FINAL_PAD = 8, 4
IOSS_SEQ_HEADER = 12
ORADIS_HEADER = 6
HDLC_MAX_FRAME = 65_535
PROBE_RECORDS = 16
PAD = b"\xa5\xa5\xa5\xa5"
FRAMINGS = ("final", "ioss_seq", "hdlc", "oradis", "gps")


@dataclass(frozen=True)
class Record:
    """One framed record: its offset in the file, its ASTERIX content (one or more data
    blocks) and the header's time: ``tod_s`` (time of day) or ``raw_time`` (ORADIS, unit
    to calibrate), ``None`` when the framing has none."""

    offset: int
    content: bytes
    tod_s: float | None = None
    raw_time: int | None = None


@dataclass(frozen=True)
class Tail:
    """Bytes from ``offset`` on that do not frame, and why."""

    offset: int
    data: bytes
    reason: str


ASTERIX_CATEGORIES = frozenset(
    {1, 2, 4, 8, 9, 10, 11, 15, 16, 17, 18, 19, 20, 21, 23, 25, 30, 31, 32, 34, 48, 62, 63,
     65, 150, 205, 238, 239, 240, 247, 252}
)  # fmt: skip
"""Categories of the EUROCONTROL ASTERIX list (and common non-standard ones): a framed
record's blocks must start with one, so that random octets do not pass as a framing."""


def blocks_fill(content: bytes) -> bool:
    """``content`` is one or more whole data blocks of known categories (LEN by LEN,
    each LEN > 3: a block holds at least one record)."""
    pos, n = 0, len(content)
    if n < 4:
        return False
    while pos < n:
        if n - pos < 4 or content[pos] not in ASTERIX_CATEGORIES:
            return False
        length = int.from_bytes(content[pos + 1 : pos + 3], "big")
        if length < 4 or pos + length > n:
            return False
        pos += length
    return True


# -- per-framing record readers: (record, next offset) or a reason ------------------------

Step = tuple[Record, int] | str


def _final_like(header: int) -> Callable[[bytes, int], Step]:
    def step(data: bytes, pos: int) -> Step:
        if len(data) - pos < header + FINAL_PAD + 3:
            return f"{len(data) - pos} octets left, shorter than a record"
        n = int.from_bytes(data[pos : pos + 2], "big")
        if n < header + FINAL_PAD + 3:
            return f"byte count {n} is shorter than a record"
        if pos + n > len(data):
            return f"byte count {n} runs past the end of the file (cut off?)"
        content = data[pos + header : pos + n - FINAL_PAD]
        if not blocks_fill(content):
            return "content does not frame as ASTERIX data blocks"
        t = int.from_bytes(data[pos + header - 3 : pos + header], "big")
        return Record(pos, content, tod_s=t / 100.0), pos + n

    return step


def _oradis(data: bytes, pos: int) -> Step:
    if len(data) - pos < ORADIS_HEADER + 3:
        return f"{len(data) - pos} octets left, shorter than a record"
    n = int.from_bytes(data[pos : pos + 2], "big")
    if n < ORADIS_HEADER + 3:
        return f"byte count {n} is shorter than a record"
    if pos + n > len(data):
        return f"byte count {n} runs past the end of the file (cut off?)"
    content = data[pos + ORADIS_HEADER : pos + n]
    if not blocks_fill(content):
        return "content does not frame as ASTERIX data blocks"
    raw_time = int.from_bytes(data[pos + 2 : pos + 6], "big")
    return Record(pos, content, raw_time=raw_time), pos + n


def _gps(data: bytes, pos: int) -> Step:
    if pos == 0:
        if len(data) < GPS_HEADER + 3 + GPS_POST:
            return "shorter than the 2200-octet GPS file header and one record"
        pos = GPS_HEADER
    if len(data) - pos < 3 + GPS_POST:
        return f"{len(data) - pos} octets left, shorter than a record"
    n = int.from_bytes(data[pos + 1 : pos + 3], "big")
    if data[pos] not in ASTERIX_CATEGORIES or n < 4:
        return f"no data block here (CAT {data[pos]}, LEN {n})"
    if pos + n + GPS_POST > len(data):
        return f"data block LEN {n} + 10 post octets run past the end of the file (cut off?)"
    post = data[pos + n : pos + n + GPS_POST]
    tod = int.from_bytes(post[6:9], "big") / 128.0
    return Record(pos, data[pos : pos + n], tod_s=tod), pos + n + GPS_POST


_FCS_TABLE: list[int] = []


def fcs16(data: bytes) -> int:
    """CRC-16/X.25 register after ``data`` (init 0xFFFF, reflected polynomial 0x8408,
    no final XOR); over a frame including its FCS octets a good frame leaves 0xF0B8."""
    if not _FCS_TABLE:
        for b in range(256):
            v = b
            for _ in range(8):
                v = (v >> 1) ^ 0x8408 if v & 1 else v >> 1
            _FCS_TABLE.append(v)
    fcs = 0xFFFF
    for b in data:  # per octet: HDLC frames are short (a few hundred octets)
        fcs = (fcs >> 8) ^ _FCS_TABLE[(fcs ^ b) & 0xFF]
    return fcs


def hdlc_fcs(frame_without_fcs: bytes) -> bytes:
    """The two FCS octets to append (ones' complement, least significant octet first)."""
    v = fcs16(frame_without_fcs) ^ 0xFFFF
    return bytes([v & 0xFF, v >> 8])


def _hdlc(data: bytes, pos: int) -> Step:
    if data[pos : pos + 2] != b"\x01\x03":
        return "no HDLC frame start (address 01, control 03)"
    end, q = len(data), pos + 2
    while q + 3 <= end:  # walk the blocks; after each, the FCS may follow
        n = int.from_bytes(data[q + 1 : q + 3], "big")
        if data[q] not in ASTERIX_CATEGORIES or n < 4 or q + n + 2 > end:
            break
        q += n
        if fcs16(data[pos : q + 2]) == 0xF0B8:
            return Record(pos, data[pos + 2 : q]), q + 2
    return "no data blocks followed by a good FCS (CRC-16/X.25)"


STEPS: dict[str, Callable[[bytes, int], Step]] = {
    "final": _final_like(FINAL_HEADER),
    "ioss_seq": _final_like(IOSS_SEQ_HEADER),
    "hdlc": _hdlc,
    "oradis": _oradis,
    "gps": _gps,
}


def detect_framing(data: bytes) -> str | None:
    """The framing of ``data`` (module docstring), or ``None``."""
    for name in FRAMINGS:
        if name == "hdlc":  # frames resynchronise: most of the octets must be good frames
            if data[:2] == b"\x01\x03":
                records, _ = walk_hdlc(data[:65_536])
                good = sum(len(r.content) + 4 for r in records)
                if records and records[0].offset == 0 and good * 2 >= min(len(data), 65_536):
                    return name
            continue
        step, pos, ok = STEPS[name], 0, 0
        while ok < PROBE_RECORDS and pos < len(data):
            r = step(data, pos)
            if isinstance(r, str):
                break
            ok, pos = ok + 1, r[1]
        cut_off = pos < len(data) and ok >= 1 and isinstance(r, str) and "past the end" in r
        if ok >= 1 and (ok == PROBE_RECORDS or pos == len(data) or cut_off):
            return name
    return None


def walk(data: bytes, framing: str) -> tuple[list[Record], Tail | None]:
    """Every record of ``data`` in ``framing``, and the damaged tail (``None`` when the
    records reach the end). HDLC skips to the next frame that checks (the skipped octets
    are one tail each, see :func:`walk_hdlc`)."""
    if framing == "hdlc":
        records, tails = walk_hdlc(data)
        return records, tails[0] if tails else None
    step, pos, out = STEPS[framing], 0, []
    while pos < len(data):
        r = step(data, pos)
        if isinstance(r, str):
            start = max(pos, GPS_HEADER) if framing == "gps" else pos
            return out, Tail(start, data[start:], f"{framing} record at octet {pos}: {r}")
        out.append(r[0])
        pos = r[1]
    return out, None


def walk_hdlc(data: bytes) -> tuple[list[Record], list[Tail]]:
    """HDLC frames; octets between frames that do not check are returned as tails."""
    records: list[Record] = []
    tails: list[Tail] = []
    pos, junk = 0, None
    while pos < len(data):
        r = _hdlc(data, pos) if data[pos : pos + 2] == b"\x01\x03" else "no frame start"
        if isinstance(r, str):
            junk = pos if junk is None else junk
            nxt = data.find(b"\x01\x03", pos + 1)
            pos = len(data) if nxt < 0 else nxt
            continue
        if junk is not None:
            tails.append(Tail(junk, data[junk:pos], f"hdlc: {pos - junk} octets at octet "
                              f"{junk} are not a frame with a good FCS"))  # fmt: skip
            junk = None
        records.append(r[0])
        pos = r[1]
    if junk is not None:
        tails.append(Tail(junk, data[junk:], f"hdlc: {len(data) - junk} octets at octet {junk} "
                          "are not a frame with a good FCS"))  # fmt: skip
    return records, tails


# -- ORADIS time --------------------------------------------------------------------------

ORADIS_UNITS: dict[str, tuple[float, bool]] = {  # name -> (seconds per count, time of day?)
    "ms_of_day": (1e-3, True),
    "1/128s_of_day": (1 / 128, True),
    "10ms_of_day": (1e-2, True),
    "unix_s": (1.0, False),
}


def oradis_time_unit(raw: list[int], record_tod: list[float | None]) -> str | None:
    """The unit of ORADIS header times (module docstring), ``None`` when none fits."""
    fits = {
        name: all(
            v * k < 86_400 if of_day else 631_152_000 <= v * k < 2**32 for v in raw
        )
        for name, (k, of_day) in ORADIS_UNITS.items()
    }
    pairs = [(v, t) for v, t in zip(raw, record_tod, strict=True) if t is not None]
    if pairs:
        best, best_err = None, None
        for name, (k, _of_day) in ORADIS_UNITS.items():
            if not fits[name]:
                continue
            errs = sorted(_tod_gap(v * k % 86_400, t) for v, t in pairs)
            err = errs[len(errs) // 2]
            if best_err is None or err < best_err:
                best, best_err = name, err
        if best is not None and best_err is not None and best_err < 60.0:
            return best
    if raw and fits["ms_of_day"]:
        return "ms_of_day"
    if raw and fits["unix_s"]:
        return "unix_s"
    return None


def _tod_gap(a: float, b: float) -> float:
    d = abs(a - b) % 86_400
    return min(d, 86_400 - d)


def oradis_time(raw: int, unit: str) -> tuple[float | None, int | None]:
    """``(time of day s, absolute ns)`` of one ORADIS header time in ``unit``."""
    k, of_day = ORADIS_UNITS[unit]
    if of_day:
        return raw * k, None
    return None, raw * NS


def iter_blocks(records: list[Record]) -> Iterator[tuple[Record, bytes]]:
    """``(record, data block)`` for every block of every record (content frames)."""
    for r in records:
        pos = 0
        while pos < len(r.content):
            n = int.from_bytes(r.content[pos + 1 : pos + 3], "big")
            yield r, r.content[pos : pos + n]
            pos += n
