"""The maritime family's configuration: ``[sync]``, ``[association]``, ``[siap]``,
``[radar_bias]``, ``[fairway]``, ``[channel_integrity]`` (the geography it shares with
the other families, radar sites, AIS settings, legs and sectors, is in the core
:class:`~pipeline.config.Config`). The channel scenario's fault schedule
``[[channel_faults]]`` and the biases it injects ``[radar_bias.simulate]`` are the
simulator's world: they are read from a scenario file (``config/scenarios/channel.toml``)
only, never from a site config (``setting(scenario=...)``).

Degrees and seconds in the file; radians and seconds here. Each value's file key,
default and valid range are declared beside it (:func:`pipeline.configspec.setting`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

from pipeline.config import AIS_AGE_WHY, GNSS_POSITION_WHY, SIGMA_SPEED_WHY, Config
from pipeline.configspec import (
    Document,
    count,
    false_alarm,
    gate,
    latitude,
    longitude,
    positive,
    probability,
    setting,
)
from pipeline.family import FamilyDeclaration

SHIP_SPEED_WHY = "a ship sails at most ~25 m/s (50 kn): 50 m/s is no ship's speed"
TIMEOUT_WHY = ("a track coasts for a few scans to minutes; a timeout beyond an hour keeps "
               "lost tracks alive")

SECTIONS = (
    "sync", "association", "siap", "radar_bias", "fairway", "channel_integrity", "channel_faults",
    "reference", "registration",
)


@dataclass(frozen=True)
class SyncConfig:
    """Two-step synchronisation (multi-radar paper eq. 7-13): sigma of the extrapolation
    interval (eq. 12, s) and the period of the synchronised epochs (s)."""

    sigma_dt_s: float = setting(0.1, gt=0.0, le=10.0, why=(
        "the timing error of a report, milliseconds to a second; beyond 10 s the clocks "
        "are not synchronised"))
    epoch_period_s: float = setting(4.0, ge=0.5, le=60.0, why=(
        "the synchronised epochs follow the scans: at most one per 0.5 s (the fastest "
        "antenna) and at least one a minute"))


@dataclass(frozen=True)
class AssociationConfig:
    """Track-to-track gates (multi-radar paper), the track timeout, and whether the
    assignment cost and its chi-square gate use position and velocity (4 dof, two-radar
    identification paper eq. 9-10 with the velocity rows) or the position only (2 dof)."""

    gate_probability: float = gate(0.999)
    max_course_difference_rad: float = setting(30.0, unit="deg", gt=0.0, le=180.0)
    max_speed_difference_mps: float = setting(2.5, gt=0.0, le=50.0, why=SHIP_SPEED_WHY)
    course_gate_min_speed_mps: float = setting(1.0, ge=0.0, le=50.0, why=SHIP_SPEED_WHY)
    track_timeout_s: float = setting(30.0, ge=1.0, le=3600.0, why=TIMEOUT_WHY)
    velocity_cost: bool = setting(True)  # position + velocity d^2 (4 dof); False: position only


@dataclass(frozen=True)
class SiteBias:
    """Registration bias of one site, reported - true: range (m), azimuth (rad), time (s),
    and range gain (dimensionless: reported range = (1 + range_gain) true range +
    range_bias_m; 0.001 = 1 m per km)."""

    range_bias_m: float = setting(0.0, ge=-1e4, le=1e4)
    azimuth_bias_rad: float = setting(0.0, unit="deg", ge=-180.0, le=180.0)
    time_offset_s: float = setting(0.0, ge=-3600.0, le=3600.0)
    range_gain: float = setting(0.0, ge=-0.1, le=0.1)


@dataclass(frozen=True)
class RadarBiasConfig:
    """``[radar_bias]``: corrections applied in batch (when ``apply``), biases injected
    by the simulator (``{site_id: SiteBias}``), and the estimator's settings."""

    apply: bool = setting(False)
    correction: Mapping[str, SiteBias] = setting({}, factory=dict)
    simulate: Mapping[str, SiteBias] = setting({}, factory=dict, scenario="channel")
    max_ais_gap_s: float = setting(40.0, gt=0.0, le=3600.0, why=AIS_AGE_WHY)
    prior_range_bias_m: float = positive(100.0)
    prior_azimuth_bias_rad: float = setting(1.0, unit="deg", gt=0.0, le=180.0)
    prior_range_gain: float = setting(0.01, gt=0.0, le=0.1)
    gate_probability: float = gate(0.999)
    min_track_share: float = setting(0.8, gt=0.0, le=1.0)
    min_reports_per_track: int = count(10)
    outlier_sigma: float = positive(3.5)
    confidence: float = probability(0.95)


