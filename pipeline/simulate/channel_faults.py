"""Channel faults of the ``channel`` scenario (``[[channel_faults]]``, issue 22): what each
fault does to a radar site's reports or to an AIS station, and the fault truth.

Every effect is applied to the arrays the fault-free simulation draws, with the same
random streams: a run with faults and the same run without them share every noise
sample, so detection and accuracy can be compared pair by pair.

Radar (per site, by the sweep time of each report, s since the scenario start):

- ``radar_outage``: the site is down: no detections, and no report is published while it
  lasts (no scan messages at all); its tracker drops the tracks it coasted through the
  outage and initiates them again afterwards (3 detections);
- ``radar_blank``: no detections in the azimuths [from, to) (clockwise, the site's own
  azimuths): the tracker coasts its tracks there for 2 scans, then drops them;
- ``radar_range_bias`` / ``radar_azimuth_bias``: the value is added to ranges / to
  azimuths and courses (a range-gate or encoder fault);
- ``radar_time_offset``: the value is added to report times (a clock jump);
- ``radar_range_gain``: ranges are multiplied by (1 + the value) (a range scale error);
- ``radar_noise``: range, azimuth, course and speed noise scaled by the factor; the
  reported sigmas stay as configured (the tracker does not know).

A bias, clock, gain or noise fault with azimuths [from, to) acts there only (an encoder
error over part of the rotation, a range error over one bearing's path); without them
(from = to) at every azimuth.

AIS (per station, by the time of each transmission): ``ais_offset`` adds an east/north
offset to the reported positions; ``ais_stuck`` reports the position, SOG and COG of the
fault start (a frozen GNSS) with fresh noise; ``ais_mmsi_swap`` makes two stations send
each other's MMSI in every message; ``ais_spoof`` adds a station on no ship.

Fault truth (:func:`fault_truth`): one row per affected channel (a swap is two rows).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import polars as pl

from pipeline.frames import TWO_PI
from pipeline.maritime.config import ChannelFault
from pipeline.messages import message_layout
from pipeline.units import NS

FAULT_TRUTH_SCHEMA: dict[str, pl.DataType] = message_layout(
    "fault_truth.schema.json").polars_schema()
"""Columns of a ``fault_truth`` frame: the fields of ``schemas/fault_truth.schema.json``."""

_UNITS = {
    "radar_range_bias": "m",
    "radar_azimuth_bias": "rad",
    "radar_time_offset": "s",
    "radar_noise": "factor",
    "radar_range_gain": "ratio",
    "ais_offset": "m",
}


def _on(f: ChannelFault, t_s: np.ndarray) -> np.ndarray:
    return (t_s >= f.start_s) & (t_s < f.end_s)


def _acts(f: ChannelFault, t_s: np.ndarray, az_rad: np.ndarray) -> np.ndarray:
    """Where a radar fault acts: while it is on, and in its azimuths when it has them."""
    on = _on(f, t_s)
    if f.azimuth_from_rad == f.azimuth_to_rad:
        return on
    return on & in_azimuths(az_rad, f.azimuth_from_rad, f.azimuth_to_rad)


def in_azimuths(az_rad: np.ndarray, lo_rad: float, hi_rad: float) -> np.ndarray:
    """Azimuths in the clockwise interval [lo, hi) (wrapping through north)."""
    width = np.mod(hi_rad - lo_rad, TWO_PI)
    return np.mod(np.asarray(az_rad) - lo_rad, TWO_PI) < width


def radar_effects(
    faults: Sequence[ChannelFault], t_s: np.ndarray, az_rad: np.ndarray, range_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Effects of one site's faults on reports swept at ``t_s`` (s), azimuth ``az_rad``
    and true range ``range_m``: (detection possible (bool), range added (m), azimuth
    added (rad), time added (s), noise factor)."""
    n = np.shape(t_s)[0]
    detect = np.ones(n, bool)
    dr, daz, dt, noise = np.zeros(n), np.zeros(n), np.zeros(n), np.ones(n)
    for f in faults:
        on = _on(f, t_s) if f.kind in ("radar_outage", "radar_blank") else _acts(f, t_s, az_rad)
        if f.kind == "radar_outage":
            detect &= ~on
        elif f.kind == "radar_blank":
            detect &= ~(on & in_azimuths(az_rad, f.azimuth_from_rad, f.azimuth_to_rad))
        elif f.kind == "radar_range_bias":
            dr += np.where(on, f.value, 0.0)
        elif f.kind == "radar_range_gain":
            dr += np.where(on, f.value * np.asarray(range_m), 0.0)
        elif f.kind == "radar_azimuth_bias":
            daz += np.where(on, f.value, 0.0)
        elif f.kind == "radar_time_offset":
            dt += np.where(on, f.value, 0.0)
        elif f.kind == "radar_noise":
            noise = np.where(on, noise * f.value, noise)
    return detect, dr, daz, dt, noise


