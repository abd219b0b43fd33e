"""The ``gaps`` scenario: ships among islands and channels whose AIS goes silent.

A pure function of (config, start time, duration, seed), like the ``channel`` scenario
(:mod:`pipeline.simulate.channel`, whose route builder it reuses): every random draw
comes from ``np.random.default_rng([seed, stream, vessel])``.

Geometry (regional ENU plane around the config's region origin; the coastline,
islands and zones of the shipped ``[gaps]`` config section): open sea to the south,
the coast along the inner channel (the fairway's middle leg) between the coast and
the island Dovhyi, the north-east channel (3.2 km wide, bending 30 deg left, 40 deg
left and 32 deg right over its first 25 km), and the islands Kruhlyi and Skhidnyi in
the open water.

Traffic: ``N_SHIPS`` ships, each on one of the route templates below (either
direction, chosen at random), on a lane offset 50-250 m to starboard of the template,
at a constant speed uniform in 3-8 m/s, rounding each waypoint on an arc of radius
500 m. Each ship starts somewhere in the first quarter of its route at the scenario
start and leaves the scene at the route's end.

- ``fairway``: the three fairway legs (south-west approach, inner channel, north-east
  channel), like the ``channel`` scenario, then on up the winding north-east channel;
- ``south``: east-west through the south passage, between Dovhyi and Skhidnyi, north
  of Kruhlyi;
- ``channel_east``: down the winding north-east channel, then south past Dovhyi's east
  end and out to the east;
- ``west_ne``: from the west bay through the inner channel into the north-east channel;
- ``around_dovhyi``: from the east sea along the south passage, around the west end of
  Dovhyi into the inner channel and up the north-east channel.

AIS: Class A (80%) or Class B at the ITU-R M.1371 intervals, as ``!AIVDM`` sentences
encoded with pyais (:mod:`pipeline.simulate.ais_traffic`). Each ship's transponder is
**silent** (no position or static message at all) during windows whose durations are
uniform in 10-60 min: the first one starts 12-25 min after the scenario start, each
next one 15-30 min after the previous one ended, while the ship is in the scene.
Truth: one row per vessel per whole second while it is in the scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import polars as pl

from pipeline.config import Config
from pipeline.frames import TWO_PI, enu_to_geodetic
from pipeline.simulate.ais_traffic import AisStation, StateFn, draw_identity, simulate_ais
from pipeline.simulate.channel import (
    RADAR_REPORT_SCHEMA,
    TRUTH_SCHEMA,
    ChannelScenario,
    Route,
    build_route,
    convergence_rad,
    offset_polyline,
)
from pipeline.units import NS

N_SHIPS = 16
SPEED_RANGE_MPS = (3.0, 8.0)
LATERAL_OFFSET_RANGE_M = (50.0, 250.0)
TURN_RADIUS_M = 500.0
START_FRACTION_MAX = 0.25
P_CLASS_B = 0.2
FIRST_SILENCE_S = (720.0, 1500.0)
SILENCE_DURATION_S = (600.0, 3600.0)
BETWEEN_SILENCES_S = (900.0, 1800.0)

ROUTES_KM: dict[str, tuple[tuple[float, float], ...]] = {
    "fairway": (
        (-15.0, -10.0),
        (-6.0, 0.0),
        (6.0, 0.0),
        (13.0, 9.0),
        (14.0, 16.0),
        (9.0, 24.0),
        (9.0, 32.0),
    ),
    "south": ((26.0, -5.5), (12.0, -4.8), (3.0, -4.8), (-6.0, -4.5), (-12.0, -3.0), (-24.0, -1.5)),
    "channel_east": (
        (9.0, 32.0),
        (9.0, 24.0),
        (14.0, 16.0),
        (13.0, 9.0),
        (6.0, 0.0),
        (6.0, -2.4),
        (14.0, -4.3),
        (28.0, -5.0),
    ),
    "west_ne": (
        (-24.0, -1.5),
        (-12.0, -0.6),
        (-6.0, 0.0),
        (6.0, 0.0),
        (13.0, 9.0),
        (14.0, 16.0),
        (9.0, 24.0),
        (9.0, 32.0),
    ),
    "around_dovhyi": (
        (26.0, -5.5),
        (12.0, -4.8),
        (3.0, -4.8),
        (-5.5, -4.3),
        (-6.6, -1.5),
        (-4.0, 0.2),
        (6.0, 0.0),
        (13.0, 9.0),
        (14.0, 16.0),
        (9.0, 24.0),
        (9.0, 32.0),
    ),
}
"""Route templates: waypoints (east_km, north_km) from the region origin."""

_SHIP, _IDENTITY, _SILENCE, _AIS = range(11, 15)  # random stream keys


@dataclass(frozen=True, eq=False)
class GapsScenario:
    """What the ``gaps`` scenario produced, as polars frames.

    - ``truth``: vessel_id, mmsi, time_ns, lat_deg, lon_deg, course_rad, speed_mps;
    - ``ais_sentences``: log_time_ns, sentence, mmsi, msg_type (after the silences);
    - ``vessels``: vessel_id, mmsi, ais_class, route, reverse, speed_mps,
      lateral_offset_m, enter_time_ns, exit_time_ns;
    - ``silences``: vessel_id, mmsi, start_ns, end_ns of each silent window [start, end).
    """

    truth: pl.DataFrame
    ais_sentences: pl.DataFrame
    vessels: pl.DataFrame
    silences: pl.DataFrame
    seed: int
    start_ns: int
    duration_s: float

    @property
    def end_ns(self) -> int:
        """End of the scenario (exclusive), ns since the Unix epoch."""
        return self.start_ns + round(self.duration_s * NS)

    def as_channel_scenario(self) -> ChannelScenario:
        """The same data in the shape :func:`pipeline.io.mcap_write.write_channel_archive`
        writes (no radar sites: ``/ais/nmea`` and ``/truth/vessels`` only)."""
        return ChannelScenario(
            truth=self.truth,
            radar_reports=pl.DataFrame(schema=RADAR_REPORT_SCHEMA),
            ais_sentences=self.ais_sentences,
            vessels=self.vessels,
            radar_track_truth=pl.DataFrame(),
            seed=self.seed,
            start_ns=self.start_ns,
            duration_s=self.duration_s,
            site_ids=(),
        )


@dataclass(frozen=True, eq=False)
class _Ship:
    vessel_id: int
    route_name: str
    reverse: bool
    route: Route
    speed_mps: float
    offset_m: float
    s_enter_m: float
    t_exit_s: float
    ais_class: str

    def state(self, t_s: np.ndarray, lat0: float, lon0: float) -> tuple[np.ndarray, ...]:
        """(lat_deg, lon_deg, true course_rad, speed_mps) at ``t_s`` s after the start."""
        x, y, c, _ = self.route.at(self.s_enter_m + self.speed_mps * np.asarray(t_s, float))
        lat, lon = enu_to_geodetic(x, y, lat0, lon0)
        course = np.mod(c - convergence_rad(lat, lon, lat0, lon0), TWO_PI)
        return lat, lon, course, np.full(np.shape(lat), self.speed_mps)

    def turn_windows_s(self) -> np.ndarray:
        t = (self.route.arc_intervals_m() - self.s_enter_m) / self.speed_mps
        return t[(t[:, 1] > 0.0) & (t[:, 0] < self.t_exit_s)]


def _plan_ships(seed: int, duration_s: float) -> list[_Ship]:
    ships = []
    for i in range(N_SHIPS):
        u = np.random.default_rng([seed, _SHIP, i]).random(6)
        names = sorted(ROUTES_KM)
        name = names[int(u[0] * len(names))]
        reverse = bool(u[1] < 0.5)
        verts = np.asarray(ROUTES_KM[name], float) * 1000.0
        if reverse:
            verts = verts[::-1]
        offset = LATERAL_OFFSET_RANGE_M[0] + u[2] * np.diff(LATERAL_OFFSET_RANGE_M)[0]
        route = build_route(offset_polyline(verts, offset), TURN_RADIUS_M)
        speed = SPEED_RANGE_MPS[0] + u[3] * np.diff(SPEED_RANGE_MPS)[0]
        s_enter = u[4] * START_FRACTION_MAX * route.length_m
        t_exit = min((route.length_m - s_enter) / speed, duration_s)
        ships.append(
            _Ship(
                i + 1,
                name,
                reverse,
                route,
                float(speed),
                float(offset),
                float(s_enter),
                float(t_exit),
                "B" if u[5] < P_CLASS_B else "A",
            )
        )
    return ships


def silent_windows(seed: int, vessel_id: int, t_exit_s: float) -> np.ndarray:
    """(n, 2) [begin, end) s since the start of a ship's AIS silences (see module doc)."""
    rng = np.random.default_rng([seed, _SILENCE, vessel_id])
    out = []
    t = rng.uniform(*FIRST_SILENCE_S)
    while t < t_exit_s:
        d = rng.uniform(*SILENCE_DURATION_S)
        out.append((t, t + d))
        t += d + rng.uniform(*BETWEEN_SILENCES_S)
    return np.asarray(out, float).reshape(-1, 2)


