"""How fast this machine is right now: a fixed single-threaded workload, timed.

On a shared VM the same code can need a third more CPU time from one hour to the next
(docs/scale.md: the same day batch, the same compute code, took 1,756 CPU s in one run
and 2,426 in another). The benches print this probe beside their figures so that two
runs can be compared: a figure that moved with the probe moved with the machine. The
workload: 50 x ``np.sin`` over 1 M doubles (memory and vector units) and a 3 M-step
Python loop (the interpreter), the two kinds of work the pipeline does. It read
0.65-0.83 CPU s on the 2-core VM on 2026-11-28 around 00:00 UTC.
"""

from __future__ import annotations

import time

import numpy as np


def probe() -> dict[str, float]:
    """{"wall_s", "cpu_s"} of the fixed workload, in this process."""
    x = np.linspace(0.0, 1.0, 1_000_000)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(50):
        np.sin(x, out=x)
    acc = 0
    for i in range(3_000_000):
        acc += i & 7
    return {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}


if __name__ == "__main__":
    p = probe()
    print(f"CPU probe: {p['cpu_s']:.2f} CPU s, {p['wall_s']:.2f} s wall")
