"""Small synthetic inputs for the batch-stage tests: straight-line ships seen by the
configured radars (polar noise with the configured sigmas, clockwise antennas), AIS
reports and truth, all as canonical input tables (radar_tracks, ais_reports, truth).

Ships are straight lines in the regional ENU frame; everything is seeded.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import polars as pl

from pipeline import frames
from pipeline.config import Config, RadarSite
from pipeline.maritime.config import maritime_config
from pipeline.units import NS

T0_NS = 1_768_435_200 * NS  # 2026-01-15T00:00:00Z
TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class Ship:
    """A straight-line ship: position (x0_m, y0_m) at T0 in regional ENU, course and
    speed constant. ``mmsi`` None: no AIS aboard."""

    vessel_id: int
    x0_m: float
    y0_m: float
    course_rad: float
    speed_mps: float
    mmsi: int | None = None

    def position(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dt = (np.asarray(t_ns) - T0_NS) / NS
        return (self.x0_m + self.speed_mps * dt * np.sin(self.course_rad),
                self.y0_m + self.speed_mps * dt * np.cos(self.course_rad))


def lane_ships(n: int, rng: np.random.Generator, *, spacing_m: float = 700.0,
               with_ais: bool = True) -> list[Ship]:
    """n ships on east-west lanes ``spacing_m`` apart (alternating directions) between
    the two default radars: well separated for the whole run."""
    ships = []
    for k in range(n):
        east = k % 2 == 0
        ships.append(Ship(
            vessel_id=k + 1,
            x0_m=float(rng.uniform(-4000, 4000)),
            y0_m=-2500.0 + spacing_m * k,
            course_rad=np.pi / 2 if east else 3 * np.pi / 2,
            speed_mps=float(rng.uniform(3.0, 7.0)),
            mmsi=(211_000_000 + k + 1) if with_ais and k % 5 != 4 else None,
        ))
    return ships


def crossing_pair(cpa_m: float = 150.0, t_cross_s: float = 300.0) -> list[Ship]:
    """Two ships heading 010 and 350 deg at 5 m/s whose paths cross at t_cross_s, then
    ``cpa_m`` apart north-south: across the radars' lines of sight (cross-range, the
    radars' worst axis) and inside the 30 deg course gate."""
    v, c = 5.0, np.radians(10.0)
    vx = v * np.sin(c)
    return [
        Ship(1, -vx * t_cross_s, -v * np.cos(c) * t_cross_s, c, v, 211_000_001),
        Ship(2, vx * t_cross_s, -v * np.cos(c) * t_cross_s + cpa_m, TWO_PI - c, v, 211_000_002),
    ]


def site_with(cfg: Config, site_id: str, **changes: float) -> Config:
    """A config whose site ``site_id`` has some fields changed."""
    sites = tuple(replace(s, **changes) if s.site_id == site_id else s for s in cfg.radar_sites)
    return replace(cfg, radar_sites=sites)


def radar_reports(
    ships: list[Ship], cfg: Config, rng: np.random.Generator, *, duration_s: float,
    scan_end_azimuth_rad: dict[str, float] | None = None,
    reported_north_error_rad: dict[str, float] | None = None,
) -> pl.DataFrame:
    """radar_tracks rows of every configured site for every ship in range.

    Scan k of a site ends at T0 + phase + k T; a target at azimuth beta is swept
    ((beta_Last - beta) mod 2pi)/2pi T before (clockwise antenna). Range, azimuth,
    course and speed get Gaussian noise with the site's sigmas. A site whose
    ``reported_north_error_rad`` is d reports azimuth/course d too small, so that its
    config north_alignment_rad = d corrects it.
    """
    scan_end_azimuth_rad = scan_end_azimuth_rad or {}
    reported_north_error_rad = reported_north_error_rad or {}
    parts = []
    for j, site in enumerate(cfg.radar_sites):
        beta_last = scan_end_azimuth_rad.get(site.site_id, 0.0)
        err = reported_north_error_rad.get(site.site_id, 0.0)
        phase = (0.37 + 0.21 * j) * site.scan_period_s
        ends = T0_NS + np.round((phase + site.scan_period_s * np.arange(
            int(duration_s / site.scan_period_s))) * NS).astype(np.int64)
        for ship in ships:
            parts.append(_site_reports(ship, site, cfg, ends, beta_last, err, rng, 100 * (j + 1)))
    return pl.concat([p for p in parts if p.height]).sort("time_ns", "site_id", "local_track_id")


