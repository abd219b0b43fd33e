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

Presets of issue 37 (evaluation without truth), each with its source; the figures as
transcribed in ``../shared/research/anchors-tracking.md`` §4 (the standards themselves
are paywalled):

- ``[requirements.vts]``, radar tracking of a VTS: IMO MSC.192(79) (shipborne radar
  performance standards, target tracking): measured range within 50 m or 1 % of the
  range and bearing within 2 deg, both at 95 %; a target is tracked when seen on 5 of 10
  consecutive scans (probability of detection per scan >= 0.5); IALA Guideline 1111
  §2.5.4.1: targets tracked individually "without track swap" (0 swaps);
- ``[requirements.ed87_report_probability]``, ``[requirements.ed87_gap_3_5s]``,
  ``[requirements.ed87_gap_over_5s]``, ``[requirements.ed87_update_period_s]``: EUROCAE
  ED-87 Table 3-1 as encoded in OpenATS COMPASS (``conf/default/eval.json``): probability
  of a target report per update interval 0.99 / 0.90 / 0.95 (manoeuvring area, apron
  taxiways, stands), update interval 1 / 1 / 5 s, probability of a 3-5 s gap <= 1e-3 /
  1e-3 / (none), of a gap > 5 s <= 1e-6 / 1e-5 / 1e-3. (An open ED-116/117 tool uses
  update periods 1 s runway, 2 s taxiway and apron lane, 5 s stand.)

A verdict needs samples: fewer than ``min_samples`` scored samples gives "not enough
samples". For a probability requirement P >= p the default minimum is the rule of
three: with no failure in n trials the one-sided 95% upper bound of 1 - P is ~3/n, so
n >= 3 / (1 - p) samples are needed before a pass can mean anything (3000 for 0.999).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import pyarrow as pa

from pipeline.configspec import Document, count, positive, setting

SECTION = "requirements"
AREAS = ("manoeuvring", "apron_taxiway", "stand")  # ED-87 area classes ([[airfield.sectors]] area)
PASS, FAIL, NOT_ENOUGH = "pass", "fail", "not enough samples"
NOT_APPLICABLE = "not applicable"  # the site has no sensor (or reference) the requirement needs
OUTCOMES = (PASS, FAIL, NOT_ENOUGH, NOT_APPLICABLE)


def rule_of_three_samples(p_min: float) -> int:
    """Samples needed before P >= p_min can be shown at ~95% with no failure: 3 / (1 - p)."""
    return math.ceil(3.0 / (1.0 - p_min) - 1e-9)


@dataclass(frozen=True)
class ConfigSection:
    """A config section read at load like a family's, owned by no family (what the
    loader needs: ``name``, the top-level ``sections``, ``parse_config(doc, core)``)."""

    name: str
    sections: tuple[str, ...]
    parse_config: Callable[[Document, Any], Any]


def _share(default: float) -> Any:
    """A share or probability in (0, 1]."""
    return setting(default, gt=0.0, le=1.0)


@dataclass(frozen=True)
class Ed87Limits:
    """``[requirements.ed87_position_p95_m]``: 95% limit of the fused surface position
    error per ED-87 area class, m."""

    manoeuvring: float = positive(12.0)
    apron_taxiway: float = positive(20.0)
    stand: float = positive(25.0)


@dataclass(frozen=True)
class Ed87ReportProbability:
    """``[requirements.ed87_report_probability]``: probability of a target report per
    update interval, per ED-87 area class (COMPASS's ED-87D/E row)."""

    manoeuvring: float = _share(0.99)
    apron_taxiway: float = _share(0.90)
    stand: float = _share(0.95)


@dataclass(frozen=True)
class Ed87UpdatePeriod:
    """``[requirements.ed87_update_period_s]``: the update interval of each area class, s."""

    manoeuvring: float = positive(1.0)
    apron_taxiway: float = positive(1.0)
    stand: float = positive(5.0)


