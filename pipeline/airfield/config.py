"""The ``[airfield]`` section of the configuration, as frozen dataclasses.

Read from the ``[airfield]`` tables of ``config/surveil.toml``; angles are degrees in
the file and radians here, durations seconds (``_s``). Each value's file key, default
and valid range are declared beside it (:func:`pipeline.configspec.setting`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from pipeline.config import SIGMA_SPEED_WHY, Config, ConfigError
from pipeline.configspec import (
    Document,
    count,
    false_alarm,
    height,
    latitude,
    longitude,
    polygon,
    positive,
    sector_list,
    setting,
    text,
)
from pipeline.family import FamilyDeclaration
from pipeline.filters.ar_errors import VarModel, is_stable

SENSOR_KINDS = ("smr", "mlat", "vasn")

# The documented default error model of each sensor kind, for a sensor whose config gives
# none (a new site cannot know its AR coefficients): AR(1) per axis, Y(k) = b Y(k-1) +
# sigma sqrt(1 - b^2) N(k), i.e. a stationary error of sigma (m, per axis) correlated over
# about 1 / (1 - b) steps of 1 s. sigma is of the order of the ED-116 / ED-117 sensor
# figures (7.5 m at 95 %, ~3-4 m per axis) with a margin; the batch scales each default
# model to the data (pipeline.airfield.selfcal), and every row computed with one says so.
# (kind: (b, sigma_m)); the VASN velocity model: (b, sigma_mps).
DEFAULT_POSITION_AR = {"smr": (0.9, 5.0), "mlat": (0.9, 5.0), "vasn": (0.8, 5.0)}
DEFAULT_VELOCITY_AR = (0.8, 0.3)


def default_model(b: float, sigma: float) -> VarModel:
    """The AR(1) model ``b I`` with a stationary standard deviation ``sigma`` per axis."""
    return VarModel(np.array([b * np.eye(2)]), sigma * math.sqrt(1.0 - b * b) * np.eye(2))
AREAS = ("manoeuvring", "apron_taxiway", "stand")
FAULT_KINDS = ("jam", "bias", "dropout")


def var_model(b: Any, gamma: Any) -> VarModel:
    """``[B1, B2, ...]`` (2x2 each) and the lower-triangular Gamma (airfield paper eq. 7,
    8) -> a stable :class:`VarModel`; ValueError(key, message) otherwise."""
    try:
        B, G = np.asarray(b, float), np.asarray(gamma, float)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"expected arrays of numbers ({exc})") from None
    if B.ndim != 3 or B.shape[1:] != (2, 2):
        raise ValueError(0, f"must be a list of 2x2 matrices, got shape {B.shape}")
    if G.shape != (2, 2):
        raise ValueError(1, f"expected shape (2, 2), got {G.shape}")
    if G[0, 1] != 0.0 or G[0, 0] <= 0 or G[1, 1] <= 0:
        raise ValueError(1, "must be lower triangular with a positive diagonal")
    model = VarModel(B, G)
    if not is_stable(model):
        raise ValueError(0, "is not a stable autoregression")
    return model


@dataclass(frozen=True)
class SensorConfig:
    """One surveillance channel. ``lat_deg``/``lon_deg``: the origin of its own frame
    (SMR: the antenna; MLAT, VASN: their reference point, normally the runway centre).
    ``position_model`` / ``velocity_model``: the nominal coloured-error models (airfield
    paper eq. 7, 8) the simulator draws from and the filter uses until ``surveil
    calibrate`` has stored fitted ones; optional: without them the documented default of
    the sensor's kind (:data:`DEFAULT_POSITION_AR`), and ``error_model`` is ``default``
    (else ``config``). ``pd``: probability of a report per update (the simulator's)."""

    sensor_id: str = text(unique=True)
    kind: str = setting(choices=SENSOR_KINDS)
    sac: int = setting(0, ge=0, le=255, file_only=True)
    sic: int = setting(0, ge=0, le=255, file_only=True)
    lat_deg: float = latitude()
    lon_deg: float = longitude()
    height_m: float = height(0.0, file_only=True)
    pd: float = setting(1.0, gt=0.0, le=1.0, file_only=True)
    position_model: VarModel | None = setting(None, sources=("position_ar", "position_gamma"),
                                              convert=var_model)
    velocity_model: VarModel | None = setting(None, sources=("velocity_ar", "velocity_gamma"),
                                              convert=var_model)
    velocity_noise_mps: float = setting(0.5, ge=0.001, le=20.0, why=SIGMA_SPEED_WHY)
    # "default": no model in the file, the kind's default (set when it loads)
    error_model: str = field(default="config", repr=False)

    @property
    def sac_sic(self) -> str:
        return f"{self.sac}/{self.sic}"


@dataclass(frozen=True)
class AirfieldSector:
    """A named polygon (lat/lon vertices) of one ED-87 area class."""

    name: str = text(unique=True)
    area: str = setting(choices=AREAS)
    polygon_lat_lon_deg: tuple[tuple[float, float], ...] = polygon()


@dataclass(frozen=True)
class IntegrityConfig:
    """Channel integrity (airfield paper eq. 21–23) and reconfiguration.

    ``q``: probability that a healthy check falls outside (d1, d2) (eq. 22; q/2 per
    tail); ``readmit_run``: consecutive passing checks before an excluded channel is
    used again; ``exclusion``: False keeps every channel in the fusion (checks are still
    recorded); ``warmup_s``: no decisions during a track's first seconds (diffuse
    prior); ``outage_min_share`` / ``outage_min_tracks``: a channel is in outage when
    fewer than that share of the (at least that many) tracks it reported in the last
    epoch are reported now."""

    q: float = false_alarm(0.01)
    readmit_run: int = count(5)
    exclusion: bool = setting(True)
    warmup_s: float = setting(1.0, ge=0.0)
    outage_min_share: float = setting(0.5, gt=0.0, le=1.0)
    outage_min_tracks: int = count(2)


@dataclass(frozen=True)
class FilterConfig:
    """Kalman filter per target (airfield paper eq. 16–19).

    ``epoch_s``: Δt; ``sigma_input_m``: position process noise per step when the VASN
    velocity is the known input; ``sigma_stationary_m``: when the target is held
    stationary (VASN silent: engines off); ``sigma_accel_mps2``: white acceleration of
    the constant-velocity fallback; ``vasn_stationary_after_s``: VASN silence after
    which a target is taken as stationary; ``track_timeout_s``: a track ends after this
    long without reports; ``association_gate_m`` / ``min_association_votes``: sensor
    tracks of different channels are one target when they are within the gate at
    enough common epochs."""

    epoch_s: float = setting(1.0, ge=0.05, le=60.0, why=(
        "surface sensors report at 1-20 Hz (SMR scans 1 s, MLAT 1 Hz); the filter steps "
        "at most 20 times a second and at least once a minute"))
    sigma_input_m: float = positive(0.2)
    sigma_stationary_m: float = positive(0.05)
    sigma_accel_mps2: float = positive(1.5)
    vasn_stationary_after_s: float = positive(3.0)
    track_timeout_s: float = setting(10.0, ge=0.1, le=3600.0, why=(
        "a surface track coasts a few updates to minutes; beyond an hour lost targets "
        "stay alive"))
    association_gate_m: float = setting(60.0, gt=0.0, le=5000.0, why=(
        "two sensors' tracks of one aircraft are metres to tens of metres apart; 5 km "
        "spans the whole airfield"))
    min_association_votes: int = count(5)


@dataclass(frozen=True)
class FaultConfig:
    """A simulated channel fault: ``jam`` (error std × ``factor``), ``bias`` (a jump of
    ``bias_m`` towards ``direction_rad``, clockwise from north) or ``dropout`` (no
    reports). Times from the scenario start, s."""

    kind: str = setting(choices=FAULT_KINDS)
    sensor_id: str = text()
    start_s: float = setting(ge=0.0)
    duration_s: float = positive()
    factor: float = positive(10.0)
    bias_m: float = setting(30.0, ge=0.0)
    direction_rad: float = setting(45.0, unit="deg", ge=-360.0, le=360.0)

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s


@dataclass(frozen=True)
class AirfieldConfig:
    name: str = text("airfield", file_only=True)
    reference_lat_deg: float = latitude()
    reference_lon_deg: float = longitude()
    sensors: tuple[SensorConfig, ...] = setting([], file_only=True)
    sectors: tuple[AirfieldSector, ...] = sector_list()
    filter: FilterConfig = setting({})
    integrity: IntegrityConfig = setting({})
    # the airfield scenario's fault schedule: config/scenarios/airfield.toml only
    faults: tuple[FaultConfig, ...] = setting([], file_only=True, scenario="airfield")

    def sensor(self, sensor_id: str) -> SensorConfig:
        for s in self.sensors:
            if s.sensor_id == sensor_id:
                return s
        raise KeyError(sensor_id)

    def sensor_of_kind(self, kind: str) -> SensorConfig:
        for s in self.sensors:
            if s.kind == kind:
                return s
        raise KeyError(kind)

    def with_faults(self, faults: tuple[FaultConfig, ...]) -> AirfieldConfig:
        return replace(self, faults=tuple(faults))

    def with_integrity(self, **changes: Any) -> AirfieldConfig:
        return replace(self, integrity=replace(self.integrity, **changes))


def parse_airfield(doc: Document, core: Config | None = None) -> AirfieldConfig | None:
    """The ``[airfield]`` tables, or None when the file has none (the airfield family
    then writes nothing). Beyond each value's range: at most one sensor of each kind, a
    VASN with its velocity model, faults on known sensors."""
    if doc.raw.get("airfield") in (None, {}):
        return None
    a = doc.read(AirfieldConfig, "airfield")
    if a is None:
        return None
    for i, s in enumerate(a.sensors):
        if sum(t.kind == s.kind for t in a.sensors[:i]):
            doc.problem(("airfield", "sensors", i, "kind"), f"a second {s.kind!r} sensor "
                        "(at most one of each kind is supported)")
    a = replace(a, sensors=tuple(_with_defaults(s) for s in a.sensors))
    ids = [s.sensor_id for s in a.sensors]
    for i, f in enumerate(a.faults):
        if f.sensor_id not in ids:
            doc.problem(("airfield", "faults", i, "sensor_id"),
                        f"no sensor {f.sensor_id!r} (sensors: {', '.join(ids)})")
    return a


def _with_defaults(s: SensorConfig) -> SensorConfig:
    """A sensor without an error model in the file gets its kind's documented default
    (``error_model = "default"``); a VASN without a velocity model, the default one."""
    out = s
    if s.position_model is None:
        out = replace(out, position_model=default_model(*DEFAULT_POSITION_AR[s.kind]),
                      error_model="default")
    if s.kind == "vasn" and s.velocity_model is None:
        out = replace(out, velocity_model=default_model(*DEFAULT_VELOCITY_AR),
                      error_model="default")
    return out


def airfield_config(cfg: Config) -> AirfieldConfig:
    """The parsed ``[airfield]`` section of ``cfg``; ConfigError when the file has none."""
    acfg = cfg.family("airfield")
    if acfg is None:
        raise ConfigError(f"config {cfg.source or ''} has no [airfield] section")
    return acfg


# what the family's stage reads of the core config (nothing), and the tables it writes
DECLARATION = FamilyDeclaration("airfield", (), ("airfield_tracks", "channel_health",
                                                 "airfield_reference"))