def simulate_gaps(cfg: Config, *, start_ns: int, duration_s: float, seed: int) -> GapsScenario:
    """Simulate the ``gaps`` scenario over [start_ns, start_ns + duration_s)."""
    if duration_s <= 0:
        raise ValueError(f"duration_s must be positive, got {duration_s}")
    lat0, lon0 = cfg.region.origin_lat_deg, cfg.region.origin_lon_deg
    ships = _plan_ships(seed, duration_s)
    stations: list[tuple[AisStation, StateFn]] = []
    mmsis, silences = [], []
    used: set[int] = set()
    for s in ships:
        ident = draw_identity(
            np.random.default_rng([seed, _IDENTITY, s.vessel_id]),
            ais_class=s.ais_class,
            kind="fairway",
            inbound=not s.reverse,
        )
        mmsi = ident.mmsi
        while mmsi in used:
            mmsi += 1
        used.add(mmsi)
        ident = replace(ident, mmsi=mmsi)
        mmsis.append(mmsi)
        station = AisStation(
            s.vessel_id,
            ident,
            s.speed_mps,
            0.0,
            s.t_exit_s,
            s.turn_windows_s(),
            (_AIS, s.vessel_id),
        )
        stations.append((station, _state_fn(s, lat0, lon0)))
        for a, b in silent_windows(seed, s.vessel_id, s.t_exit_s):
            silences.append((s.vessel_id, mmsi, start_ns + round(a * NS), start_ns + round(b * NS)))
    ais = simulate_ais(stations, start_ns=start_ns, duration_s=duration_s, seed=seed)
    sil = pl.DataFrame(
        silences,
        schema={"vessel_id": pl.Int64, "mmsi": pl.Int64, "start_ns": pl.Int64, "end_ns": pl.Int64},
        orient="row",
    )
    return GapsScenario(
        truth=_truth(ships, mmsis, lat0, lon0, start_ns, duration_s),
        ais_sentences=_silence(ais, sil),
        vessels=_vessels(ships, mmsis, start_ns),
        silences=sil,
        seed=seed,
        start_ns=start_ns,
        duration_s=float(duration_s),
    )


