"""The ``region`` scenario: a regional VTS day, ~1,000 ships seen by six coastal radars
with overlapping coverage and by AIS, simulated slice by slice (never the whole day in
memory).

Geography: :mod:`pipeline.simulate.region_layout` (three ports, a two-lane traffic
separation scheme, two anchorages, fishing grounds, two ferry lines, radar sites along
the coast). Deterministic per seed; the traffic plan is drawn hour block by hour block
(each block from its own seed stream), so a run of any length is a prefix of a longer
one with the same seed and start.

Traffic (``n_ships`` is the mean number of ships in the scene; the day has peaks):

- **transit** ships on the lanes, edge to edge (30 % of the mean count);
- **arrivals** from the west (eastbound lane), the east (westbound lane) or the south
  (crossing both lanes), up a port approach to a port entrance (13 %);
- **arrivals via an anchorage**: to a random point of an anchorage, at anchor 1-10 h
  (swinging on a circle of 40-80 m), then to a port (22 %: most of them at anchor);
- **departures** from a port down its approach to a lane or south (13 %);
- **small craft** (fishing, pleasure): from a port to a fishing ground, a few slow legs
  there, back to port; they leave mostly around dawn (20 %);
- **ferries**: two lines (across the lanes to an offshore terminal; along the coast),
  two ferries each, 05:30-22:30 every day.

Merchant arrivals and departures follow a diurnal rate 1 + 0.3 cos(2 pi (h - 9) / 24)
(h = UTC hour), small craft a dawn peak, so the number of ships in the scene swings
by about +-30 % around ``n_ships`` over the day. The plan starts 16 h before the
scenario start so the first hour is in steady state (ships under way, at anchor).

AIS carriage: merchant ships Class A (90 %), Class B (4 %), none (6 %); small craft
Class B or none (half each); ferries Class A. Class A at anchor reports every 3 min with
navigational status 1 (at anchor), otherwise as in :mod:`pipeline.simulate.ais_traffic`
(ITU-R M.1371 intervals, message 3 when the interval changes); Class B every 30 s
(180 s at <= 2 kn); static data every 6 min (messages 5, 24 A/B, through pyais).
Position reports are encoded by :mod:`pipeline.simulate.ais_encode` (the same sentences
as pyais, vectorised).

Radars: each site's tracker as in the ``channel`` scenario (antenna sweep times,
detection probability 0.97, initiation after 3 detections, 2 coasted scans, a confirmed
track lost with probability 0.002 per scan, reports published at the scan end), run
with its state carried from slice to slice; local track ids count up per site from 1.
Unlike the channel scenario's white errors, a track report's errors (range, azimuth,
course, speed) are those of a tracker's filtered output: first-order Gauss-Markov over
the track's scans with correlation time TRACKER_ERROR_TAU_S (15 s) and the site's
sigmas as stationary standard deviations.
Report values are rounded to a tracker's output resolution (range 1 cm, azimuth 1e-6 rad,
...). Truth: every ``truth_period_s`` (default 5 s) per vessel, lat/lon, true course,
speed.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np
import polars as pl
from pyais.encode import MSG_CLASS, ais_to_nmea_0183

from pipeline.frames import TWO_PI, enu_to_geodetic, enu_to_polar, geodetic_to_enu, polar_to_enu
from pipeline.simulate.ais_encode import SENTENCE_BYTES, encode_class_a, encode_class_b
from pipeline.simulate.ais_traffic import (
    COG_SIGMA_RAD,
    GNSS_SIGMA_M,
    SOG_SIGMA_MPS,
    AisIdentity,
    _offset_lat_lon,  # GNSS error on the ellipsoid
    class_a_interval_s,
    class_b_interval_s,
    draw_identity,
)
from pipeline.simulate.channel import (
    DETECTION_PROBABILITY,
    INITIATION_SCANS,
    MAX_COAST_SCANS,
    RADAR_REPORT_SCHEMA,
    TRACK_LOSS_PROBABILITY,
    TRUTH_SCHEMA,
    Route,
    build_route,
    convergence_rad,
)
from pipeline.simulate.region_layout import (
    ANCHORAGE_PORTS,
    ANCHORAGES,
    APPROACH_OFFSET_M,
    FERRY_LINES,
    GROUNDS,
    KM,
    LANE_EB_Y_M,
    LANE_WB_Y_M,
    PORTS,
    X_EDGE_M,
    Y_SOUTH_M,
    RegionLayout,
    SiteSpec,
)
from pipeline.units import KNOT_MPS, NS

# --- traffic ------------------------------------------------------------------------------
SHARES = {"transit": 0.30, "arrival": 0.13, "anchor": 0.22, "departure": 0.13, "craft": 0.20}
"""Share of the mean ship count per kind (ferries come on top)."""
MERCHANT_SPEED_MPS = (4.0, 9.5)
CRAFT_TRANSIT_SPEED_MPS = (4.0, 6.0)
CRAFT_FISHING_SPEED_MPS = (1.5, 2.5)
FERRY_SPEED_MPS = (7.0, 9.0)
FERRIES_PER_LINE = 2
FERRY_HOURS = (5.5, 22.5)
ANCHOR_DWELL_H = (1.0, 10.0)
ANCHOR_SWING_M = (40.0, 80.0)
ANCHOR_SWING_PERIOD_S = (1200.0, 3600.0)
LANE_HALF_WIDTH_M = 400.0
TURN_RADIUS_M = 600.0
CRAFT_TURN_RADIUS_M = 100.0
FERRY_TURN_RADIUS_M = 150.0
P_MERCHANT_CLASS = (0.90, 0.04)  # A, B (rest: no AIS)
P_CRAFT_CLASS_B = 0.5
PLAN_LEAD_H = 16
"""The traffic plan starts this many hours before the scenario (steady state at t = 0)."""
RADAR_WARMUP_S = 60.0
TRACKER_ERROR_TAU_S = 15.0
"""Correlation time of a site tracker's output errors, s: a track report is a filtered
estimate, its error changes little from one scan to the next (white report errors would
let any downstream Kalman filter average them away, which real track data do not allow)."""
TRUTH_PERIOD_S = 5.0
STATIC_INTERVAL_S = 360.0
ANCHOR_AIS_INTERVAL_S = 180.0
SLICE_S = 600
"""Slices of log time generated at once, s (aligned to multiples of SLICE_S since the epoch)."""

# random stream keys (second word of the seed sequence)
_PLAN, _IDENT, _RADAR, _RADAR_PHASE, _AIS, _AIS_PHASE, _FERRY = range(21, 28)
_KINDS = ("transit", "arrival", "anchor", "departure", "craft")
_STATUS = pl.Series("status", ["", "new", "confirmed", "coasting"], dtype=pl.String)


# --- vessel plans -------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Phase:
    """A part of a vessel's life: on a route at constant speed (``route`` set; arc
    length ``s0_m`` at ``t0_s``), or at anchor (``route`` None: swinging about
    (cx_m, cy_m) on a circle of ``swing_m`` with angular rate ``omega_radps``, back at
    the anchor point at t0 and t1). Times in s since the scenario start."""

    t0_s: float
    t1_s: float
    route: Route | None = None
    s0_m: float = 0.0
    speed_mps: float = 0.0
    cx_m: float = 0.0
    cy_m: float = 0.0
    swing_m: float = 0.0
    omega_radps: float = 0.0


@dataclass(eq=False)
class Vessel:
    """A planned vessel: id, kind, AIS class ("A"/"B"/None) and identity, life span
    [t_enter_s, t_exit_s) and phases; ``ais_*``: the AIS schedule (interval breakpoints,
    the interval and navigational status in each)."""

    vessel_id: int
    kind: str
    ais_class: str | None
    identity: AisIdentity | None
    t_enter_s: float
    t_exit_s: float
    phases: tuple[Phase, ...]
    ais_breaks: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ais_steps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ais_status: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def mmsi(self) -> int | None:
        return None if self.identity is None else self.identity.mmsi


def _route_phase(route: Route, t0: float, speed: float, s0: float = 0.0) -> Phase:
    return Phase(t0, t0 + (route.length_m - s0) / speed, route, s0, speed)


def _lane(rng: np.random.Generator, y: float) -> float:
    return y + rng.uniform(-LANE_HALF_WIDTH_M, LANE_HALF_WIDTH_M)


def _entry(rng: np.random.Generator, side: str, port_x: float) -> list[tuple[float, float]]:
    """The first vertices of an arrival from ``side`` towards an approach at ``port_x``."""
    if side == "west":
        y = _lane(rng, LANE_EB_Y_M)
        return [(-X_EDGE_M, y), (port_x - 9 * KM, y)]
    if side == "east":
        y = _lane(rng, LANE_WB_Y_M)
        return [(X_EDGE_M, y), (port_x + 9 * KM, y)]
    return [(port_x + rng.uniform(-8, 8) * KM, Y_SOUTH_M)]


def _exit(rng: np.random.Generator, side: str, port_x: float) -> list[tuple[float, float]]:
    """The last vertices of a departure from an approach at ``port_x`` towards ``side``."""
    if side == "west":
        y = _lane(rng, LANE_WB_Y_M)
        return [(port_x - 8 * KM, y), (-X_EDGE_M, y)]
    if side == "east":
        y = _lane(rng, LANE_EB_Y_M)
        return [(port_x + 8 * KM, y), (X_EDGE_M, y)]
    return [(port_x - rng.uniform(-8, 8) * KM, Y_SOUTH_M)]


def _plan_one(kind: str, rng: np.random.Generator, t0: float) -> list[Phase]:
    """Phases of one vessel of ``kind`` entering at ``t0`` (s)."""
    sides = ("west", "east", "south")
    side = sides[int(rng.choice(3, p=(0.4, 0.4, 0.2)))]
    ports = tuple(PORTS)
    if kind == "transit":
        if rng.random() < 0.5:
            y = _lane(rng, LANE_EB_Y_M)
            verts = [(-X_EDGE_M, y), (X_EDGE_M, y)]
        else:
            y = _lane(rng, LANE_WB_Y_M)
            verts = [(X_EDGE_M, y), (-X_EDGE_M, y)]
        speed = rng.uniform(*MERCHANT_SPEED_MPS)
        return [_route_phase(build_route(np.array(verts), TURN_RADIUS_M), t0, speed)]
    if kind == "arrival":
        px, py = PORTS[ports[int(rng.integers(3))]]
        ax = px + APPROACH_OFFSET_M
        verts = [*_entry(rng, side, px), (ax, -11 * KM), (ax, py - 0.8 * KM)]
        speed = rng.uniform(*MERCHANT_SPEED_MPS)
        return [_route_phase(build_route(np.array(verts), TURN_RADIUS_M), t0, speed)]
    if kind == "departure":
        px, py = PORTS[ports[int(rng.integers(3))]]
        dx = px - APPROACH_OFFSET_M
        turn_y = -11 * KM if side == "west" else -13 * KM if side == "east" else -12 * KM
        verts = [(dx, py - 0.8 * KM), (dx, turn_y), *_exit(rng, side, px)]
        speed = rng.uniform(*MERCHANT_SPEED_MPS)
        return [_route_phase(build_route(np.array(verts), TURN_RADIUS_M), t0, speed)]
    if kind == "anchor":
        name = tuple(ANCHORAGES)[int(rng.integers(len(ANCHORAGES)))]
        cx, cy, r = ANCHORAGES[name]
        rho, phi = r * math.sqrt(rng.random()), rng.uniform(0, TWO_PI)
        anchor = (cx + rho * math.sin(phi), cy + rho * math.cos(phi))
        port = ANCHORAGE_PORTS[name][int(rng.integers(2))]
        px, py = PORTS[port]
        speed = rng.uniform(*MERCHANT_SPEED_MPS)
        inbound = build_route(np.array([*_entry(rng, side, anchor[0]), anchor]), TURN_RADIUS_M)
        p1 = _route_phase(inbound, t0, speed)
        dwell = rng.uniform(*ANCHOR_DWELL_H) * 3600.0
        period = rng.uniform(*ANCHOR_SWING_PERIOD_S)
        turns = max(1, round(dwell / period))
        p2 = Phase(p1.t1_s, p1.t1_s + dwell, None, cx_m=anchor[0], cy_m=anchor[1],
                   swing_m=rng.uniform(*ANCHOR_SWING_M), omega_radps=TWO_PI * turns / dwell)
        ax = px + APPROACH_OFFSET_M
        onward = build_route(np.array([anchor, (ax, -6 * KM), (ax, py - 0.8 * KM)]),
                             TURN_RADIUS_M)
        return [p1, p2, _route_phase(onward, p2.t1_s, rng.uniform(*MERCHANT_SPEED_MPS))]
    if kind == "craft":
        gname = tuple(GROUNDS)[int(rng.integers(len(GROUNDS)))]
        gx, gy, gr = GROUNDS[gname]
        port = min(PORTS, key=lambda p: abs(PORTS[p][0] - gx) + rng.uniform(0, 30 * KM))
        px, py = PORTS[port]
        start = (px + rng.uniform(-0.6, 0.6) * KM, py - 0.8 * KM)
        rho, phi = gr * math.sqrt(rng.random()), rng.uniform(0, TWO_PI)
        first = (gx + rho * math.sin(phi), gy + rho * math.cos(phi))
        pts = [first]
        heading = math.atan2(first[0] - start[0], first[1] - start[1])
        for _ in range(int(rng.integers(3, 7))):
            turn = rng.uniform(-1.9, 1.9)  # at most ~110 deg per turn
            step = rng.uniform(1.5, 4.0) * KM
            x, y = (pts[-1][0] + step * math.sin(heading + turn),
                    pts[-1][1] + step * math.cos(heading + turn))
            if math.hypot(x - gx, y - gy) > gr:  # turn back towards the ground's centre
                home = math.atan2(gx - pts[-1][0], gy - pts[-1][1])
                turn = max(-1.9, min(1.9, math.remainder(home - heading, TWO_PI)))
            heading += turn
            pts.append((pts[-1][0] + step * math.sin(heading),
                        pts[-1][1] + step * math.cos(heading)))
        v_out, v_fish, v_back = (rng.uniform(*CRAFT_TRANSIT_SPEED_MPS),
                                 rng.uniform(*CRAFT_FISHING_SPEED_MPS),
                                 rng.uniform(*CRAFT_TRANSIT_SPEED_MPS))
        out = _route_phase(build_route(np.array([start, first]), CRAFT_TURN_RADIUS_M), t0, v_out)
        fish = _route_phase(build_route(np.array(pts), CRAFT_TURN_RADIUS_M), out.t1_s, v_fish)
        back = _route_phase(build_route(np.array([pts[-1], start]), CRAFT_TURN_RADIUS_M),
                            fish.t1_s, v_back)
        return [out, fish, back]
    raise ValueError(kind)


def _merchant_profile(hour_of_day: float) -> float:
    return 1.0 + 0.3 * math.cos(TWO_PI * (hour_of_day - 9.0) / 24.0)


_CRAFT_NORM = float(np.mean([0.3 + 3.5 * math.exp(-(((h + 0.5) - 6.0) / 1.5) ** 2)
                             for h in range(24)]))


def _craft_profile(hour_of_day: float) -> float:
    return (0.3 + 3.5 * math.exp(-((hour_of_day - 6.0) / 1.5) ** 2)) / _CRAFT_NORM


@functools.cache
def _mean_life_s(kind: str) -> float:
    """Mean time in the scene of a vessel of ``kind`` (fixed-seed sample of the planner,
    independent of the scenario seed)."""
    rng = np.random.default_rng([0, _PLAN, _KINDS.index(kind)])
    lives = [p[-1].t1_s - p[0].t0_s for p in (_plan_one(kind, rng, 0.0) for _ in range(300))]
    return float(np.mean(lives))


class TrafficPlan:
    """Vessels of the scenario, planned hour block by hour block on demand.

    Block h (hours since the scenario start, from -PLAN_LEAD_H) draws, from its own seed
    stream, the vessels entering during it: Poisson numbers per kind at the kind's mean
    rate times the hour's diurnal factor, entry times uniform in the hour; plus the day's
    ferries in the block holding 05:30 UTC. Ids count up in block order and entry time.
    """

    def __init__(self, n_ships: int, seed: int, start_ns: int) -> None:
        if n_ships < 1:
            raise ValueError(f"the region needs at least one ship, got {n_ships}")
        self.n_ships = n_ships
        self.seed = seed
        self.start_ns = start_ns
        self.rates = {k: SHARES[k] * n_ships / _mean_life_s(k) for k in _KINDS}
        self.next_block = -PLAN_LEAD_H
        self.next_id = 1
        self.vessels: list[Vessel] = []
        self.mmsis: set[int] = set()

    def _hour_of_day(self, t_s: float) -> float:
        return ((self.start_ns / NS + t_s) / 3600.0) % 24.0

    def _block(self, h: int) -> list[Vessel]:
        t_a = h * 3600.0
        hod = self._hour_of_day(t_a + 1800.0)
        entries: list[tuple[float, str, tuple]] = []
        for k, kind in enumerate(_KINDS):
            rng = np.random.default_rng([self.seed, _PLAN, k, h + 10_000])
            factor = _craft_profile(hod) if kind == "craft" else _merchant_profile(hod)
            n = int(rng.poisson(self.rates[kind] * 3600.0 * factor))
            for i, t in enumerate(np.sort(t_a + 3600.0 * rng.random(n))):
                entries.append((float(t), kind, (k, h + 10_000, i)))
        # ferries: the block holding 05:30 of a UTC day
        day_start = t_a - self._hour_of_day(t_a) * 3600.0
        for d in (day_start, day_start + 86400.0):
            t_f = d + FERRY_HOURS[0] * 3600.0
            if t_a <= t_f < t_a + 3600.0:
                for j in range(len(FERRY_LINES)):
                    for f in range(FERRIES_PER_LINE):
                        entries.append((t_f + 60.0 * f, "ferry", (9, h + 10_000, j, f)))
        entries.sort(key=lambda e: (e[0], e[2]))
        out = []
        for t, kind, key in entries:
            rng = np.random.default_rng([self.seed, _PLAN, 99, *key])
            if kind == "ferry":
                phases = _ferry_phases(rng, key, t)
                ais_class: str | None = "A"
            else:
                phases = _plan_one(kind, rng, t)
                u = rng.random()
                if kind == "craft":
                    ais_class = "B" if u < P_CRAFT_CLASS_B else None
                else:
                    pa, pb = P_MERCHANT_CLASS
                    ais_class = "A" if u < pa else "B" if u < pa + pb else None
            out.append(self._vessel(kind, ais_class, tuple(phases), key))
        return out

    def _vessel(self, kind: str, ais_class: str | None, phases: tuple[Phase, ...],
                key: tuple) -> Vessel:
        vid = self.next_id
        self.next_id += 1
        identity = None
        if ais_class is not None:
            ident = draw_identity(
                np.random.default_rng([self.seed, _IDENT, *key]),
                ais_class=ais_class,
                kind="ferry" if kind == "ferry" else "fairway",
                inbound=kind in ("arrival", "anchor"),
            )
            mmsi = ident.mmsi
            while mmsi in self.mmsis:
                mmsi = mmsi + 1 if mmsi % 1_000_000 != 999_999 else mmsi - 999_999 + 100_000
            self.mmsis.add(mmsi)
            identity = replace(ident, mmsi=mmsi)
        v = Vessel(vid, kind, ais_class, identity, phases[0].t0_s, phases[-1].t1_s, phases)
        if ais_class is not None:
            v.ais_breaks, v.ais_steps, v.ais_status = _ais_schedule(v)
        return v

    def active(self, t0_s: float, t1_s: float) -> list[Vessel]:
        """Vessels in the scene at some time of [t0_s, t1_s), in id order; vessels that
        left before t0_s are forgotten (slices must be asked for in time order)."""
        while self.next_block * 3600.0 < t1_s:
            self.vessels.extend(self._block(self.next_block))
            self.next_block += 1
        self.vessels = [v for v in self.vessels if v.t_exit_s >= t0_s - 3600.0]
        return [v for v in self.vessels if v.t_enter_s < t1_s and v.t_exit_s > t0_s]


def _empty_radar() -> pl.DataFrame:
    return pl.DataFrame(schema={**RADAR_REPORT_SCHEMA, "vessel_id": pl.Int64})


def _ferry_phases(rng: np.random.Generator, key: tuple, t0: float) -> list[Phase]:
    line = tuple(FERRY_LINES)[key[2]]
    route = build_route(np.array(FERRY_LINES[line]), FERRY_TURN_RADIUS_M, closed=True)
    speed = rng.uniform(*FERRY_SPEED_MPS)
    s0 = route.length_m * key[3] / FERRIES_PER_LINE
    dur = (FERRY_HOURS[1] - FERRY_HOURS[0]) * 3600.0
    return [Phase(t0, t0 + dur, route, s0, speed)]


def _ais_schedule(v: Vessel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Breakpoints b_0 < b_1 < ... (s) and, in each [b_i, b_i+1), the position-report
    interval (s) and navigational status of ``v`` (ITU-R M.1371 Tables 1-2; "changing
    course" = on a turning arc; at anchor: 3 min, status 1)."""
    breaks: list[float] = []
    steps: list[float] = []
    status: list[int] = []
    for p in v.phases:
        if p.route is None:
            breaks.append(p.t0_s)
            steps.append(ANCHOR_AIS_INTERVAL_S if v.ais_class == "A" else 180.0)
            status.append(1)
            continue
        sog_kn = p.speed_mps / KNOT_MPS
        if v.ais_class == "B":
            breaks.append(p.t0_s)
            steps.append(class_b_interval_s(sog_kn))
            status.append(0)
            continue
        arcs = p.route.arc_intervals_m()
        if p.route.closed:
            n_loops = math.ceil((p.s0_m + p.speed_mps * (p.t1_s - p.t0_s)) / p.route.length_m) + 1
            arcs = np.vstack([arcs + j * p.route.length_m for j in range(n_loops)])
        t_arcs = p.t0_s + (arcs - p.s0_m) / p.speed_mps
        t_arcs = t_arcs[(t_arcs[:, 1] > p.t0_s) & (t_arcs[:, 0] < p.t1_s)]
        edges = [p.t0_s]
        turning = [False]
        for a, b in t_arcs:
            if a > edges[-1]:
                edges.append(float(a))
                turning.append(True)
            else:
                turning[-1] = True
            if b < p.t1_s:
                edges.append(float(b))
                turning.append(False)
        for e, turn in zip(edges, turning, strict=True):
            breaks.append(e)
            steps.append(class_a_interval_s(sog_kn, turn))
            status.append(0)
    return np.asarray(breaks), np.asarray(steps), np.asarray(status, np.int64)


