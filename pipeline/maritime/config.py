"""The maritime family's configuration: ``[sync]``, ``[association]``, ``[siap]``,
``[radar_bias]`` and ``[fairway]`` (the geography it shares with the other families,
radar sites, AIS settings, legs and sectors, is in the core :class:`~pipeline.config.Config`).

Degrees and seconds in the file; radians and seconds here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pipeline.config import Config

SECTIONS = ("sync", "association", "siap", "radar_bias", "fairway")


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


@dataclass(frozen=True)
class MaritimeConfig:
    """Everything the maritime stage reads beyond the core config."""

    sync: SyncConfig = field(default_factory=SyncConfig)
    association: AssociationConfig = field(default_factory=AssociationConfig)
    siap: SiapConfig = field(default_factory=SiapConfig)
    radar_bias: RadarBiasConfig = field(default_factory=RadarBiasConfig)
    max_cross_track_m: float = 2000.0


def maritime_config(cfg: Config) -> MaritimeConfig:
    """The maritime family's config, parsed when ``cfg`` was loaded."""
    return cfg.family("maritime")


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
