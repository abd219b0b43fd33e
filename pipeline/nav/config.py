"""The ``[ownship]`` config section -> frozen dataclasses (degrees and seconds in the
file, radians and seconds here). Parsed only here; stages receive the dataclasses."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pipeline.config import Config, ConfigError
from pipeline.filters.current_log import CurrentLogSettings
from pipeline.filters.gyro_gnss_log import FilterSettings, GyroModel, NavFilterModel, RollModel


@dataclass(frozen=True)
class OwnshipScenarioConfig:
    """Scenario parameters (SI units; degrees only in the ``_deg`` names)."""

    platform_id: str = "ownship"
    start_lat_deg: float = 46.30
    start_lon_deg: float = 30.70
    initial_heading_rad: float = math.radians(90.0)  # east: the paper gives no heading
    accel_mps2: float = 0.05  # paper eq. 5
    max_speed_mps: float = 9.0
    turn_start_s: float = 900.0  # minute 15
    turn_duration_s: float = 240.0  # a full turn by minute 19
    turn_direction: int = 1  # +1 to starboard
    truth_step_s: float = 0.1
    sample_period_s: float = 1.0
    gnss_lat_sigma_deg: float = 2.9e-5  # paper eq. 4
    gnss_position_tau_s: float = 60.0
    gnss_speed_sigma_mps: float = 0.053  # paper eq. 4
    gnss_velocity_tau_s: float = 15.0
    outages_s: tuple[tuple[float, float], ...] = ((960.0, 30.0), (1320.0, 120.0))
    # GNSS position jumps (start_s, duration_s, east_m, north_m): positions moved, the
    # velocity not (spoofing, multipath, a receiver fault)
    jumps: tuple[tuple[float, float, float, float], ...] = ()
    outlier_count: int = 6
    outlier_position_m: tuple[float, float] = (40.0, 150.0)
    outlier_velocity_mps: tuple[float, float] = (1.0, 3.0)
    log_sigma_mps: float = 0.5
    log_bias_mps: float = 0.2
    current_speed_mps: float = 0.3
    current_set_rad: float = math.radians(120.0)  # direction the current flows to
    heading_resolution_deg: float = 0.01
    accelerometer_sigma_rad: float = 1e-4
    amplifier_sigma_rad: float = 1e-5
    initial_gyro_error_sigma_rad: float = math.radians(0.5)
    gyro: GyroModel = field(default_factory=GyroModel)
    roll: RollModel = field(default_factory=RollModel)


@dataclass(frozen=True)
class NavSettings:
    """Batch, mode and dead-reckoning settings (SI)."""

    filter_step_s: float = 1.0
    warmup_s: float = 900.0
    convergence_s: float = 600.0
    max_gap_s: float = 600.0
    gnss_timeout_s: float = 2.5
    gnss_position_sigma_m: float = math.radians(2.9e-5) * 6_371_000.0
    dr_correction_window_s: float = 120.0
    dr_bound_n_sigma: float = 3.0
    gnss_position_tau_s: float = 60.0  # correlation time of the GNSS position error
    gnss_q: float = 0.001  # false-alarm probability of the GNSS position test
    gnss_readmit_run: int = 5  # fixes in a row that pass before the position is used again
    gnss_exclusion: bool = True  # false: test the fixes, use them anyway


@dataclass(frozen=True)
class OwnshipConfig:
    nav: NavSettings = field(default_factory=NavSettings)
    model: NavFilterModel = field(default_factory=NavFilterModel)
    current: CurrentLogSettings = field(default_factory=CurrentLogSettings)
    scenario: OwnshipScenarioConfig = field(default_factory=OwnshipScenarioConfig)


def _f(raw: Mapping[str, Any], key: str, default: float) -> float:
    v = raw.get(key, default)
    if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
        raise ConfigError(f"[ownship] {key} must be a finite number, got {v!r}")
    return float(v)


def ownship_config(cfg: Config) -> OwnshipConfig:
    """The nav family's config (``[ownship]``), parsed when ``cfg`` was loaded."""
    return cfg.family("nav")


