"""Registration per sector where a radar's error is not the same at every azimuth (issue
38 item 1, "per sector where it differs"; ``pipeline.maritime.registration``), seeded
Monte Carlo (driver: ``bench/registration_sectors.py``; slow test:
tests/maritime/test_registration_montecarlo.py).

Per seed and fault: the ``channel`` scenario's 900 s scene with one fault of R1 for 360
s from 300 s, through the maritime stage with one registration per site (``per_sector =
false``) and with sectors registered on their own where they differ (the default). The
faults: a range bias of 100 m over R1's azimuths 40-90 deg (a range error on one
bearing's path; approach_ne lies there, the other sectors not), an azimuth bias of 1 deg
and a range bias of 100 m over its azimuths 50-140 deg (an encoder error over part of
the rotation: inner_channel and approach_ne lie there, and the part of approach_sw east
of the site: a sector half in the fault), and, as the control, the same azimuth bias at
every azimuth (nothing to gain from sectors). :func:`summarise` gives per fault, over
the runs: fused RMS and p95 against truth from 60 s after the onset to the end of the
fault (medians), the (epoch, ship) pairs followed by two fused tracks, the share of runs
where the per-sector p95 is no worse than the per-site one (``p95_sector_le_site``), the
share of R1's fault epochs registered per sector and of epochs before the onset (a false
split).
"""

from __future__ import annotations

import math

import polars as pl

from pipeline.experiments.channel_montecarlo import maritime_inputs
from pipeline.experiments.registration_no_ais import fused_accuracy
from pipeline.families import load_config
from pipeline.family import Window
from pipeline.maritime.config import ChannelFault, with_faults, with_registration
from pipeline.maritime.stage import stage
from pipeline.simulate import DEFAULT_START_NS
from pipeline.simulate.scenarios import with_scenario
from pipeline.units import NS

DURATION_S, ONSET_S, FAULT_S, SETTLE_S = 900.0, 300.0, 360.0, 60.0
SITE = "R1"
AZIMUTHS = {"azimuth_from_rad": math.radians(50.0), "azimuth_to_rad": math.radians(140.0)}
NE = {"azimuth_from_rad": math.radians(40.0), "azimuth_to_rad": math.radians(90.0)}
#: name, ChannelFault fields (kind, its size, the azimuths it acts in)
FAULTS = (
    ("range_bias_in_40_90_deg", {"kind": "radar_range_bias", "range_bias_m": 100.0, **NE}),
    ("azimuth_bias_in_50_140_deg", {"kind": "radar_azimuth_bias",
                                    "azimuth_bias_rad": math.radians(1.0), **AZIMUTHS}),
    ("range_bias_in_50_140_deg", {"kind": "radar_range_bias", "range_bias_m": 100.0,
                                  **AZIMUTHS}),
    ("azimuth_bias_everywhere", {"kind": "radar_azimuth_bias",
                                 "azimuth_bias_rad": math.radians(1.0)}),
)


def _ns(s: float) -> int:
    return DEFAULT_START_NS + round(s * NS)


def run_one(args: tuple[int, int]) -> dict:
    """One seed and fault (picklable arguments: the seed, the index in FAULTS)."""
    seed, i = args
    name, fields = FAULTS[i]
    fault = ChannelFault(start_s=ONSET_S, duration_s=FAULT_S, site_id=SITE, **fields)
    cfg = with_faults(with_scenario(load_config(), ["channel"]), (fault,))
    window = Window(DEFAULT_START_NS, _ns(DURATION_S))
    inputs, _ = maritime_inputs(cfg, seed, window.start_ns, DURATION_S)
    row: dict = {"fault": name, "seed": seed}
    for per_sector in (False, True):
        out = stage(inputs, window, with_registration(cfg, True, per_sector=per_sector))
        row |= fused_accuracy(out, _ns(ONSET_S + SETTLE_S), _ns(ONSET_S + FAULT_S),
                              "sector" if per_sector else "site")
        if per_sector:
            reg = out["sensor_registration"].filter(pl.col("site_id") == SITE)
            split = pl.col("registration_scope") == "sector"
            during = reg.filter(pl.col("time_ns").is_between(_ns(ONSET_S), _ns(ONSET_S + FAULT_S),
                                                             closed="left"))
            row["sector_share_fault"] = float(during.select(split.mean()).item())
            row["sector_share_before"] = float(
                reg.filter(pl.col("time_ns") < _ns(ONSET_S)).select(split.mean()).item())
    return row


def summarise(rows: pl.DataFrame) -> pl.DataFrame:
    """One row per fault of :func:`run_one`'s rows (module docstring)."""
    return rows.group_by("fault", maintain_order=True).agg(
        pl.len().alias("runs"),
        pl.col("rms_site_m", "rms_sector_m", "p95_site_m", "p95_sector_m").median().round(1),
        pl.col("duplicates_site", "duplicates_sector").median(),
        (pl.col("p95_sector_m") <= pl.col("p95_site_m")).mean().round(3)
        .alias("p95_sector_le_site"),
        pl.col("sector_share_fault", "sector_share_before").mean().round(4),
    )
