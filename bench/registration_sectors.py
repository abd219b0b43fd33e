"""Registration per sector where a radar's error differs (issue 38 item 1): the seeded
Monte Carlo of ``pipeline.experiments.registration_sectors`` over ``--runs`` seeds, on ``--workers``
processes, printed per fault.

    PYTHONPATH=. .venv/bin/python -m bench.registration_sectors [--runs 20] [--first-seed 3000]

(as a module: ``bench/pipeline.py`` would shadow the package when run as a script)
Seeded: the same figures on every run. docs/integrity.md §9 has the 30-seed table.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor

import polars as pl

from pipeline.experiments.registration_sectors import FAULTS, run_one, summarise


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=3000)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    jobs = [(s, i) for i in range(len(FAULTS)) for s in range(a.first_seed,
                                                              a.first_seed + a.runs)]
    with ProcessPoolExecutor(a.workers) as pool:
        rows = pl.DataFrame(list(pool.map(run_one, jobs)))
    with pl.Config(tbl_cols=-1, tbl_width_chars=250, tbl_rows=-1):
        print(summarise(rows))


if __name__ == "__main__":
    main()
