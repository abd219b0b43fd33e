"""Reports over a long archive: every report over 1 hour, 1 day and 7 days, in a 1-day and
a 7-day warehouse of the regional scenario (issue 34, item 3).

    .venv/bin/python bench/reports_archive.py --day DIR --config FILE [--days 7]
        [--workdir DIR] [--json FILE] [--reports a,b,...] [--cases ...] [--merge FILE]
        [--outputs DIR]

``--day`` is a warehouse holding one batched day (``bench/region_day.py`` leaves one in its
workdir, ``wh/``, with the archive's ``region.toml`` as ``--config``). The 7-day warehouse
is that day's every table copied ``--days`` times, each copy's times (every ``*_ns``
column holding absolute times, the ``date`` partition) shifted by one more day: the same
density and file layout (row groups, statistics) as a week of the same traffic, built in
minutes instead of a week of simulation; it is made once and reused
(``<workdir>/wh7``, a marker file says from what).

Each report runs as ``surveil report NAME --format csv`` in its own process, as an
analyst's command would: wall and CPU seconds (the process and its children), over

- 1 hour (12:00-13:00 of the first day) in the 1-day and in the 7-day warehouse: the goal
  is about the same cost (row-group and partition pruning: a longer archive must not make
  an hour's report slower);
- the first day, in both (goal: the 16 reports <= 60 s in all over a day);
- the whole week, in the 7-day warehouse.

``--cases`` runs some of these (7d@7d costs about as much as the others together);
``--merge FILE`` shows an earlier run's cases (its ``--json``) beside this run's. The
CSV of one window must be the same in both warehouses: the bench says which differ.
Figures: docs/scale.md, "Reports over a long archive".
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from urllib.parse import unquote

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from deltalake import DeltaTable
from deltalake.transaction import AddAction, create_table_with_add_actions

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

DAY_NS = 86_400 * 10**9
HOUR_NS = 3_600 * 10**9
ABSOLUTE_NS = 10**18  # ns after 2001-09-09: a column whose values all are is a time


def shifted_copy(day: Path, out: Path, days: int, tables: set[str]) -> dict[str, int]:
    """Every table of warehouse ``day`` copied into ``out``, those of ``tables`` ``days``
    times, copy k's absolute times (and ``date`` partition) shifted by k days, the others
    once (hard links: radar_tracks and the ledgers, read by no report, a quarter of a
    day's bytes); rows per table.

    The layout is the day's: each data file is rewritten row group by row group (same
    row groups, codec and dictionary columns; copy 0 is a hard link of the file), so
    the statistics a reader prunes by are those of the pipeline's files; each table is
    then one Delta commit of every copy's files (statistics from each file's footer, as
    the pipeline's commits carry) and a checkpoint, as a long-lived table has."""
    from pipeline.warehouse.views import rebuild_views_file

    written: dict[str, int] = {}
    with ProcessPoolExecutor(2) as pool:
        for folder in sorted((day / "tables").iterdir()):
            if not (folder / "_delta_log").is_dir():
                continue
            source = DeltaTable(str(folder))
            partitions = source.metadata().partition_columns
            target = out / "tables" / folder.name
            copies = []
            for uri in source.file_uris():
                path = Path(unquote(uri).removeprefix("file://"))
                for k in range(days if folder.name in tables else 1):
                    dest, values = _shifted_path(target, path.relative_to(folder), k)
                    copies.append((path, dest, k * DAY_NS, values))
            if not copies:
                continue
            list(pool.map(_copy_file, *zip(*[c[:3] for c in copies], strict=True)))
            adds = [_add_action(dest, target, values) for _, dest, _, values in copies]
            create_table_with_add_actions(str(target), source.schema(), adds,
                                          partition_by=partitions or None)
            DeltaTable(str(target)).create_checkpoint()
            written[folder.name] = sum(json.loads(a.stats)["numRecords"] for a in adds)
    rebuild_views_file(out)
    return written


def _shifted_path(table: Path, rel: Path, k: int) -> tuple[Path, dict[str, str | None]]:
    """Where copy ``k`` of data file ``rel`` goes, and its partition values (a
    ``date=YYYY-MM-DD`` folder moved by ``k`` days)."""
    import datetime as dt

    values: dict[str, str | None] = {}
    parts = []
    for part in rel.parts[:-1]:
        key, _, value = part.partition("=")
        if key == "date":
            value = (dt.date.fromisoformat(value) + dt.timedelta(days=k)).isoformat()
        values[key] = value
        parts.append(f"{key}={value}")
    return table.joinpath(*parts, f"copy{k}-{rel.name}"), values


