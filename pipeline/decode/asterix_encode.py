"""EUROCONTROL ASTERIX CAT010 encoder for SMR and MLAT target reports (vectorised).

CAT010 (Transmission of Monosensor Surface Movement Data, edition 1.1): a data block is
``CAT (1 octet) | LEN (2 octets, the whole block) | records``; a record is its FSPEC
followed by the present items in User Application Profile order. We send target reports
(I010/000 = 1) with a fixed item set per sensor kind, so every record of a kind has the
same FSPEC and the same length and a batch of n records is built as an (n, length)
uint8 array, one item at a time (no per-record Python).

====  =========  ================================================  =============  ======
FRN   item       content                                          LSB            kinds
====  =========  ================================================  =============  ======
1     I010/010   SAC, SIC                                          -              both
2     I010/000   message type (1: target report)                   -              both
3     I010/020   target report descriptor: TYP (3 PSR, 1 Mode-S    -              both
                 MLAT), GBS, one extension with TOT (1 aircraft,
                 2 vehicle, 0 undetermined)
4     I010/140   time of day, s since UTC midnight                 1/128 s        both
6     I010/040   RHO, THETA polar position from the sensor         1 m, 360/2^16  smr
7     I010/042   X, Y Cartesian position (two's complement)        1 m            mlat
8     I010/200   ground speed, track angle                         2^-14 NM/s,    smr
                                                                   360/2^16 deg
9     I010/202   Vx, Vy Cartesian velocity (two's complement)      0.25 m/s       mlat
10    I010/161   track number (12 bits)                            -              both
11    I010/170   track status: TRE (last report), TCC, STH         -              both
13    I010/220   target address (24 bits)                          -              mlat
14    I010/245   target identification: STI + 8 six-bit chars      -              mlat
22    I010/500   standard deviation of position σx, σy, cov(x,y)   0.25 m, 0.25   both
                                                                   m, 0.25 m²
====  =========  ================================================  =============  ======

Values are rounded to the nearest LSB (:func:`quantise` gives the same numbers, so a
simulator can hold exactly what a decoder will read back). Angles are radians
clockwise from north here, velocities m/s, times int64 ns UTC.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from pipeline.units import NM_M, NS

NS_PER_DAY = 86_400 * NS

CATEGORY = 10
TOD_LSB_S = 1.0 / 128.0
RHO_LSB_M = 1.0
THETA_LSB_RAD = 2.0 * math.pi / 65536.0
XY_LSB_M = 1.0
VXY_LSB_MPS = 0.25
GS_LSB_MPS = NM_M * 2.0**-14
SIGMA_LSB_M = 0.25
COV_LSB_M2 = 0.25
MAX_BLOCK_BYTES = 65535

TYP_MODE_S_MLAT = 1
TYP_PSR = 3
TOT = {"aircraft": 1, "vehicle": 2}

# FSPEC per kind: FRNs 1,2,3,4,6 | 8,10,11 | - | 22  (smr)
#                 FRNs 1,2,3,4,7 | 9,10,11,13,14 | - | 22  (mlat)
FSPEC = {
    "smr": bytes([0xF5, 0xB1, 0x01, 0x80]),
    "mlat": bytes([0xF3, 0x77, 0x01, 0x80]),
}

_ICAO_CHARS = " ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"


def _icao6(c: str) -> int:
    """ICAO Annex 10 six-bit code of one character (A-Z 1-26, space 32, 0-9 48-57)."""
    if c == " ":
        return 32
    if "A" <= c <= "Z":
        return ord(c) - ord("A") + 1
    if "0" <= c <= "9":
        return 48 + ord(c) - ord("0")
    raise ValueError(f"character {c!r} has no ICAO six-bit code")


def quantise(value: np.ndarray, lsb: float) -> np.ndarray:
    """``value`` rounded to the nearest multiple of ``lsb`` (what the wire carries)."""
    return np.round(np.asarray(value, float) / lsb) * lsb


def quantise_azimuth(azimuth_rad: np.ndarray) -> np.ndarray:
    """Azimuth on the I010/040 grid, in [0, 2π)."""
    return np.mod(np.round(np.asarray(azimuth_rad) / THETA_LSB_RAD), 65536) * THETA_LSB_RAD


@dataclass(frozen=True)
class Cat010Reports:
    """A batch of CAT010 target reports of ONE sensor kind (``smr`` or ``mlat``).

    Arrays have one entry per report. ``time_ns``: time of applicability (int64 ns UTC);
    ``smr``: ``range_m``, ``azimuth_rad``, ``speed_mps``, ``course_rad``; ``mlat``:
    ``x_m``, ``y_m``, ``vx_mps``, ``vy_mps``, ``target_address`` (24-bit), ``callsign``
    (≤ 8 characters of A-Z 0-9 space), ``target_type`` ("aircraft"/"vehicle"/"").
    ``sigma_x_m``, ``sigma_y_m``, ``cov_xy_m2``: the I010/500 accuracy; ``last`` marks a
    track's last report (I010/170 TRE)."""

    kind: str
    sac: int
    sic: int
    time_ns: np.ndarray
    track_number: np.ndarray
    sigma_x_m: np.ndarray
    sigma_y_m: np.ndarray
    cov_xy_m2: np.ndarray
    last: np.ndarray
    range_m: np.ndarray | None = None
    azimuth_rad: np.ndarray | None = None
    speed_mps: np.ndarray | None = None
    course_rad: np.ndarray | None = None
    x_m: np.ndarray | None = None
    y_m: np.ndarray | None = None
    vx_mps: np.ndarray | None = None
    vy_mps: np.ndarray | None = None
    target_address: np.ndarray | None = None
    callsign: np.ndarray | None = None
    target_type: np.ndarray | None = None


