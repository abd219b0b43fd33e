"""The ``[airfield]`` section of the configuration, as frozen dataclasses.

Parsed from ``cfg.section("airfield")`` (see ``config/surveil.toml``); angles are
degrees in the file and radians here, durations seconds (``_s``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from pipeline.config import Config, ConfigError
from pipeline.filters.ar_errors import VarModel, is_stable

SENSOR_KINDS = ("smr", "mlat", "vasn")
AREAS = ("manoeuvring", "apron_taxiway", "stand")
FAULT_KINDS = ("jam", "bias", "dropout")


@dataclass(frozen=True)
class SensorConfig:
    """One surveillance channel. ``lat_deg``/``lon_deg``: the origin of its own frame
    (SMR: the antenna; MLAT, VASN: their reference point, normally the runway centre).
    ``position_model`` / ``velocity_model``: the nominal coloured-error models (airfield
    paper eq. 7, 8) the simulator draws from and the filter uses until ``surveil
    calibrate`` has stored fitted ones. ``pd``: probability of a report per update."""

    sensor_id: str
    kind: str
    sac: int
    sic: int
    lat_deg: float
    lon_deg: float
    height_m: float
    pd: float
    position_model: VarModel
    velocity_model: VarModel | None = None
    velocity_noise_mps: float = 0.5

    @property
    def sac_sic(self) -> str:
        return f"{self.sac}/{self.sic}"


@dataclass(frozen=True)
class AirfieldSector:
    """A named polygon (lat/lon vertices) of one ED-87 area class."""

    name: str
    area: str
    polygon_lat_lon_deg: tuple[tuple[float, float], ...]


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

    q: float = 0.01
    readmit_run: int = 5
    exclusion: bool = True
    warmup_s: float = 1.0
    outage_min_share: float = 0.5
    outage_min_tracks: int = 2


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

    epoch_s: float = 1.0
    sigma_input_m: float = 0.2
    sigma_stationary_m: float = 0.05
    sigma_accel_mps2: float = 1.5
    vasn_stationary_after_s: float = 3.0
    track_timeout_s: float = 10.0
    association_gate_m: float = 60.0
    min_association_votes: int = 5


@dataclass(frozen=True)
class FaultConfig:
    """A simulated channel fault: ``jam`` (error std × ``factor``), ``bias`` (a jump of
    ``bias_m`` towards ``direction_rad``, clockwise from north) or ``dropout`` (no
    reports). Times from the scenario start, s."""

    kind: str
    sensor_id: str
    start_s: float
    duration_s: float
    factor: float = 10.0
    bias_m: float = 30.0
    direction_rad: float = math.radians(45.0)

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s


@dataclass(frozen=True)
class AirfieldConfig:
    name: str
    reference_lat_deg: float
    reference_lon_deg: float
    sensors: tuple[SensorConfig, ...]
    sectors: tuple[AirfieldSector, ...]
    filter: FilterConfig
    integrity: IntegrityConfig
    faults: tuple[FaultConfig, ...]

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


def _matrix(x: Any, shape: tuple[int, ...], what: str) -> np.ndarray:
    a = np.asarray(x, float)
    if a.shape != shape:
        raise ValueError(f"{what}: expected shape {shape}, got {a.shape}")
    return a


def _var_model(raw: Mapping[str, Any], b_key: str, g_key: str, sid: str) -> VarModel:
    B = np.asarray(raw[b_key], float)
    if B.ndim != 3 or B.shape[1:] != (2, 2):
        raise ValueError(f"sensor {sid}: {b_key} must be a list of 2x2 matrices")
    G = _matrix(raw[g_key], (2, 2), f"sensor {sid}: {g_key}")
    if G[0, 1] != 0.0 or G[0, 0] <= 0 or G[1, 1] <= 0:
        raise ValueError(f"sensor {sid}: {g_key} must be lower triangular, positive diagonal")
    model = VarModel(B, G)
    if not is_stable(model):
        raise ValueError(f"sensor {sid}: {b_key} is not a stable autoregression")
    return model


def _sensor(raw: Mapping[str, Any]) -> SensorConfig:
    sid = str(raw["sensor_id"])
    kind = str(raw["kind"])
    if kind not in SENSOR_KINDS:
        raise ValueError(f"sensor {sid}: kind must be one of {SENSOR_KINDS}, got {kind!r}")
    vel = None
    if "velocity_ar" in raw:
        vel = _var_model(raw, "velocity_ar", "velocity_gamma", sid)
    elif kind == "vasn":
        raise ValueError(f"sensor {sid}: a vasn sensor needs velocity_ar / velocity_gamma")
    pd = float(raw.get("pd", 1.0))
    if not 0.0 < pd <= 1.0:
        raise ValueError(f"sensor {sid}: pd must be in (0, 1]")
    return SensorConfig(
        sensor_id=sid,
        kind=kind,
        sac=int(raw.get("sac", 0)),
        sic=int(raw.get("sic", 0)),
        lat_deg=float(raw["lat_deg"]),
        lon_deg=float(raw["lon_deg"]),
        height_m=float(raw.get("height_m", 0.0)),
        pd=pd,
        position_model=_var_model(raw, "position_ar", "position_gamma", sid),
        velocity_model=vel,
        velocity_noise_mps=float(raw.get("velocity_noise_mps", 0.5)),
    )


def _fault(raw: Mapping[str, Any], sensor_ids: set[str]) -> FaultConfig:
    kind = str(raw["kind"])
    if kind not in FAULT_KINDS:
        raise ValueError(f"fault kind must be one of {FAULT_KINDS}, got {kind!r}")
    if raw["sensor_id"] not in sensor_ids:
        raise ValueError(f"fault on unknown sensor {raw['sensor_id']!r}")
    return FaultConfig(
        kind=kind,
        sensor_id=str(raw["sensor_id"]),
        start_s=float(raw["start_s"]),
        duration_s=float(raw["duration_s"]),
        factor=float(raw.get("factor", 10.0)),
        bias_m=float(raw.get("bias_m", 30.0)),
        direction_rad=math.radians(float(raw.get("direction_deg", 45.0))),
    )


def parse_airfield(section: Mapping[str, Any]) -> AirfieldConfig:
    """``[airfield]`` TOML mapping -> :class:`AirfieldConfig` (raises ValueError)."""
    sensors = tuple(_sensor(s) for s in section.get("sensors", []))
    ids = [s.sensor_id for s in sensors]
    if len(set(ids)) != len(ids):
        raise ValueError("airfield sensor ids must be unique")
    for kind in SENSOR_KINDS:
        if sum(s.kind == kind for s in sensors) > 1:
            raise ValueError(f"at most one {kind} sensor is supported")
    sectors = []
    for s in section.get("sectors", []):
        if s["area"] not in AREAS:
            raise ValueError(f"sector {s['name']}: area must be one of {AREAS}")
        poly = tuple((float(p[0]), float(p[1])) for p in s["polygon"])
        if len(poly) < 3:
            raise ValueError(f"sector {s['name']} needs at least 3 vertices")
        sectors.append(AirfieldSector(str(s["name"]), str(s["area"]), poly))
    fcfg = FilterConfig(**section.get("filter", {}))
    icfg = IntegrityConfig(**section.get("integrity", {}))
    if not 0.0 < icfg.q < 1.0:
        raise ValueError("integrity.q must be in (0, 1)")
    if icfg.readmit_run < 1:
        raise ValueError("integrity.readmit_run must be >= 1")
    faults = tuple(_fault(f, set(ids)) for f in section.get("faults", []))
    return AirfieldConfig(
        name=str(section.get("name", "airfield")),
        reference_lat_deg=float(section["reference_lat_deg"]),
        reference_lon_deg=float(section["reference_lon_deg"]),
        sensors=sensors,
        sectors=tuple(sectors),
        filter=fcfg,
        integrity=icfg,
        faults=faults,
    )


def airfield_config(cfg: Config) -> AirfieldConfig:
    """The parsed ``[airfield]`` section of ``cfg``; ConfigError when the file has none."""
    acfg = cfg.family("airfield")
    if acfg is None:
        raise ConfigError(f"config {cfg.source or ''} has no [airfield] section")
    return acfg


def parse_airfield_section(raw: Mapping[str, Any], core: Config | None = None
                           ) -> AirfieldConfig | None:
    """The ``[airfield]`` section parsed, or None when the file has none (the airfield
    family then writes nothing)."""
    return parse_airfield(raw) if raw else None
