"""Registration where no ship carries AIS (issue 38 item 1): the seeded Monte Carlo of
``pipeline.experiments.registration_no_ais`` over ``--runs`` seeds, on ``--workers``
processes, printed per fault kind.

    PYTHONPATH=. .venv/bin/python -m bench.registration_no_ais [--runs 20] [--first-seed 2000]

(as a module: ``bench/pipeline.py`` would shadow the package when run as a script)
Seeded: the same figures on every run. docs/integrity.md §9 has the 30-seed table.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from types import ModuleType

import polars as pl

from pipeline.experiments import registration_no_ais


def drive(experiment: ModuleType, first_seed: int, description: str) -> None:
    """Run ``experiment``'s ``run_one`` for every seed and fault of its ``FAULTS`` (options
    ``--runs``, ``--first-seed``, ``--workers``) and print its ``summarise`` table."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=first_seed)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    jobs = [(s, i) for i in range(len(experiment.FAULTS))
            for s in range(a.first_seed, a.first_seed + a.runs)]
    with ProcessPoolExecutor(a.workers) as pool:
        rows = pl.DataFrame(list(pool.map(experiment.run_one, jobs)))
    with pl.Config(tbl_cols=-1, tbl_width_chars=250, tbl_rows=-1):
        print(experiment.summarise(rows))


if __name__ == "__main__":
    drive(registration_no_ais, first_seed=2000, description=__doc__.splitlines()[0])
