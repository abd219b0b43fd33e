"""A regional day end to end: simulate (once, cached), then time ingest + batch + every
report of the 24 h `region` scenario, and a one-hour reprocess of it.

    .venv/bin/python bench/region_day.py [--workdir DIR] [--json FILE] [--ships 1000]
        [--radars 6] [--seed 7] [--duration 24h] [--executor process]

Each step runs the ``surveil`` command in its own process, as a nightly job would
(process pool of ``[execution] max_workers`` = 2 workers on this machine), while a sampler
sums the resident memory of the command and all its workers every 0.2 s: "peak RSS" is
the whole job's (driver + workers at the same moment), "driver" the command's own process
(the single committer), "peak worker" the largest of its worker processes. CPU seconds
are the job's and its children's (``RUSAGE_CHILDREN``). Before each step the bench times
a fixed workload (``bench/cpu_probe.py``): the VM's speed swings by a third from hour to
hour, and a step's figures are comparable between runs only beside it. The archive
(``--workdir``/archive, with its region.toml) is simulated once and reused while its
parameters match; the warehouse is made anew each run.

Goals (issue 19): the day in <= 15 minutes of wall time on the 2-core machine, <= 4 GB
for the whole job, <= 2 GB per worker; a 1-hour reprocess <= 1/20 of the day's time.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SURVEIL = Path(sys.executable).with_name("surveil")
START = "2026-01-15T00:00:00Z"
PAGE = os.sysconf("SC_PAGE_SIZE")


class TreeMemory(threading.Thread):
    """Peaks of the summed RSS of a process and its descendants, of the process itself
    and of its largest descendant."""

    def __init__(self, pid: int) -> None:
        super().__init__(daemon=True)
        self.pid = pid
        self.peak = 0
        self.peak_one = 0
        self.peak_driver = 0
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            total, driver, largest = self.sample()
            self.peak = max(self.peak, total)
            self.peak_driver = max(self.peak_driver, driver)
            self.peak_one = max(self.peak_one, largest)
            self.stop.wait(0.2)

    def sample(self) -> tuple[int, int, int]:
        parent: dict[int, int] = {}
        for d in os.listdir("/proc"):
            if d.isdigit():
                try:
                    with open(f"/proc/{d}/stat") as f:
                        parent[int(d)] = int(f.read().rsplit(")", 1)[1].split()[1])
                except OSError:
                    continue
        tree, frontier = {self.pid}, [self.pid]
        while frontier:
            p = frontier.pop()
            kids = [c for c, pp in parent.items() if pp == p and c not in tree]
            tree.update(kids)
            frontier += kids
        total = driver = largest = 0
        for p in tree:
            try:
                with open(f"/proc/{p}/statm") as f:
                    rss = int(f.read().split()[1]) * PAGE
            except OSError:
                continue
            total += rss
            if p == self.pid:
                driver = rss
            else:
                largest = max(largest, rss)
        return total, driver, largest


def run(step: str, args: list[str], fatal: bool = True) -> dict:
    """Run ``surveil <args>``; wall, CPU of the command and its workers, peak memory.
    A failing step ends the bench, except where ``fatal`` is False (a report): then its
    error is kept under "failed" and the day's other figures are still printed."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen([str(SURVEIL), *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO)
    mem = TreeMemory(proc.pid)
    mem.start()
    out, err = proc.communicate()
    wall = time.perf_counter() - t0
    mem.stop.set()
    mem.join()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0 and fatal:
        raise SystemExit(f"{step} failed ({proc.returncode}):\n{out[-3000:]}\n{err[-3000:]}")
    failed = ((err.strip().splitlines() or [f"exit {proc.returncode}"])[-1][:300]
              if proc.returncode != 0 else "")
    print(f"  {step}: {wall:.1f} s wall{' FAILED: ' + failed if proc.returncode else ''}",
          file=sys.stderr, flush=True)
    return {"step": step, "wall_s": wall, "failed": failed or None,
            "cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
            "peak_rss_mb": mem.peak / 2**20, "peak_driver_mb": mem.peak_driver / 2**20,
            "peak_worker_mb": mem.peak_one / 2**20,
            "stdout": out}


