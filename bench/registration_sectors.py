"""Registration per sector where a radar's error differs (issue 38 item 1): the seeded
Monte Carlo of ``pipeline.experiments.registration_sectors`` over ``--runs`` seeds, on
``--workers`` processes, printed per fault.

    PYTHONPATH=. .venv/bin/python -m bench.registration_sectors [--runs 20] [--first-seed 3000]

(as a module: ``bench/pipeline.py`` would shadow the package when run as a script)
Seeded: the same figures on every run. docs/integrity.md §9 has the 30-seed table.
"""

from __future__ import annotations

from bench.registration_no_ais import drive
from pipeline.experiments import registration_sectors

if __name__ == "__main__":
    drive(registration_sectors, first_seed=3000, description=__doc__.splitlines()[0])
