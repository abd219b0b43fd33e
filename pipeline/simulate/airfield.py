"""The ``airfield`` scenario: surface traffic watched by SMR, MLAT and VASN (airfield paper).

A pure function of (airfield config, start time, duration, seed): no files, no clock.
Random draws come from ``np.random.default_rng((seed, stream, ...))`` with a fixed key
per purpose (traffic, per-sensor errors, detections), so the traffic of a seed does not
depend on the sensors and a sensor's errors do not depend on another sensor's.

**Layout** (east/north metres from the reference point = runway centre; the shipped
config's sector polygons are these areas): runway 09/27 along y = 0, x ∈ [−1500, 1500];
parallel taxiway A at y = 180 with connectors at x = −1450, −700, 0, 700, 1450; apron
entrances at x = ±850 up to the apron taxiway (taxilane) at y = 330; 12 stands at
x = −660 + 120 i, stand point y = 400; a service road at y = 520 with vehicle depots
at its ends (depot slots 30 m apart).

**Traffic.** Paths are straight legs joined by circular arcs (``build_route`` of the
channel scenario; radius 40 m on taxiways, 20 m at line-up). Along a path the speed
follows the envelope of: the leg's cruise speed, the arc limit sqrt(a_lat R) with
a_lat = 1 m/s², acceleration from the start speed and braking to the end speed at the
move's rates (forward/backward passes on a 0.25 m grid); position and speed at any
time are exact for that piecewise-constant-acceleration profile.

- *Parked aircraft*: 8 of the 12 stands are occupied at the start, engines off and
  transponder off (seen by the SMR only).
- *Departures* (one every ~9 min): start-up on the stand (engines and transponder on,
  60 s), pushback to the taxilane at 1 m/s, 30 s, taxi at 8 m/s via the west apron
  entrance and taxiway A to the runway 09 holding point, hold 40 s, line up, 15 s,
  take-off roll at 2.2 m/s² until 70 m/s (lift-off: the target leaves the scene).
- *Arrivals* (one every ~10 min) touch down at the west end at 65 m/s, brake at
  2 m/s², vacate at the x = 700 connector, taxi to a free stand, keep engines on for
  60 s, then engines and transponder off.
- *Vehicles* (transponder/squitter always on): 4 apron vehicles shuttle between a depot
  and random stands (engines on when moving and during 2-min services, off during
  depot stops), 1 inspection car loops taxiway A and the runway, 1 sweeper drives
  taxiway A back and forth.

**Sensors** (one report per target per second, at whole seconds of the scene):

- detection: SMR every target with probability ``pd``; MLAT only transponder-on
  targets; VASN only engines-on targets (blind to a stationary target with engines off).
- errors: per sensor and target, a stationary vector AR(2) position error (east/north,
  the config's ``position_model``, airfield paper eq. 7) added in the common frame
  (the model of eq. 5); VASN velocity: truth + AR(1) error (eq. 8); SMR/MLAT velocity:
  truth + white noise ``velocity_noise_mps`` (their trackers' smoothed velocity; not
  used by the filter).
- faults (config ``faults``): ``jam`` adds white noise of std sqrt(factor² − 1) σ_s per
  axis (σ_s the stationary error std), so the error std is × factor; ``bias`` adds
  ``bias_m`` towards ``direction``; ``dropout`` removes every report.
- wire values: SMR range/azimuth from its antenna, MLAT x/y from its reference point,
  both rounded to the ASTERIX CAT010 LSBs exactly as the encoder sends them; VASN
  x/y/velocity from its reference point in mm and mm/s (JSON).
- track numbers: SMR one per target, MLAT one per transponder-on period, VASN one per
  engines-on period (a new number after each engine start), 12 bits, from a per-sensor
  base; the last report of a track is marked.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import polars as pl

from pipeline.airfield.config import AirfieldConfig, FaultConfig, SensorConfig
from pipeline.decode import asterix_encode as cat010
from pipeline.filters.ar_errors import VarModel, simulate_var, stationary_covariance
from pipeline.frames import enu_to_geodetic, enu_to_polar, geodetic_to_enu, site_rotation_rad
from pipeline.simulate.channel import Route, build_route
from pipeline.units import NS

# --- layout (m from the reference point) ---------------------------------------------
RUNWAY_WEST_X = -1500.0
RUNWAY_EAST_X = 1500.0
TAXIWAY_Y = 180.0
HOLD_Y = 60.0
TAXILANE_Y = 330.0
STAND_Y = 400.0
SERVICE_Y = 520.0
SERVICE_POINT_Y = 470.0
APRON_ENTRY_X = (-850.0, 850.0)
CONNECTOR_X = (-1450.0, -700.0, 0.0, 700.0, 1450.0)
STAND_X = tuple(-660.0 + 120.0 * i for i in range(12))
DEPOT_X = (-900.0, 900.0)
TAXI_RADIUS_M = 40.0
LINEUP_RADIUS_M = 20.0
LATERAL_ACCEL_MPS2 = 1.0
GRID_M = 0.25

# --- traffic --------------------------------------------------------------------------
N_PARKED = 8
DEPARTURE_PERIOD_S = 540.0
ARRIVAL_PERIOD_S = 600.0
TAXI_SPEED_MPS = 8.0
LANDING_SPEED_MPS = 65.0
LIFTOFF_SPEED_MPS = 70.0
N_APRON_VEHICLES = 4
AIRLINES = ("AFL", "SBI", "UTA", "PBD", "DLH", "THY", "AUA", "LOT")

# random stream keys
_TRAFFIC, _ERRORS, _DETECT, _VELNOISE, _JAM = range(1, 6)
_SENSOR_INDEX = {"smr": 0, "mlat": 1, "vasn": 2}
TRACK_BASE = {"smr": 100, "mlat": 1000, "vasn": 2000}


# --- motion --------------------------------------------------------------------------


@dataclass(frozen=True)
class Park:
    """Stay put for ``duration_s`` (inf: to the end) with the given engine/transponder."""

    duration_s: float
    engines_on: bool
    transponder_on: bool


@dataclass(frozen=True)
class Move:
    """Follow ``vertices`` (m) joined by arcs of ``radius_m``: cruise speed per leg
    (``leg_speed_mps``, one per polyline edge), start speed, accel/decel rates; the move
    ends at rest, or when ``vanish_at_mps`` is reached (lift-off)."""

    vertices: tuple[tuple[float, float], ...]
    leg_speed_mps: tuple[float, ...]
    radius_m: float = TAXI_RADIUS_M
    v_start_mps: float = 0.0
    accel_mps2: float = 0.5
    decel_mps2: float = 1.0
    transponder_on: bool = True
    vanish_at_mps: float | None = None


@dataclass(frozen=True)
class Mission:
    target_id: int
    kind: str  # aircraft | vehicle
    callsign: str
    address: int
    appear_s: float
    activities: tuple[Park | Move, ...]
    start_xy: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True, eq=False)
class Profile:
    """Speed profile of a move on its route: grid of arc length, speed, time."""

    route: Route
    s_m: np.ndarray
    v_mps: np.ndarray
    t_s: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1])

    def at(self, tau_s: np.ndarray) -> tuple[np.ndarray, ...]:
        """(x, y, vx, vy) at times ``tau_s`` since the move began (exact within the
        constant-acceleration grid cells)."""
        tau = np.clip(tau_s, 0.0, self.t_s[-1])
        i = np.clip(np.searchsorted(self.t_s, tau, side="right") - 1, 0, self.t_s.size - 2)
        dt = self.t_s[i + 1] - self.t_s[i]
        a = np.where(dt > 0, (self.v_mps[i + 1] - self.v_mps[i]) / np.where(dt > 0, dt, 1), 0)
        u = tau - self.t_s[i]
        s = np.minimum(self.s_m[i] + self.v_mps[i] * u + 0.5 * a * u * u, self.s_m[i + 1])
        v = self.v_mps[i] + a * u
        x, y, course, _ = self.route.at(s)
        return x, y, v * np.sin(course), v * np.cos(course)


def _leg_index(route: Route) -> np.ndarray:
    """Polyline edge of each route piece (arcs belong to the edge before them)."""
    return np.cumsum(route.turn == 0) - 1


def speed_profile(move: Move) -> Profile:
    """The speed envelope of :class:`Move` on its route, and the time along it."""
    route = build_route(np.asarray(move.vertices, float), move.radius_m)
    n = max(math.ceil(route.length_m / GRID_M), 2)
    s = np.linspace(0.0, route.length_m, n + 1)
    piece = np.clip(np.searchsorted(route.s_start_m, s, side="right") - 1, 0, None)
    leg = _leg_index(route)[piece]
    speeds = np.asarray(move.leg_speed_mps, float)
    env = speeds[np.clip(leg, 0, speeds.size - 1)]
    on_arc = route.turn[piece] != 0
    nxt = speeds[np.clip(leg + 1, 0, speeds.size - 1)]
    arc_limit = math.sqrt(LATERAL_ACCEL_MPS2 * move.radius_m)
    env = np.where(on_arc, np.minimum(np.minimum(env, nxt), arc_limit), env)
    env[0] = move.v_start_mps
    if move.vanish_at_mps is None:
        env[-1] = 0.0
    e2 = env * env
    fwd = 2 * move.accel_mps2 * s + np.minimum.accumulate(e2 - 2 * move.accel_mps2 * s)
    bwd = (
        -2 * move.decel_mps2 * s + np.minimum.accumulate((e2 + 2 * move.decel_mps2 * s)[::-1])[::-1]
    )
    v = np.sqrt(np.clip(np.minimum(fwd, bwd), 0.0, None))
    if move.vanish_at_mps is not None:
        k = np.flatnonzero(v >= move.vanish_at_mps)
        if k.size:
            s, v = s[: k[0] + 1], v[: k[0] + 1]
    vsum = v[1:] + v[:-1]
    dt = np.where(vsum > 0, 2.0 * np.diff(s) / np.where(vsum > 0, vsum, 1.0), 0.0)
    return Profile(route, s, v, np.concatenate([[0.0], np.cumsum(dt)]))


# --- missions ------------------------------------------------------------------------


def _departure_moves(stand_x: float) -> list[Park | Move]:
    west = APRON_ENTRY_X[0]
    hold_x = CONNECTOR_X[0]
    return [
        Park(60.0, True, True),
        Move(((stand_x, STAND_Y), (stand_x, TAXILANE_Y)), (1.0,), accel_mps2=0.2, decel_mps2=0.3),
        Park(30.0, True, True),
        Move(
            (
                (stand_x, TAXILANE_Y),
                (west, TAXILANE_Y),
                (west, TAXIWAY_Y),
                (hold_x, TAXIWAY_Y),
                (hold_x, HOLD_Y),
            ),
            (TAXI_SPEED_MPS,) * 4,
        ),
        Park(40.0, True, True),
        Move(
            ((hold_x, HOLD_Y), (hold_x, 0.0), (hold_x + 70.0, 0.0)),
            (4.0, 4.0),
            radius_m=LINEUP_RADIUS_M,
        ),
        Park(15.0, True, True),
        Move(
            ((hold_x + 70.0, 0.0), (RUNWAY_EAST_X, 0.0)),
            (90.0,),
            accel_mps2=2.2,
            vanish_at_mps=LIFTOFF_SPEED_MPS,
        ),
    ]


def _arrival_moves(stand_x: float) -> list[Park | Move]:
    exit_x, entry_x = CONNECTOR_X[3], APRON_ENTRY_X[1]
    path = (
        (RUNWAY_WEST_X, 0.0),
        (exit_x, 0.0),
        (exit_x, TAXIWAY_Y),
        (entry_x, TAXIWAY_Y),
        (entry_x, TAXILANE_Y),
        (stand_x, TAXILANE_Y),
        (stand_x, STAND_Y),
    )
    return [
        Move(
            path,
            (LANDING_SPEED_MPS,) + (TAXI_SPEED_MPS,) * 5,
            v_start_mps=LANDING_SPEED_MPS,
            decel_mps2=2.0,
        ),
        Park(60.0, True, True),
        Park(math.inf, False, False),
    ]


def _depot(i: int) -> float:
    """Depot x of apron vehicle i: the two ends of the service road, 30 m apart slots."""
    return DEPOT_X[i % 2] + (30.0 if DEPOT_X[i % 2] < 0 else -30.0) * (i // 2)


def _apron_vehicle(rng: np.random.Generator, depot_x: float, duration_s: float) -> list:
    acts: list[Park | Move] = [Park(float(rng.uniform(0, 200)), False, True)]
    t = 0.0
    while t < duration_s:
        sx = float(rng.choice(STAND_X))
        out = ((depot_x, SERVICE_Y), (sx, SERVICE_Y), (sx, SERVICE_POINT_Y))
        acts += [
            Park(10.0, True, True),
            Move(out, (6.0, 3.0), radius_m=20.0),
            Park(120.0, True, True),
            Move(out[::-1], (3.0, 6.0), radius_m=20.0),
            Park(float(rng.uniform(120, 400)), False, True),
        ]
        t += 250.0  # a cycle takes longer: plan more cycles than the scene needs
    return acts


def _inspection_loop(duration_s: float) -> list:
    east, west = CONNECTOR_X[-1], CONNECTOR_X[0]
    loop = (
        (APRON_ENTRY_X[0], TAXIWAY_Y),
        (east, TAXIWAY_Y),
        (east, 0.0),
        (west, 0.0),
        (west, TAXIWAY_Y),
        (APRON_ENTRY_X[0] + 100.0, TAXIWAY_Y),
    )
    acts: list[Park | Move] = []
    for _ in range(int(duration_s // 500) + 1):
        acts += [
            Move(loop, (10.0, 10.0, 14.0, 10.0, 10.0)),
            Park(30.0, True, True),
            Move(((APRON_ENTRY_X[0] + 100.0, TAXIWAY_Y), (APRON_ENTRY_X[0], TAXIWAY_Y)), (3.0,)),
            Park(20.0, True, True),
        ]
    return acts


def _sweeper(duration_s: float) -> list:
    a, b = (CONNECTOR_X[1] + 50.0, TAXIWAY_Y), (CONNECTOR_X[3] - 50.0, TAXIWAY_Y)
    acts: list[Park | Move] = []
    for _ in range(int(duration_s // 300) + 1):
        acts += [
            Move((a, b), (7.0,)),
            Park(20.0, True, True),
            Move((b, a), (7.0,)),
            Park(60.0, True, True),
        ]
    return acts


def plan_missions(duration_s: float, seed: int) -> list[Mission]:
    """Every target of the scene and what it does (traffic random stream only)."""
    rng = np.random.default_rng((seed, _TRAFFIC))
    stands = rng.permutation(len(STAND_X))
    parked, free = list(stands[:N_PARKED]), list(stands[N_PARKED:])
    missions: list[Mission] = []
    airline = iter(rng.choice(AIRLINES, size=200))
    flight = iter(rng.integers(100, 9999, size=200))
    addresses = iter(rng.choice(np.arange(0x400000, 0x500000), size=200, replace=False))

    def aircraft(acts: list, appear: float, xy: tuple[float, float]) -> None:
        missions.append(
            Mission(
                len(missions) + 1,
                "aircraft",
                f"{next(airline)}{next(flight)}",
                int(next(addresses)),
                appear,
                tuple(acts),
                xy,
            )
        )

    n_dep = max(1, int(duration_s // DEPARTURE_PERIOD_S))
    dep_times = 60.0 + DEPARTURE_PERIOD_S * np.arange(n_dep) + rng.uniform(0, 120, n_dep)
    for k, stand in enumerate(parked):
        sx = STAND_X[stand]
        if k < n_dep and dep_times[k] < duration_s:
            aircraft(
                [Park(float(dep_times[k]), False, False), *_departure_moves(sx)], 0.0, (sx, STAND_Y)
            )
        else:
            aircraft([Park(math.inf, False, False)], 0.0, (sx, STAND_Y))
    n_arr = max(1, int(duration_s // ARRIVAL_PERIOD_S))
    arr_times = 150.0 + ARRIVAL_PERIOD_S * np.arange(n_arr) + rng.uniform(0, 120, n_arr)
    for k in range(min(n_arr, len(free))):
        if arr_times[k] < duration_s:
            aircraft(_arrival_moves(STAND_X[free[k]]), float(arr_times[k]), (RUNWAY_WEST_X, 0.0))
    vehicles = [
        (
            f"VEH{i + 1:02d}",
            (_depot(i), SERVICE_Y),
            _apron_vehicle(rng, _depot(i), duration_s),
        )
        for i in range(N_APRON_VEHICLES)
    ]
    vehicles += [
        ("RWYINSP", (APRON_ENTRY_X[0], TAXIWAY_Y), _inspection_loop(duration_s)),
        ("SWEEP1", (CONNECTOR_X[1] + 50.0, TAXIWAY_Y), _sweeper(duration_s)),
    ]
    for name, xy, acts in vehicles:
        missions.append(
            Mission(
                len(missions) + 1, "vehicle", name, 0x4B0000 + len(missions), 0.0, tuple(acts), xy
            )
        )
    return missions


def sample_mission(m: Mission, epochs_s: np.ndarray) -> dict[str, np.ndarray]:
    """The target's state at the scene epochs it is present at (truth, 1 Hz).

    Loops over the mission's activities (a few dozen), vectorised over epochs."""
    cols: dict[str, list[np.ndarray]] = {
        k: [] for k in ("t", "x", "y", "vx", "vy", "engines", "xpdr")
    }
    t0 = m.appear_s
    xy = m.start_xy
    for act in m.activities:
        if t0 >= epochs_s[-1] + 1:
            break
        if isinstance(act, Park):
            t1 = t0 + act.duration_s
            sel = epochs_s[(epochs_s >= t0) & (epochs_s < t1)]
            n = sel.size
            parts = (
                sel,
                np.full(n, xy[0]),
                np.full(n, xy[1]),
                np.zeros(n),
                np.zeros(n),
                np.full(n, act.engines_on),
                np.full(n, act.transponder_on),
            )
        else:
            prof = speed_profile(act)
            t1 = t0 + prof.duration_s
            sel = epochs_s[(epochs_s >= t0) & (epochs_s < t1)]
            x, y, vx, vy = prof.at(sel - t0)
            n = sel.size
            parts = (sel, x, y, vx, vy, np.ones(n, bool), np.full(n, act.transponder_on))
            end = prof.at(np.array([prof.duration_s]))
            xy = (float(end[0][0]), float(end[1][0]))
            if act.vanish_at_mps is not None:
                for k, p in zip(cols, parts, strict=True):
                    cols[k].append(p)
                return {k: np.concatenate(v) for k, v in cols.items()}
        for k, p in zip(cols, parts, strict=True):
            cols[k].append(p)
        t0 = t1
    return {k: np.concatenate(v) if v else np.empty(0) for k, v in cols.items()}


