"""The maritime family's configuration: ``[sync]``, ``[association]``, ``[siap]``,
``[radar_bias]``, ``[fairway]``, ``[channel_integrity]`` and the channel scenario's fault
schedule ``[[channel_faults]]`` (the geography it shares with the other families,
radar sites, AIS settings, legs and sectors, is in the core :class:`~pipeline.config.Config`).

Degrees and seconds in the file; radians and seconds here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pipeline.config import Config

SECTIONS = (
    "sync", "association", "siap", "radar_bias", "fairway", "channel_integrity", "channel_faults",
)


@dataclass(frozen=True)
class SyncConfig:
    """Two-step synchronisation (multi-radar paper eq. 7-13): sigma of the extrapolation
    interval (eq. 12, s) and the period of the synchronised epochs (s)."""

    sigma_dt_s: float = 0.1
    epoch_period_s: float = 4.0


@dataclass(frozen=True)
class AssociationConfig:
    """Track-to-track gates (multi-radar paper) and the track timeout."""

    gate_probability: float = 0.999
    max_course_difference_rad: float = math.radians(30.0)
    max_speed_difference_mps: float = 2.5
    course_gate_min_speed_mps: float = 1.0
    track_timeout_s: float = 30.0


@dataclass(frozen=True)
class SiteBias:
    """Registration bias of one site, reported - true: range (m), azimuth (rad), time (s)."""

    range_bias_m: float = 0.0
    azimuth_bias_rad: float = 0.0
    time_offset_s: float = 0.0


@dataclass(frozen=True)
class RadarBiasConfig:
    """``[radar_bias]``: corrections applied in batch (when ``apply``), biases injected
    by the simulator, and the estimator's settings."""

    apply: bool = False
    correction: Mapping[str, SiteBias] = field(default_factory=dict)
    simulate: Mapping[str, SiteBias] = field(default_factory=dict)
    max_ais_gap_s: float = 40.0
    prior_range_bias_m: float = 100.0
    prior_azimuth_bias_rad: float = math.radians(1.0)
    gate_probability: float = 0.999
    min_track_share: float = 0.8
    min_reports_per_track: int = 10
    outlier_sigma: float = 3.5
    confidence: float = 0.95


@dataclass(frozen=True)
class SiapConfig:
    """``[siap]`` section: track-to-truth gate probability (chi-square, 2 dof), largest
    association distance (m), and the window pairing two changes into a swap (s)."""

    gate_probability: float = 0.999
    max_distance_m: float = 500.0
    swap_window_s: float = 60.0


RADAR_FAULT_KINDS = (
    "radar_outage", "radar_blank", "radar_range_bias", "radar_azimuth_bias",
    "radar_time_offset", "radar_noise",
)
AIS_FAULT_KINDS = ("ais_offset", "ais_stuck", "ais_mmsi_swap", "ais_spoof")
FAULT_KINDS = RADAR_FAULT_KINDS + AIS_FAULT_KINDS
# TOML keys each kind takes besides kind, start_s, duration_s
_FAULT_KEYS: dict[str, tuple[str, ...]] = {
    "radar_outage": ("site_id",),
    "radar_blank": ("site_id", "azimuth_from_deg", "azimuth_to_deg"),
    "radar_range_bias": ("site_id", "bias_m"),
    "radar_azimuth_bias": ("site_id", "bias_deg"),
    "radar_time_offset": ("site_id", "offset_s"),
    "radar_noise": ("site_id", "factor"),
    "ais_offset": ("vessel_id", "sector", "east_m", "north_m"),
    "ais_stuck": ("vessel_id", "sector"),
    "ais_mmsi_swap": ("vessel_id", "other_vessel_id", "sector"),
    "ais_spoof": ("mmsi", "start", "course_deg", "speed_mps"),
}


