"""What a warehouse holds of one site, for ``surveil config init``: where its positions
lie, which sensors reported, and what each sensor's data say about itself.

Read from the raw tables only (``ais_reports``, ``radar_tracks``, ``airfield_obs``,
``nav_gnss``, ``nav_heading``, ``nav_speed_log``, ``asterix_service``, ``arpa_targets``),
column by column; positions are subsampled to :data:`MAX_POSITIONS` evenly (the
survey describes the traffic's extent, it does not need every report).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import polars as pl

from pipeline.warehouse.delta import read_table

MAX_POSITIONS = 200_000
"""Positions kept per table for the extent and the origin (evenly subsampled)."""


@dataclass(frozen=True)
class AisSource:
    """One AIS channel (a receiver, or an imported log / CSV export)."""

    topic: str
    reports: int
    mmsis: int
    class_b: int  # reports of class B transponders
    start_ns: int
    end_ns: int


@dataclass(frozen=True)
class RadarSource:
    """One radar site of ``radar_tracks`` (its reports carry no site position)."""

    site_id: str
    reports: int
    tracks: int
    scan_period_s: float  # median of the reports' own scan period
    max_range_m: float  # largest range reported
    sigma_range_m: float  # median of the reports' sigmas
    sigma_azimuth_rad: float
    sigma_speed_mps: float
    sigma_course_rad: float


@dataclass(frozen=True)
class AirfieldSource:
    """One data source of ``airfield_obs`` (an ASTERIX SAC/SIC, a VASN)."""

    sensor_id: str  # 'SAC/SIC' (or the id its MCAP metadata gives)
    kind: str  # smr | mlat | vasn | adsb | psr | ssr | system_track | other
    category: int | None
    sac: int | None
    sic: int | None
    reports: int
    polar: int  # reports with range/azimuth from the sensor
    cartesian: int  # with x/y from the sensor's (or the reference point's) frame
    geodetic: int  # with WGS-84 latitude/longitude
    targets: int  # distinct track numbers or addresses

    @property
    def sac_sic(self) -> str | None:
        return None if self.sac is None or self.sic is None else f"{self.sac}/{self.sic}"


@dataclass(frozen=True)
class Platform:
    """One own-ship platform of the nav tables (a vessel or vehicle)."""

    platform_id: str
    fixes: int
    headings: int
    speed_logs: int
    talkers: tuple[str, ...]
    sentences: tuple[str, ...]


@dataclass
class Survey:
    """What the site's recordings hold (see the module docstring)."""

    site: str | None
    start_ns: int | None = None
    end_ns: int | None = None
    # (lat_deg, lon_deg) samples per table that carries geodetic positions
    positions: dict[str, np.ndarray] = field(default_factory=dict)
    ais: list[AisSource] = field(default_factory=list)
    radars: list[RadarSource] = field(default_factory=list)
    airfield: list[AirfieldSource] = field(default_factory=list)
    platforms: list[Platform] = field(default_factory=list)
    arpa_targets: int = 0
    service_messages: dict[int, int] = field(default_factory=dict)  # ASTERIX category -> n

    @property
    def all_positions(self) -> np.ndarray:
        """(n, 2) lat/lon of every table's samples."""
        parts = [p for p in self.positions.values() if p.size]
        return np.concatenate(parts) if parts else np.empty((0, 2))

    @property
    def vessel_positions(self) -> np.ndarray:
        """(n, 2) lat/lon of the vessels seen (AIS; the own ships'), for the water test."""
        parts = [self.positions[t] for t in ("ais_reports", "nav_gnss") if t in self.positions]
        return np.concatenate(parts) if parts else np.empty((0, 2))


def _read(warehouse: Path, table: str, columns: list[str], site: str | None) -> pl.DataFrame:
    return pl.from_arrow(read_table(warehouse, table, columns=columns, site=site, sort=False))


def _thin(df: pl.DataFrame, n: int = MAX_POSITIONS) -> pl.DataFrame:
    if df.height <= n:
        return df
    return df.gather_every(int(np.ceil(df.height / n)))


def _span(survey: Survey, t: pl.Series) -> None:
    if t.len() == 0:
        return
    lo, hi = int(t.min()), int(t.max())
    survey.start_ns = lo if survey.start_ns is None else min(survey.start_ns, lo)
    survey.end_ns = hi if survey.end_ns is None else max(survey.end_ns, hi)


def _positions(df: pl.DataFrame) -> np.ndarray:
    ll = _thin(df.select("lat_deg", "lon_deg").drop_nulls().filter(
        pl.col("lat_deg").is_between(-90, 90) & pl.col("lon_deg").is_between(-180, 180)
        & ~((pl.col("lat_deg") == 0) & (pl.col("lon_deg") == 0))))  # 0/0: no fix
    return ll.to_numpy().astype(float).reshape(-1, 2)


