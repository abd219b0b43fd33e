"""Maritime batch speed: ours and Stone Soup side by side on one slice of the region
scenario, and our cost per radar report against traffic density.

    .venv/bin/python bench/batch.py [--workdir DIR] [--json FILE] [--ships 100]
        [--slice 5m] [--densities 100,300,1000,3000] [--density-slice 10m]
        [--radars 6] [--seed 7] [--repeat 3] [--no-stonesoup]

1. **Side by side** (``--ships``, ``--slice``): the region scenario (simulated once and
   ingested once, cached under ``--workdir``), then in separate processes, each with its
   libraries imported before the clock starts and its threads capped to one:

   - ours: ``pipeline.batch.run_batch`` of the maritime family over the slice, serial
     executor (read the inputs, align, sync, associate, fuse, identify, score, SIAP,
     cross-track, stage the outputs, commit them to Delta, rebuild the views);
     ``--repeat`` runs, median;
   - Stone Soup (``stonesoup``, dev dependency): a ``MultiTargetTracker`` with
     ``GNNWith2DAssignment`` over a Mahalanobis ``DistanceHypothesiser`` (gate
     chi2(0.999, 2), as ours), constant-velocity Kalman predictor/updater, a
     ``MultiMeasurementInitiator`` (2 points) and a 30 s ``UpdateTimeDeleter`` (our track
     timeout). Every radar track report the batch reads is one detection: the report's
     position in the regional frame, synchronised to its scan end (multi-radar paper
     eq. 7, as our step 1), with one measurement model per radar site (the site's
     polar covariance at its median range, so that Stone Soup's per-model caches work:
     the configuration of the published 7.4 ms/target-scan anchor); detections of one
     site's scan form one detection set. Only the tracker loop is timed.

   Time per target-scan = CPU time / radar reports read (one report = one target in
   one scan of one radar); the ratio is Stone Soup's over ours. Accuracy: every estimate
   (our fused points; Stone Soup's track states) against the truth vessel nearest to it
   at its time (truth interpolated, within 500 m), RMS over the matched estimates, the
   same function for both.

2. **Cost against density** (``--densities``, ``--density-slice``): ours alone on the
   region with that many ships (mean in the scene; the slice starts at 15:00 UTC, when
   the scene holds about the mean), time per radar report and peak RSS of the batch (its
   volume-sized units one after another in the one process); ``--repeat`` runs, median.
   Also the stage alone (median of as many runs): the
   slice as one unit, read and computed, no staging, commit or views (what the batch
   adds has a part that does not shrink with the slice: it weighs on the sparse one).

CPU times (``time.process_time``, all threads of the process) are the headline: this
2-core machine is shared, and wall times swing with other tenants' load (printed too).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
_HERE = Path(__file__).resolve().parent
# run as a script: bench/ is sys.path[0] and bench/pipeline.py would shadow the package
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(REPO))

NS = 10**9
START_NS = 1_768_489_200 * NS  # 2026-01-15T15:00:00Z: the region holds ~the mean ship count
ONE_THREAD = {k: "1" for k in ("POLARS_MAX_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                               "MKL_NUM_THREADS", "RAYON_NUM_THREADS")}

# Code run in a fresh interpreter per measurement (imports before the clock starts).
CHILD = textwrap.dedent(
    r'''
    import json, resource, statistics, sys, time
    from pathlib import Path
    what, a = sys.argv[1], json.loads(sys.argv[2])
    sys.path.insert(0, a["repo"])
    import numpy as np, polars as pl
    from pipeline.families import load_config
    cfg = load_config(a["config"])
    wh = Path(a["warehouse"])
    out = {}

    def clock():
        return time.perf_counter(), time.process_time()

    def peak_rss_mb():
        # this process's own high-water mark: ru_maxrss would also hold the bench's RSS
        # at the fork (Linux keeps it across exec)
        try:
            with open("/proc/self/status") as f:
                return next(int(ln.split()[1]) for ln in f if ln.startswith("VmHWM")) / 1024
        except (OSError, StopIteration):
            return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    if what == "prepare":
        from pipeline.ingest.driver import run_ingest
        from jobs.simulate import run_simulate
        files = run_simulate("region", a["duration_s"], a["seed"], Path(a["archive"]), cfg,
                             start_ns=a["start_ns"], ships=a["ships"], radars=a["radars"])
        cfg = load_config(Path(a["archive"]) / "region.toml")
        s = run_ingest(files, cfg, wh, executor="process")
        out["rows"] = dict(s.rows)
    elif what == "ours":
        from pipeline.batch import read_inputs, run_batch
        from pipeline.families import family
        from pipeline.family import Window
        from pipeline.warehouse.delta import read_table
        fam = family("maritime")
        w = Window(a["start_ns"], a["end_ns"])
        runs = []
        for _ in range(a["repeat"]):
            t0, c0 = clock()
            s = run_batch(cfg, wh, start_ns=w.start_ns, end_ns=w.end_ns, executor_kind="serial",
                          families=("maritime",))
            t1, c1 = clock()
            assert s.committed and not s.failed_units, s.render()
            runs.append((t1 - t0, c1 - c0))
        # the batch's peak (its units one after another in this process), before the
        # reads below hold the whole slice at once
        out["batch_peak_rss_mb"] = peak_rss_mb()
        n = read_inputs(fam, wh, cfg, w)["radar_tracks"].height
        stage = []
        for _ in range(a["repeat"]):
            t0, c0 = clock()
            fam.stage(read_inputs(fam, wh, cfg, w), w, cfg)
            t1, c1 = clock()
            stage.append((t1 - t0, c1 - c0))
        # the reconstruction of the reference (issue 37) alone, on the unit's AIS
        from pipeline.maritime.config import maritime_config
        from pipeline.maritime.reference import reconstruct
        ais = read_inputs(fam, wh, cfg, w)["ais_reports"]
        rec = []
        for _ in range(a["repeat"]):
            t0, c0 = clock()
            reconstruct(ais, cfg.region, cfg.ais, maritime_config(cfg).reference)
            t1, c1 = clock()
            rec.append(c1 - c0)
        out.update(reports=n, wall_s=[r[0] for r in runs], cpu_s=[r[1] for r in runs],
                   stage_wall_s=statistics.median(r[0] for r in stage),
                   stage_cpu_s=statistics.median(r[1] for r in stage), rows=dict(s.rows),
                   reference_cpu_s=statistics.median(rec), ais_reports=ais.height)
        fused = pl.from_arrow(read_table(wh, "system_tracks", start_ns=w.start_ns,
                                         end_ns=w.end_ns))
        out["estimates"] = {"time_ns": fused["time_ns"].to_list(),
                            "x": fused["x_enu_m"].to_list(), "y": fused["y_enu_m"].to_list()}
    elif what == "ray":
        import ray
        from jobs.batch import run_batch
        ray.init(num_cpus=a["cpus"], include_dashboard=False, _node_ip_address="127.0.0.1",
                 object_store_memory=256 * 1024 * 1024, log_to_driver=False)
        walls = []
        for _ in range(a["repeat"]):
            t0, c0 = clock()
            s = run_batch(cfg, wh, start_ns=a["start_ns"], end_ns=a["end_ns"],
                          executor_kind="ray", families=("maritime",))
            t1, c1 = clock()
            assert s.committed and not s.failed_units, s.render()
            walls.append(t1 - t0)
        ray.shutdown()
        out.update(wall_s=walls, units=s.units_total)
    elif what == "stonesoup":
        from bench_stonesoup import detections, run_tracker
        sets, n = detections(wh, cfg, a["read_from_ns"], a["end_ns"])
        t0, c0 = clock()
        tracks = run_tracker(sets)
        t1, c1 = clock()
        states = [(s.timestamp, float(s.state_vector[0, 0]), float(s.state_vector[2, 0]))
                  for tr in tracks for s in tr.states]
        epoch = np.datetime64(0, "us")
        t_ns = [int((np.datetime64(ts, "us") - epoch).astype(np.int64)) * 1000
                for ts, _, _ in states]
        keep = [a["start_ns"] <= t < a["end_ns"] for t in t_ns]
        out.update(detections=n, wall_s=[t1 - t0], cpu_s=[c1 - c0], tracks=len(tracks),
                   estimates={"time_ns": [t for t, k in zip(t_ns, keep) if k],
                              "x": [s[1] for s, k in zip(states, keep) if k],
                              "y": [s[2] for s, k in zip(states, keep) if k]})
    out["peak_rss_mb"] = peak_rss_mb()
    print(json.dumps(out))
    '''
)


def child(what: str, **args) -> dict:
    env = {**os.environ, **ONE_THREAD, "PYTHONPATH": f"{REPO}{os.pathsep}{_HERE}"}
    args.setdefault("repo", str(REPO))
    res = subprocess.run([sys.executable, "-c", CHILD, what, json.dumps(args)], env=env,
                         capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise SystemExit(f"{what} failed:\n{res.stderr[-4000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def prepare(work: Path, ships: int, radars: int, seed: int, duration_s: float) -> Path:
    """The region's archive and warehouse for one density, made once (cached)."""
    d = work / f"region-{ships}x{radars}-s{seed}-{START_NS // NS}-{int(duration_s)}s"
    if not (d / "done").exists():
        import shutil

        shutil.rmtree(d, ignore_errors=True)
        # the plan and trackers run from the slice start; radar margin: 10 s before it
        child("prepare", config=None, warehouse=str(d / "wh"), archive=str(d / "archive"),
              duration_s=duration_s + 10.0, seed=seed, start_ns=START_NS - 10 * NS,
              ships=ships, radars=radars)
        (d / "done").write_text("ok\n")
    return d