# --- scenario ------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class AirfieldScenario:
    """What the ``airfield`` scenario produced.

    - ``truth``: one row per target per second: time_ns, target_id, kind, callsign,
      target_address, x_m/y_m/vx_mps/vy_mps (east/north from the reference point),
      lat_deg, lon_deg, engines_on, transponder_on.
    - ``reports``: one row per sensor report in wire units (see module doc) with the
      ``airfield_obs`` columns it fills, plus log_time_ns, ``last`` (track's last
      report), cov_xy_m2 and, for evaluation only, target_id and the true error
      (err_x_m, err_y_m in the common frame; not archived).
    - ``targets``: one row per target (target_id, kind, callsign, target_address).
    """

    truth: pl.DataFrame
    reports: pl.DataFrame
    targets: pl.DataFrame
    seed: int
    start_ns: int
    duration_s: float
    faults: tuple[FaultConfig, ...] = field(default=())

    @property
    def end_ns(self) -> int:
        return self.start_ns + round(self.duration_s * NS)


def _truth(
    missions: Sequence[Mission], epochs_s: np.ndarray, cfg: AirfieldConfig, start_ns: int
) -> pl.DataFrame:
    frames = []
    for m in missions:  # one pass per target (a few dozen)
        d = sample_mission(m, epochs_s)
        n = d["t"].size
        frames.append(
            pl.DataFrame(
                {
                    "time_ns": start_ns + np.round(d["t"] * NS).astype(np.int64),
                    "target_id": np.full(n, m.target_id, np.int64),
                    "kind": [m.kind] * n,
                    "callsign": [m.callsign] * n,
                    "target_address": np.full(n, m.address, np.int64),
                    "x_m": d["x"],
                    "y_m": d["y"],
                    "vx_mps": d["vx"],
                    "vy_mps": d["vy"],
                    "engines_on": d["engines"].astype(bool),
                    "transponder_on": d["xpdr"].astype(bool),
                }
            )
        )
    truth = pl.concat(frames).sort(["time_ns", "target_id"])
    lat, lon = enu_to_geodetic(
        truth["x_m"].to_numpy(),
        truth["y_m"].to_numpy(),
        cfg.reference_lat_deg,
        cfg.reference_lon_deg,
    )
    return truth.with_columns(pl.Series("lat_deg", lat), pl.Series("lon_deg", lon))