@dataclass(frozen=True)
class ChannelFault:
    """One fault the ``channel`` simulator injects (``[[channel_faults]]``), from
    ``start_s`` for ``duration_s`` (s from the scenario start). Radar faults name a
    ``site_id``: ``radar_outage`` (the site publishes no scans), ``radar_blank`` (no
    detections in the azimuths [azimuth_from_rad, azimuth_to_rad), clockwise: the
    tracker coasts, then drops its tracks there), ``radar_range_bias`` (``value`` m added
    to ranges), ``radar_azimuth_bias`` (``value`` rad added to azimuths and courses),
    ``radar_time_offset`` (``value`` s added to report times), ``radar_noise`` (range,
    azimuth, course and speed noise x ``value``; the reported sigmas unchanged). AIS
    faults name a vessel (``vessel_id``; None: the simulator picks, with the run's seed, a
    Class A vessel in the scene for the whole fault, in ``sector`` when given):
    ``ais_offset`` (positions moved ``east_m``, ``north_m``: an antenna/GNSS fault),
    ``ais_stuck`` (position, SOG and COG frozen at the fault start), ``ais_mmsi_swap``
    (the vessel and ``other_vessel_id`` transmit each other's MMSI), ``ais_spoof`` (a
    transponder that is on no ship, ``mmsi``, sails a straight line from ``start_lat_deg``,
    ``start_lon_deg`` at ``course_rad``, ``speed_mps``)."""

    kind: str
    start_s: float
    duration_s: float
    site_id: str | None = None
    value: float = 0.0
    azimuth_from_rad: float = 0.0
    azimuth_to_rad: float = 0.0
    vessel_id: int | None = None
    other_vessel_id: int | None = None
    sector: str | None = None
    east_m: float = 0.0
    north_m: float = 0.0
    mmsi: int = 0
    start_lat_deg: float = 0.0
    start_lon_deg: float = 0.0
    course_rad: float = 0.0
    speed_mps: float = 0.0

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s

    @property
    def sensor_kind(self) -> str:
        return "radar" if self.kind in RADAR_FAULT_KINDS else "ais"


@dataclass(frozen=True)
class ChannelIntegrityConfig:
    """``[channel_integrity]``: the maritime channel integrity test (airfield paper eq.
    21-23 applied to radars and AIS, ``pipeline.maritime.integrity``).

    - ``radar_q``, ``ais_q``: false-alarm probability of one radar decision (a radar in a
      sector at an epoch) and of one AIS report (eq. 22). A radar excluded by a false
      alarm takes its information out of the fused picture of a whole sector for
      ``readmit_run`` epochs; a transponder only its reports out of the identification
      vote: the radars' q is the smaller;
    - ``readmit_run``: consecutive passing checks that readmit an excluded channel;
    - ``exclusion``: false records every check but fuses and identifies with every channel;
    - ``ais_sigma_position_m``: AIS position sigma the test assumes (the transponder's
      GNSS), ``ais_max_age_s``: an AIS report is a reference this long after it was sent;
    - ``ais_warmup_reports``: a transponder without a reference track is decided from its
      report number ``ais_warmup_reports + 1`` on (a new ship's radar track needs ~3 scans);
    - ``ais_jump_m``: a report this far from the transponder's previous one dead-reckoned
      with its SOG/COG is a jump (another ship sends the MMSI, a position fault);
    - ``outlier_q``: a radar's per-track NIS above chi2_2(1 - outlier_q) marks the track an
      outlier; outliers fewer than half of the channel's tracks in a sector are left out of
      its test (an AIS fault of one ship, not the radar);
    - ``coverage_min_targets``, ``coverage_miss_share``: a radar misses a sector when at
      least ``coverage_min_targets`` ships that other channels see in its range there are
      not detected by it, for more than ``coverage_miss_share`` of them;
    - ``scan_gap_factor``: a site whose last scan ended more than this many scan periods
      ago is in outage (missing scans)."""

    radar_q: float = 0.001
    ais_q: float = 0.01
    readmit_run: int = 5
    exclusion: bool = True
    ais_sigma_position_m: float = 3.0
    ais_max_age_s: float = 10.0
    ais_warmup_reports: int = 2
    ais_jump_m: float = 150.0
    outlier_q: float = 1e-4
    coverage_min_targets: int = 2
    coverage_miss_share: float = 0.5
    scan_gap_factor: float = 1.5


@dataclass(frozen=True)
class MaritimeConfig:
    """Everything the maritime stage reads beyond the core config."""

    sync: SyncConfig = field(default_factory=SyncConfig)
    association: AssociationConfig = field(default_factory=AssociationConfig)
    siap: SiapConfig = field(default_factory=SiapConfig)
    radar_bias: RadarBiasConfig = field(default_factory=RadarBiasConfig)
    max_cross_track_m: float = 2000.0
    integrity: ChannelIntegrityConfig = field(default_factory=ChannelIntegrityConfig)
    faults: tuple[ChannelFault, ...] = ()