@dataclass(frozen=True)
class Ed87Gap35:
    """``[requirements.ed87_gap_3_5s]``: largest probability of a 3-5 s gap (1: none)."""

    manoeuvring: float = _share(1e-3)
    apron_taxiway: float = _share(1e-3)
    stand: float = _share(1.0)


@dataclass(frozen=True)
class Ed87GapOver5:
    """``[requirements.ed87_gap_over_5s]``: largest probability of a gap over 5 s."""

    manoeuvring: float = _share(1e-6)
    apron_taxiway: float = _share(1e-5)
    stand: float = _share(1e-3)


@dataclass(frozen=True)
class VtsRequirements:
    """``[requirements.vts]``: IMO MSC.192(79) radar tracking and IALA G1111 (module
    docstring): range error 95% within ``radar_range_p95_m`` or ``radar_range_p95_share``
    of the range (the larger), bearing error 95% within ``radar_bearing_p95_deg``, PD per
    scan >= ``radar_detection`` (5 of 10 scans), at most ``max_track_swaps`` swaps."""

    radar_range_p95_m: float = positive(50.0)
    radar_range_p95_share: float = setting(0.01, gt=0.0, lt=1.0)
    radar_bearing_p95_deg: float = positive(2.0)
    radar_detection: float = _share(0.5)
    max_track_swaps: int = setting(0, ge=0)


@dataclass(frozen=True)
class AirfieldRequirements:
    """``[requirements.airfield]``: sensor level (ED-116/117), m; P(ID) (ED-87) and the
    samples it needs (0 or absent: the rule of three, 3 / (1 - P))."""

    sensor_position_p95_m: float = positive(7.5)
    p_identification: float = _share(0.999)
    p_identification_min_samples: int = setting(0, ge=0)


@dataclass(frozen=True)
class MaritimeRequirements:
    """``[requirements.maritime]``: OUR targets for the VTS picture (module docstring)."""

    position_p95_m: float = positive(100.0)
    identification_share: float = _share(0.99)
    cross_track_rms_60s_p95_m: float = positive(50.0)
    siap_completeness: float = _share(0.95)


@dataclass(frozen=True)
class RequirementsConfig:
    """``[requirements]``: limits in SI units, as in the file. ``min_samples``: fewest
    samples behind any verdict. Read through the flat properties below."""

    min_samples: int = count(100)
    ed87: Ed87Limits = setting({}, key="ed87_position_p95_m", factory=Ed87Limits)
    airfield: AirfieldRequirements = setting({}, factory=AirfieldRequirements)
    maritime: MaritimeRequirements = setting({}, factory=MaritimeRequirements)
    vts: VtsRequirements = setting({}, factory=VtsRequirements)
    ed87_report_probability: Ed87ReportProbability = setting(
        {}, factory=Ed87ReportProbability)
    ed87_update_period_s: Ed87UpdatePeriod = setting({}, factory=Ed87UpdatePeriod)
    ed87_gap_3_5s: Ed87Gap35 = setting({}, factory=Ed87Gap35)
    ed87_gap_over_5s: Ed87GapOver5 = setting({}, factory=Ed87GapOver5)

    @property
    def ed87_position_p95_m(self) -> dict[str, float]:
        """Area class -> 95% limit, m."""
        return {a: float(getattr(self.ed87, a)) for a in AREAS}

    @property
    def sensor_position_p95_m(self) -> float:
        return self.airfield.sensor_position_p95_m

    @property
    def p_identification(self) -> float:
        return self.airfield.p_identification

    @property
    def p_identification_min_samples(self) -> int:
        n = self.airfield.p_identification_min_samples
        return n or rule_of_three_samples(self.p_identification)

    @property
    def maritime_position_p95_m(self) -> float:
        return self.maritime.position_p95_m

    @property
    def maritime_identification_share(self) -> float:
        return self.maritime.identification_share

    @property
    def maritime_cross_track_rms_60s_p95_m(self) -> float:
        return self.maritime.cross_track_rms_60s_p95_m

    @property
    def maritime_siap_completeness(self) -> float:
        return self.maritime.siap_completeness

    def sql_params(self) -> dict[str, float]:
        """The parameters reports bind (``$ed87_manoeuvring_p95_m``, ...)."""
        out = {f"ed87_{area}_p95_m": v for area, v in self.ed87_position_p95_m.items()}
        out["sensor_p95_m"] = float(self.sensor_position_p95_m)
        out["p_identification_min"] = float(self.p_identification)
        for area in AREAS:
            out[f"ed87_{area}_report_p"] = float(getattr(self.ed87_report_probability, area))
            out[f"ed87_{area}_update_s"] = float(getattr(self.ed87_update_period_s, area))
            out[f"ed87_{area}_gap_3_5s_p"] = float(getattr(self.ed87_gap_3_5s, area))
            out[f"ed87_{area}_gap_over_5s_p"] = float(getattr(self.ed87_gap_over_5s, area))
        out["vts_range_p95_m"] = float(self.vts.radar_range_p95_m)
        out["vts_range_p95_share"] = float(self.vts.radar_range_p95_share)
        out["vts_bearing_p95_deg"] = float(self.vts.radar_bearing_p95_deg)
        out["vts_min_detection"] = float(self.vts.radar_detection)
        return out