def _error_series(model: VarModel, truth: pl.DataFrame, rng: np.random.Generator) -> np.ndarray:
    """A stationary AR error per row of ``truth`` (one independent series per target)."""
    tid = truth["target_id"].to_numpy()
    ids, inv = np.unique(tid, return_inverse=True)
    t = truth["time_ns"].to_numpy()
    k = (t - t.min()) // NS
    series = simulate_var(model, int(k.max()) + 1, ids.size, rng)
    return series[inv, k]


def _track_numbers(kind: str, tid: np.ndarray, t_ns: np.ndarray, on: np.ndarray) -> np.ndarray:
    """Track number per row (rows sorted by target then time): a new track at each
    rising edge of ``on`` within a target (SMR: ``on`` is always true, one track per
    target); numbered in order of track start, from the sensor's base, 12 bits."""
    new_target = np.r_[True, tid[1:] != tid[:-1]]
    prev_on = np.r_[False, on[:-1]] & ~new_target
    start = on & ~prev_on
    order = np.maximum(np.cumsum(start) - 1, 0)
    first_t = t_ns[start]
    rank = np.empty(first_t.size, np.int64)
    rank[np.argsort(first_t, kind="stable")] = np.arange(first_t.size)
    return (TRACK_BASE[kind] + rank[order]) % 4096 if first_t.size else np.zeros_like(tid)


