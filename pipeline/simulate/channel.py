"""The ``channel`` scenario: ships on a narrow fairway watched by coastal radars and AIS.

A pure function of (config, start time, duration, seed): no files, no clock; every
random draw comes from ``np.random.default_rng`` seeded by ``seed`` and a fixed stream
key (vessel, site), so the traffic, the radar noise and the AIS schedule of a vessel do
not depend on how many other draws were made. A longer run therefore extends a shorter
one with the same seed: same ships and identical truth, reports and sentences over the
common time span.

Traffic (regional ENU plane, the region origin of the config):

- **Fairway ships** follow the fairway legs in config order (L1→L2→L3, "inbound") or
  in reverse ("outbound"), each on a lane offset to its starboard side of the axis by
  100–250 m, at a constant speed drawn uniformly in 3–9 m/s. Legs meet at waypoints
  where the ship turns at a constant rate on a circular arc of radius 600 m tangent to
  both legs (rate of turn V/R). 11 ships per direction are already under way at the
  start, spread uniformly along the route; more arrive at the fairway ends as a Poisson
  stream whose rate keeps the count roughly steady; a ship that reaches the far end
  leaves the scene (its truth, radar tracks and AIS just end).
- **Close pass**: the first inbound and the first outbound ship keep 60 m lanes and
  meet abeam at the middle of the middle leg (L2) 300 s after the start, 120 m apart:
  a closely spaced pair seen end-on by both radars (unfavourable aspect).
- **Ferries**: 3 ferries shuttle across the middle leg, perpendicular to it (north–south
  for L2), on racetrack loops 4 km long and 400 m wide with 150 m turns, at 5–7 m/s.
- **AIS carriage**: of the 22 initial fairway ships, 4 carry no AIS and 4 carry
  Class B; ferries and the close-pass pair carry Class A. Arriving ships carry no AIS
  with probability 0.15 and Class B with probability 0.2 (of those with AIS).

Radars (each ``cfg.radar_sites`` entry): the antenna turns clockwise with period
``T = scan_period_s``; scan k runs over [t0_k, t0_k + T) with t0_k = t0 + k T (t0 a
random phase per site) and points at azimuth β (in the radar's own azimuth reference,
true azimuth − ``north_alignment_rad``) at t0_k + β / 2π · T: the relation the
multi-radar paper's eq. 7 inverts, Δt = |β_sh − β_Last| / 2π · t_scan with
β_Last = 2π. A target is swept when the antenna reaches its azimuth (solved by two
fixed-point iterations). The site's own tracker ("partial track processing") reports
it with time = that sweep time, published at the end of the scan (log time):

- range and azimuth = truth + white Gaussian noise with the site's ``sigma_range_m``
  and ``sigma_azimuth_rad``; x/y are the noisy polar position in the site's ENU frame;
  course and speed = truth (in the site frame, i.e. with meridian convergence) + white
  Gaussian noise with ``sigma_course_rad`` and ``sigma_speed_mps``. The report's sigma
  fields are the configured ones (honest for measured reports).
- a plot is detected with probability 0.97 per scan; a track is initiated after 3
  consecutive detections ("new" on the first report, "confirmed" after); a missed scan
  is coasted (linear prediction from the previous report, status "coasting", same sigma
  fields: the extrapolation adds < 1 m to errors of 15 m and more); after 2 coasted
  scans a third miss drops the track. A confirmed track is lost with probability 0.002
  per scan (a tracker swap or drop). A dropped track stops reporting (the warehouse
  keeps no status, so no "lost" message is sent); the site re-initiates the target
  after 3 detections under a new local track id. Tracks also end when the target
  leaves the scene or ``max_range_m``. Local track ids increase with initiation time
  per site from 1000 · (site index + 1).
- the trackers run for 60 s before the start on the ships already under way (not
  archived), so the log opens, like a cut from a continuous archive, with confirmed
  tracks; ships that arrive later start with "new" tracks.
- registration bias (``[radar_bias.simulate]``, see :mod:`pipeline.maritime.bias`; none by
  default): every measured range is scaled by 1 + range_gain and the site's
  range_bias_m added to it (a range clock's scale error, a trigger delay),
  azimuth_bias_deg added to every azimuth and course (a misaligned antenna encoder), and
  time_offset_s to every report time (a clock offset; the log time is the recorder's and
  is not shifted).

AIS: see :mod:`pipeline.simulate.ais_traffic` (ITU-R M.1371 intervals, pyais encoding).

Truth: one row per vessel per whole second of the scene while the vessel is in it;
course is clockwise from true north at the vessel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import polars as pl
import shapely
from scipy.special import ndtr

from pipeline.config import Config, RadarSite
from pipeline.frames import (
    TWO_PI,
    enu_to_geodetic,
    enu_to_polar,
    geodetic_to_enu,
    polar_to_enu,
    wrap_angle,
)
from pipeline.geometry import sector_polygons
from pipeline.maritime.config import ChannelFault, SiteBias, channel_faults, radar_bias_config
from pipeline.messages import RADAR_REPORT, message_layout
from pipeline.simulate.ais_traffic import AisStation, StateFn, draw_identity, simulate_ais
from pipeline.simulate.channel_faults import (
    FAULT_TRUTH_SCHEMA,
    fault_truth,
    pick_vessel,
    radar_effects,
    radar_silent,
)
from pipeline.units import NS

# --- traffic -----------------------------------------------------------------------
N_INITIAL_PER_DIRECTION = 11
SPEED_RANGE_MPS = (3.0, 9.0)
LATERAL_OFFSET_RANGE_M = (100.0, 250.0)
FAIRWAY_TURN_RADIUS_M = 600.0
N_NO_AIS_INITIAL = 4
N_CLASS_B_INITIAL = 4
P_NO_AIS_ARRIVAL = 0.15
P_CLASS_B_ARRIVAL = 0.2
CLOSE_PASS_TIME_S = 300.0
CLOSE_PASS_OFFSET_M = 60.0
N_FERRIES = 3
FERRY_HALF_CROSSING_M = 2000.0
FERRY_LANE_SEPARATION_M = 400.0
FERRY_TURN_RADIUS_M = 150.0
FERRY_SPEED_RANGE_MPS = (5.0, 7.0)

# --- radar site tracker ----------------------------------------------------------
DETECTION_PROBABILITY = 0.97
TRACK_LOSS_PROBABILITY = 0.002
INITIATION_SCANS = 3
MAX_COAST_SCANS = 2
RADAR_WARMUP_S = 60.0
SCAN_END_AZIMUTH_RAD = TWO_PI

# random stream keys (second element of the seed sequence)
_FLEET, _ARRIVALS, _FERRIES, _IDENTITY, _RADAR_PHASE, _RADAR, _AIS = range(1, 8)

RADAR_REPORT_SCHEMA: dict[str, pl.DataType] = {
    **message_layout(RADAR_REPORT).polars_schema(),  # every field of the report, in order
    "log_time_ns": pl.Int64(),
}
TRUTH_SCHEMA: dict[str, pl.DataType] = message_layout("truth_state.schema.json").polars_schema()
_STATUS = np.array(["", "new", "confirmed", "coasting"], dtype=object)


@dataclass(frozen=True, eq=False)
class ChannelScenario:
    """Everything the ``channel`` scenario produced, as polars frames.

    - ``truth``: vessel_id, mmsi (null without AIS), time_ns, lat_deg, lon_deg,
      course_rad (clockwise from true north), speed_mps; one row per vessel per second.
    - ``radar_reports``: the fields of ``surveil.RadarTrackReport`` plus ``log_time_ns``
      (end of the scan, when the site publishes).
    - ``ais_sentences``: log_time_ns, sentence (one ``!AIVDM`` sentence per row), and,
      for tests and evaluation only (not archived), mmsi and msg_type.
    - ``vessels``: one row per vessel: vessel_id, mmsi, ais_class ("A"/"B"/null),
      shipname, kind ("fairway"/"ferry"), route, speed_mps, lateral_offset_m,
      enter_time_ns, exit_time_ns, close_pass.
    - ``radar_track_truth``: site_id, track_id, vessel_id, first_time_ns,
      last_time_ns, n_reports: which vessel each local track follows.
    - ``fault_truth``: the injected faults (``[[channel_faults]]``), one row per
      affected channel (:func:`pipeline.simulate.channel_faults.fault_truth`).

    ``seed``, ``start_ns`` (ns since the Unix epoch, UTC) and ``duration_s`` are the
    arguments of the run; ``site_ids`` the radar sites in config order.
    """

    truth: pl.DataFrame
    radar_reports: pl.DataFrame
    ais_sentences: pl.DataFrame
    vessels: pl.DataFrame
    radar_track_truth: pl.DataFrame
    seed: int
    start_ns: int
    duration_s: float
    site_ids: tuple[str, ...]
    fault_truth: pl.DataFrame = field(
        default_factory=lambda: pl.DataFrame(schema=FAULT_TRUTH_SCHEMA)
    )

    @property
    def end_ns(self) -> int:
        """End of the scenario (exclusive), ns since the Unix epoch."""
        return self.start_ns + round(self.duration_s * NS)


# --- routes ----------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Route:
    """A path in the regional ENU plane: straight segments joined by circular arcs.

    Parametrised by arc length s (m); segment i begins at ``s_start_m[i]``. A straight
    segment (``turn[i] == 0``) starts at (``x_m``, ``y_m``) with course ``course_rad``;
    an arc turns to starboard (``turn`` = +1, course increasing) or to port (−1) about
    the centre (``x_m``, ``y_m``) with radius ``radius_m``, starting at course
    ``course_rad``. A closed route repeats with period ``length_m``.
    """

    s_start_m: np.ndarray
    turn: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    course_rad: np.ndarray
    radius_m: float
    length_m: float
    closed: bool

    def at(self, s_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(east_m, north_m, course_rad in [0, 2π), on_arc) at arc lengths ``s_m``."""
        s = np.asarray(s_m, float)
        s = np.mod(s, self.length_m) if self.closed else np.clip(s, 0.0, self.length_m)
        i = np.clip(np.searchsorted(self.s_start_m, s, side="right") - 1, 0, self.turn.size - 1)
        ds = s - self.s_start_m[i]
        turn = self.turn[i]
        c = self.course_rad[i] + turn * ds / self.radius_m
        arc = turn != 0
        # arc: p = centre + turn R (-cos c, sin c); straight: p = start + ds (sin c, cos c)
        R = self.radius_m
        x = np.where(arc, self.x_m[i] - turn * R * np.cos(c), self.x_m[i] + ds * np.sin(c))
        y = np.where(arc, self.y_m[i] + turn * R * np.sin(c), self.y_m[i] + ds * np.cos(c))
        return x, y, np.mod(c, TWO_PI), arc

    def arc_intervals_m(self) -> np.ndarray:
        """(n, 2) [s_begin, s_end) of the turning arcs within one pass of the route."""
        ends = np.append(self.s_start_m[1:], self.length_m)
        arc = self.turn != 0
        return np.column_stack([self.s_start_m[arc], ends[arc]])