@dataclass(frozen=True)
class SiapConfig:
    """``[siap]`` section: track-to-truth gate probability (chi-square, 2 dof), largest
    association distance (m), and the window pairing two changes into a swap (s)."""

    gate_probability: float = gate(0.999)
    max_distance_m: float = positive(500.0)
    swap_window_s: float = positive(60.0)


def _name_or_empty(v: str) -> str | None:
    """A radar site / sector name, or "" for none (its existence is checked by
    :func:`parse_maritime`)."""
    return None if v == v.strip() else "no blanks around a name"


RADAR_FAULT_KINDS = (
    "radar_outage", "radar_blank", "radar_range_bias", "radar_azimuth_bias",
    "radar_time_offset", "radar_noise", "radar_range_gain",
)
AIS_FAULT_KINDS = ("ais_offset", "ais_stuck", "ais_mmsi_swap", "ais_spoof")
FAULT_KINDS = RADAR_FAULT_KINDS + AIS_FAULT_KINDS


@dataclass(frozen=True)
class ChannelFault:
    """One fault the ``channel`` simulator injects (``[[channel_faults]]``), from
    ``start_s`` for ``duration_s`` (s from the scenario start). Radar faults name a
    ``site_id``: ``radar_outage`` (the site publishes no scans), ``radar_blank`` (no
    detections in the azimuths [azimuth_from_deg, azimuth_to_deg), clockwise: the
    tracker coasts, then drops its tracks there), ``radar_range_bias`` (``bias_m`` added
    to ranges), ``radar_azimuth_bias`` (``bias_deg`` added to azimuths and courses),
    ``radar_time_offset`` (``offset_s`` added to report times), ``radar_noise`` (range,
    azimuth, course and speed noise x ``factor``; the reported sigmas unchanged),
    ``radar_range_gain`` (ranges x (1 + ``gain``): a range scale error); a bias, clock,
    gain or noise fault with azimuths acts in [azimuth_from_deg, azimuth_to_deg) only
    (an encoder error over part of the rotation). AIS
    faults name a vessel (``vessel_id``, 1-based; 0 or absent: the simulator picks, with
    the run's seed, a Class A vessel in the scene for the whole fault, in ``sector`` when
    given):
    ``ais_offset`` (positions moved ``east_m``, ``north_m``: an antenna/GNSS fault),
    ``ais_stuck`` (position, SOG and COG frozen at the fault start), ``ais_mmsi_swap``
    (the vessel and ``other_vessel_id`` transmit each other's MMSI), ``ais_spoof`` (a
    transponder on no ship, ``mmsi``, sails a straight line from ``start`` = [lat, lon]
    at ``course_deg``, ``speed_mps``)."""

    kind: str = setting(choices=FAULT_KINDS)
    start_s: float = setting(ge=0.0)
    duration_s: float = positive()
    site_id: str = setting("", check=_name_or_empty)
    range_bias_m: float = setting(0.0, key="bias_m", ge=-1e4, le=1e4)
    azimuth_bias_rad: float = setting(0.0, key="bias_deg", unit="deg", ge=-180.0, le=180.0)
    time_offset_s: float = setting(0.0, key="offset_s", ge=-3600.0, le=3600.0)
    factor: float = setting(1.0, ge=1.0, le=1000.0)
    range_gain: float = setting(0.0, key="gain", ge=-0.5, le=0.5)
    azimuth_from_rad: float = setting(0.0, unit="deg", ge=0.0, le=360.0)
    azimuth_to_rad: float = setting(0.0, unit="deg", ge=0.0, le=360.0)
    vessel_id: int = setting(0, ge=0)  # 0: chosen by the simulator
    other_vessel_id: int = setting(0, ge=0)
    sector: str = setting("", check=_name_or_empty)  # "": anywhere
    east_m: float = setting(0.0, ge=-1e5, le=1e5)
    north_m: float = setting(0.0, ge=-1e5, le=1e5)
    mmsi: int = setting(0, ge=0, le=999_999_999)
    start_lat_deg: float = latitude(0.0, key=("start", 0))
    start_lon_deg: float = longitude(0.0, key=("start", 1))
    course_rad: float = setting(0.0, unit="deg", ge=-360.0, le=360.0)
    speed_mps: float = setting(0.0, ge=0.0, le=50.0)

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s

    @property
    def sensor_kind(self) -> str:
        return "radar" if self.kind in RADAR_FAULT_KINDS else "ais"

    @property
    def value(self) -> float:
        """The size of a radar fault (range bias m, azimuth bias rad, time offset s,
        noise factor, range gain; 0 for the others)."""
        return {
            "radar_range_bias": self.range_bias_m,
            "radar_azimuth_bias": self.azimuth_bias_rad,
            "radar_time_offset": self.time_offset_s,
            "radar_noise": self.factor,
            "radar_range_gain": self.range_gain,
        }.get(self.kind, 0.0)