def _site_reports(
    ship: Ship, site: RadarSite, cfg: Config, ends: np.ndarray, beta_last: float, err: float,
    rng: np.random.Generator, id_offset: int,
) -> pl.DataFrame:
    T = site.scan_period_s
    rho = frames.site_rotation_rad(site.lat_deg, site.lon_deg,
                                   cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
    t = ends.astype(float)
    for _ in range(3):  # sweep time: the antenna reaches the target's azimuth
        r, az = _site_polar(ship, site, cfg, t.astype(np.int64))
        t = ends - np.mod(beta_last - az, TWO_PI) / TWO_PI * T * NS
    t_ns = np.round(t).astype(np.int64)
    r, az = _site_polar(ship, site, cfg, t_ns)
    keep = r <= site.max_range_m
    n = int(keep.sum())
    rm = r[keep] + rng.normal(0.0, site.sigma_range_m, n)
    azm = np.mod(az[keep] - err + rng.normal(0.0, site.sigma_azimuth_rad, n), TWO_PI)
    x_site, y_site = frames.polar_to_enu(rm, azm)
    course = np.mod(ship.course_rad - rho - err + rng.normal(0.0, site.sigma_course_rad, n),
                    TWO_PI)
    return pl.DataFrame({
        "time_ns": t_ns[keep],
        "site_id": site.site_id,
        "local_track_id": id_offset + ship.vessel_id,
        "range_m": rm,
        "azimuth_rad": azm,
        "x_site_m": x_site,
        "y_site_m": y_site,
        "course_rad": course,
        "speed_mps": ship.speed_mps + rng.normal(0.0, site.sigma_speed_mps, n),
        "sigma_range_m": site.sigma_range_m,
        "sigma_azimuth_rad": site.sigma_azimuth_rad,
        "sigma_course_rad": site.sigma_course_rad,
        "sigma_speed_mps": site.sigma_speed_mps,
        "scan_period_s": T,
        "scan_end_azimuth_rad": np.mod(beta_last - err, TWO_PI),
        "source_file": "synthetic.mcap",
        "topic": f"/radar/{site.site_id}/tracks",
        "log_time_ns": t_ns[keep],
    }, schema_overrides={"local_track_id": pl.Int64})


def _site_polar(
    ship: Ship, site: RadarSite, cfg: Config, t_ns: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    x, y = ship.position(t_ns)
    lat, lon = frames.enu_to_geodetic(x, y, cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
    e, n = frames.geodetic_to_enu(lat, lon, site.lat_deg, site.lon_deg)
    return frames.enu_to_polar(e, n)


def truth_table(ships: list[Ship], cfg: Config, *, duration_s: float,
                step_s: float = 1.0) -> pl.DataFrame:
    """truth rows every ``step_s`` from T0 - 10 s to T0 + duration + 10 s."""
    t = T0_NS + np.round(np.arange(-10.0, duration_s + 10.0, step_s) * NS).astype(np.int64)
    parts = []
    for s in ships:
        x, y = s.position(t)
        lat, lon = frames.enu_to_geodetic(x, y, cfg.region.origin_lat_deg,
                                          cfg.region.origin_lon_deg)
        parts.append(pl.DataFrame({
            "time_ns": t, "vessel_id": s.vessel_id, "mmsi": s.mmsi, "lat_deg": lat,
            "lon_deg": lon, "course_rad": s.course_rad, "speed_mps": s.speed_mps,
            "source_file": "synthetic.mcap", "topic": "/truth", "log_time_ns": t,
        }, schema_overrides={"vessel_id": pl.Int64, "mmsi": pl.Int64}))
    return pl.concat(parts).sort("time_ns", "vessel_id")


def ais_reports(ships: list[Ship], cfg: Config, rng: np.random.Generator, *,
                duration_s: float, period_s: float = 10.0) -> pl.DataFrame:
    """AIS position reports of the ships with an MMSI: GNSS noise with the config's
    sigma_position_m, SOG noise sigma_sog_mps, COG noise 1 deg; per-ship phase."""
    parts = []
    sp = cfg.ais.sigma_position_m
    for s in ships:
        if s.mmsi is None:
            continue
        t = T0_NS + np.round((rng.uniform(0, period_s) + np.arange(
            -3.0, duration_s / period_s) * period_s) * NS).astype(np.int64)
        x, y = s.position(t)
        x, y = x + rng.normal(0, sp, t.size), y + rng.normal(0, sp, t.size)
        lat, lon = frames.enu_to_geodetic(x, y, cfg.region.origin_lat_deg,
                                          cfg.region.origin_lon_deg)
        parts.append(pl.DataFrame({
            "time_ns": t, "mmsi": s.mmsi, "msg_type": 1, "ais_class": "A",
            "lat_deg": lat, "lon_deg": lon,
            "sog_mps": s.speed_mps + rng.normal(0, cfg.ais.sigma_sog_mps, t.size),
            "cog_rad": np.mod(s.course_rad + rng.normal(0, np.radians(1.0), t.size), TWO_PI),
        }, schema_overrides={"mmsi": pl.Int64, "msg_type": pl.Int16}))
    return pl.concat(parts).sort("time_ns", "mmsi")


def epochs_for(duration_s: float, cfg: Config) -> np.ndarray:
    """Epoch grid covering the run, starting once every radar has a full scan."""
    from pipeline.maritime.sync import epoch_grid

    period_s = maritime_config(cfg).sync.epoch_period_s
    return epoch_grid(T0_NS + 10 * NS, T0_NS + int(duration_s * NS), period_s)


def vessel_of(local_track_id: pl.Expr) -> pl.Expr:
    """Vessel id of a synthetic local track id (site offset 100 * (site index + 1))."""
    return local_track_id % 100


@dataclass(frozen=True)
class Chain:
    """Every stage's output on one synthetic run."""

    cfg: Config
    ships: list[Ship]
    radar: pl.DataFrame
    truth: pl.DataFrame
    ais: pl.DataFrame
    aligned: pl.DataFrame
    synced: pl.DataFrame
    associated: pl.DataFrame
    fused: pl.DataFrame
    identifications: pl.DataFrame
    errors: pl.DataFrame


def run_chain(ships: list[Ship], cfg: Config, seed: int, duration_s: float) -> Chain:
    """align -> sync -> associate -> fuse -> geometry -> identify -> score."""
    from pipeline.geometry import add_geodetic, assign_sectors, cross_track
    from pipeline.maritime.align import align_reports
    from pipeline.maritime.associate import associate_tracks
    from pipeline.maritime.fuse import fuse
    from pipeline.maritime.identity import identify
    from pipeline.maritime.score import score_tracks
    from pipeline.maritime.sync import synchronise

    rng = np.random.default_rng(seed)
    radar = radar_reports(ships, cfg, rng, duration_s=duration_s,
                          scan_end_azimuth_rad={"R1": 0.0, "R2": 2.5})
    truth = truth_table(ships, cfg, duration_s=duration_s)
    ais = ais_reports(ships, cfg, rng, duration_s=duration_s)
    aligned, _ = align_reports(radar, cfg)
    sync = maritime_config(cfg).sync
    synced = synchronise(aligned, epochs_ns=epochs_for(duration_s, cfg), sync=sync)
    associated = associate_tracks(synced, cfg=maritime_config(cfg).association)
    fused = fuse(associated)
    fused = add_geodetic(fused, cfg.region)
    fused = assign_sectors(fused, cfg.sectors, cfg.region)
    fused = cross_track(fused, cfg.fairway_legs, cfg.region, maritime_config(cfg).max_cross_track_m)
    identifications, fused = identify(fused, ais, cfg=cfg.ais, region=cfg.region)
    associated = assign_sectors(associated, cfg.sectors, cfg.region)
    errors = score_tracks(fused, associated, truth=truth, ais_reports=ais, region=cfg.region,
                          sectors=cfg.sectors)
    return Chain(cfg, ships, radar, truth, ais, aligned, synced, associated, fused,
                 identifications, errors)
