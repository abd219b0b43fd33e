"""Simulated AIS traffic: station identities, ITU-R M.1371 reporting schedules and
``!AIVDM`` sentences encoded with pyais.

What is modelled (ITU-R M.1371-5, Annex 1 §4.2 / Table 1 for Class A, Table 2 for
Class B "CS"; intervals in seconds):

========================================  ==================
Class A, 0–14 kn                          10
Class A, 0–14 kn and changing course      3 1/3
Class A, 14–23 kn                         6
Class A, 14–23 kn and changing course     2
Class A, > 23 kn                          2
Class B CS, > 2 kn                        30
Class B CS, <= 2 kn                       180
Static, Class A (message 5)               360
Static, Class B (message 24 A + B)        360
========================================  ==================

"Changing course" is taken as "on a turning arc of the route" (the simulator knows it).
Class A ships send message 1 (SOTDMA), and message 3 (ITDMA) for the first report
after their reporting interval changed; Class B ships send message 18. Ships at anchor
or moored (3 min) do not occur in the scenario.

Every transmission is received (no slot collisions, no coverage holes). The reception
time (MCAP log time) is the transmission time rounded to the millisecond; the position
is the true position at that time plus white Gaussian GNSS error (``sigma`` 3 m east and
north); SOG and COG are the truth plus small white noise, quantised as on the air
(0.1 kn, 0.1 deg). The UTC-second field is the second of the fix. The two sentences of a
message 5 share one log time and carry a sequential message id 0–9 that advances over
all multi-sentence messages in time order.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from datetime import UTC, datetime

import numpy as np
import polars as pl
from pyais import encode_dict

from pipeline.simulate.channel_faults import ais_mmsi, ais_offsets, ais_state_times
from pipeline.units import KNOT_MPS

"""One knot in m/s."""

CLASS_A_STATIC_INTERVAL_S = 360.0
CLASS_B_STATIC_INTERVAL_S = 360.0
CLASS_B_PART_B_DELAY_S = 1.0
"""Message 24 part B follows part A after this delay, s."""

GNSS_SIGMA_M = 3.0
"""1-sigma GNSS position error, east and north, m."""
SOG_SIGMA_MPS = 0.05
COG_SIGMA_RAD = math.radians(0.5)

_WGS84_A_M = 6378137.0
_WGS84_E2 = 6.69437999014e-3

StateFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
"""``state(t_s) -> (lat_deg, lon_deg, course_rad, speed_mps)`` of one vessel at times
``t_s`` (s since the scenario start); course clockwise from true north."""


def class_a_interval_s(sog_kn: float, changing_course: bool) -> float:
    """Class A position-report interval, s (ITU-R M.1371-5 Annex 1, Table 1)."""
    if sog_kn > 23.0:
        return 2.0
    if sog_kn > 14.0:
        return 2.0 if changing_course else 6.0
    return 10.0 / 3.0 if changing_course else 10.0


def class_b_interval_s(sog_kn: float) -> float:
    """Class B "CS" position-report interval, s (ITU-R M.1371-5 Annex 1, Table 2)."""
    return 30.0 if sog_kn > 2.0 else 180.0


@dataclass(frozen=True)
class AisIdentity:
    """Static data a station broadcasts (messages 5 and 24). Dimensions in m."""

    mmsi: int
    ais_class: str  # "A" | "B"
    shipname: str
    callsign: str
    imo: int  # 0 for Class B
    ship_type: int  # ITU-R M.1371 ship and cargo type code
    to_bow_m: int
    to_stern_m: int
    to_port_m: int
    to_starboard_m: int
    draught_m: float
    destination: str
    vendor_id: str


@dataclass(frozen=True, eq=False)
class AisStation:
    """One AIS-equipped vessel as the scheduler sees it.

    ``turn_windows_s``: (n, 2) array of [begin, end) times, s since the scenario start,
    while the vessel is changing course. Speed is constant over the vessel's life.
    ``faults``: its ``ais_offset`` / ``ais_stuck`` channel faults, ``swaps``: (``ais_mmsi_swap``
    fault, the MMSI it sends meanwhile) (:mod:`pipeline.simulate.channel_faults`).
    """

    vessel_id: int
    identity: AisIdentity
    speed_mps: float
    t_enter_s: float
    t_exit_s: float
    turn_windows_s: np.ndarray
    seed_key: tuple[int, ...]
    faults: tuple = ()
    swaps: tuple = ()


# --- identities ------------------------------------------------------------------

# MID -> call sign prefix (ITU Radio Regulations, Appendix 42), a few Black Sea and
# open-register flags.
_FLAGS: tuple[tuple[int, str], ...] = (
    (272, "UR"),  # Ukraine
    (271, "TC"),  # Türkiye
    (248, "9H"),  # Malta
    (636, "D5"),  # Liberia
    (538, "V7"),  # Marshall Islands
    (209, "5B"),  # Cyprus
    (241, "SV"),  # Greece
    (264, "YQ"),  # Romania
    (207, "LZ"),  # Bulgaria
)
_NAME_FIRST = (
    "DNIPRO",
    "ODESA",
    "PIVDENNYI",
    "CHORNOMORSK",
    "IZMAIL",
    "DANUBE",
    "AEGEAN",
    "MARMARA",
    "ANATOLIA",
    "HANSA",
    "AMBER",
    "CORAL",
    "NORDIC",
    "ATLANTIC",
    "PONTIC",
    "TAVRIA",
)
_NAME_SECOND = (
    "STAR",
    "TRADER",
    "SPIRIT",
    "PIONEER",
    "GLORY",
    "WAVE",
    "EXPRESS",
    "HOPE",
    "VENTURE",
    "PRIDE",
    "LIGHT",
    "BREEZE",
    "CARRIER",
    "PROSPECT",
)
_SMALL_CRAFT = (
    "CHAIKA",
    "DELFIN",
    "VESNA",
    "ALBATROS",
    "MRIYA",
    "ZORIA",
    "KALYNA",
    "BRIZ",
    "SKIF",
    "KATRAN",
    "BUREVISNYK",
    "VITRYLO",
)
_DESTINATIONS_INBOUND = ("ODESA", "PIVDENNYI", "CHORNOMORSK", "MYKOLAIV")
_DESTINATIONS_OUTBOUND = ("ISTANBUL", "CONSTANTA", "VARNA", "PIRAEUS", "BOURGAS")
_ALNUM = "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"


def _imo_with_check_digit(body6: int) -> int:
    """IMO number: six digits plus the check digit (sum of digit x weight 7..2, mod 10)."""
    digits = [int(c) for c in f"{body6:06d}"]
    check = sum(d * w for d, w in zip(digits, range(7, 1, -1), strict=True)) % 10
    return body6 * 10 + check


def draw_identity(
    rng: np.random.Generator, *, ais_class: str, kind: str, inbound: bool
) -> AisIdentity:
    """Random but plausible static data for one station.

    ``kind``: "fairway" (merchant ship or, for Class B, small craft) or "ferry".
    The MMSI is MID followed by six digits (a ship station, ITU-R M.585).
    """
    if ais_class == "B":
        mid, cs_prefix = _FLAGS[0] if rng.random() < 0.8 else _FLAGS[int(rng.integers(1, 9))]
    else:
        mid, cs_prefix = _FLAGS[int(rng.integers(0, len(_FLAGS)))]
    mmsi = mid * 1_000_000 + int(rng.integers(100_000, 1_000_000))
    callsign = cs_prefix + "".join(_ALNUM[int(i)] for i in rng.integers(0, 36, size=4))
    destination = (_DESTINATIONS_INBOUND if inbound else _DESTINATIONS_OUTBOUND)[
        int(rng.integers(0, 4))
    ]
    if kind == "ferry":
        name = f"FERRY {_NAME_FIRST[int(rng.integers(0, len(_NAME_FIRST)))]}"
        ship_type, length, beam, draught = 60, rng.uniform(60, 110), rng.uniform(14, 20), 4.0
        destination = "CROSSING"
    elif ais_class == "B":
        name = f"{_SMALL_CRAFT[int(rng.integers(0, len(_SMALL_CRAFT)))]} {int(rng.integers(1, 99))}"
        ship_type = (37, 36, 30)[int(rng.integers(0, 3))]  # pleasure, sailing, fishing
        length, beam, draught = rng.uniform(8, 22), rng.uniform(3, 6), 1.5
    else:
        name = (
            f"{_NAME_FIRST[int(rng.integers(0, len(_NAME_FIRST)))]} "
            f"{_NAME_SECOND[int(rng.integers(0, len(_NAME_SECOND)))]}"
        )
        ship_type = (70, 70, 70, 80, 80, 52)[int(rng.integers(0, 6))]  # cargo, tanker, tug
        if ship_type == 52:
            length, beam, draught = rng.uniform(25, 40), rng.uniform(8, 12), 4.0
        else:
            length, beam, draught = rng.uniform(90, 200), rng.uniform(14, 32), rng.uniform(6, 11)
    to_bow = round(length * rng.uniform(0.7, 0.85))
    to_port = round(beam / 2)
    return AisIdentity(
        mmsi=mmsi,
        ais_class=ais_class,
        shipname=name[:20],
        callsign=callsign,
        imo=0 if ais_class == "B" else _imo_with_check_digit(int(rng.integers(900_000, 1_000_000))),
        ship_type=ship_type,
        to_bow_m=min(to_bow, 511),
        to_stern_m=min(round(length) - to_bow, 511),
        to_port_m=min(to_port, 63),
        to_starboard_m=min(round(beam) - to_port, 63),
        draught_m=round(float(draught), 1),
        destination=destination,
        vendor_id="SRV",
    )


# --- schedules ---------------------------------------------------------------------


def _turning(t: float, windows: np.ndarray) -> bool:
    i = int(np.searchsorted(windows[:, 0], t, side="right")) - 1
    return i >= 0 and t < windows[i, 1]


def position_report_times(
    station: AisStation, phase_u: float, duration_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Times of the position reports, s since the scenario start, and their message id.

    The first report comes ``phase_u`` (uniform in [0, 1)) of an interval after the
    vessel appears; each next one one reporting interval (Table 1/2) later.
    """
    sog_kn = station.speed_mps / KNOT_MPS
    end = min(station.t_exit_s, duration_s)
    times: list[float] = []
    msg_ids: list[int] = []
    windows = station.turn_windows_s
    if station.identity.ais_class == "B":
        step = class_b_interval_s(sog_kn)
        t = station.t_enter_s + phase_u * step
        n = max(0, math.ceil((end - t) / step))
        arr = t + step * np.arange(n, dtype=float)
        return arr[arr < end], np.full(int(np.sum(arr < end)), 18, dtype=np.int16)
    t = station.t_enter_s + phase_u * class_a_interval_s(
        sog_kn, _turning(station.t_enter_s, windows)
    )
    prev_step = None
    while t < end:
        step = class_a_interval_s(sog_kn, _turning(t, windows))
        times.append(t)
        # ITDMA (message 3) announces a change of the reporting rate
        msg_ids.append(3 if prev_step is not None and step != prev_step else 1)
        prev_step = step
        t += step
    return np.asarray(times, dtype=float), np.asarray(msg_ids, dtype=np.int16)