def parse_requirements(doc: Document, core: Any = None) -> RequirementsConfig | None:
    """``[requirements]`` (defaults when absent); problems go to ``doc``."""
    return doc.read(RequirementsConfig, SECTION)


REQUIREMENTS_SECTION = ConfigSection(SECTION, (SECTION,), parse_requirements)


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
    # why the requirement does not apply at this site ("no radar at this site"), or ""
    not_applicable: str = ""

    @property
    def outcome(self) -> str:
        """pass, fail, not enough samples, or not applicable (:data:`OUTCOMES`)."""
        return NOT_APPLICABLE if self.not_applicable else self.status

    @property
    def status(self) -> str:
        """``pass`` / ``fail`` / ``not enough samples``, or ``not applicable: <why>``
        (a site without the sensor the requirement needs is not short of samples)."""
        if self.not_applicable:
            return f"{NOT_APPLICABLE}: {self.not_applicable}"
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
    not_applicable: Mapping[str, str] | None = None,
) -> list[Verdict]:
    """Judge every requirement on the report tables it applies to.

    ``reports``: report name -> its output (``surface_accuracy_by_area``,
    ``accuracy_by_sector``, ``identification_by_sector``, ``cross_track_by_leg``,
    ``siap_by_sector``; a missing one counts as empty). ``sectors`` / ``legs``: the
    configured maritime sectors and fairway legs; each gets a verdict even without rows
    ("not enough samples", 0). ``airfield``: the config has an airfield (its three area
    classes and P(ID) get verdicts even without rows). ``not_applicable``: requirement
    group -> why it does not apply at this site (``maritime``: the fused picture's
    accuracy and identification, e.g. "no radar at this site"; ``siap``, ``cross_track``,
    ``airfield``: ED-87 accuracy, sensor accuracy, P(ID)); such verdicts say so instead
    of "not enough samples"."""
    out: list[Verdict] = []
    n_min = req.min_samples
    na = dict(not_applicable or {})

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
    out += evaluate_reference_presets(reports, req)
    return [replace(v, not_applicable=na[g]) if (g := _group(v)) in na else v for v in out]


def _group(v: Verdict) -> str:
    """The requirement group of a verdict (``evaluate``'s ``not_applicable`` keys)."""
    if v.report in ("surface_accuracy_by_area", "surface_detection_by_area"):
        return "airfield"
    if v.report == "siap_by_sector":
        return "siap"
    if v.report == "cross_track_by_leg":
        return "cross_track"
    return "maritime"