def _state_fn(s: _Ship, lat0: float, lon0: float) -> StateFn:
    def state(t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        lat, lon, course, speed = s.state(t_s, lat0, lon0)
        return lat, lon, course, speed

    return state


def _silence(ais: pl.DataFrame, silences: pl.DataFrame) -> pl.DataFrame:
    """Drop every sentence a ship would have sent inside one of its silent windows."""
    if silences.height == 0 or ais.height == 0:
        return ais
    hit = (
        ais.with_row_index("_row")
        .join(silences, on="mmsi", how="inner")
        .filter(
            pl.col("log_time_ns").is_between(pl.col("start_ns"), pl.col("end_ns"), closed="left")
        )["_row"]
        .unique()
    )
    return ais.with_row_index("_row").filter(~pl.col("_row").is_in(hit.implode())).drop("_row")


def _truth(
    ships: list[_Ship], mmsis: list[int], lat0: float, lon0: float, start_ns: int, duration_s: float
) -> pl.DataFrame:
    parts = []
    for s, mmsi in zip(ships, mmsis, strict=True):
        t = np.arange(0, math.floor(min(s.t_exit_s, duration_s)) + 1, dtype=np.int64)
        t = t[t < duration_s]
        lat, lon, course, speed = s.state(t.astype(float), lat0, lon0)
        parts.append(
            pl.DataFrame(
                {
                    "vessel_id": np.full(t.size, s.vessel_id, dtype=np.int64),
                    "mmsi": np.full(t.size, mmsi, dtype=np.int64),
                    "time_ns": start_ns + t * NS,
                    "lat_deg": lat,
                    "lon_deg": lon,
                    "course_rad": course,
                    "speed_mps": speed,
                },
                schema=TRUTH_SCHEMA,
            )
        )
    return pl.concat(parts).sort(["time_ns", "vessel_id"])


def _vessels(ships: list[_Ship], mmsis: list[int], start_ns: int) -> pl.DataFrame:
    return pl.DataFrame(
        {
            "vessel_id": [s.vessel_id for s in ships],
            "mmsi": mmsis,
            "ais_class": [s.ais_class for s in ships],
            "route": [s.route_name for s in ships],
            "reverse": [s.reverse for s in ships],
            "speed_mps": [s.speed_mps for s in ships],
            "lateral_offset_m": [s.offset_m for s in ships],
            "enter_time_ns": [start_ns] * len(ships),
            "exit_time_ns": [start_ns + round(s.t_exit_s * NS) for s in ships],
        }
    )
