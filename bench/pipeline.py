"""End-to-end pipeline benchmark on the simulated `channel` scenario.

    .venv/bin/python bench/pipeline.py [--duration 1h] [--seed 7] [--workdir DIR]

Runs each stage in its own subprocess (so peak RSS is per stage) and prints wall time,
throughput and peak memory: simulate -> MCAP, ingest -> Delta, batch -> derived tables,
the two spine reports. In the same run it measures a baseline for ingest: the plain
`mcap` reader with `iter_decoded_messages` + `json.loads` + `pa.Table.from_pylist` +
Parquet for the radar channels, and prints our ingest's ratio to it; for batch it prints
the real-time factor (hours of log per hour of wall time) and fused track-epochs/s.
No thresholds: numbers to read, not asserts.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

STAGE = textwrap.dedent(
    """
    import json, resource, sys, time
    from pathlib import Path
    stage, args = sys.argv[1], json.loads(sys.argv[2])
    t0 = time.perf_counter()
    out = {}
    if stage == "simulate":
        from jobs.simulate import run_simulate
        from pipeline.families import load_config
        files = run_simulate("channel", args["duration_s"], args["seed"], Path(args["archive"]),
                             load_config(), start_ns=args["start_ns"])
        out["files"] = [str(f) for f in files]
    elif stage == "ingest":
        from pipeline.ingest.driver import run_ingest
        from pipeline.families import load_config
        s = run_ingest([Path(f) for f in args["files"]], load_config(), Path(args["warehouse"]),
                       executor=args["executor"])
        out["messages"] = s.messages_read
        out["rows"] = dict(s.rows)
    elif stage == "batch":
        from jobs.batch import run_batch
        from pipeline.families import load_config
        s = run_batch(load_config(), Path(args["warehouse"]), start_ns=args["start_ns"],
                      end_ns=args["end_ns"], executor_kind=args["executor"])
        out["rows"] = dict(s.rows)
    elif stage == "report":
        from pipeline.reports import run_named_report
        for name in ("accuracy_by_sector", "identification_by_sector"):
            run_named_report(Path(args["warehouse"]), name)
    elif stage == "baseline":
        import pyarrow as pa, pyarrow.parquet as pq
        from mcap.reader import make_reader
        from mcap.decoder import DecoderFactory as _Unused  # noqa: F401
        rows, n = [], 0
        for f in args["files"]:
            with open(f, "rb") as fh:
                reader = make_reader(fh)
                for _schema, channel, message in reader.iter_messages(topics=args["topics"]):
                    rows.append(json.loads(message.data))
                    n += 1
        table = pa.Table.from_pylist(rows)
        pq.write_table(table, args["out"])
        out["messages"] = n
    out["wall_s"] = time.perf_counter() - t0
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps(out))
    """
)


def run_stage(stage: str, **args) -> dict:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    res = subprocess.run([sys.executable, "-c", STAGE, stage, json.dumps(args)], env=env,
                         capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise SystemExit(f"stage {stage} failed:\n{res.stderr}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", default="1h")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--executor", default="process", choices=["serial", "process"])
    ap.add_argument("--workdir", default=None)
    a = ap.parse_args()
    sys.path.insert(0, str(REPO))
    from jobs.simulate import DEFAULT_START_NS, parse_duration

    duration_s = parse_duration(a.duration)
    work = Path(a.workdir or tempfile.mkdtemp(prefix="surveil-bench-"))
    start_ns, end_ns = DEFAULT_START_NS, DEFAULT_START_NS + int(duration_s * 1e9)
    sim = run_stage("simulate", duration_s=duration_s, seed=a.seed,
                    archive=str(work / "archive"), start_ns=start_ns)
    files = sim["files"]
    ing = run_stage("ingest", files=files, warehouse=str(work / "wh"), executor=a.executor)
    base = run_stage("baseline", files=files, topics=["/radar/R1/tracks", "/radar/R2/tracks"],
                     out=str(work / "baseline.parquet"))
    bat = run_stage("batch", warehouse=str(work / "wh"), start_ns=start_ns, end_ns=end_ns,
                    executor=a.executor)
    rep = run_stage("report", warehouse=str(work / "wh"))

    radar_rows = ing["rows"].get("radar_tracks", 0)
    base_rate = base["messages"] / base["wall_s"]
    ingest_rate = ing["messages"] / ing["wall_s"]
    fused = bat["rows"].get("system_tracks", 0)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}; scenario channel {duration_s:.0f} s seed {a.seed}; "
          f"executor {a.executor}")
    print(f"{'stage':<10}{'wall s':>9}{'peak RSS MB':>13}  throughput")
    print(f"{'simulate':<10}{sim['wall_s']:>9.2f}{sim['peak_rss_mb']:>13.0f}  "
          f"{len(files)} file(s)")
    print(f"{'ingest':<10}{ing['wall_s']:>9.2f}{ing['peak_rss_mb']:>13.0f}  "
          f"{ingest_rate:,.0f} msg/s all channels ({ing['messages']:,} msgs, "
          f"{radar_rows:,} radar rows); x{ingest_rate / base_rate:.1f} vs baseline")
    print(f"{'baseline':<10}{base['wall_s']:>9.2f}{base['peak_rss_mb']:>13.0f}  "
          f"{base_rate:,.0f} msg/s radar only (mcap iter_messages + json.loads + "
          f"from_pylist + parquet)")
    print(f"{'batch':<10}{bat['wall_s']:>9.2f}{bat['peak_rss_mb']:>13.0f}  "
          f"{fused / bat['wall_s']:,.0f} fused track-epochs/s; real-time factor "
          f"x{duration_s / bat['wall_s']:,.0f}")
    print(f"{'reports':<10}{rep['wall_s']:>9.2f}{rep['peak_rss_mb']:>13.0f}  2 reports")
    print(f"work dir: {work}")


if __name__ == "__main__":
    main()