def build_route(vertices_m: np.ndarray, radius_m: float, *, closed: bool = False) -> Route:
    """Route through ``vertices_m`` ((n, 2) east/north, m), rounding each interior vertex
    with an arc of ``radius_m`` tangent to both legs. ``closed``: the loop v0…v(n-1)v0."""
    v = np.asarray(vertices_m, float)
    if closed:
        mid = 0.5 * (v[-1] + v[0])
        v = np.vstack([mid, v, mid])
    d = np.diff(v, axis=0)
    seg_len = np.hypot(d[:, 0], d[:, 1])
    if np.any(seg_len <= 0.0):
        raise ValueError("route has repeated vertices")
    u = d / seg_len[:, None]
    course = np.arctan2(u[:, 0], u[:, 1])
    theta = np.append(wrap_angle(np.diff(course)), 0.0)  # turn at the end of leg i
    tangent = radius_m * np.tan(np.abs(theta) / 2.0)
    s_start, turn, xs, ys, cs = [], [], [], [], []
    s = 0.0
    p = v[0]
    for i in range(d.shape[0]):
        arc_begin = v[i + 1] - u[i] * tangent[i]
        straight = float(np.dot(arc_begin - p, u[i]))
        if straight < -1e-6:
            raise ValueError(f"leg {i} is too short for turns of radius {radius_m} m")
        s_start.append(s), turn.append(0), xs.append(p[0]), ys.append(p[1]), cs.append(course[i])
        s += max(straight, 0.0)
        if abs(theta[i]) > 1e-12:
            sign = 1 if theta[i] > 0 else -1
            centre = arc_begin + sign * radius_m * np.array([np.cos(course[i]), -np.sin(course[i])])
            s_start.append(s), turn.append(sign), xs.append(centre[0]), ys.append(centre[1])
            cs.append(course[i])
            s += radius_m * abs(theta[i])
            p = v[i + 1] + u[i + 1] * tangent[i]
        else:
            p = v[i + 1]
    return Route(
        s_start_m=np.asarray(s_start),
        turn=np.asarray(turn, dtype=np.int8),
        x_m=np.asarray(xs),
        y_m=np.asarray(ys),
        course_rad=np.asarray(cs),
        radius_m=float(radius_m),
        length_m=s,
        closed=closed,
    )