# --- kinematics of many vessels at once -----------------------------------------------------


class Kinematics:
    """Positions of a set of vessels at arbitrary times, vectorised over (vessel, time)
    queries: phases and route segments of all vessels concatenated, looked up with one
    ``searchsorted`` on integer keys (vessel << 40 | time in ms; route << 40 | arc length
    in mm)."""

    def __init__(self, vessels: list[Vessel]) -> None:
        self.vessels = vessels
        rows = []
        routes: dict[int, int] = {}
        seg_key, seg_turn, seg_x, seg_y, seg_c, seg_s = [], [], [], [], [], []
        r_radius, r_len, r_closed = [], [], []
        for vi, v in enumerate(vessels):
            for p in v.phases:
                rid = -1
                if p.route is not None:
                    rid = routes.get(id(p.route), -1)
                    if rid < 0:
                        rid = routes[id(p.route)] = len(r_len)
                        rt = p.route
                        seg_key.append((rid << 40) + np.round(rt.s_start_m * 1000).astype(np.int64))
                        seg_turn.append(rt.turn.astype(np.float64))
                        seg_x.append(rt.x_m)
                        seg_y.append(rt.y_m)
                        seg_c.append(rt.course_rad)
                        seg_s.append(rt.s_start_m)
                        r_radius.append(rt.radius_m)
                        r_len.append(rt.length_m)
                        r_closed.append(rt.closed)
                rows.append((vi, p.t0_s, rid, p.s0_m, p.speed_mps, p.cx_m, p.cy_m, p.swing_m,
                             p.omega_radps))
        a = np.array(rows, dtype=float).reshape(-1, 9)
        self.p_vessel = a[:, 0].astype(np.int64)
        self.p_t0 = a[:, 1]
        self.p_key = (self.p_vessel << 40) + _ms(self.p_t0)
        self.p_route = a[:, 2].astype(np.int64)
        self.p_s0, self.p_speed = a[:, 3], a[:, 4]
        self.p_cx, self.p_cy, self.p_swing, self.p_omega = a[:, 5], a[:, 6], a[:, 7], a[:, 8]
        def cat(xs: list, dt: type = float) -> np.ndarray:
            return np.concatenate(xs) if xs else np.zeros(0, dt)

        self.seg_key = cat(seg_key, np.int64)
        self.seg_turn, self.seg_x, self.seg_y = cat(seg_turn), cat(seg_x), cat(seg_y)
        self.seg_c, self.seg_s = cat(seg_c), cat(seg_s)
        self.r_radius, self.r_len = np.array(r_radius), np.array(r_len)
        self.r_closed = np.array(r_closed, bool)

    def at(self, vi: np.ndarray, t_s: np.ndarray) -> tuple[np.ndarray, ...]:
        """(x_m, y_m, course_rad (regional frame), speed_mps) of vessels ``vi`` (indices
        into the vessel list) at times ``t_s``."""
        vi = np.asarray(vi, np.int64)
        t = np.asarray(t_s, float)
        p = np.searchsorted(self.p_key, (vi << 40) + _ms(t), side="right") - 1
        p = np.maximum(p, 0)
        dt = t - self.p_t0[p]
        rid = self.p_route[p]
        on_route = rid >= 0
        x = np.empty(t.size)
        y = np.empty(t.size)
        c = np.empty(t.size)
        v = np.empty(t.size)
        # anchor: back at the anchor point at both ends of the phase
        a = ~on_route
        if a.any():
            pa = p[a]
            phi = self.p_omega[pa] * dt[a]
            r = self.p_swing[pa]
            x[a] = self.p_cx[pa] + r * np.sin(phi)
            y[a] = self.p_cy[pa] + r * (np.cos(phi) - 1.0)
            c[a] = np.mod(phi + np.pi / 2, TWO_PI)
            v[a] = r * np.abs(self.p_omega[pa])
        if on_route.any():
            pr = p[on_route]
            r = rid[on_route]
            s = self.p_s0[pr] + self.p_speed[pr] * dt[on_route]
            length = self.r_len[r]
            s = np.where(self.r_closed[r], np.mod(s, length), np.clip(s, 0.0, length))
            k = np.searchsorted(self.seg_key, (r << 40) + np.round(s * 1000).astype(np.int64),
                                side="right") - 1
            ds = s - self.seg_s[k]
            turn = self.seg_turn[k]
            R = self.r_radius[r]
            cc = self.seg_c[k] + turn * ds / R
            arc = turn != 0
            x[on_route] = np.where(arc, self.seg_x[k] - turn * R * np.cos(cc),
                                   self.seg_x[k] + ds * np.sin(cc))
            y[on_route] = np.where(arc, self.seg_y[k] + turn * R * np.sin(cc),
                                   self.seg_y[k] + ds * np.cos(cc))
            c[on_route] = np.mod(cc, TWO_PI)
            v[on_route] = self.p_speed[pr]
        return x, y, c, v