def maritime_config(cfg: Config) -> MaritimeConfig:
    """The maritime family's config, parsed when ``cfg`` was loaded."""
    return cfg.family("maritime")


def channel_faults(cfg: Config) -> tuple[ChannelFault, ...]:
    """The channel scenario's fault schedule (``[[channel_faults]]``)."""
    return maritime_config(cfg).faults


def without_faults(cfg: Config) -> Config:
    """``cfg`` with an empty ``[[channel_faults]]`` schedule (the fault-free scenario)."""
    from dataclasses import replace

    fam = dict(cfg.families)
    fam["maritime"] = replace(maritime_config(cfg), faults=())
    return replace(cfg, families=fam)


def with_faults(cfg: Config, faults: tuple[ChannelFault, ...]) -> Config:
    """``cfg`` with ``faults`` as the channel scenario's schedule."""
    from dataclasses import replace

    fam = dict(cfg.families)
    fam["maritime"] = replace(maritime_config(cfg), faults=tuple(faults))
    return replace(cfg, families=fam)


def radar_bias_config(cfg: Config) -> RadarBiasConfig:
    return maritime_config(cfg).radar_bias


def siap_config(cfg: Config) -> SiapConfig:
    return maritime_config(cfg).siap


def parse_maritime(raw: Mapping[str, Any], core: Config) -> MaritimeConfig:
    """Parse the maritime sections of the whole TOML document ``raw``."""
    a = raw.get("association", {})
    assoc = AssociationConfig(
        gate_probability=a.get("gate_probability", 0.999),
        max_course_difference_rad=math.radians(a.get("max_course_difference_deg", 30.0)),
        max_speed_difference_mps=a.get("max_speed_difference_mps", 2.5),
        course_gate_min_speed_mps=a.get("course_gate_min_speed_mps", 1.0),
        track_timeout_s=a.get("track_timeout_s", 30.0),
    )
    s = raw.get("siap", {})
    siap = SiapConfig(
        gate_probability=float(s.get("gate_probability", 0.999)),
        max_distance_m=float(s.get("max_distance_m", 500.0)),
        swap_window_s=float(s.get("swap_window_s", 60.0)),
    )
    return MaritimeConfig(
        sync=SyncConfig(**raw.get("sync", {})),
        association=assoc,
        siap=siap,
        radar_bias=_radar_bias(raw.get("radar_bias", {})),
        max_cross_track_m=raw.get("fairway", {}).get("max_cross_track_m", 2000.0),
        integrity=_integrity(raw.get("channel_integrity", {})),
        faults=tuple(_fault(f, core) for f in raw.get("channel_faults", [])),
    )


def _integrity(raw: Mapping[str, Any]) -> ChannelIntegrityConfig:
    """``[channel_integrity]`` (unknown keys are errors)."""
    d = ChannelIntegrityConfig()
    unknown = set(raw) - set(d.__dataclass_fields__)
    if unknown:
        raise ValueError(f"[channel_integrity]: unknown keys {sorted(unknown)}")
    out = ChannelIntegrityConfig(**{
        k: type(getattr(d, k))(v) for k, v in raw.items()
    })
    if not all(0.0 < v < 1.0 for v in (out.radar_q, out.ais_q, out.outlier_q)):
        raise ValueError("[channel_integrity]: radar_q, ais_q and outlier_q must be in (0, 1)")
    if out.readmit_run < 1 or out.ais_warmup_reports < 0 or out.coverage_min_targets < 1:
        raise ValueError("[channel_integrity]: readmit_run and coverage_min_targets >= 1, "
                         "ais_warmup_reports >= 0")
    return out