def _offset_lat_lon(
    lat_deg: np.ndarray, lon_deg: np.ndarray, east_m: np.ndarray, north_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Move WGS-84 points by small east/north offsets (m), with the ellipsoid's radii."""
    phi = np.radians(lat_deg)
    w = 1.0 - _WGS84_E2 * np.sin(phi) ** 2
    n_radius = _WGS84_A_M / np.sqrt(w)
    m_radius = _WGS84_A_M * (1.0 - _WGS84_E2) / w**1.5
    return (
        lat_deg + np.degrees(north_m / m_radius),
        lon_deg + np.degrees(east_m / (n_radius * np.cos(phi))),
    )


def simulate_ais(
    stations: Sequence[tuple[AisStation, StateFn]],
    *,
    start_ns: int,
    duration_s: float,
    seed: int,
) -> pl.DataFrame:
    """AIS sentences received from ``stations`` during [0, duration_s).

    Returns a frame ``log_time_ns`` (int64, reception time), ``sentence`` (str, one NMEA
    sentence per row; the sentences of one message are consecutive rows with the same
    log time), ``mmsi`` (int64) and ``msg_type`` (int16), sorted by log time.
    """
    rows: list[tuple[float, int, int, int, dict]] = []  # (t, vessel, part_order, nparts, dict)
    for station, state in stations:
        rng = np.random.default_rng([seed, *station.seed_key])
        phase_pos, phase_static = rng.random(2)
        t_pos, msg_ids = position_report_times(station, float(phase_pos), duration_s)
        t_pos = np.round(t_pos * 1e3) / 1e3  # received with ms time stamps
        ident = station.identity
        if t_pos.size:
            z = rng.standard_normal((t_pos.size, 4))
            lat, lon, course, speed = state(ais_state_times(station.faults, t_pos))
            off = ais_offsets(station.faults, t_pos)
            lat, lon = _offset_lat_lon(
                lat, lon, GNSS_SIGMA_M * z[:, 0] + off[:, 0], GNSS_SIGMA_M * z[:, 1] + off[:, 1]
            )
            sog_kn = np.clip(np.round((speed + SOG_SIGMA_MPS * z[:, 2]) / KNOT_MPS, 1), 0, 102.2)
            cog_deg = np.mod(np.round(np.degrees(course + COG_SIGMA_RAD * z[:, 3]), 1), 360.0)
            heading = np.mod(np.round(np.degrees(course)), 360).astype(int)
            fix_ns = start_ns + np.round(t_pos * 1e3).astype(np.int64) * 1_000_000
            second = (fix_ns // 1_000_000_000) % 60
            for i in range(t_pos.size):
                msg: dict = {
                    "type": int(msg_ids[i]),
                    "mmsi": ais_mmsi(station.swaps, ident.mmsi, float(t_pos[i])),
                    "speed": float(sog_kn[i]),
                    "accuracy": True,
                    "lon": float(lon[i]),
                    "lat": float(lat[i]),
                    "course": float(cog_deg[i]),
                    "second": int(second[i]),
                }
                if ident.ais_class == "A":
                    msg.update(status=0, heading=int(heading[i]), maneuver=0)
                else:
                    msg.update(heading=511, cs=True, dsc=True, band=True, msg22=True)
                rows.append((float(t_pos[i]), station.vessel_id, 0, 1, msg))
        end = min(station.t_exit_s, duration_s)
        step = CLASS_A_STATIC_INTERVAL_S if ident.ais_class == "A" else CLASS_B_STATIC_INTERVAL_S
        t_static = station.t_enter_s + float(phase_static) * step
        t_static_all = t_static + step * np.arange(max(0, math.ceil((end - t_static) / step)))
        for t in t_static_all[t_static_all < end]:
            sent = replace(ident, mmsi=ais_mmsi(station.swaps, ident.mmsi, float(t)))
            rows.extend(_static_messages(sent, float(t), station.vessel_id, start_ns))
    # time order; the parts of a message 24 follow each other by their own times
    rows.sort(key=lambda r: (r[0], r[1], r[2]))
    log_time: list[int] = []
    sentences: list[str] = []
    mmsis: list[int] = []
    types: list[int] = []
    seq_counter = 0
    tx_counter: dict[int, int] = {}
    for t, vessel_id, _, nparts, msg in rows:
        k = tx_counter.get(vessel_id, 0)
        tx_counter[vessel_id] = k + 1
        channel = "A" if k % 2 == 0 else "B"  # stations alternate the two VHF channels
        seq_id = None
        if nparts > 1:
            seq_id = seq_counter % 10
            seq_counter += 1
        parts = encode_dict(
            msg, talker_id="AI", sentence_type="VDM", radio_channel=channel, seq_id=seq_id
        )
        t_ns = start_ns + round(t * 1e3) * 1_000_000
        for p in parts:
            log_time.append(t_ns)
            sentences.append(p)
            mmsis.append(msg["mmsi"])
            types.append(msg["type"])
    return pl.DataFrame(
        {"log_time_ns": log_time, "sentence": sentences, "mmsi": mmsis, "msg_type": types},
        schema={
            "log_time_ns": pl.Int64,
            "sentence": pl.String,
            "mmsi": pl.Int64,
            "msg_type": pl.Int16,
        },
    )


def _static_messages(
    ident: AisIdentity, t: float, vessel_id: int, start_ns: int
) -> list[tuple[float, int, int, int, dict]]:
    """Message 5 (Class A, two sentences) or messages 24 A and B (Class B) at ``t``."""
    dims = {
        "to_bow": ident.to_bow_m,
        "to_stern": ident.to_stern_m,
        "to_port": ident.to_port_m,
        "to_starboard": ident.to_starboard_m,
    }
    if ident.ais_class == "A":
        eta = datetime.fromtimestamp(start_ns // 1_000_000_000 + 86_400, tz=UTC)
        msg5 = {
            "type": 5,
            "mmsi": ident.mmsi,
            "ais_version": 2,
            "imo": ident.imo,
            "callsign": ident.callsign,
            "shipname": ident.shipname,
            "ship_type": ident.ship_type,
            "epfd": 1,
            "month": eta.month,
            "day": eta.day,
            "hour": 12,
            "minute": 0,
            "draught": ident.draught_m,
            "destination": ident.destination,
            "dte": False,
            **dims,
        }
        return [(t, vessel_id, 0, 2, msg5)]
    part_a = {"type": 24, "mmsi": ident.mmsi, "partno": 0, "shipname": ident.shipname}
    part_b = {
        "type": 24,
        "mmsi": ident.mmsi,
        "partno": 1,
        "ship_type": ident.ship_type,
        "vendorid": ident.vendor_id,
        "model": 1,
        "serial": ident.mmsi % 1_000_000,
        "callsign": ident.callsign,
        **dims,
    }
    return [(t, vessel_id, 0, 1, part_a), (t + CLASS_B_PART_B_DELAY_S, vessel_id, 1, 1, part_b)]