def _be(values: np.ndarray, n_bytes: int, *, signed: bool = False, what: str = "") -> np.ndarray:
    """(n,) integers -> (n, n_bytes) big-endian uint8; out-of-range raises."""
    v = np.asarray(values, np.int64)
    lo, hi = (
        (-(1 << (8 * n_bytes - 1)), (1 << (8 * n_bytes - 1)) - 1)
        if signed
        else (0, (1 << (8 * n_bytes)) - 1)
    )
    if v.size and (v.min() < lo or v.max() > hi):
        raise ValueError(f"{what} out of range for {n_bytes} octets: [{v.min()}, {v.max()}]")
    v = np.mod(v, 1 << (8 * n_bytes))
    shifts = 8 * np.arange(n_bytes - 1, -1, -1)
    return ((v[:, None] >> shifts[None, :]) & 0xFF).astype(np.uint8)


def _time_of_day(time_ns: np.ndarray) -> np.ndarray:
    """I010/140 counts: seconds since UTC midnight / (1/128 s), rounded."""
    tod_ns = np.mod(np.asarray(time_ns, np.int64), NS_PER_DAY)
    return np.mod(np.round(tod_ns / (TOD_LSB_S * NS)).astype(np.int64), 1 << 24)


def _callsign_bits(callsign: np.ndarray) -> np.ndarray:
    """(n,) strings -> (n, 6) uint8 of I010/245 TId (8 × 6 bits), space padded."""
    names = [str(c or "").upper().ljust(8)[:8] for c in callsign]
    # one pass over distinct names (a few dozen), not over reports
    table = {n: sum(_icao6(ch) << (6 * (7 - i)) for i, ch in enumerate(n)) for n in set(names)}
    return _be(np.array([table[n] for n in names], np.int64), 6, what="callsign")