def _fault_masks(
    faults: Sequence[FaultConfig], sensor_id: str, tau_s: np.ndarray
) -> list[tuple[FaultConfig, np.ndarray]]:
    return [
        (f, (tau_s >= f.start_s) & (tau_s < f.end_s)) for f in faults if f.sensor_id == sensor_id
    ]


def _sensor_reports(
    s: SensorConfig,
    cfg: AirfieldConfig,
    truth: pl.DataFrame,
    seed: int,
    start_ns: int,
    faults: Sequence[FaultConfig],
) -> pl.DataFrame:
    """Reports of sensor ``s`` for every truth row it detects (rows: target, time)."""
    si = _SENSOR_INDEX[s.kind]
    tr = truth.sort(["target_id", "time_ns"])
    err = _error_series(s.position_model, tr, np.random.default_rng((seed, _ERRORS, si)))
    sigma = np.sqrt(np.diag(stationary_covariance(s.position_model))[:2])
    tau = (tr["time_ns"].to_numpy() - start_ns) / NS
    visible = {
        "smr": np.ones(tr.height, bool),
        "mlat": tr["transponder_on"].to_numpy(),
        "vasn": tr["engines_on"].to_numpy(),
    }[s.kind]
    tid, t_ns = tr["target_id"].to_numpy(), tr["time_ns"].to_numpy()
    jam_rng = np.random.default_rng((seed, _JAM, si))
    jam_noise = jam_rng.standard_normal((tr.height, 2)) * sigma
    for f, on in _fault_masks(faults, s.sensor_id, tau):
        if f.kind == "jam":
            err = err + np.where(on[:, None], math.sqrt(f.factor**2 - 1.0) * jam_noise, 0.0)
        elif f.kind == "bias":
            b = f.bias_m * np.array([math.sin(f.direction_rad), math.cos(f.direction_rad)])
            err = err + np.where(on[:, None], b, 0.0)
        else:
            visible = visible & ~on
    track = _track_numbers(s.kind, tid, t_ns, visible)
    detect = np.random.default_rng((seed, _DETECT, si)).random(tr.height) < s.pd
    keep = visible & detect
    x = tr["x_m"].to_numpy() + err[:, 0]
    y = tr["y_m"].to_numpy() + err[:, 1]
    vx, vy = tr["vx_mps"].to_numpy(), tr["vy_mps"].to_numpy()
    out = pl.DataFrame(
        {
            "time_ns": t_ns,
            "target_id": tid,
            "track_number": track,
            "err_x_m": err[:, 0],
            "err_y_m": err[:, 1],
        }
    )
    lat, lon = enu_to_geodetic(x, y, cfg.reference_lat_deg, cfg.reference_lon_deg)
    xs, ys = geodetic_to_enu(lat, lon, s.lat_deg, s.lon_deg)
    rot = site_rotation_rad(cfg.reference_lat_deg, cfg.reference_lon_deg, s.lat_deg, s.lon_deg)
    c, sn = math.cos(rot), math.sin(rot)
    # eq. 4 in reverse: azimuths in the sensor frame are the common ones + rot
    vxs, vys = c * vx + sn * vy, -sn * vx + c * vy
    cov = stationary_covariance(s.position_model)[:2, :2]
    common = {
        "sensor_id": s.sensor_id,
        "sensor_kind": s.kind,
        "sac": s.sac,
        "sic": s.sic,
        "sigma_x_m": cat010.quantise(sigma[0], cat010.SIGMA_LSB_M),
        "sigma_y_m": cat010.quantise(sigma[1], cat010.SIGMA_LSB_M),
        "cov_xy_m2": cat010.quantise(cov[0, 1], cat010.COV_LSB_M2),
    }
    if s.kind == "smr":
        rng_v = np.random.default_rng((seed, _VELNOISE, si))
        nvx = vxs + s.velocity_noise_mps * rng_v.standard_normal(tr.height)
        nvy = vys + s.velocity_noise_mps * rng_v.standard_normal(tr.height)
        r, az = enu_to_polar(xs, ys)
        spd, crs = enu_to_polar(nvx, nvy)
        out = out.with_columns(
            pl.Series("range_m", cat010.quantise(r, cat010.RHO_LSB_M)),
            pl.Series("azimuth_rad", cat010.quantise_azimuth(az)),
            pl.Series("speed_mps", cat010.quantise(spd, cat010.GS_LSB_MPS)),
            pl.Series("course_rad", cat010.quantise_azimuth(crs)),
        )
    elif s.kind == "mlat":
        rng_v = np.random.default_rng((seed, _VELNOISE, si))
        out = out.with_columns(
            pl.Series("x_m", cat010.quantise(xs, cat010.XY_LSB_M)),
            pl.Series("y_m", cat010.quantise(ys, cat010.XY_LSB_M)),
            pl.Series(
                "vx_mps",
                cat010.quantise(
                    vxs + s.velocity_noise_mps * rng_v.standard_normal(tr.height),
                    cat010.VXY_LSB_MPS,
                ),
            ),
            pl.Series(
                "vy_mps",
                cat010.quantise(
                    vys + s.velocity_noise_mps * rng_v.standard_normal(tr.height),
                    cat010.VXY_LSB_MPS,
                ),
            ),
            tr["target_address"],
            tr["callsign"],
            tr["kind"].alias("target_type"),
        )
    else:
        verr = _error_series(s.velocity_model, tr, np.random.default_rng((seed, _VELNOISE, si)))
        out = out.with_columns(
            pl.Series("x_m", np.round(xs, 3)),
            pl.Series("y_m", np.round(ys, 3)),
            pl.Series("vx_mps", np.round(vxs + verr[:, 0], 3)),
            pl.Series("vy_mps", np.round(vys + verr[:, 1], 3)),
            pl.Series("err_vx_mps", verr[:, 0]),
            pl.Series("err_vy_mps", verr[:, 1]),
        )
    out = out.with_columns(**{k: pl.lit(v) for k, v in common.items()})
    out = out.filter(pl.Series(keep))
    # the last report of a track: the last kept row of each (target, track) run
    out = out.with_columns(
        (pl.col("time_ns") == pl.col("time_ns").max().over(["target_id", "track_number"])).alias(
            "last"
        )
    )
    return out