def truth_rms(d: Path, est: dict) -> tuple[float, float]:
    """(RMS error m, share of estimates matched): each estimate against the truth vessel
    nearest to it at its time (truth linearly interpolated), within 500 m."""
    import numpy as np
    import polars as pl

    from pipeline.families import load_config
    from pipeline.frames import geodetic_to_enu
    from pipeline.warehouse.delta import read_table

    cfg = load_config(d / "archive" / "region.toml")
    truth = pl.from_arrow(read_table(d / "wh", "truth")).sort("vessel_id", "time_ns")
    x, y = geodetic_to_enu(truth["lat_deg"].to_numpy(), truth["lon_deg"].to_numpy(),
                           cfg.region.origin_lat_deg, cfg.region.origin_lon_deg)
    truth = truth.select("vessel_id", "time_ns").with_columns(pl.Series("tx", x),
                                                              pl.Series("ty", y))
    steps = truth["time_ns"].diff()
    period = int(steps.filter(steps > 0).min())
    pts = pl.DataFrame(est, schema={"time_ns": pl.Int64, "x": pl.Float64, "y": pl.Float64})
    if pts.height == 0:
        return float("nan"), 0.0
    pts = pts.with_row_index("p").with_columns(
        (pl.col("time_ns") // period * period).alias("t0"))
    a = truth.rename({"time_ns": "t0", "tx": "x0", "ty": "y0"})
    b = truth.rename({"time_ns": "t1", "tx": "x1", "ty": "y1"})
    j = (pts.join(a, on="t0").with_columns((pl.col("t0") + period).alias("t1"))
         .join(b, on=["vessel_id", "t1"]))
    f = (pl.col("time_ns") - pl.col("t0")) / period
    j = j.with_columns((pl.col("x0") + f * (pl.col("x1") - pl.col("x0"))).alias("rx"),
                       (pl.col("y0") + f * (pl.col("y1") - pl.col("y0"))).alias("ry"))
    j = j.with_columns(((pl.col("x") - pl.col("rx")) ** 2
                        + (pl.col("y") - pl.col("ry")) ** 2).alias("e2"))
    best = j.group_by("p").agg(pl.col("e2").min()).filter(pl.col("e2") <= 500.0**2)
    return float(np.sqrt(best["e2"].mean())), best.height / pts.height


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", default=None)
    ap.add_argument("--json", default=None, help="write the figures to this file")
    ap.add_argument("--ships", type=int, default=100)
    ap.add_argument("--slice", default="5m", help="side-by-side slice (Stone Soup runs it)")
    ap.add_argument("--densities", default="100,300,1000,3000")
    ap.add_argument("--density-slice", default="10m")
    ap.add_argument("--radars", type=int, default=6)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-stonesoup", action="store_true")
    ap.add_argument("--ray", action="store_true",
                    help="also: the maritime batch of the densest slice (several volume units) "
                         "as Ray tasks on a local cluster of 1, then 2 CPUs (needs the ray "
                         "extra)")
    a = ap.parse_args()
    from jobs.common import parse_duration

    work = Path(a.workdir or Path(tempfile.gettempdir()) / "surveil-bench-batch")
    work.mkdir(parents=True, exist_ok=True)
    result: dict = {"machine": {"cpu": platform.processor() or platform.machine(),
                                "cores": os.cpu_count(),
                                "python": platform.python_version()}}
    from bench.cpu_probe import probe

    result["cpu_probe_s"] = {"start": probe()["cpu_s"]}
    print(f"machine: {result['machine']['cpu']}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}; one thread per process; CPU s = process_time; "
          f"CPU probe {result['cpu_probe_s']['start']:.2f} s (bench/cpu_probe.py)")

    # 1. side by side --------------------------------------------------------------------
    if not a.no_stonesoup:
        slice_s = parse_duration(a.slice)
        d = prepare(work, a.ships, a.radars, a.seed, slice_s)
        cfg = str(d / "archive" / "region.toml")
        w = {"start_ns": START_NS, "end_ns": START_NS + int(slice_s * NS)}
        ours = child("ours", config=cfg, warehouse=str(d / "wh"), repeat=a.repeat, **w)
        from pipeline.families import family, load_config

        margin = family("maritime").inputs(load_config(cfg))[0].before_s
        ss = child("stonesoup", config=cfg, warehouse=str(d / "wh"),
                   read_from_ns=START_NS - int(margin * NS), **w)
        o_cpu, o_wall = statistics.median(ours["cpu_s"]), statistics.median(ours["wall_s"])
        o_us = o_cpu / ours["reports"] * 1e6
        s_ms = ss["cpu_s"][0] / ss["detections"] * 1e3
        o_rms, o_share = truth_rms(d, ours.pop("estimates"))
        s_rms, s_share = truth_rms(d, ss.pop("estimates"))
        ratio = s_ms * 1e3 / o_us
        ratio_wall = (ss["wall_s"][0] / ss["detections"]) / (o_wall / ours["reports"])
        print(f"\nside by side: region {a.ships} ships x {a.radars} radars, {a.slice} from "
              f"15:00 UTC ({ours['reports']:,} radar reports read by each)")
        print(f"{'':<12}{'CPU s':>9}{'wall s':>9}{'per target-scan':>18}{'RMS m':>8}"
              f"{'matched':>9}")
        print(f"{'ours':<12}{o_cpu:>9.2f}{o_wall:>9.2f}{o_us:>15.2f} us{o_rms:>8.1f}"
              f"{o_share:>9.1%}   (stage alone {ours['stage_cpu_s']:.2f} CPU s)")
        print(f"{'Stone Soup':<12}{ss['cpu_s'][0]:>9.2f}{ss['wall_s'][0]:>9.2f}"
              f"{s_ms:>15.2f} ms{s_rms:>8.1f}{s_share:>9.1%}   ({ss['tracks']} tracks)")
        print(f"ratio (Stone Soup / ours per target-scan): x{ratio:,.0f} CPU, "
              f"x{ratio_wall:,.0f} wall; accuracy: ours {o_rms:.1f} m vs {s_rms:.1f} m "
              f"({'no worse' if o_rms <= s_rms else 'WORSE'})")
        result["side_by_side"] = {
            "ships": a.ships, "radars": a.radars, "slice_s": slice_s, "reports": ours["reports"],
            "ours": {**ours, "us_per_target_scan_cpu": o_us, "rms_m": o_rms,
                     "matched_share": o_share},
            "stonesoup": {**ss, "ms_per_target_scan_cpu": s_ms, "rms_m": s_rms,
                          "matched_share": s_share},
        }
        result["stonesoup_ratio_per_target_scan"] = ratio
        result["stonesoup_ratio_per_target_scan_wall"] = ratio_wall

    # 2. cost against density -------------------------------------------------------------
    dens_s = parse_duration(a.density_slice)
    rows = []
    print(f"\ncost against density: ours, {a.density_slice} from 15:00 UTC, serial, one thread")
    print(f"{'ships':>7}{'targets':>9}{'reports':>11}{'CPU s':>8}{'wall s':>8}"
          f"{'us/report CPU':>15}{'us/report wall':>16}{'stage us/report':>17}"
          f"{'peak RSS MB':>13}{'reference us/report':>21}{'of the stage':>14}")
    for ships in (int(x) for x in a.densities.split(",") if x):
        d = prepare(work, ships, a.radars, a.seed, dens_s)
        cfg = str(d / "archive" / "region.toml")
        r = child("ours", config=cfg, warehouse=str(d / "wh"), repeat=a.repeat,
                  start_ns=START_NS, end_ns=START_NS + int(dens_s * NS))
        r.pop("estimates")
        targets = _targets(d)
        cpu, wall = statistics.median(r["cpu_s"]), statistics.median(r["wall_s"])
        row = {"ships": ships, "simultaneous_targets": targets, "reports": r["reports"],
               "cpu_s": cpu, "wall_s": wall, "us_per_report_cpu": cpu / r["reports"] * 1e6,
               "us_per_report_wall": wall / r["reports"] * 1e6,
               "stage_us_per_report_cpu": r["stage_cpu_s"] / r["reports"] * 1e6,
               "peak_rss_mb": r["batch_peak_rss_mb"],
               "reference_us_per_report_cpu": r["reference_cpu_s"] / r["reports"] * 1e6,
               "reference_share_of_stage": r["reference_cpu_s"] / r["stage_cpu_s"],
               "ais_reports": r["ais_reports"]}
        rows.append(row)
        print(f"{ships:>7}{targets:>9}{r['reports']:>11,}{cpu:>8.2f}{wall:>8.2f}"
              f"{row['us_per_report_cpu']:>15.2f}{row['us_per_report_wall']:>16.2f}"
              f"{row['stage_us_per_report_cpu']:>17.2f}{row['peak_rss_mb']:>13.0f}"
              f"{row['reference_us_per_report_cpu']:>21.2f}"
              f"{row['reference_share_of_stage']:>14.1%}")
    if rows:
        per = [r["us_per_report_cpu"] for r in rows]
        stage = [r["stage_us_per_report_cpu"] for r in rows]
        result["linear"] = rows
        result["linear_spread"] = max(per) / min(per)
        result["linear_spread_stage"] = max(stage) / min(stage)
        print(f"spread of the per-report CPU time: x{max(per) / min(per):.2f} (goal <= 1.5); "
              f"of the stage's alone: x{max(stage) / min(stage):.2f} (the batch's staging, "
              f"commit and views cost a part that does not shrink with the slice)")
    if a.ray:  # the densest slice: ~300k reports per unit, so several units to spread
        ray_ships = max(int(x) for x in a.densities.split(",") if x)
        d = prepare(work, ray_ships, a.radars, a.seed, dens_s)
        cfg = str(d / "archive" / "region.toml")
        w = {"start_ns": START_NS, "end_ns": START_NS + int(dens_s * NS)}
        one = child("ray", config=cfg, warehouse=str(d / "wh"), cpus=1, repeat=a.repeat, **w)
        two = child("ray", config=cfg, warehouse=str(d / "wh"), cpus=2, repeat=a.repeat, **w)
        w1, w2 = statistics.median(one["wall_s"]), statistics.median(two["wall_s"])
        result["ray_scaling"] = {"ships": ray_ships, "units": two["units"], "one_worker_wall_s": w1,
                                 "two_workers_wall_s": w2, "speedup": w1 / w2}
        print(f"\nRay, local cluster, {ray_ships:,} ships x {a.density_slice} "
              f"({two['units']} units): "
              f"1 worker {w1:.1f} s, 2 workers {w2:.1f} s wall (median of {a.repeat}); "
              f"speed-up x{w1 / w2:.2f}")
    result["cpu_probe_s"]["end"] = probe()["cpu_s"]
    print(f"CPU probe at the end: {result['cpu_probe_s']['end']:.2f} s; work dir: {work}")
    if a.json:
        Path(a.json).write_text(json.dumps(result, indent=2))


def _targets(d: Path) -> int:
    """Vessels in the scene at the middle of the slice (truth)."""
    import polars as pl

    from pipeline.warehouse.delta import read_table

    t = pl.from_arrow(read_table(d / "wh", "truth", columns=["time_ns", "vessel_id"]))
    mid = t["time_ns"].sort()[t.height // 2]
    return t.filter(pl.col("time_ns") == mid)["vessel_id"].n_unique()


if __name__ == "__main__":
    main()