def _fault(raw: Mapping[str, Any], core: Config) -> ChannelFault:
    """One ``[[channel_faults]]`` entry (degrees in the file, radians here)."""
    kind = raw.get("kind")
    if kind not in _FAULT_KEYS:
        raise ValueError(f"[[channel_faults]]: kind must be one of {FAULT_KINDS}, got {kind!r}")
    allowed = {"kind", "start_s", "duration_s", *_FAULT_KEYS[kind]}
    unknown = set(raw) - allowed
    if unknown:
        raise ValueError(f"[[channel_faults]] {kind}: unknown keys {sorted(unknown)}")
    start, duration = float(raw["start_s"]), float(raw["duration_s"])
    if start < 0.0 or duration <= 0.0:
        raise ValueError(f"[[channel_faults]] {kind}: start_s >= 0 and duration_s > 0")
    site = raw.get("site_id")
    if kind in RADAR_FAULT_KINDS and site not in {s.site_id for s in core.radar_sites}:
        raise ValueError(f"[[channel_faults]] {kind}: site_id {site!r} is not a radar site")
    sector = raw.get("sector")
    if sector is not None and sector not in {s.name for s in core.sectors}:
        raise ValueError(f"[[channel_faults]] {kind}: sector {sector!r} is not a sector")
    value = {
        "radar_range_bias": float(raw.get("bias_m", 0.0)),
        "radar_azimuth_bias": math.radians(float(raw.get("bias_deg", 0.0))),
        "radar_time_offset": float(raw.get("offset_s", 0.0)),
        "radar_noise": float(raw.get("factor", 1.0)),
    }.get(kind, 0.0)
    if kind == "radar_noise" and value < 1.0:
        raise ValueError("[[channel_faults]] radar_noise: factor >= 1")
    start_ll = raw.get("start", [0.0, 0.0])
    if kind == "ais_spoof" and ("start" not in raw or "mmsi" not in raw):
        raise ValueError("[[channel_faults]] ais_spoof: needs mmsi and start = [lat, lon]")
    vid, other = raw.get("vessel_id"), raw.get("other_vessel_id")
    return ChannelFault(
        kind=kind,
        start_s=start,
        duration_s=duration,
        site_id=site,
        value=value,
        azimuth_from_rad=math.radians(float(raw.get("azimuth_from_deg", 0.0))),
        azimuth_to_rad=math.radians(float(raw.get("azimuth_to_deg", 0.0))),
        vessel_id=None if vid is None else int(vid),
        other_vessel_id=None if other is None else int(other),
        sector=sector,
        east_m=float(raw.get("east_m", 0.0)),
        north_m=float(raw.get("north_m", 0.0)),
        mmsi=int(raw.get("mmsi", 0)),
        start_lat_deg=float(start_ll[0]),
        start_lon_deg=float(start_ll[1]),
        course_rad=math.radians(float(raw.get("course_deg", 0.0))),
        speed_mps=float(raw.get("speed_mps", 0.0)),
    )


def _site_biases(raw: Mapping) -> dict[str, SiteBias]:
    return {
        site: SiteBias(
            range_bias_m=float(v.get("range_bias_m", 0.0)),
            azimuth_bias_rad=math.radians(float(v.get("azimuth_bias_deg", 0.0))),
            time_offset_s=float(v.get("time_offset_s", 0.0)),
        )
        for site, v in raw.items()
    }


def _radar_bias(raw: Mapping[str, Any]) -> RadarBiasConfig:
    """``[radar_bias]`` (degrees in the file, radians here; defaults when absent)."""
    d = RadarBiasConfig()
    return RadarBiasConfig(
        apply=bool(raw.get("apply", False)),
        correction=_site_biases(raw.get("correction", {})),
        simulate=_site_biases(raw.get("simulate", {})),
        max_ais_gap_s=float(raw.get("max_ais_gap_s", d.max_ais_gap_s)),
        prior_range_bias_m=float(raw.get("prior_range_bias_m", d.prior_range_bias_m)),
        prior_azimuth_bias_rad=math.radians(
            float(raw.get("prior_azimuth_bias_deg", math.degrees(d.prior_azimuth_bias_rad)))
        ),
        gate_probability=float(raw.get("gate_probability", d.gate_probability)),
        min_track_share=float(raw.get("min_track_share", d.min_track_share)),
        min_reports_per_track=int(raw.get("min_reports_per_track", d.min_reports_per_track)),
        outlier_sigma=float(raw.get("outlier_sigma", d.outlier_sigma)),
        confidence=float(raw.get("confidence", d.confidence)),
    )
