"""Thin entry points composing pipeline stages: ingest, batch, report, reprocess, simulate, demo.

Before any of them imports polars, the commands' own process gets ``POLARS_MAX_THREADS=1``
unless the caller set it: polars sums floats per group in an order that depends on how its
threads split the rows, so with more than one thread a float aggregate (SIAP's summed
position errors, say) can differ in its last bits from one run to the next, and an exact
reprocess or a crash trial could not compare tables row for row. The batch is parallel by
process (``[execution]``; pool workers are capped to ``threads_per_worker``, 1 by default),
so the serial executor's process is capped the same way; measured: no slower.
"""

import os

os.environ.setdefault("POLARS_MAX_THREADS", "1")