@dataclass(frozen=True)
class ChannelIntegrityConfig:
    """``[channel_integrity]``: the maritime channel integrity test (airfield paper eq.
    21-23 applied to radars and AIS, ``pipeline.maritime.integrity``).

    - ``radar_q``, ``ais_q``: false-alarm probability of one radar decision (a radar in a
      sector at an epoch) and of one AIS report (eq. 22). A radar excluded by a false
      alarm takes its information out of the fused picture for ``readmit_run`` epochs; a
      transponder only its reports out of the identification vote: the radars' q is the
      smaller;
    - ``readmit_run``: consecutive passing checks that readmit an excluded channel;
    - ``radar_confirm``: epochs in a row a radar must fail (upper tail) before it is
      excluded (1: at the first failure, the airfield rule; the flag is never delayed);
    - ``exclusion``: false records every check but fuses and identifies with every channel;
    - ``ais_sigma_position_m``: AIS position sigma the test assumes (the transponder's
      GNSS), ``ais_max_age_s``: an AIS report is a reference this long after it was sent;
    - ``ais_warmup_reports``: a transponder without a reference track is decided from its
      report number ``ais_warmup_reports + 1`` on (a new ship's radar track needs ~3 scans);
    - ``ais_jump_m``: a report this far from the transponder's previous one dead-reckoned
      with its SOG/COG is a jump (another ship sends the MMSI, a position fault);
    - ``ais_sigma_sog_mps``, ``ais_sigma_cog_deg``, ``ais_max_gap_s``: the transponder's
      kinematic self-test (each report against the previous one, at most this old, moved
      on by their SOG and COG): a stuck position; ``ais_sigma_report_age_s``: how old a
      report's position may be at its reception time, for reports without a time stamp
      (the test then takes the reception time; with one, the fix's second);
      ``ais_manoeuvre_psd_m2_s3``: white-noise acceleration between two reports
      (spectral density; q dt^3 / 12 per axis, ``pipeline.maritime.integrity.fix_time``
      and ``_kinematics``);
    - ``outlier_q``: a radar's per-track NIS above chi2_2(1 - outlier_q) marks the track an
      outlier; outliers fewer than half of the channel's tracks in a sector are left out of
      its test (an AIS fault of one ship, not the radar);
    - ``coverage_min_targets``, ``coverage_miss_share``: a radar misses a sector when at
      least ``coverage_min_targets`` ships that other channels see in its range there are
      not detected by it, for more than ``coverage_miss_share`` of them;
    - ``scan_gap_factor``: a site whose last scan ended more than this many scan periods
      ago is in outage (missing scans);
    - ``witness_s``: a radar takes part in the AIS checks of a sector (is a witness that a
      transponder there has a radar track, or none) only while it publishes scans and has
      detected ``coverage_min_targets`` ships (distinct tracks, each in ``readmit_run``
      epochs) in that sector within this long: a declared radar without data, or a
      sector it does not see, is out of service there, not evidence against every
      transponder in its range (issue 35). At most the unit's lead-in (``unit_settle_s +
      identity_window_s``) for results that do not depend on where units are cut;
    - ``unit_settle_s``: how long a batch work unit tracks before its window (besides
      the identity test's ``identity_window_s``) so that the pairings, the exclusions and
      the AIS reference tracks enter the window as they would in one pass: the batch's
      results then do not depend on where its units are cut, unless a channel fault's
      effects outlast it
      (``pipeline.maritime.stage``; tests/maritime/test_unit_seams.py cuts units inside
      five faults). Each unit tracks ``unit_settle_s + 2 identity_window_s`` more than
      its window: the price of that independence. 0: no overlap but the minute the
      stitch compares (faster, ~3x on a regional day's dense units; the state, the
      identity tests and SIAP's continuity then start afresh at every unit seam)."""

    radar_q: float = false_alarm(0.001)
    ais_q: float = false_alarm(0.01)
    readmit_run: int = count(5)
    radar_confirm: int = count(2)
    exclusion: bool = setting(True)
    ais_sigma_position_m: float = setting(3.0, ge=0.1, le=1000.0, why=GNSS_POSITION_WHY)
    ais_max_age_s: float = setting(10.0, gt=0.0, le=3600.0, why=AIS_AGE_WHY)
    ais_warmup_reports: int = setting(2, ge=0)
    ais_jump_m: float = positive(150.0)
    ais_sigma_sog_mps: float = setting(0.1, ge=0.001, le=20.0, why=SIGMA_SPEED_WHY)
    ais_sigma_cog_rad: float = positive(1.0, unit="deg")
    ais_max_gap_s: float = positive(60.0)
    ais_sigma_report_age_s: float = setting(0.5, ge=0.0, le=60.0, why=(
        "a receiver stamps a report within seconds of its fix, not minutes"))
    ais_manoeuvre_psd_m2_s3: float = setting(0.03, ge=0.0, le=100.0, why=(
        "ships accelerate by at most a few m/s^2"))
    outlier_q: float = false_alarm(1e-4)
    coverage_min_targets: int = count(2)
    coverage_miss_share: float = probability(0.5)
    scan_gap_factor: float = setting(1.5, gt=1.0, le=100.0, why=(
        "an outage is declared after this many missed scans; beyond 100 an outage of "
        "minutes goes unseen"))
    witness_s: float = positive(300.0)
    unit_settle_s: float = setting(300.0, ge=0.0, le=3600.0)