def _ms(t_s: np.ndarray) -> np.ndarray:
    """Time in ms since 1e6 s before the scenario start (keeps keys positive)."""
    return np.round((np.asarray(t_s, float) + 1e6) * 1000.0).astype(np.int64)


# --- the simulation, slice by slice ---------------------------------------------------------


@dataclass
class _SiteState:
    """One site's tracker state per vessel id (arrays grown as ids come)."""

    t_first_s: float
    next_track: int = 1
    in_track: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    streak: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    misses: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    track: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    last: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))  # x, y, c, v, t
    err: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))  # r, az, c, v, t

    def grow(self, n: int) -> None:
        if self.in_track.size >= n:
            return
        m = max(n, 2 * self.in_track.size)
        k = self.in_track.size
        self.in_track = np.concatenate([self.in_track, np.zeros(m - k, bool)])
        self.streak = np.concatenate([self.streak, np.zeros(m - k, np.int64)])
        self.misses = np.concatenate([self.misses, np.zeros(m - k, np.int64)])
        self.track = np.concatenate([self.track, np.full(m - k, -1, np.int64)])
        self.last = np.vstack([self.last, np.zeros((m - k, 5))])
        self.err = np.vstack([self.err, np.zeros((m - k, 5))])


@dataclass
class RegionSlice:
    """What the region produced in one slice of log time [start_ns, end_ns): radar
    reports (RADAR_REPORT_SCHEMA), AIS sentences (log_time_ns, sentence), truth
    (TRUTH_SCHEMA), and for evaluation only (not archived) the vessel each radar
    report follows (``radar_vessel``: vessel_id, one per radar report row)."""

    start_ns: int
    end_ns: int
    radar_reports: pl.DataFrame
    ais_sentences: pl.DataFrame
    truth: pl.DataFrame
    radar_vessel: pl.Series


