"""The maritime family's configuration: ``[sync]``, ``[association]``, ``[siap]``,
``[radar_bias]`` and ``[fairway]`` (the geography it shares with the other families,
radar sites, AIS settings, legs and sectors, is in the core :class:`~pipeline.config.Config`).

Degrees and seconds in the file; radians and seconds here. Each value's file key,
default and valid range are declared beside it (:func:`pipeline.configspec.setting`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from pipeline.config import Config
from pipeline.configspec import Document, count, positive, probability, setting

SECTIONS = ("sync", "association", "siap", "radar_bias", "fairway")


@dataclass(frozen=True)
class SyncConfig:
    """Two-step synchronisation (multi-radar paper eq. 7-13): sigma of the extrapolation
    interval (eq. 12, s) and the period of the synchronised epochs (s)."""

    sigma_dt_s: float = positive(0.1)
    epoch_period_s: float = positive(4.0)


@dataclass(frozen=True)
class AssociationConfig:
    """Track-to-track gates (multi-radar paper), the track timeout, and whether the
    assignment cost and its chi-square gate use position and velocity (4 dof, two-radar
    identification paper eq. 9-10 with the velocity rows) or the position only (2 dof)."""

    gate_probability: float = probability(0.999)
    max_course_difference_rad: float = setting(30.0, unit="deg", gt=0.0, le=180.0)
    max_speed_difference_mps: float = positive(2.5)
    course_gate_min_speed_mps: float = setting(1.0, ge=0.0)
    track_timeout_s: float = positive(30.0)
    velocity_cost: bool = setting(True)  # position + velocity d^2 (4 dof); False: position only


@dataclass(frozen=True)
class SiteBias:
    """Registration bias of one site, reported - true: range (m), azimuth (rad), time (s)."""

    range_bias_m: float = setting(0.0, ge=-1e4, le=1e4)
    azimuth_bias_rad: float = setting(0.0, unit="deg", ge=-180.0, le=180.0)
    time_offset_s: float = setting(0.0, ge=-3600.0, le=3600.0)


@dataclass(frozen=True)
class RadarBiasConfig:
    """``[radar_bias]``: corrections applied in batch (when ``apply``), biases injected
    by the simulator (``{site_id: SiteBias}``), and the estimator's settings."""

    apply: bool = setting(False)
    correction: Mapping[str, SiteBias] = setting({}, factory=dict)
    simulate: Mapping[str, SiteBias] = setting({}, factory=dict)
    max_ais_gap_s: float = positive(40.0)
    prior_range_bias_m: float = positive(100.0)
    prior_azimuth_bias_rad: float = setting(1.0, unit="deg", gt=0.0, le=180.0)
    gate_probability: float = probability(0.999)
    min_track_share: float = setting(0.8, gt=0.0, le=1.0)
    min_reports_per_track: int = count(10)
    outlier_sigma: float = positive(3.5)
    confidence: float = probability(0.95)


@dataclass(frozen=True)
class SiapConfig:
    """``[siap]`` section: track-to-truth gate probability (chi-square, 2 dof), largest
    association distance (m), and the window pairing two changes into a swap (s)."""

    gate_probability: float = probability(0.999)
    max_distance_m: float = positive(500.0)
    swap_window_s: float = positive(60.0)


@dataclass(frozen=True)
class MaritimeConfig:
    """Everything the maritime stage reads beyond the core config (one field per
    section; ``max_cross_track_m`` from ``[fairway]``)."""

    sync: SyncConfig = setting({}, factory=SyncConfig)
    association: AssociationConfig = setting({}, factory=AssociationConfig)
    siap: SiapConfig = setting({}, factory=SiapConfig)
    radar_bias: RadarBiasConfig = setting({}, factory=RadarBiasConfig)
    max_cross_track_m: float = positive(2000.0, key=("fairway", "max_cross_track_m"))


def maritime_config(cfg: Config) -> MaritimeConfig:
    """The maritime family's config, parsed when ``cfg`` was loaded."""
    return cfg.family("maritime")


def radar_bias_config(cfg: Config) -> RadarBiasConfig:
    return maritime_config(cfg).radar_bias


def siap_config(cfg: Config) -> SiapConfig:
    return maritime_config(cfg).siap


def parse_maritime(doc: Document, core: Config | None) -> MaritimeConfig | None:
    """The maritime sections of the document; a bias for a site that is not a radar
    site is a problem."""
    m = doc.read(MaritimeConfig)
    if m is not None and core is not None:
        sites = {s.site_id for s in core.radar_sites}
        for part in ("correction", "simulate"):
            for site in getattr(m.radar_bias, part):
                if site not in sites:
                    doc.problem(("radar_bias", part, site),
                                f"no radar site {site!r} (sites: {', '.join(sorted(sites))})")
    return m
