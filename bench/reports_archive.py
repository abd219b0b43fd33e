"""Reports over a long archive: every report over 1 hour, 1 day and 7 days, in a 1-day and
a 7-day warehouse of the regional scenario (issue 34, item 3).

    .venv/bin/python bench/reports_archive.py --day DIR --config FILE [--days 7]
        [--workdir DIR] [--json FILE] [--reports a,b,...]

``--day`` is a warehouse holding one batched day (``bench/region_day.py`` leaves one in its
workdir, ``wh/``, with the archive's ``region.toml`` as ``--config``). The 7-day warehouse
is that day's every table copied ``--days`` times, each copy's times (every ``*_ns``
column holding absolute times, the ``date`` partition) shifted by one more day: the same
density and layout as a week of the same traffic, built in minutes instead of a week of
simulation; it is made once and reused (``<workdir>/wh7``, a marker file says from what).

Each report runs as ``surveil report NAME --format csv`` in its own process, as an
analyst's command would: wall and CPU seconds (the process and its children), over

- 1 hour (12:00-13:00 of the first day) in the 1-day and in the 7-day warehouse: the goal
  is about the same cost (row-group and partition pruning: a longer archive must not make
  an hour's report slower);
- the first day, in both (goal: the 16 reports <= 60 s in all over a day);
- the whole week, in the 7-day warehouse.
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
import time
from pathlib import Path
from urllib.parse import unquote

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

DAY_NS = 86_400 * 10**9
HOUR_NS = 3_600 * 10**9
ABSOLUTE_NS = 10**18  # ns after 2001-09-09: a column whose values all are is a time


def shifted_copy(day: Path, out: Path, days: int) -> dict[str, int]:
    """Every table of warehouse ``day`` copied into ``out`` ``days`` times, copy k's
    absolute times shifted by k days; rows per table written."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq
    from deltalake import DeltaTable, write_deltalake

    from pipeline.tables import spec
    from pipeline.warehouse.views import rebuild_views_file

    written: dict[str, int] = {}
    for folder in sorted((day / "tables").iterdir()):
        if not (folder / "_delta_log").is_dir():
            continue
        name = folder.name
        source = DeltaTable(str(folder))
        partitions = source.metadata().partition_columns
        files = [unquote(u).removeprefix("file://") for u in source.file_uris()]
        target = str(out / "tables" / name)
        written[name] = 0
        for path in files:
            table = pq.read_table(path)
            times = [f.name for f in table.schema if f.name.endswith("_ns")
                     and pa.types.is_integer(f.type) and table.num_rows
                     and (pc.min(table[f.name]).as_py() or 0) > ABSOLUTE_NS]
            for k in range(days):
                part = table
                for col in times:
                    i = part.schema.get_field_index(col)
                    part = part.set_column(i, col, pc.add(part[col], k * DAY_NS))
                if "date" in partitions:
                    t = spec(name).time_column
                    date = pc.cast(pc.cast(part[t], pa.timestamp("ns")), pa.date32())
                    part = part.append_column("date", date)
                write_deltalake(target, part, mode="append",
                                partition_by=partitions or None)
                written[name] += part.num_rows
    rebuild_views_file(out)
    return written


def run_report(config: str, warehouse: Path, name: str, start_ns: int, end_ns: int) -> dict:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "jobs.cli", "--config", config, "--warehouse", str(warehouse),
         "report", name, "--from", str(start_ns), "--to", str(end_ns), "--format", "csv"],
        capture_output=True, text=True, cwd=REPO)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    rows = max(0, proc.stdout.count("\n") - 1)
    return {"wall_s": wall, "cpu_s": cpu, "rows": rows, "rc": proc.returncode,
            "error": proc.stderr.strip().splitlines()[-1] if proc.returncode else ""}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--day", required=True, help="a warehouse holding one batched day")
    ap.add_argument("--config", required=True, help="its config (region.toml)")
    ap.add_argument("--days", type=int, default=7)
    ap.add_argument("--workdir", default="/tmp/surveil-bench-reports")
    ap.add_argument("--reports", default="", help="comma-separated (default: every report)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()

    from pipeline.simulate import DEFAULT_START_NS

    day, work = Path(a.day).resolve(), Path(a.workdir)
    week = work / f"wh{a.days}"
    marker = week / ".built-from.json"
    params = {"day": str(day), "days": a.days,
              "day_mtime": max(p.stat().st_mtime for p in (day / "tables").rglob("*.json"))}
    if not marker.exists() or json.loads(marker.read_text()) != params:
        shutil.rmtree(week, ignore_errors=True)
        t0 = time.perf_counter()
        rows = shifted_copy(day, week, a.days)
        print(f"built {week}: {sum(rows.values()):,} rows in "
              f"{time.perf_counter() - t0:.0f} s", flush=True)
        marker.write_text(json.dumps(params))
    names = [n for n in a.reports.split(",") if n] or [
        ln.split()[0] for ln in subprocess.run(
            [sys.executable, "-m", "jobs.cli", "--config", a.config, "report", "--list"],
            capture_output=True, text=True, cwd=REPO, check=True).stdout.splitlines()
        if ln.strip()]
    hour = (DEFAULT_START_NS + 12 * HOUR_NS, DEFAULT_START_NS + 13 * HOUR_NS)
    first_day = (DEFAULT_START_NS, DEFAULT_START_NS + DAY_NS)
    whole = (DEFAULT_START_NS, DEFAULT_START_NS + a.days * DAY_NS)
    cases = {"1h@1d": (day, hour), f"1h@{a.days}d": (week, hour),
             "1d@1d": (day, first_day), f"1d@{a.days}d": (week, first_day),
             f"{a.days}d@{a.days}d": (week, whole)}
    results: dict[str, dict[str, dict]] = {}
    for n in names:
        results[n] = {c: run_report(a.config, wh, n, *w) for c, (wh, w) in cases.items()}
        print(n, {c: round(r["wall_s"], 2) for c, r in results[n].items()}, flush=True)
    print(f"\nmachine: {platform.machine()}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}; wall s per report (rows)")
    head = "".join(f"{c:>16}" for c in cases)
    print(f"{'report':<28}{head}{f'1h {a.days}d/1d':>10}")
    for n, by in results.items():
        cells = "".join(f"{by[c]['wall_s']:>9.2f} ({by[c]['rows']:>4})"
                        if not by[c]["rc"] else f"{'FAILED':>16}" for c in cases)
        ratio = by[f"1h@{a.days}d"]["wall_s"] / by["1h@1d"]["wall_s"]
        print(f"{n:<28}{cells}{ratio:>10.2f}")
    totals = {c: sum(by[c]["wall_s"] for by in results.values()) for c in cases}
    print(f"{'all ' + str(len(results)):<28}" + "".join(f"{totals[c]:>16.1f}" for c in cases)
          + f"{totals[f'1h@{a.days}d'] / totals['1h@1d']:>10.2f}")
    print(f"goals: 1-hour reports in the {a.days}-day warehouse ~ the 1-day one "
          f"(x{totals[f'1h@{a.days}d'] / totals['1h@1d']:.2f}); all reports over a day "
          f"<= 60 s ({totals['1d@1d']:.1f} s in the 1-day warehouse, "
          f"{totals[f'1d@{a.days}d']:.1f} s in the {a.days}-day one)")
    if a.json:
        Path(a.json).write_text(json.dumps({"params": params, "results": results,
                                            "totals_wall_s": totals}, indent=2))


if __name__ == "__main__":
    main()
