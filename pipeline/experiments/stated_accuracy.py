"""The stated-accuracy check when a site's sigmas are stated too small (issue 38 item 2,
estimated sensor accuracy; :func:`pipeline.maritime.registration.stated_accuracy_scale`),
seeded Monte Carlo (driver: ``bench/stated_accuracy.py``; slow test:
tests/maritime/test_stated_accuracy_montecarlo.py).

Per seed and misstatement: the ``channel`` scenario's 600 s scene without faults, both
radars' reports with their range, azimuth, speed and course sigmas (the reports' own
sigma columns: what a site's recorder or config says) multiplied by the misstatement's
factors, through the maritime stage with the check off (``accuracy_min_scale`` = 100)
and on (the default); and once as stated (the right sigmas). The misstatements: azimuth sigmas at
half (range right), range sigmas at half (azimuth right), both at half, range at a third
and azimuth at 0.7, speed and course sigmas at half (position right), all four at 0.7
and at half. :func:`summarise` gives per misstatement, over the runs: fused RMS, p95 and
mean NEES against truth over the scene (means), the share of radar rows fused, the
(epoch, ship) pairs followed by two fused tracks (means), the scales the check found
along and across the line of sight and on the speed and course (medians over the
sites' epochs; the truth: 1 / factor^2), and the same figures with the right sigmas.
"""

from __future__ import annotations

import numpy as np
import polars as pl

from pipeline.experiments.channel_montecarlo import maritime_inputs
from pipeline.experiments.registration_no_ais import duplicates
from pipeline.families import load_config
from pipeline.family import Window
from pipeline.maritime.config import with_faults, with_registration
from pipeline.maritime.stage import stage
from pipeline.simulate import DEFAULT_START_NS
from pipeline.simulate.scenarios import with_scenario
from pipeline.units import NS

DURATION_S = 600.0
#: name, the factors on the stated (range, azimuth, speed, course) sigmas
FAULTS = (
    ("azimuth_at_half", (1.0, 0.5, 1.0, 1.0)),
    ("range_at_half", (0.5, 1.0, 1.0, 1.0)),
    ("both_at_half", (0.5, 0.5, 1.0, 1.0)),
    ("range_third_azimuth_0.7", (1.0 / 3.0, 0.7, 1.0, 1.0)),
    ("velocity_at_half", (1.0, 1.0, 0.5, 0.5)),
    ("all_four_at_0.7", (0.7, 0.7, 0.7, 0.7)),
    ("all_four_at_half", (0.5, 0.5, 0.5, 0.5)),
)
SIGMAS = ("sigma_range_m", "sigma_azimuth_rad", "sigma_speed_mps", "sigma_course_rad")
AXES = ("range", "azimuth", "speed", "course")


def _figures(out: dict, tag: str) -> dict[str, float]:
    e = out["track_errors"].filter((pl.col("source") == "fused")
                                   & (pl.col("reference") == "truth"))
    err = e["error_m"].drop_nulls().to_numpy()
    return {f"rms_{tag}_m": float(np.sqrt(np.mean(err**2))),
            f"p95_{tag}_m": float(np.quantile(err, 0.95)),
            f"nees_{tag}": float(e["nees"].drop_nulls().mean()),
            f"fused_{tag}": float(out["associations"]["used"].mean()),
            f"duplicates_{tag}": duplicates(e)}


def run_one(args: tuple[int, int]) -> dict:
    """One seed and misstatement (picklable arguments: the seed, the index in FAULTS)."""
    seed, i = args
    name, factors = FAULTS[i]
    cfg = with_faults(with_scenario(load_config(), ["channel"]), ())
    window = Window(DEFAULT_START_NS, DEFAULT_START_NS + round(DURATION_S * NS))
    inputs, _ = maritime_inputs(cfg, seed, window.start_ns, DURATION_S)
    misstated = {**inputs, "radar_tracks": inputs["radar_tracks"].with_columns(
        pl.col(col) * f for col, f in zip(SIGMAS, factors, strict=True))}
    off = with_registration(cfg, True, accuracy_min_scale=100.0)
    on = stage(misstated, window, cfg)
    row = {"misstatement": name, "seed": seed,
           **_figures(stage(inputs, window, cfg), "right"),
           **_figures(stage(misstated, window, off), "off"), **_figures(on, "on")}
    scale = on["sensor_registration"].select(
        pl.col(f"stated_{a}_variance_scale").median().alias(a) for a in AXES).row(0)
    return (row | {f"{a}_scale": v for a, v in zip(AXES, scale, strict=True)}
            | {f"{a}_truth": f**-2 for a, f in zip(AXES, factors, strict=True)})


def summarise(rows: pl.DataFrame) -> pl.DataFrame:
    """One row per misstatement of :func:`run_one`'s rows (module docstring)."""
    tags = ("right", "off", "on")
    return rows.group_by("misstatement", maintain_order=True).agg(
        pl.len().alias("runs"),
        *(pl.col(f"rms_{t}_m", f"p95_{t}_m").mean().round(1) for t in tags),
        *(pl.col(f"nees_{t}").mean().round(2) for t in tags),
        *(pl.col(f"fused_{t}").mean().round(3) for t in ("off", "on")),
        *(pl.col(f"duplicates_{t}").mean() for t in tags),
        *(pl.col(f"{a}_scale").median().round(2) for a in AXES),
        *(pl.col(f"{a}_truth").first().round(2) for a in AXES),
    )