def offset_polyline(vertices_m: np.ndarray, offset_m: float) -> np.ndarray:
    """The polyline shifted ``offset_m`` to starboard of its direction of travel
    (mitred at interior vertices)."""
    v = np.asarray(vertices_m, float)
    d = np.diff(v, axis=0)
    u = d / np.hypot(d[:, 0], d[:, 1])[:, None]
    n = np.column_stack([u[:, 1], -u[:, 0]])  # starboard normal of the heading
    out = v.copy()
    out[0] += offset_m * n[0]
    out[-1] += offset_m * n[-1]
    for i in range(1, v.shape[0] - 1):
        m = n[i - 1] + n[i]
        out[i] += offset_m * m / (1.0 + float(np.dot(n[i - 1], n[i])))
    return out


def convergence_rad(
    lat_deg: np.ndarray, lon_deg: np.ndarray, origin_lat_deg: float, origin_lon_deg: float
) -> np.ndarray:
    """Angle of true north at (lat, lon) in the ENU frame of the origin (meridian
    convergence, Δλ · sin φ_mean, same sign as :func:`pipeline.frames.site_rotation_rad`):
    course_frame = course_true + convergence."""
    return -np.radians(np.asarray(lon_deg) - origin_lon_deg) * np.sin(
        np.radians(0.5 * (np.asarray(lat_deg) + origin_lat_deg))
    )


# --- vessels ---------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _Vessel:
    key: tuple[int, ...]
    kind: str
    route_name: str
    route: Route
    speed_mps: float
    s_enter_m: float
    t_enter_s: float
    t_exit_s: float
    t_seen_from_s: float  # radar tracking may start here (< 0: warm-up before the start)
    lateral_offset_m: float
    close_pass: bool
    ais_class: str | None
    inbound: bool

    def s_at(self, t_s: np.ndarray) -> np.ndarray:
        return self.s_enter_m + self.speed_mps * (np.asarray(t_s, float) - self.t_enter_s)

    def turn_windows_s(self) -> np.ndarray:
        """(n, 2) [begin, end) times, s since the start, while the vessel turns."""
        arcs = self.route.arc_intervals_m()
        travelled = self.speed_mps * (self.t_exit_s - self.t_enter_s)
        if self.route.closed:
            n_loops = math.ceil((self.s_enter_m + travelled) / self.route.length_m) + 1
            arcs = np.vstack([arcs + j * self.route.length_m for j in range(n_loops)])
        t = self.t_enter_s + (arcs - self.s_enter_m) / self.speed_mps
        keep = (t[:, 1] > self.t_enter_s) & (t[:, 0] < self.t_exit_s)
        return t[keep]