def _copy_file(path: Path, dest: Path, shift_ns: int) -> None:
    """``path`` as ``dest`` with every absolute time column (``*_ns``, integer, its
    smallest value after 2001) moved by ``shift_ns``, row group by row group."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    if shift_ns == 0:
        os.link(path, dest)
        return
    md = pq.read_metadata(path)
    strings = [md.schema.column(i).name for i in range(md.num_columns)
               if md.schema.column(i).logical_type.type == "STRING"]
    src = pq.ParquetFile(path, read_dictionary=strings)
    schema = src.schema_arrow
    times = [f.name for f in schema if f.name.endswith("_ns") and pa.types.is_integer(f.type)
             and _smallest(md, schema.get_field_index(f.name)) > ABSOLUTE_NS]
    codec = md.row_group(0).column(0).compression if md.num_row_groups else "ZSTD"
    with pq.ParquetWriter(dest, schema, compression=codec) as writer:
        for g in range(md.num_row_groups):
            group = src.read_row_group(g)
            for col in times:
                i = group.schema.get_field_index(col)
                group = group.set_column(i, schema.field(i),
                                         pc.add(group[col], pa.scalar(shift_ns, pa.int64())))
            writer.write_table(group, row_group_size=group.num_rows)


def _smallest(md: pq.FileMetaData, column: int) -> int:
    """The smallest value of an integer column over a file's row groups (footer
    statistics; 0 when none has any)."""
    lows = [s.min for g in range(md.num_row_groups)
            if (s := md.row_group(g).column(column).statistics) is not None and s.has_min_max]
    return min(lows, default=0)


def _add_action(dest: Path, table: Path, values: dict[str, str | None]) -> AddAction:
    """The Delta Add action of data file ``dest`` of ``table``, its statistics from
    its footer (as the pipeline's staged commits carry them)."""
    from pipeline.warehouse.staged import _footer_stats, _stats_json

    md = pq.read_metadata(dest)
    names = [md.schema.column(i).name for i in range(md.num_columns)
             if md.schema.column(i).physical_type != "BYTE_ARRAY"
             or md.schema.column(i).logical_type.type == "STRING"]
    return AddAction(str(dest.relative_to(table)), dest.stat().st_size, values,
                     int(time.time() * 1000), True,
                     _stats_json(md.num_rows, _footer_stats(md, names)))


def run_report(config: str, warehouse: Path, name: str, start_ns: int, end_ns: int,
               keep: Path | None = None) -> dict:
    """``surveil report NAME --format csv`` over ``[start_ns, end_ns)``: wall and CPU
    seconds (the process and its children), rows; the CSV written to ``keep`` when given
    (to compare a report's output before and after a change)."""
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
    if keep is not None:
        keep.parent.mkdir(parents=True, exist_ok=True)
        keep.write_text(proc.stdout)
    return {"wall_s": wall, "cpu_s": cpu, "rows": rows, "rc": proc.returncode,
            "csv_sha256": hashlib.sha256(proc.stdout.encode()).hexdigest()[:16],
            "error": proc.stderr.strip().splitlines()[-1] if proc.returncode else ""}


def print_table(results: dict[str, dict[str, dict]], cases: list[str], days: int) -> None:
    """Wall and CPU seconds per report and case, the sums, and the goals of the cases
    measured."""
    one, many = "1h@1d", f"1h@{days}d"
    print(f"{'report':<27}" + "".join(f"{c:>16}" for c in cases) + f"{f'1h {days}d/1d':>9}")
    print(f"{'':<27}" + f"{'wall   CPU':>16}" * len(cases) + f"{'CPU':>9}")
    for n, by in results.items():
        cells = "".join(f"{by[c]['wall_s']:>9.2f}{by[c]['cpu_s']:>7.2f}" if not by[c]["rc"]
                        else f"{'FAILED':>16}" for c in cases)
        print(f"{n:<27}{cells}{_ratio(by[many], by[one]) if many in by and one in by else '':>9}")
    total = {c: {k: sum(by[c][k] for by in results.values()) for k in ("wall_s", "cpu_s")}
             for c in cases}
    print(f"{'all ' + str(len(results)):<27}"
          + "".join(f"{total[c]['wall_s']:>9.1f}{total[c]['cpu_s']:>7.1f}" for c in cases)
          + (f"{_ratio(total[many], total[one]):>9}" if many in total and one in total else ""))
    failed = [f"{n} ({c}: {by[c]['error']})" for n, by in results.items() for c in cases
              if by[c]["rc"]]
    if failed:
        print("FAILED: " + "; ".join(failed))
    # the same window over the same rows: a report's CSV must not depend on the archive's
    # length (one that does reads outside its window)
    pairs = [(c, c.replace("@1d", f"@{days}d")) for c in (one, "1d@1d")
             if c in total and c.replace("@1d", f"@{days}d") in total]
    differ = [f"{n} ({c})" for n, by in results.items() for c, d in pairs
              if by[c]["csv_sha256"] != by[d]["csv_sha256"]]
    if pairs:
        print("output of the same window in both warehouses: " + (
            "identical for every report" if not differ else "differs for " + ", ".join(differ)))
    if many in total and one in total:
        print(f"goal: the 1-hour reports in the {days}-day warehouse cost about what they "
              f"cost in the 1-day one: CPU x{_ratio(total[many], total[one])}, wall "
              f"x{total[many]['wall_s'] / total[one]['wall_s']:.2f}")
    for c in ("1d@1d", f"1d@{days}d"):
        if c in total:
            print(f"goal: all reports over a day <= 60 s ({c}): {total[c]['wall_s']:.1f} s "
                  f"wall, {total[c]['cpu_s']:.1f} CPU-s")


def _ratio(a: dict, b: dict) -> str:
    return f"{a['cpu_s'] / b['cpu_s']:.2f}" if b["cpu_s"] else "-"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--day", required=True, help="a warehouse holding one batched day")
    ap.add_argument("--config", required=True, help="its config (region.toml)")
    ap.add_argument("--days", type=int, default=7)
    ap.add_argument("--workdir", default="/tmp/surveil-bench-reports")
    ap.add_argument("--reports", default="", help="comma-separated (default: every report)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--cases", default="",
                    help="comma-separated, of 1h@1d,1h@7d,1d@1d,1d@7d,7d@7d (default: all; "
                         "7d@7d costs about as much as the others together)")
    ap.add_argument("--merge", default=None,
                    help="the --json of an earlier run: its cases shown beside this run's")
    ap.add_argument("--outputs", default=None,
                    help="a folder: each report's CSV kept as <case>/<report>.csv")
    a = ap.parse_args()

    from pipeline.reports import load_report
    from pipeline.simulate import DEFAULT_START_NS

    day, work = Path(a.day).resolve(), Path(a.workdir)
    week = work / f"wh{a.days}"
    every = [ln.split()[0] for ln in subprocess.run(
        [sys.executable, "-m", "jobs.cli", "--config", a.config, "report", "--list"],
        capture_output=True, text=True, cwd=REPO, check=True).stdout.splitlines() if ln.strip()]
    names = [n for n in a.reports.split(",") if n] or every
    tables = sorted({t for n in every for t in load_report(n).tables_used()})
    marker = week / ".built-from.json"
    params = {"day": str(day), "days": a.days, "tables": tables,
              "day_mtime": max(p.stat().st_mtime for p in (day / "tables").rglob("*.json"))}
    if not marker.exists() or json.loads(marker.read_text()) != params:
        shutil.rmtree(week, ignore_errors=True)
        t0 = time.perf_counter()
        rows = shifted_copy(day, week, a.days, set(tables))
        print(f"built {week}: {sum(rows.values()):,} rows of {len(rows)} tables in "
              f"{time.perf_counter() - t0:.0f} s", flush=True)
        marker.write_text(json.dumps(params))
    hour = (DEFAULT_START_NS + 12 * HOUR_NS, DEFAULT_START_NS + 13 * HOUR_NS)
    first_day = (DEFAULT_START_NS, DEFAULT_START_NS + DAY_NS)
    whole = (DEFAULT_START_NS, DEFAULT_START_NS + a.days * DAY_NS)
    cases = {"1h@1d": (day, hour), f"1h@{a.days}d": (week, hour),
             "1d@1d": (day, first_day), f"1d@{a.days}d": (week, first_day),
             f"{a.days}d@{a.days}d": (week, whole)}
    if a.cases:
        cases = {c: w for c, w in cases.items() if c in a.cases.split(",")}
    results: dict[str, dict[str, dict]] = {}
    outputs = Path(a.outputs) if a.outputs else None
    for n in names:
        results[n] = {c: run_report(a.config, wh, n, *w,
                                    keep=outputs / c / f"{n}.csv" if outputs else None)
                      for c, (wh, w) in cases.items()}
        print(n, {c: (round(r["wall_s"], 2), round(r["cpu_s"], 2))
                  for c, r in results[n].items()}, flush=True)
        if a.json:  # after every report: a run stopped early keeps what it measured
            Path(a.json).write_text(json.dumps({"params": params, "cases": {
                c: {"warehouse": str(wh), "start_ns": w[0], "end_ns": w[1]}
                for c, (wh, w) in cases.items()}, "results": results,
                "load_average_1min": os.getloadavg()[0]}, indent=2))
    shown = list(cases)
    if a.merge:  # an earlier run's cases (e.g. 7d@7d alone), this run's taking precedence
        earlier = json.loads(Path(a.merge).read_text())["results"]
        for n in results:
            results[n] = {**earlier.get(n, {}), **results[n]}
        order = ["1h@1d", f"1h@{a.days}d", "1d@1d", f"1d@{a.days}d", f"{a.days}d@{a.days}d"]
        shown = [c for c in order if all(c in by for by in results.values())]
    print(f"\nmachine: {platform.machine()}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}, load average {os.getloadavg()[0]:.1f} at the end; "
          f"seconds per report (wall, CPU of the command); the last column is CPU of the "
          f"1-hour report in the {a.days}-day warehouse over the 1-day one")
    print_table(results, shown, a.days)


if __name__ == "__main__":
    main()
