"""The demo hour's identification, judged by the ship each track follows and by the
nearest ship (issue 38, item 3; ``pipeline.experiments.identification``).

    PYTHONPATH=. .venv/bin/python -m bench.identification [--seed 7] [--duration-s 3600]

(as a module: ``bench/pipeline.py`` would shadow the package when run as a script)

Simulates the ``channel`` scenario with the demo site's fault schedule (what
``surveil demo`` archives), runs the maritime stage over it in memory (the batch's code;
one window, which the batch's units reproduce row for row), and prints per sector: the
shares of track time with the correct / a wrong / no MMSI for ships with and without
AIS, under both judges, and the time to the first identification of each track that
follows a ship with AIS, and the test's outcomes per candidate pair (same ship or not,
confirmed or not). Seeded: the same figures on every run.
"""

from __future__ import annotations

import argparse

import polars as pl

from pipeline.experiments.channel_montecarlo import maritime_inputs
from pipeline.experiments.identification import (
    first_identification_delay,
    identification_shares,
    judged_points,
    pair_outcomes,
)
from pipeline.families import load_config
from pipeline.family import Window
from pipeline.maritime.stage import stage
from pipeline.simulate import DEFAULT_START_NS
from pipeline.simulate.scenarios import with_scenario
from pipeline.units import NS


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--duration-s", type=float, default=3600.0)
    args = ap.parse_args()
    cfg = with_scenario(load_config(), ["channel"])
    inputs, sc = maritime_inputs(cfg, args.seed, DEFAULT_START_NS, args.duration_s)
    window = Window(DEFAULT_START_NS, DEFAULT_START_NS + round(args.duration_s * NS))
    out = stage(inputs, window, cfg)
    points = judged_points(out, sc.radar_track_truth, sc.vessels)
    with pl.Config(tbl_rows=40, tbl_width_chars=160, float_precision=4):
        for judge in ("nearest", "followed"):
            print(f"judge: {judge}")
            print(identification_shares(points, ["sector"], judge))
        print("time to the first identification (tracks following a ship with AIS)")
        print(first_identification_delay(points, ["sector"]))
        print("candidate pairs (track, MMSI matched at least once): outcomes of the test")
        print(pair_outcomes(points, out["identifications"]))


if __name__ == "__main__":
    main()
