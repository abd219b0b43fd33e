"""The ``[ownship]`` config section -> frozen dataclasses (degrees and seconds in the
file, radians and seconds here). Each value's file key, default and valid range are
declared beside it (:func:`pipeline.configspec.setting`); the filter kernels' settings
(``pipeline.filters``) are assembled from the file-shaped sections below, since one file
value may feed several of them. Parsed only here; stages receive the dataclasses."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from pipeline.config import SIGMA_SPEED_WHY, Config
from pipeline.configspec import (
    Document,
    count,
    false_alarm,
    latitude,
    longitude,
    positive,
    setting,
    text,
)
from pipeline.family import FamilyDeclaration
from pipeline.filters.current_log import CurrentLogSettings
from pipeline.filters.gyro_gnss_log import FilterSettings, GyroModel, NavFilterModel, RollModel

EARTH_RADIUS_M = 6_371_000.0


def _outages(outages: tuple[tuple[float, float], ...]) -> str | None:
    bad = [i for i, (_, duration) in enumerate(outages) if duration <= 0]
    return f"outage {bad[0]}: [start_s, duration_s] needs a duration > 0" if bad else None


def _jumps(jumps: tuple[tuple[float, ...], ...]) -> str | None:
    bad = [i for i, j in enumerate(jumps) if len(j) != 4 or j[0] < 0 or j[1] <= 0]
    return (f"jump {bad[0]}: [start_s >= 0, duration_s > 0, east_m, north_m]" if bad
            else None)


@dataclass(frozen=True)
class OwnshipScenarioConfig:
    """Scenario parameters (SI units; degrees only in the ``_deg`` names), from
    ``[ownship.scenario]``; the sensor sigmas and the gyro and roll models are copied
    from ``[ownship]`` and its sub-tables."""

    platform_id: str = text("ownship")
    start_lat_deg: float = latitude(46.30, key=("start", 0))
    start_lon_deg: float = longitude(30.70, key=("start", 1))
    # east: the paper gives no heading
    initial_heading_rad: float = setting(90.0, unit="deg", ge=-360.0, le=360.0)
    accel_mps2: float = positive(0.05)  # paper eq. 5
    max_speed_mps: float = positive(9.0)
    turn_start_s: float = setting(900.0, ge=0.0)  # minute 15
    turn_duration_s: float = positive(240.0)  # a full turn by minute 19
    turn_direction: int = 1  # +1 to starboard
    truth_step_s: float = 0.1
    sample_period_s: float = 1.0
    gnss_lat_sigma_deg: float = 2.9e-5  # paper eq. 4
    gnss_position_tau_s: float = 60.0
    gnss_speed_sigma_mps: float = 0.053  # paper eq. 4
    gnss_velocity_tau_s: float = 15.0
    outages_s: tuple[tuple[float, float], ...] = setting(
        [[960.0, 30.0], [1320.0, 120.0]], key="outages", ge=0.0, check=_outages)
    # GNSS position jumps [start_s, duration_s, east_m, north_m]: positions moved, the
    # velocity not (spoofing, multipath, a receiver fault); issue 22
    jumps: tuple[tuple[float, float, float, float], ...] = setting([], check=_jumps)
    outlier_count: int = setting(6, ge=0)
    outlier_position_m: tuple[float, float] = (40.0, 150.0)
    outlier_velocity_mps: tuple[float, float] = (1.0, 3.0)
    log_sigma_mps: float = 0.5
    log_bias_mps: float = setting(0.2, ge=-10.0, le=10.0)
    current_speed_mps: float = setting(0.3, ge=0.0)
    # direction the current flows to
    current_set_rad: float = setting(120.0, unit="deg", ge=-360.0, le=360.0)
    heading_resolution_deg: float = 0.01
    accelerometer_sigma_rad: float = 1e-4
    amplifier_sigma_rad: float = 1e-5
    initial_gyro_error_sigma_rad: float = math.radians(0.5)
    gyro: GyroModel = field(default_factory=GyroModel)
    roll: RollModel = field(default_factory=RollModel)


@dataclass(frozen=True)
class NavSettings:
    """Batch, mode and dead-reckoning settings (SI), from ``[ownship]``."""

    filter_step_s: float = setting(1.0, ge=0.01, le=60.0, why=(
        "the gyro and GNSS report at 1-100 Hz: the filter steps at most 100 times a "
        "second and at least once a minute"))
    warmup_s: float = setting(900.0, ge=0.0)
    convergence_s: float = setting(600.0, ge=0.0)
    max_gap_s: float = positive(600.0)
    gnss_timeout_s: float = setting(2.5, gt=0.0, le=600.0, why=(
        "a receiver gives a fix every 0.1-1 s: seconds without one are an outage, 10 "
        "minutes is far past it"))
    gnss_position_sigma_m: float = setting(
        2.9e-5, key="gnss_position_sigma_deg", gt=0.0, le=0.01,
        convert=lambda deg: math.radians(deg) * EARTH_RADIUS_M, why=(
            "a GNSS latitude sigma is millimetres to tens of metres: 0.01 deg is 1.1 km, "
            "no fix"))
    dr_correction_window_s: float = positive(120.0)
    dr_bound_n_sigma: float = positive(3.0)
    # the GNSS position test (pipeline/nav/integrity.py, issue 22)
    gnss_position_tau_s: float = positive(60.0)  # correlation time of the position error
    gnss_q: float = false_alarm(0.001)  # false-alarm probability of one fix
    gnss_readmit_run: int = count(5)  # fixes in a row that pass before it is used again
    gnss_exclusion: bool = setting(True)  # false: test every fix, use them anyway


@dataclass(frozen=True)
class _FilterKeys:
    """The filter's keys of ``[ownship]`` (file defaults; the kernels' differ)."""

    gnss_accel_sigma_mps2: float = positive(0.019)
    gate_n_sigma: float = positive(3.0)
    max_difference_gap_s: float = positive(3.0)
    gnss_velocity_sigma_mps: float = setting(0.053, ge=0.001, le=20.0, why=SIGMA_SPEED_WHY)
    gnss_velocity_tau_s: float = positive(15.0)
    log_sigma_mps: float = setting(0.5, ge=0.001, le=20.0, why=SIGMA_SPEED_WHY)
    current_walk_mps_per_sqrt_s: float = positive(2e-4)


@dataclass(frozen=True)
class _GyroKeys:
    """``[ownship.gyro]``: our corrected-gyrocompass model and its signal noises."""

    azimuth_gain_per_s: float = positive(0.24)
    tilt_damping_per_s: float = positive(2.8e-3)
    amplifier_time_constant_s: float = positive(2.0)
    mount_height_m: float = setting(3.0, ge=-100.0, le=100.0)
    azimuth_noise_rad_per_sqrt_s: float = positive(5.7e-5, unit="deg")
    tilt_noise_rad_per_sqrt_s: float = positive(5.7e-5, unit="deg")
    accelerometer_sigma_rad: float = positive(0.0057, unit="deg")
    amplifier_sigma_rad: float = positive(0.00057, unit="deg")


@dataclass(frozen=True)
class _RollKeys:
    """``[ownship.roll]``: irregular roll, paper eq. 6."""

    variance_rad2: float = positive(0.12)
    frequency_radps: float = positive(0.6)
    irregularity_per_s: float = positive(0.01)


@dataclass(frozen=True)
class OwnshipConfig:
    nav: NavSettings = field(default_factory=NavSettings)
    model: NavFilterModel = field(default_factory=NavFilterModel)
    current: CurrentLogSettings = field(default_factory=CurrentLogSettings)
    scenario: OwnshipScenarioConfig = field(default_factory=OwnshipScenarioConfig)


def ownship_config(cfg: Config) -> OwnshipConfig:
    """The nav family's config (``[ownship]``), parsed when ``cfg`` was loaded."""
    return cfg.family("nav")