def evaluate_reference_presets(reports: Mapping[str, pa.Table], req: RequirementsConfig
                               ) -> list[Verdict]:
    """The verdicts of the issue-37 presets (module docstring) on the rows present:
    per radar and sector PD (IMO 5 of 10 scans), range accuracy (share within 50 m or 1 %
    of range, >= 0.95) and bearing accuracy (95 % within 2 deg); per sector the swaps
    (IALA G1111); per ED-87 area the fused report probability and the 3-5 s and > 5 s
    gap probabilities."""
    out: list[Verdict] = []
    n_min = req.min_samples
    vts = req.vts
    pd_min = rule_of_three_samples(vts.radar_detection)
    for r in _rows(reports.get("detection_by_sector")):
        if r["target_class"] != "(all classes)":
            continue
        out.append(Verdict("IMO MSC.192(79) detection, 5 of 10 scans",
                           f"{r['sector']}, radar {r['radar']} (vs {r['reference']})",
                           "detection_by_sector", "pd", _num(r.get("pd")), ">=",
                           vts.radar_detection, "", int(r.get("expected_scans") or 0),
                           max(n_min, pd_min)))
    for r in _rows(reports.get("error_decomposition")):
        if r["source"] == "fused" or r.get("range_within_vts_share") is None:
            continue
        scope = f"{r['sector']}, radar {r['source']} (vs {r['reference']})"
        out.append(Verdict("IMO MSC.192(79) range within 50 m or 1% of range, 95%", scope,
                           "error_decomposition", "range_within_vts_share",
                           _num(r.get("range_within_vts_share")), ">=", 0.95, "",
                           int(r.get("samples") or 0), n_min))
        out.append(Verdict("IMO MSC.192(79) bearing accuracy 95%", scope,
                           "error_decomposition", "azimuth_p95_deg",
                           _num(r.get("azimuth_p95_deg")), "<=", vts.radar_bearing_p95_deg,
                           "deg", int(r.get("samples") or 0), n_min))
    for r in _rows(reports.get("track_continuity")):
        out.append(Verdict("IALA G1111 no track swaps", f"{r['sector']} (vs {r['reference']})",
                           "track_continuity", "track_swaps", _num(r.get("track_swaps")), "<=",
                           float(vts.max_track_swaps), "", int(r.get("target_epochs") or 0),
                           n_min))
    for r in _rows(reports.get("surface_detection_by_area")):
        if r["source"] != "fused" or r["area"] not in AREAS:
            continue
        p = float(getattr(req.ed87_report_probability, r["area"]))
        out.append(Verdict("ED-87 probability of target report per update interval",
                           f"{r['area']}, fused", "surface_detection_by_area", "pd",
                           _num(r.get("pd")), ">=", p, "", int(r.get("expected_intervals") or 0),
                           max(n_min, rule_of_three_samples(p))))
    for r in _rows(reports.get("surface_accuracy_by_area")):
        if r["source"] != "fused" or r["area"] not in AREAS:
            continue
        for metric, limits, label in (
                ("gap_3_5s_share", req.ed87_gap_3_5s, "ED-87 continuity: gaps of 3-5 s"),
                ("gap_over_5s_share", req.ed87_gap_over_5s, "ED-87 continuity: gaps > 5 s")):
            lim = float(getattr(limits, r["area"]))
            if lim >= 1.0:
                continue
            out.append(Verdict(label, f"{r['area']}, fused", "surface_accuracy_by_area", metric,
                               _num(r.get(metric)), "<=", lim, "", int(r.get("updates") or 0),
                               max(n_min, rule_of_three_samples(1.0 - lim))))
    return out


def _ordered(configured: Iterable[str], *found: Mapping[str, Any]) -> list[str]:
    """Configured names first (in config order), then any other name the rows carry."""
    names = list(configured)
    for rows in found:
        names += [n for n in rows if n not in names and not str(n).startswith("(")]
    return names