@dataclass(frozen=True)
class RegistrationConfig:
    """``[registration]``: online registration and estimated accuracy of each radar
    (``pipeline.maritime.registration``, issue 38): each site's range bias, azimuth bias,
    clock offset and range gain estimated by weighted least squares over the channel
    integrity's leave-one-out residuals (and radar-radar pairs) of the epochs within
    ``window_s`` before or after (or both), applied before fusion; each (site, sector)'s
    variance scale from the same residuals.

    - ``enabled``: false fuses the reports as reported (the integrity's exclusions alone);
    - ``per_sector``: a sector whose registration differs from the rest of its site's
      (a likelihood-ratio test at ``apply_q``) is registered on its own evidence; false:
      one registration per site;
    - ``window_s``: each one-sided window, s; at most the unit's look-ahead
      (``[ais] identity_window_s``) so that results do not depend on where units are cut;
    - ``decorrelation_s``: how long a radar track's errors stay correlated (the tracker
      smooths over scans): the window's information is divided by this many epochs;
    - ``jump_q``: false-alarm probability of the test that the windows before and after
      an epoch disagree (a registration jump: the estimate takes the side that fits);
    - ``apply_q``: an estimate is applied once it differs from zero at this probability
      (chi2(4)), a variance scale once the corrected NIS leaves its chi-square tails at it;
    - ``min_tracks``: track-epochs in the window before an estimate or a scale is used;
    - ``max_scale``: the largest variance scale;
    - ``readmit_max_scale``: a radar the integrity excluded is fused again (its corrected
      and rescaled residuals passing) only while its variance scale is at most this: a
      radar much noisier than its sigmas stays excluded;
    - ``accuracy_window_s``, ``accuracy_min_scale``: the stated-accuracy check
      (:func:`pipeline.maritime.registration.stated_accuracy_scale`): a site whose reports
      are noisier than their sigmas say by at least ``accuracy_min_scale`` in variance in
      three quarters of the minutes within ``accuracy_window_s`` of an epoch is tracked
      on its covariances scaled there, along the line of sight and across it each by
      its own factor (an axis below ``accuracy_min_scale`` as stated), and its speed and
      course sigmas by the same rule against its ships' AIS SOG and COG
      (:func:`~pipeline.maritime.registration.stated_velocity_scale`)."""

    enabled: bool = setting(True)
    per_sector: bool = setting(True)
    window_s: float = setting(40.0, ge=1.0, le=300.0, why=(
        "at least a scan; at most the unit's look-ahead (identity_window_s, 300 s by "
        "default) for results that do not depend on where units are cut"))
    decorrelation_s: float = setting(30.0, ge=0.0, le=600.0, why=(
        "a radar tracker smooths over a few to tens of scans"))
    jump_q: float = false_alarm(0.001)
    apply_q: float = false_alarm(0.01)
    min_tracks: int = count(20)
    max_scale: float = setting(100.0, ge=1.0, le=1e4, why=(
        "a radar 100x worse in variance than its sigmas (10x in sigma) is a fault"))
    readmit_max_scale: float = setting(2.0, ge=1.0, le=1e4, why=(
        "a radar 1.4x as noisy as its sigmas (2x in variance) adds little to the other "
        "radars and its tracks split off the association"))
    accuracy_window_s: float = setting(300.0, ge=60.0, le=300.0, why=(
        "five minutes or more on either side: a fault of a few minutes is not a standing "
        "misstatement; at most the unit's look-ahead (identity_window_s, 300 s by default)"))
    accuracy_min_scale: float = setting(1.3, ge=1.0, le=100.0, why=(
        "sigmas stated 15 % too small or more: less changes no exclusion"))