def simulate_airfield(
    cfg: AirfieldConfig, *, start_ns: int, duration_s: float, seed: int
) -> AirfieldScenario:
    """Simulate the airfield scene for ``duration_s`` s from ``start_ns`` (a whole
    second, ns since the Unix epoch, UTC)."""
    if start_ns % NS:
        raise ValueError("start_ns must be a whole second")
    epochs = np.arange(0.0, math.floor(duration_s - 1e-9) + 1.0)
    missions = plan_missions(duration_s, seed)
    truth = _truth(missions, epochs, cfg, start_ns)
    parts = [_sensor_reports(s, cfg, truth, seed, start_ns, cfg.faults) for s in cfg.sensors]
    latency = {"smr": 200_000_000, "mlat": 150_000_000, "vasn": 300_000_000}
    reports = pl.concat(parts, how="diagonal_relaxed").with_columns(
        (pl.col("time_ns") + pl.col("sensor_kind").replace_strict(latency, default=0)).alias(
            "log_time_ns"
        )
    )
    targets = pl.DataFrame(
        {
            "target_id": [m.target_id for m in missions],
            "kind": [m.kind for m in missions],
            "callsign": [m.callsign for m in missions],
            "target_address": [m.address for m in missions],
        }
    )
    return AirfieldScenario(
        truth=truth,
        reports=reports.sort(["time_ns", "sensor_id", "track_number"]),
        targets=targets,
        seed=seed,
        start_ns=start_ns,
        duration_s=duration_s,
        faults=tuple(cfg.faults),
    )
