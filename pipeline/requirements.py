"""The requirements reports are judged against (``[requirements]`` in the config), and
the verdict of each: pass, fail, or not enough samples.

The figures live in the config, never in SQL: the reports that print them
(``sql/surface_accuracy_by_area.sql``) take them as bound parameters
(:meth:`RequirementsConfig.sql_params`), and ``surveil audit`` judges every report row a
requirement applies to (:func:`evaluate`).

Standards (EUROCAE ED-87 via public transcriptions, see the design brief):

- surface position accuracy, 95th percentile of the fused tracks' horizontal error,
  per ED-87 area class: manoeuvring area 12 m, apron taxiways 20 m, stands 25 m;
- sensor level (ED-116/117): each channel's reports, 95% within 7.5 m;
- probability of identification >= 0.999 (cooperative targets).

The maritime figures are OUR targets for the demo VTS region (no public standard gives
them; IALA V-128 / G1111's tables were not obtainable): fused position error 95% per
sector, share of fused track time with the right MMSI for ships with AIS, the fused
60-s RMS cross-track error per fairway leg, SIAP completeness.

A verdict needs samples: fewer than ``min_samples`` scored samples gives "not enough
samples". For a probability requirement P >= p the default minimum is the rule of
three: with no failure in n trials the one-sided 95% upper bound of 1 - P is ~3/n, so
n >= 3 / (1 - p) samples are needed before a pass can mean anything (3000 for 0.999).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import pyarrow as pa

from pipeline.config import ConfigError

SECTION = "requirements"
AREAS = ("manoeuvring", "apron_taxiway", "stand")  # ED-87 area classes ([[airfield.sectors]] area)
PASS, FAIL, NOT_ENOUGH = "pass", "fail", "not enough samples"


def rule_of_three_samples(p_min: float) -> int:
    """Samples needed before P >= p_min can be shown at ~95% with no failure: 3 / (1 - p)."""
    return math.ceil(3.0 / (1.0 - p_min) - 1e-9)


@dataclass(frozen=True)
class RequirementsConfig:
    """``[requirements]``: limits in SI units, one value per line of the config.

    ``ed87_position_p95_m``: area class -> 95th-percentile limit of the fused surface
    position error, m. ``sensor_position_p95_m``: each airfield channel, m.
    ``p_identification``: fused, cooperative targets. ``maritime_*``: our VTS targets
    (module docstring). ``min_samples``: fewest samples behind any verdict;
    ``p_identification_min_samples``: for P(ID) (default: rule of three)."""

    min_samples: int = 100
    ed87_position_p95_m: Mapping[str, float] = field(
        default_factory=lambda: {"manoeuvring": 12.0, "apron_taxiway": 20.0, "stand": 25.0})
    sensor_position_p95_m: float = 7.5
    p_identification: float = 0.999
    p_identification_min_samples: int = 3000
    maritime_position_p95_m: float = 100.0
    maritime_identification_share: float = 0.99
    maritime_cross_track_rms_60s_p95_m: float = 50.0
    maritime_siap_completeness: float = 0.95

    def sql_params(self) -> dict[str, float]:
        """The parameters reports bind (``$ed87_manoeuvring_p95_m``, ...)."""
        out = {f"ed87_{area}_p95_m": float(v) for area, v in self.ed87_position_p95_m.items()}
        out["sensor_p95_m"] = float(self.sensor_position_p95_m)
        out["p_identification_min"] = float(self.p_identification)
        return out


_MARITIME_KEYS = {
    "position_p95_m": "maritime_position_p95_m",
    "identification_share": "maritime_identification_share",
    "cross_track_rms_60s_p95_m": "maritime_cross_track_rms_60s_p95_m",
    "siap_completeness": "maritime_siap_completeness",
}
_AIRFIELD_KEYS = {
    "sensor_position_p95_m": "sensor_position_p95_m",
    "p_identification": "p_identification",
    "p_identification_min_samples": "p_identification_min_samples",
}


def parse_requirements(raw: Mapping[str, Any], core: Any = None) -> RequirementsConfig:
    """``[requirements]`` of the whole TOML document -> :class:`RequirementsConfig`
    (defaults when absent). ConfigError names the bad key."""
    sec = raw.get(SECTION, {})
    if not isinstance(sec, Mapping):
        raise ConfigError("[requirements] must be a table")
    kw: dict[str, Any] = {}
    for key, value in sec.items():
        if key == "min_samples":
            kw["min_samples"] = _count(value, "[requirements] min_samples")
        elif key == "ed87_position_p95_m":
            kw[key] = _areas(value)
        elif key in ("airfield", "maritime"):
            names = _AIRFIELD_KEYS if key == "airfield" else _MARITIME_KEYS
            if not isinstance(value, Mapping):
                raise ConfigError(f"[requirements.{key}] must be a table")
            for k, v in value.items():
                if k not in names:
                    raise ConfigError(f"[requirements.{key}] unknown key {k!r}; known: "
                                      f"{', '.join(names)}")
                what = f"[requirements.{key}] {k}"
                kw[names[k]] = _count(v, what) if k.endswith("min_samples") else _number(v, what)
        else:
            raise ConfigError(f"[requirements] unknown key {key!r}; known: min_samples, "
                              "ed87_position_p95_m, airfield, maritime")
    if "p_identification" in kw and "p_identification_min_samples" not in kw:
        kw["p_identification_min_samples"] = rule_of_three_samples(kw["p_identification"])
    req = RequirementsConfig(**kw)
    for name in ("p_identification", "maritime_identification_share",
                 "maritime_siap_completeness"):
        if not 0.0 < getattr(req, name) <= 1.0:
            raise ConfigError(f"[requirements] {name} must be in (0, 1]")
    for name in ("sensor_position_p95_m", "maritime_position_p95_m",
                 "maritime_cross_track_rms_60s_p95_m"):
        if not getattr(req, name) > 0:
            raise ConfigError(f"[requirements] {name} must be positive")
    return req


def _number(v: Any, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"{what} must be a finite number, not {v!r}")
    return float(v)


def _count(v: Any, what: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < 1:
        raise ConfigError(f"{what} must be a positive integer, not {v!r}")
    return v


def _areas(value: Any) -> dict[str, float]:
    what = "[requirements.ed87_position_p95_m]"
    if not isinstance(value, Mapping):
        raise ConfigError(f"{what} must be a table of area class = metres")
    unknown = set(value) - set(AREAS)
    missing = set(AREAS) - set(value)
    if unknown or missing:
        raise ConfigError(f"{what} needs exactly the area classes {', '.join(AREAS)}"
                          + (f"; unknown: {', '.join(sorted(unknown))}" if unknown else "")
                          + (f"; missing: {', '.join(sorted(missing))}" if missing else ""))
    out = {a: _number(value[a], f"{what} {a}") for a in AREAS}
    if any(v <= 0 for v in out.values()):
        raise ConfigError(f"{what} limits must be positive")
    return out


def requirements_config(cfg: Any) -> RequirementsConfig:
    """The ``[requirements]`` of a loaded config (defaults when it was loaded without)."""
    families = getattr(cfg, "families", {}) or {}
    req = families.get(SECTION)
    return req if isinstance(req, RequirementsConfig) else RequirementsConfig()


# --- verdicts ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Verdict:
    """One requirement judged on one report row (or on no row: 0 samples)."""

    requirement: str     # e.g. "ED-87 position accuracy 95%"
    scope: str           # e.g. "area manoeuvring, fused"
    report: str          # the sql/ report the value comes from
    metric: str          # its column
    value: float | None
    comparison: str      # "<=" | ">="
    limit: float
    unit: str
    samples: int
    min_samples: int

    @property
    def status(self) -> str:
        if self.value is None or self.samples < self.min_samples:
            return NOT_ENOUGH
        ok = self.value <= self.limit if self.comparison == "<=" else self.value >= self.limit
        return PASS if ok else FAIL

    def as_row(self) -> dict[str, Any]:
        return {"requirement": self.requirement, "scope": self.scope, "status": self.status,
                "value": self.value, "comparison": self.comparison, "limit": self.limit,
                "unit": self.unit, "samples": self.samples, "min_samples": self.min_samples,
                "report": self.report, "metric": self.metric}


def _rows(t: pa.Table | None) -> list[dict[str, Any]]:
    return [] if t is None else t.to_pylist()


def _num(v: Any) -> float | None:
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)


def evaluate(
    reports: Mapping[str, pa.Table],
    req: RequirementsConfig,
    *,
    sectors: Iterable[str] = (),
    legs: Iterable[str] = (),
    airfield: bool = True,
) -> list[Verdict]:
    """Judge every requirement on the report tables it applies to.

    ``reports``: report name -> its output (``surface_accuracy_by_area``,
    ``accuracy_by_sector``, ``identification_by_sector``, ``cross_track_by_leg``,
    ``siap_by_sector``; a missing one counts as empty). ``sectors`` / ``legs``: the
    configured maritime sectors and fairway legs; each gets a verdict even without rows
    ("not enough samples", 0). ``airfield``: the config has an airfield (its three area
    classes and P(ID) get verdicts even without rows)."""
    out: list[Verdict] = []
    n_min = req.min_samples

    # airfield: ED-87 per area (fused), sensor level per area and channel, P(ID) per area
    surface = _rows(reports.get("surface_accuracy_by_area"))
    fused = {r["area"]: r for r in surface if r["source"] == "fused"}
    areas = list(AREAS) if airfield else sorted(a for a in fused if a in AREAS)
    for area in areas:
        r = fused.get(area, {})
        out.append(Verdict("ED-87 position accuracy 95%", f"{area}, fused",
                           "surface_accuracy_by_area", "p95_error_m", _num(r.get("p95_error_m")),
                           "<=", req.ed87_position_p95_m[area], "m", int(r.get("scored") or 0),
                           n_min))
    for area in areas:
        r = fused.get(area, {})
        out.append(Verdict("ED-87 probability of identification", f"{area}, fused",
                           "surface_accuracy_by_area", "p_identification",
                           _num(r.get("p_identification")), ">=", req.p_identification, "",
                           int(r.get("id_samples") or 0), req.p_identification_min_samples))
    for r in surface:
        if r["source"] == "fused" or r["area"] not in AREAS:
            continue
        out.append(Verdict("ED-116/117 sensor position accuracy 95%",
                           f"{r['area']}, {r['source']}", "surface_accuracy_by_area",
                           "p95_error_m", _num(r.get("p95_error_m")), "<=",
                           req.sensor_position_p95_m, "m", int(r.get("scored") or 0), n_min))

    # maritime (our targets): per sector and per leg
    acc = {}
    for r in _rows(reports.get("accuracy_by_sector")):
        if r["source"] == "fused":
            acc.setdefault(r["sector"], r)  # truth before ais (the report's order)
    ident: dict[str, dict[str, Any]] = {}
    for r in _rows(reports.get("identification_by_sector")):
        if r["vessel_class"] in ("AIS aboard", "ais-identified (no truth)"):
            ident.setdefault(r["sector"], r)
    xt = {r["leg_id"]: r for r in _rows(reports.get("cross_track_by_leg"))
          if r["source"] == "fused"}
    siap = {r["sector"]: r for r in _rows(reports.get("siap_by_sector"))}
    sector_list = _ordered(sectors, acc, ident)
    for s in sector_list:
        r = acc.get(s, {})
        out.append(Verdict("maritime position accuracy 95% (our target)", f"{s}, fused",
                           "accuracy_by_sector", "p95_error_m", _num(r.get("p95_error_m")),
                           "<=", req.maritime_position_p95_m, "m",
                           int(r.get("samples") or 0), n_min))
    for s in sector_list:
        r = ident.get(s, {})
        out.append(Verdict("maritime identification, correct MMSI share (our target)",
                           f"{s}, ships with AIS", "identification_by_sector", "correct_share",
                           _num(r.get("correct_share")), ">=",
                           req.maritime_identification_share, "", int(r.get("samples") or 0),
                           n_min))
    for s in _ordered(sectors, siap):
        r = siap.get(s, {})
        out.append(Verdict("maritime SIAP completeness (our target)", s, "siap_by_sector",
                           "completeness", _num(r.get("completeness")), ">=",
                           req.maritime_siap_completeness, "", int(r.get("truth_epochs") or 0),
                           n_min))
    for leg in _ordered(legs, xt):
        r = xt.get(leg, {})
        out.append(Verdict("maritime cross-track 60-s RMS error 95% (our target)",
                           f"leg {leg}, fused", "cross_track_by_leg", "p95_rms_60s_m",
                           _num(r.get("p95_rms_60s_m")), "<=",
                           req.maritime_cross_track_rms_60s_p95_m, "m",
                           int(r.get("samples") or 0), n_min))
    return out


def _ordered(configured: Iterable[str], *found: Mapping[str, Any]) -> list[str]:
    """Configured names first (in config order), then any other name the rows carry."""
    names = list(configured)
    for rows in found:
        names += [n for n in rows if n not in names and not str(n).startswith("(")]
    return names
