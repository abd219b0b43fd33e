"""Crash trials: SIGKILL real `surveil` subprocesses at seeded random points and check
what readers see.

    .venv/bin/python bench/crash.py [--trials 50] [--seed 1] [--workdir DIR]
                                    [--commands ingest,batch,reprocess,run]
                                    [--at random|commit|both]

Setup: a 10-minute `channel` archive (one file: ingest commits file by file, so one
file makes its old and new states the only two), a warehouse made by `surveil run` over
it (the *base*), and a config whose change alters every derived
table (epoch period 4 -> 5 s). Each command's *old* and *new* states are measured by
running it to completion on a copy:

==========  ==============================  ========================================
command     old state                       new state
==========  ==============================  ========================================
ingest      empty warehouse                 the archive ingested
run         empty warehouse                 ingested and batched (+ a runs row);
                                            between: the file ingested, not batched
batch       base                            the window batched with the changed config
reprocess   base                            a sub-window reprocessed, changed config
==========  ==============================  ========================================

A trial copies the old state, starts the command in its own process group, SIGKILLs the
group at a uniform random point of the command's measured duration (``--at random``) or
in the 0.3 s after the command's first pending marker appears, i.e. while it commits
table after table (``--at commit``; ``both`` alternates), then checks, as a reader sees
them (``read_table``: pending markers honoured):

- each table equals exactly its old or its new rows (as multisets; wall-clock columns
  dropped); otherwise the rows missing from the nearer state are *lost* and rows present
  more often than in either state are *duplicated*;
- whether the tables of the trial are all old, all new, or a mix across tables;
- that the reports run (``accuracy_by_sector``, ``siap_by_sector``);
- that re-running the command to completion converges to the new state exactly;
- for comparison, what a reader that ignores the pending markers would see (each
  table's latest Delta version: how readers read before the markers): whether that is
  a mix across tables.

Prints one line per trial and the totals: trials, kills, states seen, tables neither
old nor new, rows lost, rows duplicated, reports failing, re-runs not converged.
No thresholds: numbers to read (the goal is 0 lost, 0 duplicated).
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import polars as pl

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from jobs.common import iso  # noqa: E402
from jobs.simulate import run_simulate  # noqa: E402
from pipeline.families import load_config  # noqa: E402
from pipeline.reports import run_named_report  # noqa: E402
from pipeline.tables import table_specs  # noqa: E402
from pipeline.units import NS  # noqa: E402
from pipeline.warehouse.delta import read_table  # noqa: E402

START_NS = 1_768_438_200 * NS  # 2026-01-15T00:50:00Z
DURATION_S = 600.0
WALL_CLOCK = {"ingest_ledger": ["ingested_at_ns"], "batch_units": ["committed_at_ns"],
              "source_overlaps": ["detected_at_ns"]}
SKIP = {"runs"}  # one row per run, by wall clock: not a state


def state(warehouse: Path) -> dict[str, pl.DataFrame]:
    """Every table as a reader sees it, as a row -> count multiset frame."""
    out = {}
    for name in table_specs():
        if name in SKIP:
            continue
        t = pl.from_arrow(read_table(warehouse, name))
        t = t.drop([c for c in WALL_CLOCK.get(name, []) if c in t.columns])
        cols = [c for c in t.columns if t.schema[c] != pl.Binary]
        t = t.select(cols)
        out[name] = (t.group_by(cols).agg(pl.len().alias("_n")).sort(cols) if t.height
                     else pl.DataFrame())
    return out


def _same(a: pl.DataFrame, b: pl.DataFrame) -> bool:
    """Equal multisets of rows (NaN equal to NaN, as in a join)."""
    if a.height == 0 or b.height == 0:
        return a.height == b.height
    return a.height == b.height and _diff(a, b) == (0, 0)


def _diff(now: pl.DataFrame, ref: pl.DataFrame) -> tuple[int, int]:
    """(rows of ``ref`` missing from ``now``, rows of ``now`` beyond ``ref``)."""
    if ref.height == 0:
        return 0, int(now["_n"].sum()) if now.height else 0
    if now.height == 0:
        return int(ref["_n"].sum()), 0
    keys = [c for c in ref.columns if c != "_n"]
    j = ref.join(now, on=keys, how="full", coalesce=True, suffix="_now", nulls_equal=True)
    j = j.with_columns(pl.col("_n").fill_null(0), pl.col("_n_now").fill_null(0))
    lost = int((j["_n"] - j["_n_now"]).clip(lower_bound=0).sum())
    extra = int((j["_n_now"] - j["_n"]).clip(lower_bound=0).sum())
    return lost, extra


def cli(config: Path, warehouse: Path, *args: str, executor: str) -> list[str]:
    return [sys.executable, "-m", "jobs.cli", "--config", str(config), "--warehouse",
            str(warehouse), *args, *(("--executor", executor) if args[0] != "sql" else ())]


def run_to_end(cmd: list[str]) -> float:
    t0 = time.monotonic()
    res = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, check=False)
    if res.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(cmd)} failed ({res.returncode}):\n{res.stderr}")
    return time.monotonic() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workdir", type=Path, default=None)
    ap.add_argument("--commands", default="ingest,batch,reprocess,run")
    ap.add_argument("--executor", default="serial", choices=["serial", "process"])
    ap.add_argument("--at", default="random", choices=["random", "commit", "both"],
                    help="kill points: uniform over the command's duration (random), in "
                         "the first 0.3 s after a pending marker appears, i.e. between "
                         "table commits (commit), or alternately (both)")
    a = ap.parse_args()
    work = a.workdir or Path(tempfile.mkdtemp(prefix="surveil-crash-"))
    work.mkdir(parents=True, exist_ok=True)
    cfg = load_config()
    default = Path(cfg.source)
    changed = work / "changed.toml"
    changed.write_text(default.read_text().replace("epoch_period_s = 4.0",
                                                   "epoch_period_s = 5.0"))
    archive = work / "archive"
    if not archive.exists():
        run_simulate("channel", DURATION_S, 7, archive, cfg, start_ns=START_NS)
    end_ns = START_NS + int(DURATION_S * NS)
    window = ("--from", iso(START_NS), "--to", iso(end_ns))
    sub = ("--from", iso(START_NS + 200 * NS), "--to", iso(START_NS + 400 * NS))
    base = work / "base"
    if not base.exists():
        run_to_end(cli(default, base, "run", str(archive), executor=a.executor))
    commands = {
        "ingest": (None, default, ("ingest", str(archive))),
        "run": (None, default, ("run", str(archive))),
        "batch": (base, changed, ("batch", *window)),
        "reprocess": (base, changed, ("reprocess", *sub)),
    }
    chosen = [c for c in a.commands.split(",") if c]
    old, new, duration = {}, {}, {}
    measure = ["ingest", *chosen] if "run" in chosen and "ingest" not in chosen else chosen
    for name in measure:
        start, config, args = commands[name]
        wh = work / f"new-{name}"
        shutil.rmtree(wh, ignore_errors=True)
        if start is not None:
            shutil.copytree(start, wh)
        old[name] = state(start) if start is not None else state(work / "nothing")
        duration[name] = run_to_end(cli(config, wh, *args, executor=a.executor))
        new[name] = state(wh)
        print(f"{name:<10} runs {duration[name]:5.1f} s to the end", flush=True)

    rng = random.Random(a.seed)
    totals: Counter = Counter()
    states: Counter = Counter()
    for trial in range(a.trials):
        name = chosen[trial % len(chosen)]
        start, config, args = commands[name]
        wh = work / "trial"
        shutil.rmtree(wh, ignore_errors=True)
        if start is not None:
            shutil.copytree(start, wh)
        mode = a.at if a.at != "both" else ("random", "commit")[trial % 2]
        at = rng.uniform(0.02, 1.0) * duration[name]
        delay = rng.uniform(0.0, 0.3)
        t0 = time.monotonic()
        proc = subprocess.Popen(cli(config, wh, *args, executor=a.executor), cwd=REPO,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                start_new_session=True)
        if mode == "random":
            time.sleep(at)
        else:  # wait for a job to start committing (its pending marker), then a moment
            marker_dir = wh / "_pending"
            while proc.poll() is None and not marker_dir.exists():
                time.sleep(0.002)
            time.sleep(delay)
            at = time.monotonic() - t0
        killed = proc.poll() is None
        if killed:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        totals["kills"] += killed
        now = state(wh)
        lost, dup, neither = 0, 0, 0
        candidates = {"old": old[name], "new": new[name]}
        if name == "run":  # the file ingested, its batch not committed
            candidates["ingested"] = new["ingest"]
        whole = [k for k, st in candidates.items()
                 if all(_same(now[t], st[t]) for t in now)]
        if whole:  # the whole warehouse is one state ("new" first when old == new)
            label = "new" if "new" in whole else whole[0]
        else:
            kinds = set()
            for table, rows in now.items():
                match = [k for k, st in candidates.items() if _same(rows, st[table])]
                if match:
                    kinds.add(match[0] if len(match) == 1 else "/".join(sorted(match)))
                    continue
                neither += 1
                kinds.add("neither")
                lo, xo = _diff(rows, old[name][table])
                ln, xn = _diff(rows, new[name][table])
                lost += min(lo, ln)
                dup += min(xo, xn)
            label = "mixed(" + ",".join(sorted(kinds)) + ")"
        states[f"{name}:{label}"] += 1
        unpinned = work / "unpinned"  # the same warehouse read without its markers
        shutil.rmtree(unpinned, ignore_errors=True)
        if wh.exists():
            shutil.copytree(wh, unpinned)
        shutil.rmtree(unpinned / "_pending", ignore_errors=True)
        raw = state(unpinned)
        totals["mixed without markers"] += not any(
            all(_same(r, st[t]) for t, r in raw.items()) for st in candidates.values())
        reports_ok = True
        for report in ("accuracy_by_sector", "siap_by_sector"):
            try:
                run_named_report(wh, report)
            except Exception:  # counted and printed
                reports_ok = False
        run_to_end(cli(config, wh, *args, executor=a.executor))
        converged = all(_same(r, new[name][t]) for t, r in state(wh).items())
        totals["trials"] += 1
        totals["tables neither old nor new"] += neither
        totals["rows lost"] += lost
        totals["rows duplicated"] += dup
        totals["mixed across tables"] += label.startswith("mixed")
        totals["reports failing"] += not reports_ok
        totals["re-runs not converged"] += not converged
        print(f"trial {trial + 1:>3} {name:<10} {mode:<6} kill at {at:5.1f} s "
              f"{'(killed)' if killed else '(done)  '} state {label:<10} "
              f"neither {neither} lost {lost} dup {dup} reports "
              f"{'ok' if reports_ok else 'FAIL'} re-run {'ok' if converged else 'DIFF'}",
              flush=True)
    print("\ntotals:")
    for key in ("trials", "kills", "tables neither old nor new", "mixed across tables",
                "mixed without markers",
                "rows lost", "rows duplicated", "reports failing", "re-runs not converged"):
        print(f"  {key:<28} {totals[key]}")
    print("  states seen (command:state, all tables of a trial):")
    for key, n in sorted(states.items()):
        print(f"    {key:<24} {n}")
    print(f"workdir: {work}")


if __name__ == "__main__":
    main()
