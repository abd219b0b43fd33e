"""The stated-accuracy check when a site's sigmas are stated too small (issue 38 item 2):
the seeded Monte Carlo of ``pipeline.experiments.stated_accuracy`` over ``--runs``
seeds, on ``--workers`` processes, printed per misstatement.

    PYTHONPATH=. .venv/bin/python -m bench.stated_accuracy [--runs 20] [--first-seed 1000]

(as a module: ``bench/pipeline.py`` would shadow the package when run as a script)
Seeded: the same figures on every run. docs/integrity.md §9 has the 20-seed table.
"""

from __future__ import annotations

from bench.registration_no_ais import drive
from pipeline.experiments import stated_accuracy

if __name__ == "__main__":
    drive(stated_accuracy, first_seed=1000, description=__doc__.splitlines()[0])