def parse_ownship(raw: Mapping[str, Any], core: Config | None = None) -> OwnshipConfig:
    """Parse the ``[ownship]`` section (defaults for anything absent)."""
    d = OwnshipConfig()
    nav = NavSettings(
        filter_step_s=_f(raw, "filter_step_s", d.nav.filter_step_s),
        warmup_s=_f(raw, "warmup_s", d.nav.warmup_s),
        convergence_s=_f(raw, "convergence_s", d.nav.convergence_s),
        max_gap_s=_f(raw, "max_gap_s", d.nav.max_gap_s),
        gnss_timeout_s=_f(raw, "gnss_timeout_s", d.nav.gnss_timeout_s),
        gnss_position_sigma_m=math.radians(_f(raw, "gnss_position_sigma_deg", 2.9e-5))
        * 6_371_000.0,
        dr_correction_window_s=_f(raw, "dr_correction_window_s", d.nav.dr_correction_window_s),
        dr_bound_n_sigma=_f(raw, "dr_bound_n_sigma", d.nav.dr_bound_n_sigma),
        gnss_position_tau_s=_f(raw, "gnss_position_tau_s", d.nav.gnss_position_tau_s),
        gnss_q=_f(raw, "gnss_q", d.nav.gnss_q),
        gnss_readmit_run=int(_f(raw, "gnss_readmit_run", d.nav.gnss_readmit_run)),
        gnss_exclusion=bool(raw.get("gnss_exclusion", d.nav.gnss_exclusion)),
    )
    if not 0.0 < nav.gnss_q < 1.0 or nav.gnss_readmit_run < 1:
        raise ConfigError("[ownship] gnss_q must be in (0, 1) and gnss_readmit_run >= 1")
    if nav.filter_step_s <= 0 or nav.gnss_timeout_s <= 0:
        raise ConfigError("[ownship] filter_step_s and gnss_timeout_s must be positive")
    g, r = raw.get("gyro", {}), raw.get("roll", {})
    gyro = GyroModel(
        azimuth_gain_per_s=_f(g, "azimuth_gain_per_s", d.model.gyro.azimuth_gain_per_s),
        tilt_damping_per_s=_f(g, "tilt_damping_per_s", d.model.gyro.tilt_damping_per_s),
        amplifier_time_constant_s=_f(g, "amplifier_time_constant_s",
                                     d.model.gyro.amplifier_time_constant_s),
        mount_height_m=_f(g, "mount_height_m", d.model.gyro.mount_height_m),
        azimuth_noise_rad_per_sqrt_s=math.radians(_f(g, "azimuth_noise_deg_per_sqrt_s",
                                                     5.7e-5)),
        tilt_noise_rad_per_sqrt_s=math.radians(_f(g, "tilt_noise_deg_per_sqrt_s", 5.7e-5)),
    )
    roll = RollModel(
        variance_rad2=_f(r, "variance_rad2", d.model.roll.variance_rad2),
        frequency_radps=_f(r, "frequency_radps", d.model.roll.frequency_radps),
        irregularity_per_s=_f(r, "irregularity_per_s", d.model.roll.irregularity_per_s),
    )
    fs = d.model.settings
    settings = FilterSettings(
        accelerometer_sigma_rad=math.radians(_f(g, "accelerometer_sigma_deg", 0.0057)),
        amplifier_sigma_rad=math.radians(_f(g, "amplifier_sigma_deg", 0.00057)),
        gnss_accel_sigma_mps2=_f(raw, "gnss_accel_sigma_mps2", fs.gnss_accel_sigma_mps2),
        log_accel_sigma_mps2=_f(raw, "log_sigma_mps", 0.5) * math.sqrt(2.0) / nav.filter_step_s,
        gate_n_sigma=_f(raw, "gate_n_sigma", fs.gate_n_sigma),
        max_difference_gap_s=_f(raw, "max_difference_gap_s", fs.max_difference_gap_s),
    )
    current = CurrentLogSettings(
        gnss_velocity_sigma_mps=_f(raw, "gnss_velocity_sigma_mps", 0.053),
        gnss_velocity_tau_s=_f(raw, "gnss_velocity_tau_s", 15.0),
        gnss_accel_sigma_mps2=settings.gnss_accel_sigma_mps2,
        log_sigma_mps=_f(raw, "log_sigma_mps", 0.5),
        current_walk_mps_per_sqrt_s=_f(raw, "current_walk_mps_per_sqrt_s", 2e-4),
    )
    return OwnshipConfig(nav, NavFilterModel(gyro, roll, settings), current,
                         _scenario(raw.get("scenario", {}), gyro, roll, settings, current))


def _scenario(sc: Mapping[str, Any], gyro: GyroModel, roll: RollModel,
              fs: FilterSettings, cl: CurrentLogSettings) -> OwnshipScenarioConfig:
    d = OwnshipScenarioConfig()
    start = sc.get("start", [d.start_lat_deg, d.start_lon_deg])
    outages = tuple((float(a), float(b)) for a, b in sc.get("outages", d.outages_s))
    return OwnshipScenarioConfig(
        platform_id=str(sc.get("platform_id", d.platform_id)),
        start_lat_deg=float(start[0]),
        start_lon_deg=float(start[1]),
        initial_heading_rad=math.radians(_f(sc, "initial_heading_deg", 90.0)),
        accel_mps2=_f(sc, "accel_mps2", d.accel_mps2),
        max_speed_mps=_f(sc, "max_speed_mps", d.max_speed_mps),
        turn_start_s=_f(sc, "turn_start_s", d.turn_start_s),
        turn_duration_s=_f(sc, "turn_duration_s", d.turn_duration_s),
        outages_s=outages,
        jumps=tuple((float(a), float(b), float(c), float(e)) for a, b, c, e in sc.get("jumps", ())),
        outlier_count=int(sc.get("outlier_count", d.outlier_count)),
        log_sigma_mps=cl.log_sigma_mps,
        log_bias_mps=_f(sc, "log_bias_mps", d.log_bias_mps),
        current_speed_mps=_f(sc, "current_speed_mps", d.current_speed_mps),
        current_set_rad=math.radians(_f(sc, "current_set_deg", 120.0)),
        gnss_speed_sigma_mps=cl.gnss_velocity_sigma_mps,
        gnss_velocity_tau_s=cl.gnss_velocity_tau_s,
        accelerometer_sigma_rad=fs.accelerometer_sigma_rad,
        amplifier_sigma_rad=fs.amplifier_sigma_rad,
        gyro=gyro,
        roll=roll,
    )