def encode_records(r: Cat010Reports) -> np.ndarray:
    """(n, record_length) uint8: one CAT010 record per row, FSPEC first."""
    if r.kind not in FSPEC:
        raise ValueError(f"CAT010 encoder supports kinds {tuple(FSPEC)}, got {r.kind!r}")
    n = len(r.time_ns)
    smr = r.kind == "smr"
    ttype = (
        np.zeros(n, np.int64)
        if r.target_type is None
        else np.array([TOT.get(str(t), 0) for t in r.target_type], np.int64)
    )
    typ = TYP_PSR if smr else TYP_MODE_S_MLAT
    gbs = 0 if smr else 1
    cols = [
        np.tile(np.frombuffer(FSPEC[r.kind], np.uint8), (n, 1)),
        _be(np.full(n, (r.sac << 8) | r.sic), 2, what="SAC/SIC"),  # I010/010
        _be(np.ones(n, np.int64), 1),  # I010/000
        np.column_stack(
            [  # I010/020
                np.full(n, (typ << 5) | (gbs << 2) | 1, np.uint8),
                (ttype << 1).astype(np.uint8),
            ]
        ),
        _be(_time_of_day(r.time_ns), 3, what="time of day"),  # I010/140
    ]
    if smr:
        rho = np.round(np.asarray(r.range_m) / RHO_LSB_M).astype(np.int64)
        theta = np.mod(np.round(np.asarray(r.azimuth_rad) / THETA_LSB_RAD), 65536)
        gs = np.round(np.asarray(r.speed_mps) / GS_LSB_MPS).astype(np.int64)
        ta = np.mod(np.round(np.asarray(r.course_rad) / THETA_LSB_RAD), 65536)
        cols += [
            _be(rho, 2, what="RHO"),
            _be(theta, 2),  # I010/040
            _be(gs, 2, what="ground speed"),
            _be(ta, 2),
        ]  # I010/200
    else:
        x = np.round(np.asarray(r.x_m) / XY_LSB_M)
        y = np.round(np.asarray(r.y_m) / XY_LSB_M)
        vx = np.round(np.asarray(r.vx_mps) / VXY_LSB_MPS)
        vy = np.round(np.asarray(r.vy_mps) / VXY_LSB_MPS)
        cols += [
            _be(x, 2, signed=True, what="X"),
            _be(y, 2, signed=True, what="Y"),  # /042
            _be(vx, 2, signed=True, what="Vx"),
            _be(vy, 2, signed=True, what="Vy"),
        ]  # /202
    status = (np.asarray(r.last, bool).astype(np.int64) << 6) | (1 << 2)  # TRE, TCC
    track = np.asarray(r.track_number, np.int64)
    if track.size and (track.min() < 0 or track.max() > 4095):
        raise ValueError("I010/161 track numbers are 12 bits: 0..4095")
    cols += [_be(track, 2), _be(status, 1)]  # I010/161, /170
    if not smr:
        cols += [
            _be(np.asarray(r.target_address, np.int64), 3, what="target address"),
            np.column_stack([np.zeros((n, 1), np.uint8), _callsign_bits(r.callsign)]),
        ]
    sx = np.minimum(np.round(np.asarray(r.sigma_x_m) / SIGMA_LSB_M), 255)
    sy = np.minimum(np.round(np.asarray(r.sigma_y_m) / SIGMA_LSB_M), 255)
    cxy = np.clip(np.round(np.asarray(r.cov_xy_m2) / COV_LSB_M2), -32768, 32767)
    cols += [_be(sx, 1), _be(sy, 1), _be(cxy, 2, signed=True)]  # I010/500
    return np.concatenate(cols, axis=1)


def encode_blocks(r: Cat010Reports, block_key: np.ndarray) -> tuple[np.ndarray, list[bytes]]:
    """Pack records into data blocks, one per run of equal ``block_key`` (e.g. the
    update time); records must be sorted by ``block_key``. Returns (the key of each
    block, the blocks' bytes). A run too long for one block (LEN is 16 bits) is split."""
    recs = encode_records(r)
    key = np.asarray(block_key)
    if key.size and np.any(key[1:] < key[:-1]):
        raise ValueError("records must be sorted by block_key")
    per_block = max(1, (MAX_BLOCK_BYTES - 3) // max(recs.shape[1], 1))
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if key.size else np.array([], int)
    bounds = np.r_[starts, key.size]
    keys, blocks = [], []
    for a, b in itertools.pairwise(bounds):  # one iteration per update cycle
        for c in range(a, b, per_block):
            body = recs[c : min(b, c + per_block)].tobytes()
            length = 3 + len(body)
            blocks.append(bytes([CATEGORY, length >> 8, length & 0xFF]) + body)
            keys.append(key[a])
    return np.asarray(keys), blocks