def radar_silent(faults: Sequence[ChannelFault], log_t_s: np.ndarray) -> np.ndarray:
    """Reports not published: those of scans ending (log time, s) during an outage."""
    out = np.zeros(np.shape(log_t_s)[0], bool)
    for f in faults:
        if f.kind == "radar_outage":
            out |= _on(f, log_t_s)
    return out


# --- AIS --------------------------------------------------------------------------


def ais_offsets(faults: Sequence[ChannelFault], t_s: np.ndarray) -> np.ndarray:
    """(n, 2) east/north offsets (m) added to one station's positions at ``t_s``."""
    out = np.zeros((np.shape(t_s)[0], 2))
    for f in faults:
        if f.kind == "ais_offset":
            out[_on(f, t_s)] += (f.east_m, f.north_m)
    return out


def ais_state_times(faults: Sequence[ChannelFault], t_s: np.ndarray) -> np.ndarray:
    """Times whose true state a station reports: the fault start while it is stuck."""
    out = np.asarray(t_s, float).copy()
    for f in faults:
        if f.kind == "ais_stuck":
            out = np.where(_on(f, t_s), f.start_s, out)
    return out


def ais_mmsi(faults: Sequence[tuple[ChannelFault, int]], own: int, t_s: float) -> int:
    """The MMSI a station sends at ``t_s``: ``own``, or the other's during a swap
    (``faults``: (swap fault, the other station's MMSI))."""
    for f, other in faults:
        if f.start_s <= t_s < f.end_s:
            return other
    return own


def pick_vessel(
    f: ChannelFault,
    candidates: Sequence[int],
    present: Callable[[int, float, float], bool],
    in_sector: Callable[[int, float, str], bool],
    seed: int,
    index: int,
    exclude: Sequence[int] = (),
) -> int | None:
    """The vessel (0-based index) an AIS fault without ``vessel_id`` hits: a seeded
    choice among ``candidates`` (Class A stations) in the scene for the whole fault (and
    in the fault's sector at its start, when it names one)."""
    ok = [
        v for v in candidates
        if v not in exclude and present(v, f.start_s, f.end_s)
        and (not f.sector or in_sector(v, f.start_s, f.sector))
    ]
    if not ok:
        return None
    rng = np.random.default_rng([seed, 9, index])
    return int(ok[int(rng.integers(0, len(ok)))])


# --- truth -------------------------------------------------------------------------


def fault_truth(
    faults: Sequence[ChannelFault],
    start_ns: int,
    duration_s: float,
    *,
    vessel_of: Sequence[int | None],
    other_of: Sequence[int | None],
    mmsi_of: Callable[[int], int | None],
) -> pl.DataFrame:
    """One row per channel a fault affects: start_ns, end_ns (clipped to the scenario),
    family ("maritime"), sensor_kind (radar | ais), channel (site id or MMSI), kind,
    value and unit (bias m / rad, offset s, noise factor, offset m), vessel_id (1-based),
    mmsi, detail. ``vessel_of``/``other_of``: per fault, the vessel index (0-based) it hit
    (None: none could be chosen, the fault is not injected)."""
    rows = []
    for f, v, o in zip(faults, vessel_of, other_of, strict=True):
        t0 = start_ns + round(f.start_s * NS)
        t1 = start_ns + round(min(f.end_s, duration_s) * NS)
        if t1 <= t0:
            continue
        base = {"start_ns": t0, "end_ns": t1, "family": "maritime",
                "sensor_kind": f.sensor_kind, "kind": f.kind, "value": f.value,
                "unit": _UNITS.get(f.kind), "vessel_id": None, "mmsi": None, "detail": None}
        if f.sensor_kind == "radar":
            detail = None
            if f.kind == "radar_blank" or f.azimuth_from_rad != f.azimuth_to_rad:
                detail = (f"azimuth {math.degrees(f.azimuth_from_rad):.1f}-"
                          f"{math.degrees(f.azimuth_to_rad):.1f} deg")
            rows.append({**base, "channel": f.site_id, "detail": detail})
        elif f.kind == "ais_spoof":
            rows.append({**base, "channel": str(f.mmsi), "mmsi": f.mmsi,
                         "detail": "transponder on no ship"})
        elif v is not None:
            if f.kind == "ais_offset":
                base.update(value=math.hypot(f.east_m, f.north_m),
                            detail=f"east {f.east_m:.1f} m, north {f.north_m:.1f} m")
            pairs = [(v, o)] + ([(o, v)] if f.kind == "ais_mmsi_swap" and o is not None else [])
            for a, b in pairs:
                m = mmsi_of(a)
                detail = base["detail"]
                if f.kind == "ais_mmsi_swap":
                    detail = f"sends the MMSI of vessel {b + 1} ({mmsi_of(b)})"
                rows.append({**base, "channel": str(m), "mmsi": m, "vessel_id": a + 1,
                             "detail": detail})
    return pl.DataFrame(rows, schema=FAULT_TRUTH_SCHEMA, orient="row") if rows else \
        pl.DataFrame(schema=FAULT_TRUTH_SCHEMA)