@dataclass(frozen=True)
class _Frame:
    lat0: float
    lon0: float

    def state(self, v: _Vessel, t_s: np.ndarray) -> tuple[np.ndarray, ...]:
        """(lat_deg, lon_deg, course_rad true, speed_mps, on_arc) of ``v`` at ``t_s``."""
        x, y, c, arc = v.route.at(v.s_at(t_s))
        lat, lon = enu_to_geodetic(x, y, self.lat0, self.lon0)
        course = np.mod(c - convergence_rad(lat, lon, self.lat0, self.lon0), TWO_PI)
        return lat, lon, course, np.full(lat.shape, v.speed_mps), arc


def _fairway_vertices(cfg: Config) -> np.ndarray:
    legs = cfg.fairway_legs
    if not legs:
        raise ValueError("the channel scenario needs fairway legs in the config")
    pts = [(legs[0].start_lat_deg, legs[0].start_lon_deg)]
    for leg in legs:
        if (leg.start_lat_deg, leg.start_lon_deg) != pts[-1]:
            pts.append((leg.start_lat_deg, leg.start_lon_deg))
        pts.append((leg.end_lat_deg, leg.end_lon_deg))
    lat, lon = np.array(pts).T
    x, y = geodetic_to_enu(lat, lon, cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
    return np.column_stack([x, y])


def _middle_leg(cfg: Config, frame: _Frame) -> tuple[np.ndarray, np.ndarray]:
    """(start, end) of the middle fairway leg in the regional frame, m."""
    leg = cfg.fairway_legs[len(cfg.fairway_legs) // 2]
    x, y = geodetic_to_enu(
        np.array([leg.start_lat_deg, leg.end_lat_deg]),
        np.array([leg.start_lon_deg, leg.end_lon_deg]),
        frame.lat0,
        frame.lon0,
    )
    return np.array([x[0], y[0]]), np.array([x[1], y[1]])


def _s_abeam(route: Route, point: np.ndarray) -> float:
    """Arc length where ``route`` passes closest to ``point`` (1 m resolution)."""
    s = np.arange(0.0, route.length_m, 1.0)
    x, y, _, _ = route.at(s)
    return float(s[np.argmin(np.hypot(x - point[0], y - point[1]))])


def _plan_vessels(cfg: Config, frame: _Frame, duration_s: float, seed: int) -> list[_Vessel]:
    axis = _fairway_vertices(cfg)
    directions = (
        ("-".join(leg.leg_id for leg in cfg.fairway_legs), axis, True),
        ("-".join(leg.leg_id for leg in reversed(cfg.fairway_legs)), axis[::-1], False),
    )
    v_lo, v_hi = SPEED_RANGE_MPS
    o_lo, o_hi = LATERAL_OFFSET_RANGE_M
    leg_a, leg_b = _middle_leg(cfg, frame)
    meet_point = 0.5 * (leg_a + leg_b)

    def fairway(
        key,
        name,
        verts,
        inbound,
        speed,
        offset,
        *,
        s_enter=None,
        t_enter=0.0,
        frac=0.0,
        ais_class="A",
        close_pass=False,
    ) -> _Vessel:
        route = build_route(offset_polyline(verts, offset), FAIRWAY_TURN_RADIUS_M)
        if s_enter is None:
            s_enter = frac * route.length_m
        if s_enter < 0.0:  # would have to start before the fairway: arrive later instead
            t_enter, s_enter = t_enter - s_enter / speed, 0.0
        t_exit = t_enter + (route.length_m - s_enter) / speed
        seen_from = max(t_enter - RADAR_WARMUP_S, t_enter - s_enter / speed)
        return _Vessel(
            key,
            "fairway",
            name,
            route,
            speed,
            s_enter,
            t_enter,
            min(t_exit, duration_s),
            seen_from,
            offset,
            close_pass,
            ais_class,
            inbound,
        )

    vessels: list[_Vessel] = []
    # initial fleet: 11 per direction under way at the start
    u = np.random.default_rng([seed, _FLEET]).random((2, N_INITIAL_PER_DIRECTION, 3))
    n_other = 2 * N_INITIAL_PER_DIRECTION - 2  # all but the close-pass pair
    carriage: list[str | None] = (
        [None] * N_NO_AIS_INITIAL
        + ["B"] * N_CLASS_B_INITIAL
        + ["A"] * (n_other - N_NO_AIS_INITIAL - N_CLASS_B_INITIAL)
    )
    order = np.random.default_rng([seed, _FLEET, 1]).permutation(n_other)
    c_iter = iter([carriage[j] for j in order])
    for d, (name, verts, inbound) in enumerate(directions):
        for i in range(N_INITIAL_PER_DIRECTION):
            speed = v_lo + (v_hi - v_lo) * u[d, i, 0]
            if i == 0:  # the close-pass pair meets abeam mid-leg at CLOSE_PASS_TIME_S
                route = build_route(
                    offset_polyline(verts, CLOSE_PASS_OFFSET_M), FAIRWAY_TURN_RADIUS_M
                )
                s_meet = _s_abeam(route, meet_point)
                vessels.append(
                    fairway(
                        (0, d, i),
                        name,
                        verts,
                        inbound,
                        speed,
                        CLOSE_PASS_OFFSET_M,
                        s_enter=s_meet - speed * CLOSE_PASS_TIME_S,
                        close_pass=True,
                    )
                )
            else:
                offset = o_lo + (o_hi - o_lo) * u[d, i, 1]
                vessels.append(
                    fairway(
                        (0, d, i),
                        name,
                        verts,
                        inbound,
                        speed,
                        offset,
                        frac=0.98 * u[d, i, 2],
                        ais_class=next(c_iter),
                    )
                )
    # ferries shuttling across the middle leg
    along = (leg_b - leg_a) / np.hypot(*(leg_b - leg_a))
    across = np.array([along[1], -along[0]])
    uf = np.random.default_rng([seed, _FERRIES]).random((N_FERRIES, 2))
    f_lo, f_hi = FERRY_SPEED_RANGE_MPS
    for j in range(N_FERRIES):
        centre = leg_a + (j + 1) / (N_FERRIES + 1) * (leg_b - leg_a)
        h, w = FERRY_HALF_CROSSING_M, 0.5 * FERRY_LANE_SEPARATION_M
        loop = np.array(
            [
                centre - h * across - w * along,
                centre + h * across - w * along,
                centre + h * across + w * along,
                centre - h * across + w * along,
            ]
        )
        route = build_route(loop, FERRY_TURN_RADIUS_M, closed=True)
        speed = f_lo + (f_hi - f_lo) * uf[j, 0]
        vessels.append(
            _Vessel(
                (1, 0, j),
                "ferry",
                f"ferry-{j + 1}",
                route,
                speed,
                uf[j, 1] * route.length_m,
                0.0,
                duration_s,
                -RADAR_WARMUP_S,
                0.0,
                False,
                "A",
                True,
            )
        )
    # arrivals at both fairway ends (Poisson, rate = initial count / mean transit time)
    arrivals: list[_Vessel] = []
    for d, (name, verts, inbound) in enumerate(directions):
        mean_inv_speed = math.log(v_hi / v_lo) / (v_hi - v_lo)
        length = float(np.sum(np.hypot(*np.diff(verts, axis=0).T)))
        rate = N_INITIAL_PER_DIRECTION / (length * mean_inv_speed)
        rng = np.random.default_rng([seed, _ARRIVALS, d])
        t, i = 0.0, 0
        while True:
            a = rng.random(5)
            t += -math.log1p(-a[0]) / rate
            if t >= duration_s:
                break
            ais_class = (
                None if a[3] < P_NO_AIS_ARRIVAL else ("B" if a[4] < P_CLASS_B_ARRIVAL else "A")
            )
            arrivals.append(
                fairway(
                    (2, d, i),
                    name,
                    verts,
                    inbound,
                    v_lo + (v_hi - v_lo) * a[1],
                    o_lo + (o_hi - o_lo) * a[2],
                    s_enter=0.0,
                    t_enter=t,
                    ais_class=ais_class,
                )
            )
            i += 1
    arrivals.sort(key=lambda v: v.t_enter_s)
    return vessels + arrivals


# --- radar -----------------------------------------------------------------------


def _site_reports(
    site: RadarSite,
    site_index: int,
    vessels: list[_Vessel],
    frame: _Frame,
    duration_s: float,
    seed: int,
    bias: SiteBias = SiteBias(),  # noqa: B008
    faults: tuple[ChannelFault, ...] = (),
) -> tuple[dict[str, np.ndarray], list[tuple]]:
    """Track reports of one site's tracker, as column arrays, plus one
    (first_time_s, vessel_index, track_no, first_row, last_row) per track. ``faults``:
    the site's channel faults (:mod:`pipeline.simulate.channel_faults`)."""
    T = site.scan_period_s
    t_first_scan = -T * float(np.random.default_rng([seed, _RADAR_PHASE, site_index]).random())
    k_max = math.ceil((duration_s - t_first_scan) / T) - 2  # last scan ending before the end
    while t_first_scan + (k_max + 1) * T >= duration_s:
        k_max -= 1

    def polar(v: _Vessel, t: np.ndarray) -> tuple[np.ndarray, ...]:
        lat, lon, course, speed, _ = frame.state(v, t)
        e, n = geodetic_to_enu(lat, lon, site.lat_deg, site.lon_deg)
        r, az = enu_to_polar(e, n)
        az = np.mod(az - site.north_alignment_rad, TWO_PI)
        c = np.mod(
            course
            + convergence_rad(lat, lon, site.lat_deg, site.lon_deg)
            - site.north_alignment_rad,
            TWO_PI,
        )
        return r, az, c, speed

    cols: dict[str, list[np.ndarray]] = {
        k: []
        for k in ("vessel", "track_no", "t", "log_t", "r", "az", "x", "y", "c", "v", "status", "dt")
    }
    tracks: list[tuple] = []
    n_rows = 0
    for vi, v in enumerate(vessels):
        k_lo = math.floor((v.t_seen_from_s - t_first_scan) / T)
        k_hi = min(k_max, math.floor((v.t_exit_s - t_first_scan) / T))
        if k_hi < k_lo:
            continue
        k = np.arange(k_lo, k_hi + 1)
        tk = t_first_scan + k * T
        # sweep time: the antenna reaches the target's azimuth (inverse of eq. 7)
        az_mid = polar(v, tk + 0.5 * T)[1]
        ts = tk + polar(v, tk + az_mid / TWO_PI * T)[1] / TWO_PI * T
        r, az, c, spd = polar(v, ts)
        valid = (ts >= v.t_seen_from_s) & (ts <= v.t_exit_s) & (r <= site.max_range_m)
        n = k.size
        z = np.random.default_rng([seed, _RADAR, site_index, *v.key]).standard_normal((n, 6))
        can_detect, f_dr, f_daz, f_dt, f_noise = radar_effects(faults, ts, az, r)
        detected = (ndtr(z[:, 0]) < DETECTION_PROBABILITY) & can_detect
        lost = ndtr(z[:, 1]) < TRACK_LOSS_PROBABILITY
        status, track_no = _track_life(valid, detected, lost)
        # the warm-up is not archived; nothing is published during an outage
        rep = np.flatnonzero((status > 0) & (ts >= 0.0) & ~radar_silent(faults, tk + T))
        if rep.size == 0:
            continue
        e_r = site.sigma_range_m * f_noise * z[:, 2]
        # (1 + gain) x measured + bias, summed so that no gain gives the same bits as before
        r_m = np.abs(r + bias.range_bias_m + f_dr + e_r + bias.range_gain * (r + f_dr + e_r))
        az_m = np.mod(
            az + bias.azimuth_bias_rad + f_daz + site.sigma_azimuth_rad * f_noise * z[:, 3],
            TWO_PI,
        )
        c_m = np.mod(
            c + bias.azimuth_bias_rad + f_daz + site.sigma_course_rad * f_noise * z[:, 4], TWO_PI
        )
        v_m = np.abs(spd + site.sigma_speed_mps * f_noise * z[:, 5])
        x_m, y_m = polar_to_enu(r_m, az_m)
        for i in np.flatnonzero(status == 3):  # coast: predict from the previous report
            dt = ts[i] - ts[i - 1]
            x_m[i] = x_m[i - 1] + v_m[i - 1] * dt * math.sin(c_m[i - 1])
            y_m[i] = y_m[i - 1] + v_m[i - 1] * dt * math.cos(c_m[i - 1])
            c_m[i], v_m[i] = c_m[i - 1], v_m[i - 1]
            r_m[i], az_m[i] = enu_to_polar(x_m[i], y_m[i])
        for name, arr in (
            ("t", ts),
            ("r", r_m),
            ("az", az_m),
            ("x", x_m),
            ("y", y_m),
            ("c", c_m),
            ("v", v_m),
            ("status", status),
            ("track_no", track_no),
            ("dt", f_dt),
        ):
            cols[name].append(arr[rep])
        cols["log_t"].append(tk[rep] + T)
        cols["vessel"].append(np.full(rep.size, vi))
        tn = track_no[rep]
        for j in np.unique(tn):
            rows = np.flatnonzero(tn == j)
            tracks.append(
                (float(ts[rep[rows[0]]]), vi, j, n_rows + rows[0], n_rows + rows[-1], rows.size)
            )
        n_rows += rep.size
    out = {k: (np.concatenate(a) if a else np.empty(0)) for k, a in cols.items()}
    return out, tracks


def _track_life(
    valid: np.ndarray, detected: np.ndarray, lost: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The site tracker's state machine over consecutive scans of one target.

    Returns per scan the report status (0 none, 1 new, 2 confirmed, 3 coasting), the
    ordinal of the track that reports it (−1 none).
    """
    n = valid.size
    status = np.zeros(n, dtype=np.int8)
    track_no = np.full(n, -1, dtype=np.int64)
    in_track, streak, misses, n_tracks = False, 0, 0, 0
    for i in range(n):
        if not valid[i]:
            in_track, streak = False, 0
            continue
        if in_track:
            if lost[i]:
                in_track, streak = False, 0
                continue
            if detected[i]:
                status[i], misses = 2, 0
            else:
                misses += 1
                if misses > MAX_COAST_SCANS:
                    in_track, streak = False, 0
                    continue
                status[i] = 3
            track_no[i] = n_tracks - 1
        else:
            streak = streak + 1 if detected[i] else 0
            if streak >= INITIATION_SCANS:
                in_track, streak, misses = True, 0, 0
                n_tracks += 1
                status[i], track_no[i] = 1, n_tracks - 1
    return status, track_no


# --- the scenario ----------------------------------------------------------------


def simulate_channel(
    cfg: Config, *, start_ns: int, duration_s: float, seed: int
) -> ChannelScenario:
    """Simulate the ``channel`` scenario over [start_ns, start_ns + duration_s).

    ``start_ns``: ns since the Unix epoch, UTC; ``duration_s``: s (> 0; the close pass
    happens 300 s after the start, so runs shorter than that do not contain it);
    ``seed``: every random draw derives from it.
    """
    if duration_s <= 0:
        raise ValueError(f"duration_s must be positive, got {duration_s}")
    frame = _Frame(cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
    plans = _plan_vessels(cfg, frame, duration_s, seed)
    faults = channel_faults(cfg)
    hit, other = _ais_fault_vessels(cfg, faults, plans, frame, seed)

    # identities (MMSIs unique, in vessel-id order)
    used: set[int] = set()
    stations: list[tuple[AisStation, StateFn]] = []
    mmsi_of: list[int | None] = []
    names: list[str | None] = []
    for vid, v in enumerate(plans, start=1):
        if v.ais_class is None:
            mmsi_of.append(None)
            names.append(None)
            continue
        ident = draw_identity(
            np.random.default_rng([seed, _IDENTITY, *v.key]),
            ais_class=v.ais_class,
            kind=v.kind,
            inbound=v.inbound,
        )
        mmsi = ident.mmsi
        while mmsi in used:
            mmsi = mmsi + 1 if mmsi % 1_000_000 != 999_999 else mmsi - 999_999 + 100_000
        used.add(mmsi)
        ident = replace(ident, mmsi=mmsi)
        mmsi_of.append(mmsi)
        names.append(ident.shipname)
        own = tuple(f for f, h in zip(faults, hit, strict=True) if h == vid - 1)
        station = AisStation(
            vid, ident, v.speed_mps, v.t_enter_s, v.t_exit_s, v.turn_windows_s(), (_AIS, *v.key),
            faults=tuple(f for f in own if f.kind in ("ais_offset", "ais_stuck")),
        )
        stations.append((station, _state_fn(frame, v)))
    stations = _with_swaps(stations, faults, hit, other)
    stations += _spoofers(cfg, faults, frame, len(plans), duration_s, seed)

    truth = _truth(plans, frame, mmsi_of, start_ns, duration_s)
    reports, links = _radar(cfg, plans, frame, start_ns, duration_s, seed)
    ais = simulate_ais(stations, start_ns=start_ns, duration_s=duration_s, seed=seed)
    injected = fault_truth(faults, start_ns, duration_s, vessel_of=hit, other_of=other,
                           mmsi_of=lambda i: mmsi_of[i])
    vessels = pl.DataFrame(
        {
            "vessel_id": np.arange(1, len(plans) + 1, dtype=np.int64),
            "mmsi": pl.Series(mmsi_of, dtype=pl.Int64),
            "ais_class": pl.Series([v.ais_class for v in plans], dtype=pl.String),
            "shipname": pl.Series(names, dtype=pl.String),
            "kind": [v.kind for v in plans],
            "route": [v.route_name for v in plans],
            "speed_mps": np.array([v.speed_mps for v in plans]),
            "lateral_offset_m": np.array([v.lateral_offset_m for v in plans]),
            "enter_time_ns": np.array(
                [start_ns + round(v.t_enter_s * NS) for v in plans], dtype=np.int64
            ),
            "exit_time_ns": np.array(
                [start_ns + round(v.t_exit_s * NS) for v in plans], dtype=np.int64
            ),
            "close_pass": [v.close_pass for v in plans],
        }
    )
    return ChannelScenario(
        truth=truth,
        radar_reports=reports,
        ais_sentences=ais,
        vessels=vessels,
        radar_track_truth=links,
        seed=seed,
        start_ns=start_ns,
        duration_s=float(duration_s),
        site_ids=tuple(s.site_id for s in cfg.radar_sites),
        fault_truth=injected,
    )


def _ais_fault_vessels(
    cfg: Config, faults: tuple[ChannelFault, ...], plans: list[_Vessel], frame: _Frame,
    seed: int,
) -> tuple[list[int | None], list[int | None]]:
    """Per fault, the vessel (0-based) an AIS fault hits and the other vessel of a swap
    (None for radar faults and spoofers, or when no vessel fits)."""
    polys = {s.name: p for s, p in zip(cfg.sectors, sector_polygons(cfg.sectors, cfg.region),
                                        strict=True)}

    def present(i: int, t0: float, t1: float) -> bool:
        return plans[i].t_enter_s <= t0 and plans[i].t_exit_s >= t1

    def in_sector(i: int, t: float, sector: str) -> bool:
        x, y, _, _ = plans[i].route.at(plans[i].s_at(np.array([t])))
        return bool(shapely.contains_xy(polys[sector], x[0], y[0]))

    class_a = [i for i, v in enumerate(plans) if v.ais_class == "A"]
    hit: list[int | None] = []
    other: list[int | None] = []
    for k, f in enumerate(faults):
        if f.sensor_kind == "radar" or f.kind == "ais_spoof":
            hit.append(None), other.append(None)
            continue
        a = f.vessel_id - 1 if f.vessel_id else pick_vessel(
            f, class_a, present, in_sector, seed, k)
        b = None
        if f.kind == "ais_mmsi_swap" and a is not None:
            b = f.other_vessel_id - 1 if f.other_vessel_id else pick_vessel(
                replace(f, sector=""), class_a, present, in_sector, seed, 1000 + k,
                exclude=(a,))
            if b is None:
                a = None
        for i in (a, b):
            if i is not None and not 0 <= i < len(plans):
                raise ValueError(f"channel fault {f.kind}: vessel {i + 1} does not exist")
            if i is not None and plans[i].ais_class is None:
                raise ValueError(f"channel fault {f.kind}: vessel {i + 1} carries no AIS")
        hit.append(a), other.append(b)
    return hit, other


def _with_swaps(
    stations: list[tuple[AisStation, StateFn]], faults: tuple[ChannelFault, ...],
    hit: list[int | None], other: list[int | None],
) -> list[tuple[AisStation, StateFn]]:
    """Stations of an MMSI swap send each other's MMSI while it lasts."""
    mmsi = {st.vessel_id - 1: st.identity.mmsi for st, _ in stations}
    swaps: dict[int, list[tuple[ChannelFault, int]]] = {}
    for f, a, b in zip(faults, hit, other, strict=True):
        if f.kind == "ais_mmsi_swap" and a is not None and b is not None:
            swaps.setdefault(a, []).append((f, mmsi[b]))
            swaps.setdefault(b, []).append((f, mmsi[a]))
    return [(replace(st, swaps=tuple(swaps.get(st.vessel_id - 1, ()))), fn)
            for st, fn in stations]


def _spoofers(
    cfg: Config, faults: tuple[ChannelFault, ...], frame: _Frame, n_vessels: int,
    duration_s: float, seed: int,
) -> list[tuple[AisStation, StateFn]]:
    """A Class A station on no ship per ``ais_spoof`` fault: a straight line from its
    start position at its course and speed (course in the regional frame)."""
    out = []
    for k, f in enumerate(faults):
        if f.kind != "ais_spoof" or f.start_s >= duration_s:
            continue
        ident = replace(
            draw_identity(np.random.default_rng([seed, _IDENTITY, 3, k]), ais_class="A",
                          kind="fairway", inbound=True),
            mmsi=f.mmsi,
        )
        x0, y0 = geodetic_to_enu(f.start_lat_deg, f.start_lon_deg, frame.lat0, frame.lon0)

        def state(t_s: np.ndarray, f=f, x0=float(x0), y0=float(y0)) -> tuple[np.ndarray, ...]:
            d = f.speed_mps * (np.asarray(t_s, float) - f.start_s)
            lat, lon = enu_to_geodetic(x0 + d * math.sin(f.course_rad),
                                       y0 + d * math.cos(f.course_rad), frame.lat0, frame.lon0)
            course = np.mod(f.course_rad - convergence_rad(lat, lon, frame.lat0, frame.lon0),
                            TWO_PI)
            return lat, lon, course, np.full(np.shape(lat), f.speed_mps)

        station = AisStation(n_vessels + 1 + k, ident, f.speed_mps, f.start_s,
                             min(f.end_s, duration_s), np.empty((0, 2)), (_AIS, 3, k))
        out.append((station, state))
    return out


def _state_fn(frame: _Frame, v: _Vessel) -> StateFn:
    def state(t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        lat, lon, course, speed, _ = frame.state(v, t_s)
        return lat, lon, course, speed

    return state


def _truth(
    plans: list[_Vessel], frame: _Frame, mmsi_of: list[int | None], start_ns: int, duration_s: float
) -> pl.DataFrame:
    parts = []
    for vid, (v, mmsi) in enumerate(zip(plans, mmsi_of, strict=True), start=1):
        t = np.arange(
            math.ceil(v.t_enter_s), math.floor(min(v.t_exit_s, duration_s)) + 1, dtype=np.int64
        )
        t = t[t < duration_s]
        if t.size == 0:
            continue
        lat, lon, course, speed, _ = frame.state(v, t.astype(float))
        parts.append(
            pl.DataFrame(
                {
                    "vessel_id": np.full(t.size, vid, dtype=np.int64),
                    "mmsi": pl.Series([mmsi] * t.size, dtype=pl.Int64),
                    "time_ns": start_ns + t * NS,
                    "lat_deg": lat,
                    "lon_deg": lon,
                    "course_rad": course,
                    "speed_mps": speed,
                },
                schema=TRUTH_SCHEMA,
            )
        )
    if not parts:
        return pl.DataFrame(schema=TRUTH_SCHEMA)
    return pl.concat(parts).sort(["time_ns", "vessel_id"])


def _radar(
    cfg: Config, plans: list[_Vessel], frame: _Frame, start_ns: int, duration_s: float, seed: int
) -> tuple[pl.DataFrame, pl.DataFrame]:
    frames, links = [], []
    for si, site in enumerate(cfg.radar_sites):
        bias = radar_bias_config(cfg).simulate.get(site.site_id, SiteBias())
        faults = tuple(f for f in channel_faults(cfg) if f.site_id == site.site_id)
        cols, tracks = _site_reports(site, si, plans, frame, duration_s, seed, bias, faults)
        n = cols["t"].size
        track_id = np.zeros(n, dtype=np.int64)
        # local track ids increase with initiation time; a track's rows are contiguous
        for rank, (_, vi, _, first, last, count) in enumerate(sorted(tracks)):
            tid = 1000 * (si + 1) + rank
            track_id[first : last + 1] = tid
            links.append(
                (
                    site.site_id,
                    tid,
                    vi + 1,
                    start_ns + round(cols["t"][first] * NS),
                    start_ns + round(cols["t"][last] * NS),
                    count,
                )
            )
        df = pl.DataFrame(
            {
                "site_id": [site.site_id] * n,
                "track_id": track_id,
                "time_ns": start_ns
                + np.round((cols["t"] + bias.time_offset_s + cols["dt"]) * NS).astype(np.int64),
                "range_m": cols["r"],
                "azimuth_rad": cols["az"],
                "x_m": cols["x"],
                "y_m": cols["y"],
                "course_rad": cols["c"],
                "speed_mps": cols["v"],
                "sigma_range_m": np.full(n, site.sigma_range_m),
                "sigma_azimuth_rad": np.full(n, site.sigma_azimuth_rad),
                "sigma_course_rad": np.full(n, site.sigma_course_rad),
                "sigma_speed_mps": np.full(n, site.sigma_speed_mps),
                "scan_period_s": np.full(n, site.scan_period_s),
                "scan_end_azimuth_rad": np.full(n, SCAN_END_AZIMUTH_RAD),
                "status": _STATUS[cols["status"].astype(np.int64)] if n else np.empty(0, object),
                "log_time_ns": start_ns + np.round(cols["log_t"] * NS).astype(np.int64),
            },
            schema=RADAR_REPORT_SCHEMA,
        )
        frames.append(df)
    reports = pl.concat(frames).sort(["log_time_ns", "site_id", "time_ns", "track_id"])
    link_schema = {
        "site_id": pl.String,
        "track_id": pl.Int64,
        "vessel_id": pl.Int64,
        "first_time_ns": pl.Int64,
        "last_time_ns": pl.Int64,
        "n_reports": pl.Int64,
    }
    track_truth = pl.DataFrame(links, schema=link_schema, orient="row").sort(
        ["site_id", "track_id"]
    )
    return reports, track_truth