def survey_warehouse(warehouse: Path, site: str | None = None) -> Survey:
    """The :class:`Survey` of ``site``'s rows (None: every row) of ``warehouse``."""
    out = Survey(site)
    ais = _read(warehouse, "ais_reports", ["time_ns", "mmsi", "ais_class", "lat_deg",
                                           "lon_deg", "topic"], site)
    if ais.height:
        _span(out, ais["time_ns"])
        out.positions["ais_reports"] = _positions(ais)
        by = ais.group_by("topic").agg(
            pl.len().alias("n"), pl.col("mmsi").n_unique().alias("m"),
            (pl.col("ais_class") == "B").sum().alias("b"),
            pl.col("time_ns").min().alias("t0"), pl.col("time_ns").max().alias("t1"),
        ).sort("n", descending=True)
        out.ais = [AisSource(*r) for r in by.iter_rows()]
    radar = _read(warehouse, "radar_tracks", [
        "time_ns", "site_id", "local_track_id", "range_m", "scan_period_s", "sigma_range_m",
        "sigma_azimuth_rad", "sigma_speed_mps", "sigma_course_rad"], site)
    if radar.height:
        _span(out, radar["time_ns"])
        by = radar.group_by("site_id").agg(
            pl.len(), pl.col("local_track_id").n_unique(), pl.col("scan_period_s").median(),
            pl.col("range_m").max(), pl.col("sigma_range_m").median(),
            pl.col("sigma_azimuth_rad").median(), pl.col("sigma_speed_mps").median(),
            pl.col("sigma_course_rad").median()).sort("site_id")
        out.radars = [RadarSource(*r) for r in by.iter_rows()]
    obs = _read(warehouse, "airfield_obs", [
        "time_ns", "sensor_id", "sensor_kind", "asterix_category", "sac", "sic",
        "message_type", "track_number", "target_address", "range_m", "x_m", "lat_deg",
        "lon_deg"], site)
    obs = obs.filter(pl.col("message_type").is_null()
                     | (pl.col("message_type") == "target report"))
    if obs.height:
        _span(out, obs["time_ns"])
        out.positions["airfield_obs"] = _positions(obs)
        by = obs.group_by("sensor_id", "sensor_kind", "asterix_category", "sac", "sic").agg(
            pl.len(), pl.col("range_m").is_not_null().sum(), pl.col("x_m").is_not_null().sum(),
            (pl.col("lat_deg").is_not_null() & pl.col("lon_deg").is_not_null()).sum(),
            pl.coalesce(pl.col("target_address"), pl.col("track_number")).n_unique(),
        ).sort("len", descending=True)
        out.airfield = [AirfieldSource(*r) for r in by.iter_rows()]
    gnss = _read(warehouse, "nav_gnss", ["time_ns", "platform_id", "talker", "sentence",
                                         "lat_deg", "lon_deg"], site)
    heading = _read(warehouse, "nav_heading", ["time_ns", "platform_id", "talker",
                                               "sentence"], site)
    log = _read(warehouse, "nav_speed_log", ["time_ns", "platform_id", "talker", "sentence"],
                site)
    if gnss.height:
        out.positions["nav_gnss"] = _positions(gnss)
    ids = sorted(set(gnss["platform_id"].to_list()) | set(heading["platform_id"].to_list())
                 | set(log["platform_id"].to_list()))
    for frame in (gnss, heading, log):
        _span(out, frame["time_ns"])
    for pid in ids:
        parts = [f.filter(pl.col("platform_id") == pid) for f in (gnss, heading, log)]
        talkers = sorted({t for f in parts for t in f["talker"].drop_nulls().to_list()})
        sentences = sorted({s for f in parts for s in f["sentence"].drop_nulls().to_list()})
        out.platforms.append(Platform(pid, parts[0].height, parts[1].height, parts[2].height,
                                      tuple(talkers), tuple(sentences)))
    arpa = _read(warehouse, "arpa_targets", ["time_ns"], site)
    out.arpa_targets = arpa.height
    svc = _read(warehouse, "asterix_service", ["asterix_category"], site)
    if svc.height:
        out.service_messages = dict(svc.group_by("asterix_category").len().iter_rows())
    return out


def sites_of(warehouse: Path) -> list[str]:
    """The sites the warehouse's ingest ledger knows files of, sorted."""
    ledger = _read(warehouse, "ingest_ledger", ["site", "status"], None)
    return sorted(set(ledger.filter(pl.col("status").is_in(["ok", "partial"]))["site"]
                      .to_list()))