def parse_ownship(doc: Document, core: Config | None = None) -> OwnshipConfig | None:
    """The ``[ownship]`` tables (defaults for anything absent), assembled into the
    filter kernels' settings."""
    nav = doc.read(NavSettings, "ownship")
    f = doc.read(_FilterKeys, "ownship")
    g = doc.read(_GyroKeys, "ownship", "gyro")
    r = doc.read(_RollKeys, "ownship", "roll")
    # the simulator's own ship ([ownship.scenario]): a scenario file only, never a site's
    sc = (doc.read(OwnshipScenarioConfig, "ownship", "scenario")
          if doc.simulator_setting(("ownship", "scenario"), "ownship")
          else OwnshipScenarioConfig())
    if nav is None or f is None or g is None or r is None or sc is None:
        return None
    gyro = GyroModel(
        azimuth_gain_per_s=g.azimuth_gain_per_s,
        tilt_damping_per_s=g.tilt_damping_per_s,
        amplifier_time_constant_s=g.amplifier_time_constant_s,
        mount_height_m=g.mount_height_m,
        azimuth_noise_rad_per_sqrt_s=g.azimuth_noise_rad_per_sqrt_s,
        tilt_noise_rad_per_sqrt_s=g.tilt_noise_rad_per_sqrt_s,
    )
    roll = RollModel(r.variance_rad2, r.frequency_radps, r.irregularity_per_s)
    settings = FilterSettings(
        accelerometer_sigma_rad=g.accelerometer_sigma_rad,
        amplifier_sigma_rad=g.amplifier_sigma_rad,
        gnss_accel_sigma_mps2=f.gnss_accel_sigma_mps2,
        log_accel_sigma_mps2=f.log_sigma_mps * math.sqrt(2.0) / nav.filter_step_s,
        gate_n_sigma=f.gate_n_sigma,
        max_difference_gap_s=f.max_difference_gap_s,
    )
    current = CurrentLogSettings(
        gnss_velocity_sigma_mps=f.gnss_velocity_sigma_mps,
        gnss_velocity_tau_s=f.gnss_velocity_tau_s,
        gnss_accel_sigma_mps2=f.gnss_accel_sigma_mps2,
        log_sigma_mps=f.log_sigma_mps,
        current_walk_mps_per_sqrt_s=f.current_walk_mps_per_sqrt_s,
    )
    scenario = replace(
        sc,
        log_sigma_mps=f.log_sigma_mps,
        gnss_speed_sigma_mps=f.gnss_velocity_sigma_mps,
        gnss_velocity_tau_s=f.gnss_velocity_tau_s,
        accelerometer_sigma_rad=g.accelerometer_sigma_rad,
        amplifier_sigma_rad=g.amplifier_sigma_rad,
        gyro=gyro,
        roll=roll,
    )
    return OwnshipConfig(nav, NavFilterModel(gyro, roll, settings), current, scenario)


# what the family's stage reads of the core config, and the tables it writes
DECLARATION = FamilyDeclaration("nav", ("region", "sectors"), ("nav_solution", "nav_outages"))
