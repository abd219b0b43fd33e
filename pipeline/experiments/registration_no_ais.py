"""Registration where no ship carries AIS: the radar-radar pairs' joint estimate (issue
38 item 1; ``pipeline.maritime.registration``), seeded Monte Carlo (driver:
``bench/registration_no_ais.py``; slow test: tests/maritime/test_registration_montecarlo.py).

Per seed and radar fault kind: the ``channel`` scenario's 600 s scene with one fault of
180 s from 240 s (the sizes of the channel-faults Monte Carlo), every AIS report removed
from the stage's inputs, through the maritime stage with the registration on and off (off
is what the batch did before the pairs: without AIS the leave-one-out test has no
evidence). :func:`summarise` gives per kind, over the runs: fused RMS and p95 against
truth from 40 s after the onset to the end of the fault (medians), the (epoch, ship)
pairs followed by two fused tracks, the share of runs whose faulted site's estimate at
mid-fault holds the injected value in its 95 % interval and whose estimate is applied
there, and the share of the other site's epochs and of the fault-free epochs (before the
onset) where an estimate was applied (false corrections).
"""

from __future__ import annotations

import math

import numpy as np
import polars as pl

from pipeline.experiments.channel_montecarlo import (
    REGISTRATION_OF,
    Z95,
    maritime_inputs,
    site_registration,
)
from pipeline.families import load_config
from pipeline.family import Window
from pipeline.maritime.config import ChannelFault, with_faults, with_registration
from pipeline.maritime.stage import stage
from pipeline.simulate import DEFAULT_START_NS
from pipeline.simulate.scenarios import with_scenario
from pipeline.units import NS

DURATION_S, ONSET_S, FAULT_S, SETTLE_S = 600.0, 240.0, 180.0, 40.0
#: kind, site, injected value (its ChannelFault field and sensor_registration estimate
#: and sigma: ``REGISTRATION_OF``)
FAULTS = (
    ("radar_range_bias", "R2", 80.0),
    ("radar_azimuth_bias", "R1", math.radians(1.0)),
    ("radar_range_gain", "R2", 0.006),
    ("radar_time_offset", "R2", 5.0),
)


def _ns(s: float) -> int:
    return DEFAULT_START_NS + round(s * NS)


def fused_accuracy(out: dict, start_ns: int, end_ns: int, tag: str) -> dict[str, float]:
    """``rms_<tag>_m``, ``p95_<tag>_m`` of the stage output ``out``'s fused errors against
    truth in [start_ns, end_ns) and ``duplicates_<tag>``: the (epoch, ship) pairs followed
    by more than one fused system track there."""
    e = out["track_errors"].filter(
        (pl.col("source") == "fused") & (pl.col("reference") == "truth")
        & pl.col("time_ns").is_between(start_ns, end_ns, closed="left"))
    err = e["error_m"].drop_nulls().to_numpy()
    return {f"rms_{tag}_m": float(np.sqrt(np.mean(err**2))),
            f"p95_{tag}_m": float(np.quantile(err, 0.95)),
            f"duplicates_{tag}": duplicates(e)}


def duplicates(e: pl.DataFrame) -> int:
    """(epoch, ship) pairs of the fused ``track_errors`` rows ``e`` followed by more than
    one fused system track."""
    per = e.group_by("time_ns", "reference_id").agg(pl.col("system_track_id").n_unique())
    return int((per["system_track_id"] > 1).sum())



def run_one(args: tuple[int, int]) -> dict:
    """One seed and fault kind (picklable arguments: the seed, the index in FAULTS)."""
    seed, i = args
    kind, site, value = FAULTS[i]
    est, sig = REGISTRATION_OF[kind]  # the fault's field is named as its estimate
    world = with_scenario(load_config(), ["channel"])
    cfg = with_faults(world, (ChannelFault(kind, ONSET_S, FAULT_S, site_id=site,
                                           **{est: value}),))
    window = Window(DEFAULT_START_NS, _ns(DURATION_S))
    inputs, _ = maritime_inputs(cfg, seed, window.start_ns, DURATION_S)
    inputs["ais_reports"] = inputs["ais_reports"].head(0)
    row: dict = {"kind": kind, "seed": seed}
    for on in (False, True):
        out = stage(inputs, window, with_registration(cfg, on))
        row |= fused_accuracy(out, _ns(ONSET_S + SETTLE_S), _ns(ONSET_S + FAULT_S),
                              "on" if on else "off")
        if on:
            reg = site_registration(out)
            mid = reg.filter((pl.col("site_id") == site)
                             & (pl.col("time_ns") >= _ns(ONSET_S + FAULT_S / 2))).head(1)
            row["within_95"] = bool(((mid[est] - value).abs() <= Z95 * mid[sig]).item())
            row["applied_mid"] = bool(mid["registration_applied"].item())
            row["estimate_mid"] = float(mid[est].item())
            other = reg.filter(pl.col("site_id") != site)
            row["other_site_applied_share"] = float(other["registration_applied"].mean())
            before = reg.filter(pl.col("time_ns") < _ns(ONSET_S - 45.0))
            row["before_applied_share"] = float(before["registration_applied"].mean())
    return row


def summarise(rows: pl.DataFrame) -> pl.DataFrame:
    """One row per fault kind of :func:`run_one`'s rows (module docstring)."""
    return rows.group_by("kind", maintain_order=True).agg(
        pl.len().alias("runs"),
        pl.col("rms_off_m", "rms_on_m", "p95_off_m", "p95_on_m").median().round(1),
        pl.col("duplicates_off", "duplicates_on").median(),
        pl.col("within_95", "applied_mid").mean().round(3),
        pl.col("other_site_applied_share", "before_applied_share").mean().round(4),
        (pl.col("p95_on_m") <= pl.col("p95_off_m")).mean().round(3).alias("p95_on_le_off"),
    )