@dataclass(frozen=True)
class ReferenceConfig:
    """``[reference]``: the reconstructed reference of vessels carrying AIS
    (``pipeline.maritime.reference``, issue 37): the two motion models of the IMM (white
    acceleration PSD, m^2/s^3, and mean sojourn, s), the outlier gate (chi-square
    probability, 2 dof) and the rejections in a row after which the target restarts, the
    longest gap between reports a segment bridges (s), how far beyond a segment's ends
    it extrapolates (s), the largest own 95 % error of a usable reference (m), the COG
    sigma of the velocity reports (deg), and the matching of tracks to references: a
    track takes a reference when within the chi-square gate ``match_gate_probability``
    at least ``min_match_share`` of the epochs both exist, and a point is scored when
    within ``max_distance_m``. Detection (``pipeline.maritime.evaluate``): a radar report
    updates its local track's target when within ``detection_max_distance_m`` of its
    reference; the coverage map's cells are ``coverage_range_bin_m`` by
    ``coverage_azimuth_bin_deg``."""

    q_low_m2ps3: float = positive(1e-4)
    q_high_m2ps3: float = positive(0.1)
    sojourn_low_s: float = positive(600.0)
    sojourn_high_s: float = positive(60.0)
    gate_probability: float = gate(0.9999)
    max_rejections: int = count(3)
    max_gap_s: float = positive(200.0)
    extrapolate_s: float = setting(10.0, ge=0.0)
    max_p95_m: float = positive(20.0)
    sigma_cog_deg: float = positive(2.0)
    match_gate_probability: float = gate(0.999)
    min_match_share: float = probability(0.5)
    max_distance_m: float = positive(2000.0)
    detection_max_distance_m: float = positive(500.0)
    coverage_range_bin_m: float = positive(1000.0)
    coverage_azimuth_bin_deg: float = setting(10.0, gt=0.0, le=90.0)


