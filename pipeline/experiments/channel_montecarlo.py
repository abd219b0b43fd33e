"""Seeded Monte Carlo of channel integrity for radars, AIS and the own ship's GNSS
(issue 22), measured like the airfield's (``pipeline.experiments.airfield_montecarlo``).

One seed = the ``channel`` scenario with a compressed fault schedule (:func:`mc_faults`:
every maritime fault kind once, 90 s each, 60 s apart, radar and AIS faults in turn)
run through the maritime stage twice (``[channel_integrity] exclusion`` on, with the
configured ``[registration]``, and off, every report fused as reported) from the same
simulated reports, the same scenario without faults (the false-alarm share and
the fault-free accuracy of each radar), and the ``ownship`` scenario with a GNSS outage
and a GNSS position jump through the nav stage (and without them). Everything from the
simulators onwards is the production code in memory: AIS and the own ship's NMEA go
through the decoders, the radar reports skip only the JSON round trip (tested exact).

Per injected fault (one row per affected channel: a swap is two):

- **detected within 3**: a radar's first decision with eta = 1 (any sector) within 3 of
  its scan periods after the fault start; an AIS transponder's first flagged report
  among its first 3 reports from the fault start (a spoofer: from its first report);
  the GNSS channel's first flagged step within 3 fixes;
- the delay (scans, reports, fixes) of that first flag, whether it came at all during
  the fault, and the share of the channel's decisions during the fault with eta = 1;
- fused accuracy during the fault, on the (time, ship) points fused in every run: RMS
  error against truth with exclusion on and off and their mean NEES (2 when the fused
  sigmas are honest), and, from the fault-free run, the RMS of the fused picture and of
  each radar alone on the same points (the best of them is the goal for a radar bias
  jump);
- identification during the fault: the share of the track time of ships without AIS
  that carries an MMSI (false identification) and the correct share of ships with AIS,
  judged by the ship each track follows (and by the nearest ship, as the report does;
  ``pipeline.experiments.identification``), beside the fault-free run's.

Fault-free runs give the share of decisions flagged per sensor kind (against radar_q,
ais_q; the GNSS position test against ``gnss_q`` and the filter's gate against its 3-sigma
tail, apart) and the share of decisions after which the channel was excluded (what false
alarms cost the fused picture: a radar is excluded after ``radar_confirm`` failures in a
row).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import polars as pl

from pipeline.config import Config
from pipeline.decode.ais import decode_ais_sentences
from pipeline.decode.nmea import decode_nmea_sentences
from pipeline.executors import make_executor
from pipeline.experiments.identification import judged_points
from pipeline.family import Window
from pipeline.filters.integrity import chi2_thresholds
from pipeline.maritime.config import ChannelFault, maritime_config, with_faults, without_faults
from pipeline.maritime.stage import stage as maritime_stage
from pipeline.nav.config import ownship_config
from pipeline.nav.solution import nav_window
from pipeline.simulate import DEFAULT_START_NS
from pipeline.simulate.channel import ChannelScenario, simulate_channel
from pipeline.simulate.ownship import (
    gnss_sentences,
    hdt_sentences,
    simulate_ownship,
    vhw_sentences,
)
from pipeline.units import NS

DETECT_WITHIN = 3
FAULT_S = 90.0
GAP_S = 60.0
FIRST_S = 120.0
LEAD_OUT_S = 60.0
SPOOF_MMSI = 272999001
GNSS_OUTAGE = (300.0, 60.0)
GNSS_JUMP = (450.0, 60.0, 50.0, -30.0)
GNSS_DURATION_S = 600.0


def mc_faults(cfg: Config) -> tuple[ChannelFault, ...]:
    """The compressed schedule of one Monte Carlo scene: every maritime fault kind once,
    ``FAULT_S`` long, ``GAP_S`` apart from ``FIRST_S`` on (radar and AIS in turn; the
    sizes of the default config's schedule)."""
    r1, r2 = (s.site_id for s in cfg.radar_sites[:2])
    kinds = [
        ChannelFault("radar_range_bias", 0, 0, site_id=r2, range_bias_m=80.0),
        ChannelFault("ais_offset", 0, 0, north_m=250.0),
        ChannelFault("radar_azimuth_bias", 0, 0, site_id=r1, azimuth_bias_rad=math.radians(1.0)),
        ChannelFault("ais_stuck", 0, 0),
        ChannelFault("radar_outage", 0, 0, site_id=r1),
        ChannelFault("ais_mmsi_swap", 0, 0),
        ChannelFault("radar_time_offset", 0, 0, site_id=r2, time_offset_s=5.0),
        ChannelFault("ais_spoof", 0, 0, mmsi=SPOOF_MMSI, start_lat_deg=46.392,
                     start_lon_deg=30.870, course_rad=math.radians(90.0), speed_mps=6.0),
        ChannelFault("radar_blank", 0, 0, site_id=r2, azimuth_from_rad=math.radians(240.0),
                     azimuth_to_rad=math.radians(285.0)),
        ChannelFault("radar_noise", 0, 0, site_id=r1, factor=4.0),
        ChannelFault("radar_range_gain", 0, 0, site_id=r2, range_gain=0.006),
    ]
    return tuple(replace(f, start_s=FIRST_S + i * (FAULT_S + GAP_S), duration_s=FAULT_S)
                 for i, f in enumerate(kinds))


def scene_duration_s(cfg: Config) -> float:
    return FIRST_S + len(mc_faults(cfg)) * (FAULT_S + GAP_S) - GAP_S + LEAD_OUT_S


@dataclass(frozen=True)
class McUnit:
    """One seed (picklable)."""

    cfg: Config
    seed: int
    start_ns: int = DEFAULT_START_NS


def maritime_inputs(cfg: Config, seed: int, start_ns: int, duration_s: float
                    ) -> tuple[dict[str, pl.DataFrame], ChannelScenario]:
    """The stage's inputs (radar_tracks, ais_reports, truth) of the channel scenario
    simulated with ``cfg``, and the scenario (its fault and radar-track truth)."""
    sc = simulate_channel(cfg, start_ns=start_ns, duration_s=duration_s, seed=seed)
    radar = sc.radar_reports.rename(
        {"track_id": "local_track_id", "x_m": "x_site_m", "y_m": "y_site_m"}
    ).with_columns(pl.lit("simulated").alias("source_file"), pl.lit("/radar").alias("topic"))
    s = sc.ais_sentences
    ais, _, _ = decode_ais_sentences([x.encode() for x in s["sentence"].to_list()],
                                     s["log_time_ns"].to_numpy(), source_file="simulated",
                                     topic="/ais/nmea")
    return {"radar_tracks": radar, "ais_reports": pl.from_arrow(ais), "truth": sc.truth}, sc


def _with_exclusion(cfg: Config, on: bool) -> Config:
    """``cfg`` with exclusion on (as configured, registration included) or off: every
    report fused as reported (no exclusion, no registration: the unprotected picture)."""
    mc = maritime_config(cfg)
    fam = dict(cfg.families)
    reg = mc.registration if on else replace(mc.registration, enabled=False)
    fam["maritime"] = replace(mc, integrity=replace(mc.integrity, exclusion=on),
                              registration=reg)
    return replace(cfg, families=fam)


def run_seed(unit: McUnit) -> dict[str, pl.DataFrame]:
    """Metrics of one seed: ``faults`` (one row per injected fault and channel),
    ``false_alarms`` (fault-free decisions and flags per sensor kind)."""
    cfg = with_faults(unit.cfg, mc_faults(unit.cfg))
    duration = scene_duration_s(unit.cfg)
    window = Window(unit.start_ns, unit.start_ns + round(duration * NS))
    inputs, sc = maritime_inputs(cfg, unit.seed, unit.start_ns, duration)
    truth = sc.fault_truth
    on = maritime_stage(inputs, window, _with_exclusion(cfg, True))
    off = maritime_stage(inputs, window, _with_exclusion(cfg, False))
    clean_inputs, clean_sc = maritime_inputs(without_faults(cfg), unit.seed, unit.start_ns,
                                             duration)
    clean = maritime_stage(clean_inputs, window, _with_exclusion(cfg, True))
    rows = _fault_rows(cfg, truth, on, off, clean, inputs["ais_reports"])
    scene = _points(clean["track_errors"], "fused", window.start_ns, window.end_ns)
    rows = rows.with_columns(pl.lit(_rms(scene)).alias("clean_scene_fused_rms_m"),
                             pl.lit(_p95(scene)).alias("clean_scene_fused_p95_m"),
                             pl.lit(float(scene["nees"].mean() or np.nan)).alias(
                                 "clean_scene_fused_nees"))
    rows = rows.hstack(_identification_rows(
        truth, judged_points(on, sc.radar_track_truth, sc.vessels),
        judged_points(clean, clean_sc.radar_track_truth, clean_sc.vessels)))
    fa = _false_alarms(clean["maritime_channel_health"], "sensor_kind")
    g_faults, g_fa = _gnss_seed(unit)
    seed = pl.lit(unit.seed).alias("seed")
    return {"faults": pl.concat([rows, g_faults], how="diagonal_relaxed").with_columns(seed),
            "false_alarms": pl.concat([fa, g_fa]).with_columns(seed)}


def _identification_rows(truth: pl.DataFrame, on: pl.DataFrame, clean: pl.DataFrame
                         ) -> pl.DataFrame:
    """Per injected fault (rows of ``truth``): over the fault, the fused points of ships
    without AIS and of those with AIS (judged by the ship each track follows, and by the
    nearest ship: :mod:`pipeline.experiments.identification`), with a wrong MMSI or
    the correct one, with exclusion on and in the fault-free run at the same time."""
    rows = []
    for f in truth.iter_rows(named=True):
        row = {}
        for run, points in (("", on), ("clean_", clean)):
            p = points.filter(pl.col("time_ns").is_between(f["start_ns"], f["end_ns"],
                                                           closed="left"))
            for judge in ("followed", "nearest"):
                ais, verdict = pl.col(f"{judge}_ais"), pl.col(f"{judge}_verdict")
                row[f"{run}no_ais_points_{judge}"] = p.filter(~ais).height
                row[f"{run}false_id_points_{judge}"] = p.filter(~ais & (verdict == "wrong")
                                                                ).height
                row[f"{run}ais_points_{judge}"] = p.filter(ais).height
                row[f"{run}correct_points_{judge}"] = p.filter(ais & (verdict == "correct")
                                                               ).height
        rows.append(row)
    return pl.DataFrame(rows)


def _false_alarms(health: pl.DataFrame, key: str) -> pl.DataFrame:
    return health.filter(pl.col("eta").is_not_null()).group_by(key).agg(
        pl.len().alias("decisions"), (pl.col("eta") == 1).sum().alias("flagged"),
        pl.col("q").mean().alias("q"), pl.col("excluded").sum().alias("excluded"),
    ).rename({key: "sensor_kind"}).select("sensor_kind", "decisions", "flagged", "q",
                                          "excluded")


def _points(errors: pl.DataFrame, source: str, t0: int, t1: int) -> pl.DataFrame:
    """(time_ns, vessel, error_m) of one source's points against truth in [t0, t1)."""
    return errors.filter(
        (pl.col("reference") == "truth") & (pl.col("source") == source)
        & pl.col("time_ns").is_between(t0, t1, closed="left") & pl.col("error_m").is_not_null()
    ).select("time_ns", pl.col("reference_id").alias("vessel"), "error_m", "nees").unique(
        ["time_ns", "vessel"], keep="first")


def _rms(points: pl.DataFrame) -> float:
    v = points["error_m"].to_numpy()
    return float(np.sqrt(np.mean(v**2))) if v.size else float("nan")


def _p95(points: pl.DataFrame) -> float:
    v = points["error_m"].to_numpy()
    return float(np.quantile(v, 0.95)) if v.size else float("nan")


def _accuracy(on: dict, off: dict, clean: dict, sites: list[str], faulted: str, t0: int,
              t1: int) -> dict[str, float]:
    """RMS errors during a fault on the same points: the (time, vessel) pairs fused in
    every run (exclusion on, off, fault-free); each fault-free radar alone on those of
    them it sees, the best of them, and the best of the radars the fault left healthy
    (the others than ``faulted``: what the fusion still has; whether the faulted radar
    was the fault-free best, ``faulted_was_best``)."""
    key = ["time_ns", "vessel"]
    f_on = _points(on["track_errors"], "fused", t0, t1)
    f_off = _points(off["track_errors"], "fused", t0, t1)
    f_clean = _points(clean["track_errors"], "fused", t0, t1)
    common = f_on.select(key).join(f_off.select(key), on=key).join(f_clean.select(key), on=key)
    alone = {s: _points(clean["track_errors"], s, t0, t1).join(common, on=key) for s in sites}
    radar = {s: _rms(v) for s, v in alone.items()}
    p95 = {s: _p95(v) for s, v in alone.items()}
    healthy = [v for s, v in p95.items() if s != faulted]
    best = float(np.nanmin(list(p95.values())))
    return {
        "points": common.height,
        "fused_rms_on_m": _rms(f_on.join(common, on=key)),
        "fused_p95_on_m": _p95(f_on.join(common, on=key)),
        "clean_best_radar_p95_m": best,
        "healthy_best_radar_p95_m": float(np.nanmin(healthy)) if healthy else float("nan"),
        "faulted_was_best": faulted in p95 and p95[faulted] == best,
        "fused_rms_off_m": _rms(f_off.join(common, on=key)),
        "clean_fused_rms_m": _rms(f_clean.join(common, on=key)),
        "fused_nees_on": float(f_on.join(common, on=key)["nees"].mean() or np.nan),
        "fused_nees_off": float(f_off.join(common, on=key)["nees"].mean() or np.nan),
        **{f"clean_{s}_rms_m": v for s, v in radar.items()},
        "clean_best_radar_rms_m": float(np.nanmin(list(radar.values()))),
    }


#: the ``sensor_registration`` estimate and sigma of each registration fault kind
REGISTRATION_OF = {
    "radar_range_bias": ("range_bias_m", "sigma_range_bias_m"),
    "radar_azimuth_bias": ("azimuth_bias_rad", "sigma_azimuth_bias_rad"),
    "radar_time_offset": ("time_offset_s", "sigma_time_offset_s"),
    "radar_range_gain": ("range_gain", "sigma_range_gain"),
}
Z95 = 1.959963984540054


def site_registration(out: dict) -> pl.DataFrame:
    """``sensor_registration`` of the stage output ``out``, one row per (epoch, site): the
    site's estimate (the same in each of its sectors; a sector registered on its own left
    out), in time order."""
    reg = out["sensor_registration"].filter(
        pl.col("registration_scope").fill_null("site") == "site")
    return reg.unique(["time_ns", "site_id"], keep="first", maintain_order=True).sort("time_ns")


def _registration(on: dict, clean: dict, f: dict) -> dict[str, float | bool | None]:
    """For a range, azimuth or clock fault: whether the faulted site's estimate at the
    middle of the fault holds the injected value in its 95 % interval
    (``registration_within_95``), the share of the fault's epochs from the first
    ``window_s`` on where it does, and the share of the same epochs of the fault-free
    run whose interval holds 0 (``clean_registration_within_share``)."""
    cols = REGISTRATION_OF.get(f["kind"])
    if cols is None or "sensor_registration" not in on or not on["sensor_registration"].height:
        return {}
    est, sig = cols
    t0, t1 = f["start_ns"], f["end_ns"]
    settle = t0 + (t1 - t0) // 3

    def within(out: dict, value: float) -> pl.DataFrame:
        reg = site_registration(out).filter(
            (pl.col("site_id") == f["channel"])
            & pl.col("time_ns").is_between(settle, t1, closed="left"))
        return reg.select("time_ns", ((pl.col(est) - value).abs() <= Z95 * pl.col(sig))
                          .alias("within"))

    fault, free = within(on, f["value"]), within(clean, 0.0)
    mid = fault.filter(pl.col("time_ns") >= (t0 + t1) // 2).head(1)["within"]
    return {
        "registration_within_95": bool(mid[0]) if mid.len() else None,
        "registration_within_share": float(fault["within"].mean() or np.nan),
        "clean_registration_within_share": float(free["within"].mean() or np.nan),
    }


def _fault_rows(cfg: Config, truth: pl.DataFrame, on: dict, off: dict, clean: dict,
                ais: pl.DataFrame) -> pl.DataFrame:
    h = on["maritime_channel_health"]
    periods = {s.site_id: s.scan_period_s for s in cfg.radar_sites}
    sites = list(periods)
    rows = []
    for f in truth.iter_rows(named=True):  # one row per injected fault and channel
        t0, t1 = f["start_ns"], f["end_ns"]
        ch = h.filter((pl.col("channel") == f["channel"]) & (pl.col("time_ns") >= t0)
                      & (pl.col("time_ns") < t1 + round(LEAD_OUT_S * NS)))
        during = ch.filter(pl.col("time_ns") < t1)
        flags = ch.filter(pl.col("eta") == 1)
        first = flags["time_ns"].min()
        if f["sensor_kind"] == "radar":
            unit = periods[f["channel"]]
            delay = None if first is None else (first - t0) / NS / unit
        else:
            sent = ais.filter((pl.col("mmsi") == f["mmsi"]) & (pl.col("time_ns") >= t0))
            delay = None if first is None else int((sent["time_ns"] <= first).sum())
        rows.append({
            "kind": f["kind"], "sensor_kind": f["sensor_kind"], "channel": f["channel"],
            "detected": first is not None and first < t1,
            "delay": delay,
            "detected_within_3": delay is not None and delay <= DETECT_WITHIN,
            "flagged_share_during": float(during["eta"].mean()) if during.height else None,
            **_accuracy(on, off, clean, sites, f["channel"], t0, t1),
            **_registration(on, clean, f),
        })
    return pl.DataFrame(rows)


def _gnss_seed(unit: McUnit) -> tuple[pl.DataFrame, pl.DataFrame]:
    """The ownship scenario with one outage and one position jump, and without them,
    through the nav stage: per fault row and the fault-free false alarms."""
    oc = ownship_config(unit.cfg)
    # the scenario's single-fix outliers are faults too: none here, so that the fault-free
    # run measures false alarms and the faulty one these two faults only
    faulty = replace(oc.scenario, outages_s=(GNSS_OUTAGE,), jumps=(GNSS_JUMP,), outlier_count=0)
    clean = replace(oc.scenario, outages_s=(), jumps=(), outlier_count=0)
    sol_f, truth = _nav_run(unit, faulty)
    sol_c, _ = _nav_run(unit, clean)
    rows = []
    for f in truth.iter_rows(named=True):
        t0, t1 = f["start_ns"], f["end_ns"]
        w = sol_f.filter(pl.col("time_ns") >= t0)
        flags = w.filter(pl.col("gnss_eta") == 1)
        first = flags["time_ns"].min()
        # delay in fixes: faulty (or missing) fixes from the start up to the first flag
        delay = None if first is None else int(
            ((w["time_ns"] > t0) & (w["time_ns"] <= first)).sum())
        during = w.filter(pl.col("time_ns") < t1)
        rows.append({
            "kind": f["kind"], "sensor_kind": "gnss", "channel": f["channel"],
            "detected": first is not None and first < t1, "delay": delay,
            "detected_within_3": delay is not None and delay <= DETECT_WITHIN,
            "flagged_share_during": float((during["gnss_eta"] == 1).mean()),
            "fused_rms_on_m": _nav_rms(sol_f, t0, t1), "clean_fused_rms_m": _nav_rms(sol_c, t0, t1),
        })
    # fault-free: the position test (at gnss_q) and the filter's 3-sigma gate apart
    d1, d2 = chi2_thresholds(oc.nav.gnss_q, 2)
    pos = sol_c.filter(pl.col("gnss_nis").is_not_null()).select(
        pl.lit("gnss_position").alias("sensor_kind"), pl.len().alias("decisions"),
        ((pl.col("gnss_nis") <= d1) | (pl.col("gnss_nis") >= d2)).sum().alias("flagged"),
        pl.lit(oc.nav.gnss_q).alias("q"), pl.col("gnss_excluded").sum().alias("excluded"))
    gate = sol_c.filter(pl.col("gate").is_not_null()).select(
        pl.lit("gnss_gate").alias("sensor_kind"), pl.len().alias("decisions"),
        (pl.col("gate") == "reject").sum().alias("flagged"),
        pl.lit(math.erfc(oc.model.settings.gate_n_sigma / math.sqrt(2.0))).alias("q"),
        (pl.col("gate") == "reject").sum().alias("excluded"))  # a rejected fix is not used
    return pl.DataFrame(rows), pl.concat([pos, gate], how="vertical_relaxed")


def _nav_rms(sol: pl.DataFrame, t0: int, t1: int) -> float:
    v = sol.filter(pl.col("time_ns").is_between(t0, t1, closed="left"))["position_error_m"]
    v = v.drop_nulls().to_numpy()
    return float(np.sqrt(np.mean(v**2))) if v.size else float("nan")


def _nav_run(unit: McUnit, sc_cfg) -> tuple[pl.DataFrame, pl.DataFrame]:
    oc = ownship_config(unit.cfg)
    sc = simulate_ownship(sc_cfg, start_ns=unit.start_ns, duration_s=GNSS_DURATION_S,
                          seed=unit.seed)
    pid = sc.platform_id
    tables = {}
    for frame_ in (gnss_sentences(sc.gnss), hdt_sentences(sc.gyro_heading),
                   vhw_sentences(sc.speed_log)):
        out = decode_nmea_sentences([s.encode() for s in frame_["sentence"].to_list()],
                                    frame_["time_ns"].to_numpy(), source_file="simulated",
                                    topic="/ownship", platform_id=pid)
        for name in ("nav_gnss", "nav_heading", "nav_speed_log"):
            t = pl.from_arrow(out[name])
            if t.height:
                tables[name] = t
    gyro = sc.gyro_signals.with_columns(pl.lit(pid).alias("platform_id"))
    truth = sc.truth.select("time_ns", "platform_id", "lat_deg", "lon_deg", "heading_rad")
    end_ns = unit.start_ns + round(GNSS_DURATION_S * NS)
    out = nav_window(tables["nav_gnss"], tables["nav_heading"], tables["nav_speed_log"], gyro,
                     truth, start_ns=unit.start_ns, end_ns=end_ns, cfg=unit.cfg, oc=oc)
    return out["nav_solution"], sc.fault_truth


def run_montecarlo(cfg: Config, *, seeds: range | list[int], executor: str = "process"
                   ) -> dict[str, pl.DataFrame]:
    """Every seed's metrics, concatenated; raises if a seed fails."""
    units = [McUnit(cfg, int(s)) for s in seeds]
    ex = make_executor(executor, min(cfg.execution.max_workers, len(units)),
                       cfg.execution.threads_per_worker)
    parts: dict[str, list[pl.DataFrame]] = {"faults": [], "false_alarms": []}
    for r in ex.map_units(run_seed, units):
        if not r.ok:
            raise RuntimeError(f"seed {r.unit.seed} failed: {r.error}")
        for k, v in r.value.items():
            parts[k].append(v)
    return {k: pl.concat(v, how="diagonal_relaxed") for k, v in parts.items()}


def _identification_shares(f: pl.DataFrame) -> list[pl.Expr]:
    """Pooled over the runs of a fault kind, during the fault: the share of the track
    time of ships without AIS carrying an MMSI (``false_id_share``; judged by the ship
    each track follows; ``_nearest``: by the nearest ship, as
    ``identification_by_sector``), the fault-free run's at the same time
    (``clean_false_id_share``), and the correct share of ships with AIS."""
    if "false_id_points_followed" not in f.columns:  # GNSS rows only
        return []

    def share(num: str, den: str) -> pl.Expr:
        return pl.col(num).sum() / pl.col(den).sum()

    return [
        share("false_id_points_followed", "no_ais_points_followed").alias("false_id_share"),
        share("false_id_points_nearest", "no_ais_points_nearest").alias(
            "false_id_share_nearest"),
        share("clean_false_id_points_followed", "clean_no_ais_points_followed").alias(
            "clean_false_id_share"),
        share("correct_points_followed", "ais_points_followed").alias("ais_correct_share"),
    ]


def _registration_shares(f: pl.DataFrame) -> list[pl.Expr]:
    """The share of runs whose registration estimate at mid-fault holds the injected
    value in its 95 % interval, the median share of the fault's epochs where it does,
    and of the fault-free run's where it holds 0 (:func:`_registration`)."""
    if "registration_within_95" not in f.columns:
        return []
    return [pl.col("registration_within_95").mean().alias("registration_within_95"),
            pl.col("registration_within_share").median().alias("registration_within_share"),
            pl.col("clean_registration_within_share").median().alias(
                "clean_registration_within_share")]


def summarise(res: dict[str, pl.DataFrame]) -> pl.DataFrame:
    """One row per fault kind: channels faulted (runs), share detected within 3 scans /
    reports / fixes, share detected during the fault, median and worst delay, fused RMS
    during the fault (median over runs) with exclusion on and off, fault-free fused and
    best single radar, the false-identification shares (:func:`_identification_shares`);
    then one row per sensor kind of the fault-free false alarms."""
    f = res["faults"]
    faults = f.group_by("kind", "sensor_kind").agg(
        pl.len().alias("runs"),
        pl.col("detected_within_3").mean().alias("p_detect_3"),
        pl.col("detected").mean().alias("p_detect"),
        pl.col("delay").median().alias("median_delay"),
        pl.col("delay").max().alias("worst_delay"),
        pl.col("flagged_share_during").median().alias("flagged_share_during"),
        pl.col("fused_rms_on_m").median().alias("fused_rms_on_m"),
        pl.col("fused_rms_off_m").median().alias("fused_rms_off_m"),
        pl.col("clean_fused_rms_m").median().alias("clean_fused_rms_m"),
        pl.col("clean_best_radar_rms_m").median().alias("clean_best_radar_rms_m"),
        pl.col("fused_nees_on").median().alias("fused_nees_on"),
        pl.col("fused_nees_off").median().alias("fused_nees_off"),
        (pl.col("fused_rms_on_m") <= pl.col("clean_best_radar_rms_m")).mean().alias(
            "share_on_le_best_radar"),
        pl.col("fused_p95_on_m").median().alias("fused_p95_on_m"),
        pl.col("clean_best_radar_p95_m").median().alias("clean_best_radar_p95_m"),
        (pl.col("fused_p95_on_m") <= pl.col("clean_best_radar_p95_m")).mean().alias(
            "share_on_p95_le_best_radar"),
        pl.col("healthy_best_radar_p95_m").median().alias("healthy_best_radar_p95_m"),
        (pl.col("fused_p95_on_m") <= pl.col("healthy_best_radar_p95_m")).mean().alias(
            "share_on_p95_le_healthy_radar"),
        pl.col("faulted_was_best").mean().alias("share_faulted_was_best"),
        *_identification_shares(f),
        *_registration_shares(f),
    ).with_columns(pl.lit(None, pl.Float64).alias("false_alarm_share"),
                   pl.lit(None, pl.Float64).alias("q"))
    fa = res["false_alarms"].group_by("sensor_kind").agg(
        pl.col("decisions").sum(), pl.col("flagged").sum(), pl.col("q").mean(),
        pl.col("excluded").sum())
    fa = fa.select(
        pl.lit("(fault-free)").alias("kind"), "sensor_kind",
        pl.col("decisions").cast(pl.UInt32).alias("runs"),
        (pl.col("flagged") / pl.col("decisions")).alias("false_alarm_share"), "q",
        (pl.col("excluded") / pl.col("decisions")).alias("false_exclusion_share"))
    return pl.concat([faults.sort("sensor_kind", "kind"), fa.sort("sensor_kind")],
                     how="diagonal_relaxed")