class RegionSimulation:
    """Generates the region slice by slice (see the module docstring)."""

    def __init__(self, layout: RegionLayout, *, n_ships: int, seed: int, start_ns: int,
                 duration_s: float, truth_period_s: float = TRUTH_PERIOD_S) -> None:
        if duration_s <= 0:
            raise ValueError(f"duration_s must be positive, got {duration_s}")
        self.layout = layout
        self.seed = seed
        self.start_ns = int(start_ns)
        self.duration_s = float(duration_s)
        self.truth_period_s = truth_period_s
        self.plan = TrafficPlan(n_ships, seed, start_ns)
        self.sites = [
            _SiteState(-s.scan_period_s
                       * float(np.random.default_rng([seed, _RADAR_PHASE, i]).random()))
            for i, s in enumerate(layout.sites)
        ]
        self.site_xy = [np.array([s.x_m, s.y_m]) for s in layout.sites]
        self.site_rho = [
            -float(convergence_rad(s.lat_deg, s.lon_deg, layout.origin_lat_deg,
                                   layout.origin_lon_deg))
            for s in layout.sites
        ]
        self.ais_next: dict[int, tuple[float, float]] = {}  # vid -> (next time, last step)
        self.tx_count: dict[int, int] = {}
        self.seq_counter = 0
        self.static_payloads: dict[tuple[int, int], tuple[str, int]] = {}

    @property
    def end_ns(self) -> int:
        return self.start_ns + round(self.duration_s * NS)

    def slices(self) -> Iterator[RegionSlice]:
        """Slices of log time in order: boundaries at multiples of SLICE_S since the
        Unix epoch, clipped to the scenario; the radars' warm-up (RADAR_WARMUP_S before
        the start) runs first and is not returned."""
        self._radar(-RADAR_WARMUP_S, 0.0, -1)
        step = SLICE_S * NS
        a = self.start_ns
        index = 0
        while a < self.end_ns:
            b = min((a // step + 1) * step, self.end_ns)
            t0, t1 = (a - self.start_ns) / NS, (b - self.start_ns) / NS
            radar = self._radar(t0, t1, index)
            yield RegionSlice(a, b, radar.drop("vessel_id"), self._ais(t0, t1, index),
                              self._truth(t0, t1), radar["vessel_id"])
            a = b
            index += 1

    # -- radar ---------------------------------------------------------------------------

    def _radar(self, t0: float, t1: float, index: int) -> pl.DataFrame:
        frames = []
        for si, site in enumerate(self.layout.sites):
            frames.append(self._site(si, site, t0, t1, index))
        frames = [f for f in frames if f.height]
        if not frames:
            return _empty_radar()
        return pl.concat(frames).sort(["log_time_ns", "site_id", "time_ns", "track_id"])

    def _site(self, si: int, site: SiteSpec, t0: float, t1: float, index: int) -> pl.DataFrame:
        st = self.sites[si]
        T = site.scan_period_s
        # scans whose end (the log time of their reports) lies in [t0, t1)
        k_lo = math.ceil((t0 - st.t_first_s - T) / T - 1e-9)
        k_hi = math.ceil((t1 - st.t_first_s - T) / T - 1e-9)
        if k_hi <= k_lo:
            return _empty_radar()
        tk = st.t_first_s + np.arange(k_lo, k_hi) * T
        vessels = self.plan.active(tk[0], tk[-1] + T)
        nv, nk = len(vessels), tk.size
        if nv == 0:
            return _empty_radar()
        kin = Kinematics(vessels)
        vid = np.array([v.vessel_id for v in vessels], np.int64)
        st.grow(int(vid.max()) + 1)
        enter = np.array([v.t_enter_s for v in vessels])
        exit_ = np.array([v.t_exit_s for v in vessels])
        vmax = np.array([max(p.speed_mps for p in v.phases) for v in vessels])
        sx, sy = self.site_xy[si]
        rho = self.site_rho[si]
        # mid-scan positions: which (vessel, scan) pairs can be in range at all
        vi_all = np.repeat(np.arange(nv), nk)
        tk_all = np.tile(tk, nv)
        t_mid = np.clip(tk_all + 0.5 * T, enter[vi_all], exit_[vi_all])
        x, y, _, _ = kin.at(vi_all, t_mid)
        near = np.hypot(x - sx, y - sy) <= site.max_range_m + 200.0 + vmax[vi_all] * T
        near &= (tk_all + T >= enter[vi_all]) & (tk_all <= exit_[vi_all])
        iv, ik = np.divmod(np.flatnonzero(near), nk)
        lo, hi = enter[iv], exit_[iv]
        # sweep time: two fixed-point steps on the azimuth (a flat frame is enough here)
        az = np.mod(np.arctan2(x[near] - sx, y[near] - sy) - rho, TWO_PI)
        ts = tk[ik] + az / TWO_PI * T
        x, y, _, _ = kin.at(iv, np.clip(ts, lo, hi))
        az = np.mod(np.arctan2(x - sx, y - sy) - rho, TWO_PI)
        ts = tk[ik] + az / TWO_PI * T
        ok = (ts >= lo) & (ts <= hi)
        iv, ik, ts = iv[ok], ik[ok], ts[ok]
        # exact geometry (through WGS-84) at the sweep time
        r = np.full((nv, nk), np.inf)
        azt = np.zeros((nv, nk))
        crs = np.zeros((nv, nk))
        spd = np.zeros((nv, nk))
        tsw = np.zeros((nv, nk))
        valid = np.zeros((nv, nk), bool)
        if iv.size:
            x, y, c, v = kin.at(iv, ts)
            lat, lon = enu_to_geodetic(x, y, self.layout.origin_lat_deg,
                                       self.layout.origin_lon_deg)
            e, n = geodetic_to_enu(lat, lon, site.lat_deg, site.lon_deg)
            rr, aa = enu_to_polar(e, n)
            course_true = c - convergence_rad(lat, lon, self.layout.origin_lat_deg,
                                              self.layout.origin_lon_deg)
            r[iv, ik] = rr
            azt[iv, ik] = aa
            crs[iv, ik] = np.mod(course_true + convergence_rad(lat, lon, site.lat_deg,
                                                               site.lon_deg), TWO_PI)
            spd[iv, ik] = v
            tsw[iv, ik] = ts
            valid[iv, ik] = True
        ts = tsw
        valid &= r <= site.max_range_m
        rng = np.random.default_rng([self.seed, _RADAR, si, index + 1])
        u = rng.random((nv, nk, 2))
        z = rng.standard_normal((nv, nk, 4))
        sig_az = math.radians(site.sigma_azimuth_deg)
        sig_c = math.radians(site.sigma_course_deg)
        out: list[tuple] = []
        for k in range(nk):
            rows, status = self._tracker_step(st, vid, valid[:, k], u[:, k, 0], u[:, k, 1])
            if rows.size == 0:
                continue
            kk = np.full(rows.size, k)
            meas = status < 3
            tsk = ts[rows, kk]
            # the site tracker's output error: first-order Gauss-Markov from scan to scan
            # (rho = exp(-dt / tau)), stationary from the track's first report
            err = st.err[vid[rows]]
            rho = np.where(status == 1, 0.0, np.exp(-(tsk - err[:, 4]) / TRACKER_ERROR_TAU_S))
            sig = np.array([site.sigma_range_m, sig_az, sig_c, site.sigma_speed_mps])
            e = rho[:, None] * err[:, :4] + np.sqrt(1.0 - rho**2)[:, None] * sig * z[rows, kk]
            st.err[vid[rows[meas]]] = np.column_stack([e, tsk])[meas]
            rm = np.abs(r[rows, kk] + e[:, 0])
            am = np.mod(azt[rows, kk] + e[:, 1], TWO_PI)
            cm = np.mod(crs[rows, kk] + e[:, 2], TWO_PI)
            vm = np.abs(spd[rows, kk] + e[:, 3])
            xm, ym = polar_to_enu(rm, am)
            # coasted scans: predicted from the previous report
            last = st.last[vid[rows]]
            dt = tsk - last[:, 4]
            xc = last[:, 0] + last[:, 3] * dt * np.sin(last[:, 2])
            yc = last[:, 1] + last[:, 3] * dt * np.cos(last[:, 2])
            xm, ym = np.where(meas, xm, xc), np.where(meas, ym, yc)
            cm, vm = np.where(meas, cm, last[:, 2]), np.where(meas, vm, last[:, 3])
            rc, ac = enu_to_polar(xm, ym)
            rm, am = np.where(meas, rm, rc), np.where(meas, am, np.mod(ac, TWO_PI))
            st.last[vid[rows]] = np.column_stack([xm, ym, cm, vm, tsk])
            # new tracks of this scan: ids in order of their sweep time
            new = np.flatnonzero(status == 1)
            if new.size:
                order = new[np.argsort(tsk[new], kind="stable")]
                st.track[vid[rows[order]]] = st.next_track + np.arange(order.size)
                st.next_track += order.size
            out.append((status, tsk, np.full(rows.size, tk[k] + T), rm, am, xm, ym, cm, vm,
                        st.track[vid[rows]], vid[rows]))
        if not out or t1 <= 0.0:
            return _empty_radar()
        status, tsk, log_t, rm, am, xm, ym, cm, vm, ids, vessel = (
            np.concatenate([o[i] for o in out]) for i in range(11)
        )
        n = status.size
        keep = tsk >= 0.0  # reports of the warm-up before the start are not archived
        df = pl.DataFrame(
            {
                "site_id": [site.site_id] * n,
                "track_id": ids,
                "time_ns": self.start_ns + np.round(tsk * NS).astype(np.int64),
                "range_m": np.round(rm, 2),
                "azimuth_rad": np.round(am, 6),
                "x_m": np.round(xm, 2),
                "y_m": np.round(ym, 2),
                "course_rad": np.round(cm, 5),
                "speed_mps": np.round(vm, 3),
                "sigma_range_m": np.full(n, site.sigma_range_m),
                "sigma_azimuth_rad": np.full(n, round(sig_az, 9)),
                "sigma_course_rad": np.full(n, round(sig_c, 9)),
                "sigma_speed_mps": np.full(n, site.sigma_speed_mps),
                "scan_period_s": np.full(n, T),
                "scan_end_azimuth_rad": np.full(n, TWO_PI),
                "status": _STATUS.gather(status),
                "log_time_ns": self.start_ns + np.round(log_t * NS).astype(np.int64),
                "vessel_id": vessel,
            },
            schema={**RADAR_REPORT_SCHEMA, "vessel_id": pl.Int64},
        )
        return df.filter(pl.Series(keep))

    def _tracker_step(self, st: _SiteState, vid: np.ndarray, valid: np.ndarray,
                      u_detect: np.ndarray, u_lost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One scan of the site tracker's state machine over the vessels (see
        :func:`pipeline.simulate.channel._track_life`); returns the rows that report and
        their status (1 new, 2 confirmed, 3 coasting)."""
        detected = u_detect < DETECTION_PROBABILITY
        lost = u_lost < TRACK_LOSS_PROBABILITY
        it = st.in_track[vid]
        streak = st.streak[vid]
        misses = st.misses[vid]
        status = np.zeros(vid.size, np.int64)
        drop = ~valid | (it & lost)
        cont = valid & it & ~lost
        misses = np.where(cont & detected, 0, np.where(cont, misses + 1, misses))
        coast_out = cont & ~detected & (misses > MAX_COAST_SCANS)
        status[cont & detected] = 2
        status[cont & ~detected & ~coast_out] = 3
        drop |= coast_out
        init = valid & ~it
        streak = np.where(init, np.where(detected, streak + 1, 0), streak)
        start = init & (streak >= INITIATION_SCANS)
        status[start] = 1
        it = np.where(drop, False, np.where(start, True, it))
        streak = np.where(drop | start, 0, streak)
        misses = np.where(start, 0, misses)
        st.in_track[vid] = it
        st.streak[vid] = streak
        st.misses[vid] = misses
        rows = np.flatnonzero(status > 0)
        return rows, status[rows]

    # -- AIS -----------------------------------------------------------------------------

    def _ais(self, t0: float, t1: float, index: int) -> pl.DataFrame:
        """AIS sentences received in [t0, t1) (reception = transmission, ms stamps)."""
        vessels = [v for v in self.plan.active(t0, t1) if v.ais_class is not None]
        pos_v, pos_t, pos_step, pos_status, pos_type = [], [], [], [], []
        stat_v, stat_t = [], []
        for i, v in enumerate(vessels):
            t, step, status, mtype = self._position_times(v, t0, t1)
            if t.size:
                pos_v.append(np.full(t.size, i))
                pos_t.append(t)
                pos_step.append(step)
                pos_status.append(status)
                pos_type.append(mtype)
            phase = float(np.random.default_rng([self.seed, _AIS_PHASE, v.vessel_id]).random())
            first = v.t_enter_s + phase * STATIC_INTERVAL_S
            k0 = max(0, math.ceil((t0 - 1.0 - first) / STATIC_INTERVAL_S))
            ts = first + STATIC_INTERVAL_S * np.arange(k0, k0 + 12)
            ts = ts[(ts >= t0 - 1.0) & (ts < t1) & (ts < v.t_exit_s)]
            stat_v.extend([i] * ts.size)
            stat_t.extend(ts.tolist())
        if not pos_v and not stat_v:
            return pl.DataFrame(schema={"log_time_ns": pl.Int64, "sentence": pl.Binary})
        pv = np.concatenate(pos_v) if pos_v else np.zeros(0, np.int64)
        pt = np.round(np.concatenate(pos_t) * 1e3) / 1e3 if pos_t else np.zeros(0)
        pstatus = np.concatenate(pos_status) if pos_status else np.zeros(0, np.int64)
        ptype = np.concatenate(pos_type) if pos_type else np.zeros(0, np.int64)
        # transmissions in time order (ties: vessel id, then part): radio channel A/B
        # alternates per station, a static message's sentences share one
        tx = []
        vids = np.array([v.vessel_id for v in vessels], np.int64)
        for j in range(pv.size):
            tx.append((pt[j], int(vids[pv[j]]), 0, "pos", j))
        for i, t in zip(stat_v, stat_t, strict=True):
            # message 5, or 24 A then 24 B one second later (each part in its own slice)
            v = vessels[i]
            if t >= t0:
                tx.append((round(t, 3), v.vessel_id, 0, "static", i))
            if v.ais_class == "B" and t0 <= t + 1.0 < t1 and t + 1.0 < v.t_exit_s:
                tx.append((round(t + 1.0, 3), v.vessel_id, 1, "static", i))
        tx.sort(key=lambda r: (r[0], r[1], r[2]))
        channel = np.empty(len(tx), dtype="<U1")
        for n, (_, vid, _, _, _) in enumerate(tx):
            k = self.tx_count.get(vid, 0)
            self.tx_count[vid] = k + 1
            channel[n] = "A" if k % 2 == 0 else "B"
        # positions: truth at the fix + GNSS noise, SOG/COG + noise, quantised on the air
        kin = Kinematics(vessels)
        x, y, c, v_ = kin.at(pv, pt)
        lat, lon = enu_to_geodetic(x, y, self.layout.origin_lat_deg, self.layout.origin_lon_deg)
        course = np.mod(c - convergence_rad(lat, lon, self.layout.origin_lat_deg,
                                            self.layout.origin_lon_deg), TWO_PI)
        z = np.random.default_rng([self.seed, _AIS, index + 1]).standard_normal((pv.size, 4))
        lat, lon = _offset_lat_lon(lat, lon, GNSS_SIGMA_M * z[:, 0], GNSS_SIGMA_M * z[:, 1])
        sog_kn = np.clip(np.round((v_ + SOG_SIGMA_MPS * z[:, 2]) / KNOT_MPS, 1), 0, 102.2)
        cog_deg = np.mod(np.round(np.degrees(course + COG_SIGMA_RAD * z[:, 3]), 1), 360.0)
        heading = np.mod(np.round(np.degrees(course)), 360).astype(np.int64)
        fix_ns = self.start_ns + np.round(pt * 1e3).astype(np.int64) * 1_000_000
        second = (fix_ns // NS) % 60
        pos_order = np.array([n for n, r in enumerate(tx) if r[3] == "pos"], np.int64)
        pos_j = np.array([r[4] for r in tx if r[3] == "pos"], np.int64)
        ch = np.empty(pv.size, dtype="<U1")
        ch[pos_j] = channel[pos_order]
        mmsi = np.array([vessels[i].mmsi for i in pv], np.int64)
        is_a = np.array([vessels[i].ais_class == "A" for i in pv], bool)
        sent = np.empty((pv.size, SENTENCE_BYTES), np.uint8)
        if is_a.any():
            sent[is_a] = encode_class_a(ptype[is_a], mmsi[is_a], pstatus[is_a], sog_kn[is_a],
                                        lon[is_a], lat[is_a], cog_deg[is_a], heading[is_a],
                                        second[is_a], ch[is_a])
        if (~is_a).any():
            b = ~is_a
            sent[b] = encode_class_b(mmsi[b], sog_kn[b], lon[b], lat[b], cog_deg[b],
                                     second[b], ch[b])
        pos_text = sent.view(f"S{SENTENCE_BYTES}").ravel()
        log_time: list[int] = []
        sentences: list[bytes] = []
        for n, (t, _, part, what, j) in enumerate(tx):
            t_ns = self.start_ns + round(t * 1e3) * 1_000_000
            if what == "pos":
                log_time.append(t_ns)
                sentences.append(bytes(pos_text[j]))
                continue
            for p in self._static(vessels[j], part, channel[n]):
                log_time.append(t_ns)
                sentences.append(p.encode())
        return pl.DataFrame({"log_time_ns": log_time, "sentence": sentences},
                            schema={"log_time_ns": pl.Int64, "sentence": pl.Binary})

    def _static(self, v: Vessel, part: int, channel: str) -> list[str]:
        """The sentences of a static message (pyais; the armoured payload of each
        vessel's message is encoded once, only the framing changes per transmission)."""
        key = (v.vessel_id, part)
        if key not in self.static_payloads:
            self.static_payloads[key] = self._static_payload(v, part)
        payload, fill = self.static_payloads[key]
        seq = None
        if v.ais_class == "A":
            seq = self.seq_counter % 10
            self.seq_counter += 1
        return ais_to_nmea_0183(payload, "AI", "VDM", channel, fill, seq)

    def _static_payload(self, v: Vessel, part: int) -> tuple[str, int]:
        ident = v.identity
        assert ident is not None
        dims = {"to_bow": ident.to_bow_m, "to_stern": ident.to_stern_m,
                "to_port": ident.to_port_m, "to_starboard": ident.to_starboard_m}
        if v.ais_class == "A":
            msg = {"type": 5, "mmsi": ident.mmsi, "ais_version": 2, "imo": ident.imo,
                   "callsign": ident.callsign, "shipname": ident.shipname,
                   "ship_type": ident.ship_type, "epfd": 1, "month": 1, "day": 1, "hour": 12,
                   "minute": 0, "draught": ident.draught_m, "destination": ident.destination,
                   "dte": False, **dims}
            return MSG_CLASS[5].create(**msg).encode()
        if part == 0:
            msg = {"type": 24, "mmsi": ident.mmsi, "partno": 0, "shipname": ident.shipname}
        else:
            msg = {"type": 24, "mmsi": ident.mmsi, "partno": 1, "ship_type": ident.ship_type,
                   "vendorid": ident.vendor_id, "model": 1, "serial": ident.mmsi % 1_000_000,
                   "callsign": ident.callsign, **dims}
        return MSG_CLASS[24].create(**msg).encode()

    def _position_times(self, v: Vessel, t0: float, t1: float) -> tuple[np.ndarray, ...]:
        """Position-report times of ``v`` in [t0, t1) with their interval, navigational
        status and message id (1 or 3 after an interval change; 18 for Class B); the
        schedule continues from the previous slice."""
        nxt, prev_step = self.ais_next.get(v.vessel_id, (math.nan, math.nan))
        if math.isnan(nxt):
            u = float(np.random.default_rng([self.seed, _AIS_PHASE, v.vessel_id, 1]).random())
            nxt = v.t_enter_s + u * float(v.ais_steps[0])
        times, steps, status = [], [], []
        end = min(t1, v.t_exit_s)
        breaks = v.ais_breaks
        while nxt < end:
            i = int(np.searchsorted(breaks, nxt, side="right")) - 1
            step = float(v.ais_steps[max(i, 0)])
            stop = min(end, breaks[i + 1] if i + 1 < breaks.size else math.inf)
            n = max(1, math.ceil((stop - nxt) / step))
            t = nxt + step * np.arange(n)
            times.append(t)
            steps.append(np.full(n, step))
            status.append(np.full(n, v.ais_status[max(i, 0)]))
            nxt = float(t[-1] + step)
        self.ais_next[v.vessel_id] = (nxt, prev_step)
        if not times:
            return np.zeros(0), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64)
        t = np.concatenate(times)
        step = np.concatenate(steps)
        st = np.concatenate(status)
        keep = t >= t0
        if v.ais_class == "B":
            mtype = np.full(t.size, 18)
        else:
            before = np.r_[prev_step, step[:-1]]
            mtype = np.where(np.isnan(before) | (before == step), 1, 3)
        self.ais_next[v.vessel_id] = (nxt, float(step[-1]))
        return t[keep], step[keep], st[keep], mtype[keep]

    # -- truth ---------------------------------------------------------------------------

    def _truth(self, t0: float, t1: float) -> pl.DataFrame:
        vessels = self.plan.active(t0, t1)
        P = self.truth_period_s
        vi, ts = [], []
        for i, v in enumerate(vessels):
            a = max(t0, v.t_enter_s)
            b = min(t1, v.t_exit_s + 1e-9)
            t = P * np.arange(math.ceil(a / P - 1e-9), math.ceil(b / P - 1e-9))
            t = t[(t >= t0) & (t < t1)]
            vi.append(np.full(t.size, i))
            ts.append(t)
        if not vessels:
            return pl.DataFrame(schema=TRUTH_SCHEMA)
        vi_a, t = np.concatenate(vi), np.concatenate(ts)
        x, y, c, v_ = Kinematics(vessels).at(vi_a, t)
        lat, lon = enu_to_geodetic(x, y, self.layout.origin_lat_deg, self.layout.origin_lon_deg)
        course = np.mod(c - convergence_rad(lat, lon, self.layout.origin_lat_deg,
                                            self.layout.origin_lon_deg), TWO_PI)
        ids = np.array([v.vessel_id for v in vessels], np.int64)
        mmsi = pl.Series([vessels[i].mmsi for i in vi_a], dtype=pl.Int64)
        return pl.DataFrame(
            {
                "vessel_id": ids[vi_a],
                "mmsi": mmsi,
                "time_ns": self.start_ns + np.round(t * NS).astype(np.int64),
                "lat_deg": np.round(lat, 8),
                "lon_deg": np.round(lon, 8),
                "course_rad": np.round(course, 6),
                "speed_mps": np.round(v_, 4),
            },
            schema=TRUTH_SCHEMA,
        ).sort("time_ns", "vessel_id")