@dataclass(frozen=True)
class MaritimeConfig:
    """Everything the maritime stage reads beyond the core config (one field per
    section; ``max_cross_track_m`` from ``[fairway]``)."""

    sync: SyncConfig = setting({}, factory=SyncConfig)
    association: AssociationConfig = setting({}, factory=AssociationConfig)
    siap: SiapConfig = setting({}, factory=SiapConfig)
    radar_bias: RadarBiasConfig = setting({}, factory=RadarBiasConfig)
    max_cross_track_m: float = positive(2000.0, key=("fairway", "max_cross_track_m"))
    integrity: ChannelIntegrityConfig = setting({}, key="channel_integrity",
                                                factory=ChannelIntegrityConfig)
    # the channel scenario's fault schedule: config/scenarios/channel.toml, never a site's
    faults: tuple[ChannelFault, ...] = setting([], key="channel_faults", scenario="channel")
    reference: ReferenceConfig = setting({}, factory=ReferenceConfig)
    registration: RegistrationConfig = setting({}, factory=RegistrationConfig)


def maritime_config(cfg: Config) -> MaritimeConfig:
    """The maritime family's config, parsed when ``cfg`` was loaded."""
    return cfg.family("maritime")


def channel_faults(cfg: Config) -> tuple[ChannelFault, ...]:
    """The channel scenario's fault schedule (``[[channel_faults]]``)."""
    return maritime_config(cfg).faults


def with_faults(cfg: Config, faults: tuple[ChannelFault, ...]) -> Config:
    """``cfg`` with ``faults`` as the channel scenario's schedule: the simulator's world
    (marked so: a scenario file is not merged on top of it again)."""
    fam = dict(cfg.families)
    fam["maritime"] = replace(maritime_config(cfg), faults=tuple(faults))
    return replace(cfg, families=fam, scenario_files=cfg.scenario_files or ("(in memory)",))


def with_registration(cfg: Config, enabled: bool, **fields: object) -> Config:
    """``cfg`` with ``[registration] enabled`` and ``fields`` set (the rest of the section
    as it is)."""
    mc = maritime_config(cfg)
    fam = dict(cfg.families)
    fam["maritime"] = replace(mc, registration=replace(mc.registration, enabled=enabled,
                                                       **fields))
    return replace(cfg, families=fam)


def without_faults(cfg: Config) -> Config:
    """``cfg`` with an empty ``[[channel_faults]]`` schedule (the fault-free scenario)."""
    return with_faults(cfg, ())


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
        if m.registration.window_s > core.ais.identity_window_s:
            doc.problem(("registration", "window_s"),
                        f"{m.registration.window_s:g} s is beyond the unit's look-ahead "
                        f"([ais] identity_window_s = {core.ais.identity_window_s:g} s): "
                        "results would depend on where units are cut")
        sectors = {s.name for s in core.sectors}
        for i, f in enumerate(m.faults):
            if f.sensor_kind == "radar" and f.site_id not in sites:
                doc.problem(("channel_faults", i, "site_id"),
                            f"{f.kind} needs a radar site (sites: {', '.join(sorted(sites))})")
            if f.sector and f.sector not in sectors:
                doc.problem(("channel_faults", i, "sector"), f"no sector {f.sector!r}")
            if f.kind == "ais_spoof" and (f.mmsi == 0 or not doc.has("channel_faults", i,
                                                                      "start")):
                doc.problem(("channel_faults", i), "ais_spoof needs mmsi and start = [lat, lon]")
    return m


# what the family's stage reads of the core config, and the tables it writes (its
# ``Family`` takes both from here; provenance reads them without importing the stage):
# the fused picture, the audit tables (SIAP against truth, cross-track error per leg,
# detection), channel integrity (issue 22), online registration (issue 38)
DECLARATION = FamilyDeclaration(
    "maritime", ("region", "radar_sites", "ais", "fairway_legs", "sectors"),
    ("associations", "system_tracks", "identifications", "track_errors", "reference_tracks",
     "siap_by_sector", "cross_track_by_leg", "radar_detection", "maritime_channel_health",
     "sensor_registration"))