def rows_of(text: str) -> dict[str, int]:
    """`name count` pairs of an ingest/batch summary."""
    out = {}
    for part in text.replace("rows:", " ").replace(",", "\n").splitlines():
        bits = part.split()
        if len(bits) >= 2 and bits[-1].isdigit():
            out[bits[0]] = int(bits[-1])
        elif len(bits) >= 3 and bits[-1] == "rows" and bits[-2].isdigit():
            out[bits[0]] = int(bits[-2])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", default="/tmp/surveil-bench-region-day")
    ap.add_argument("--json", default=None)
    ap.add_argument("--ships", type=int, default=1000)
    ap.add_argument("--radars", type=int, default=6)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--duration", default="24h")
    ap.add_argument("--executor", default="process", choices=["serial", "process", "ray"])
    a = ap.parse_args()
    sys.path.insert(0, str(REPO))
    from bench.cpu_probe import probe
    from jobs.common import parse_duration
    from pipeline.units import NS

    work = Path(a.workdir)
    archive, wh = work / "archive", work / "wh"
    duration_s = parse_duration(a.duration)
    params = {"ships": a.ships, "radars": a.radars, "seed": a.seed, "duration_s": duration_s,
              "start": START}
    marker = archive / ".complete.json"
    steps = []
    if not marker.exists() or json.loads(marker.read_text()) != params:
        shutil.rmtree(archive, ignore_errors=True)
        steps.append(run("simulate", ["simulate", "--scenario", "region", "--ships",
                                      str(a.ships), "--radars", str(a.radars), "--seed",
                                      str(a.seed), "--duration", a.duration, "--start", START,
                                      "--out", str(archive)]))
        marker.write_text(json.dumps(params))
    config = str(archive / "region.toml")
    files = sorted(str(p) for p in archive.glob("*.mcap"))
    shutil.rmtree(wh, ignore_errors=True)
    base = ["--config", config, "--warehouse", str(wh)]
    from pipeline.simulate import DEFAULT_START_NS

    end_ns = DEFAULT_START_NS + int(duration_s * NS)
    window = ["--from", str(DEFAULT_START_NS), "--to", str(end_ns)]
    day = []
    probes = {"ingest": probe()}
    day.append(run("ingest", [*base, "ingest", "--executor", a.executor, *files]))
    probes["batch"] = probe()
    day.append(run("batch", [*base, "batch", "--executor", a.executor, *window]))
    names = [ln.split()[0] for ln in run("list", [*base, "report", "--list"])["stdout"]
             .splitlines() if ln.strip()]
    probes["reports"] = probe()
    t0 = time.perf_counter()
    reports = [run(f"report {n}", [*base, "report", n, *window, "--format", "csv"],
                   fatal=False) for n in names]
    day.append({"step": f"reports ({len(names)})", "wall_s": time.perf_counter() - t0,
                "cpu_s": sum(r["cpu_s"] for r in reports),
                "peak_rss_mb": max(r["peak_rss_mb"] for r in reports),
                "peak_driver_mb": max(r["peak_driver_mb"] for r in reports),
                "peak_worker_mb": max(r["peak_worker_mb"] for r in reports), "stdout": ""})
    # a one-hour reprocess in the middle of the day (files re-ingested, window re-batched)
    mid = DEFAULT_START_NS + int(min(12 * 3600, duration_s / 2) // 3600 * 3600 * NS)
    hour = ["--from", str(mid), "--to", str(mid + 3600 * NS)]
    probes["reprocess 1 h"] = probe()
    reprocess = run("reprocess 1 h", [*base, "reprocess", "--executor", a.executor, *hour])

    ingested = rows_of(day[0]["stdout"])
    batched = rows_of(day[1]["stdout"])
    records = sum(v for k, v in ingested.items() if k != "rejects")
    total = sum(s["wall_s"] for s in day)
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}; region {a.ships} ships x {a.radars} radars, "
          f"{a.duration}, seed {a.seed}; executor {a.executor}")
    print(f"records: {records:,} ingested (radar_tracks {ingested.get('radar_tracks', 0):,}, "
          f"ais_reports {ingested.get('ais_reports', 0):,}, truth {ingested.get('truth', 0):,});"
          f" derived rows {sum(batched.values()):,}")
    print(f"{'step':<16}{'wall s':>9}{'CPU s':>9}{'records/s':>13}{'peak RSS MB':>13}"
          f"{'driver MB':>11}{'peak worker MB':>16}{'CPU probe s':>13}")
    for s in [*steps, *day, reprocess]:
        n = records if s["step"] in ("ingest", "batch") else 0
        rate = f"{n / s['wall_s']:,.0f}" if n else ""
        p = probes.get(s["step"].split(" (")[0])
        s["cpu_probe_s"] = p["cpu_s"] if p else None
        speed = f"{p['cpu_s']:.2f}" if p else ""
        print(f"{s['step']:<16}{s['wall_s']:>9.1f}{s['cpu_s']:>9.1f}{rate:>13}"
              f"{s['peak_rss_mb']:>13.0f}{s['peak_driver_mb']:>11.0f}"
              f"{s['peak_worker_mb']:>16.0f}{speed:>13}")
    peak = max(s["peak_rss_mb"] for s in day)
    print(f"day (ingest + batch + reports): {total:.0f} s = {total / 60:.1f} min "
          f"(goal <= 15 min); peak RSS {peak / 1024:.2f} GB (goal <= 4), largest worker "
          f"{max(s['peak_worker_mb'] for s in day) / 1024:.2f} GB (goal <= 2 per worker), "
          f"driver {max(s['peak_driver_mb'] for s in day) / 1024:.2f} GB")
    for r in reports:
        if r["failed"]:
            print(f"{r['step']} failed after {r['wall_s']:.0f} s: {r['failed']}")
    print(f"1-hour reprocess: {reprocess['wall_s']:.0f} s = 1/{total / reprocess['wall_s']:.0f}"
          f" of the day (goal <= 1/20)")
    if a.json:
        for s in [*steps, *day, *reports, reprocess]:
            s.pop("stdout", None)
        Path(a.json).write_text(json.dumps({
            "params": params, "records": records, "ingested": ingested, "derived": batched,
            "steps": [*steps, *day], "reports": reports, "reprocess_1h": reprocess,
            "day_wall_s": total,
            "day_peak_rss_mb": peak, "reprocess_fraction_of_day": reprocess["wall_s"] / total,
        }, indent=2))


if __name__ == "__main__":
    main()
