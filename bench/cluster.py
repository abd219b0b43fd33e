"""Beyond one machine, measured here: the region slice batched on Ray clusters of 1, 2 and
4 local nodes, with the warehouse on local disk and on an S3-compatible server, then
every shipped report over it from each storage (issue 39, item 5).

    .venv/bin/python bench/cluster.py [--workdir DIR] [--ships 3000] [--radars 6]
        [--slice 10m] [--nodes 1,2,4] [--repeat 3] [--json FILE]

1. The region scenario's slice (``--ships`` x ``--radars``, ``--slice`` from 15:00 UTC),
   simulated once and cached under ``--workdir``.
2. An S3-compatible server on loopback: moto's standalone server (``python -m
   moto.server``, the dev extra) in a process of its own, one bucket.
3. Per storage (``local``: a folder; ``s3``: ``s3://bucket/wh``), the slice ingested
   into a new warehouse (process executor, 2 workers).
4. Per number of nodes and storage: a Ray cluster of that many raylets on this machine
   (``ray.cluster_utils.Cluster``, one CPU each: the units run one per node), the
   maritime batch of the slice as Ray tasks (``executor_kind="ray"``), then the cluster
   shut down. Each run replaces the same window.
5. Per storage: every shipped report over the slice, in this process, ``--repeat``
   times (median), as ``surveil report`` runs it (a new DuckDB connection each time).

Figures: wall s; CPU s of the job's processes (this process and every process below it,
Ray's raylets, GCS and workers included; the S3 server's apart, "store CPU"); bytes
moved: what the job's processes read and wrote (``/proc/PID/io`` ``rchar + wchar``:
files, sockets and pipes alike, so on S3 every request and answer; locally the files,
from the page cache or the disk), and on S3 the server's own (what it received and
sent). This is a 2-core machine: 4 nodes run 4 units at once on 2 cores, so the
4-node row measures the cluster's overhead, not its speed-up. The S3 server is a
Python process on the same cores, slower than a real store per request and competing
for the CPU: its cost is printed apart, not added to the job's.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import socket
import statistics
import subprocess
import sys
import time
import urllib.request
import uuid
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
_HERE = Path(__file__).resolve().parent

NS = 10**9
START_NS = 1_768_489_200 * NS  # 2026-01-15T15:00:00Z, as bench/batch.py's slices
KEY_ID, SECRET, REGION = "bench", "bench-secret", "us-east-1"
_TICK = os.sysconf("SC_CLK_TCK")


def _stat(pid: int) -> tuple[int, float] | None:
    """(parent pid, CPU s of the process and its reaped children) from /proc."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return int(fields[1]), sum(int(x) for x in fields[11:15]) / _TICK


def _io(pid: int) -> int:
    """Bytes the process read and wrote (rchar + wchar: files, sockets, pipes)."""
    try:
        with open(f"/proc/{pid}/io") as f:
            got = dict(line.split(": ") for line in f.read().splitlines())
    except OSError:
        return 0
    return int(got["rchar"]) + int(got["wchar"])


def _counters(root: int, exclude: set[int]) -> dict[int, tuple[float, int]]:
    """pid -> (CPU s, bytes moved) of ``root`` and every process below it, but
    ``exclude`` (and what is below them)."""
    stats = {}
    for name in os.listdir("/proc"):
        if name.isdigit() and (st := _stat(int(name))) is not None:
            stats[int(name)] = st
    keep, frontier = {root}, [root]
    while frontier:
        parent = frontier.pop()
        for pid, (ppid, _) in stats.items():
            if ppid == parent and pid not in keep and pid not in exclude:
                keep.add(pid)
                frontier.append(pid)
    return {pid: (stats[pid][1], _io(pid)) for pid in keep if pid in stats}


class Meter:
    """Wall, CPU and bytes of the job's process tree, and the store's (its server's CPU,
    the request and response bytes it counted), apart."""

    def __init__(self, store: tuple[int, str] | None, remote: bool = True) -> None:
        self.store, self.remote = store, remote

    def _now(self) -> tuple[dict, float, dict]:
        pid, endpoint = self.store if self.store else (None, None)
        job = _counters(os.getpid(), {pid} if pid else set())
        tree = _counters(pid, set()).values() if pid else []
        return job, sum(c for c, _ in tree), store_bytes(endpoint)

    def __enter__(self) -> Meter:
        self._t0 = time.perf_counter()
        self._before, self._cpu0, self._moved0 = self._now()
        return self

    def __exit__(self, *exc: object) -> None:
        after, cpu, moved = self._now()
        self.wall_s = time.perf_counter() - self._t0
        self.cpu_s = sum(c - self._before.get(pid, (0.0, 0))[0] for pid, (c, _) in after.items())
        self.file_bytes = sum(b - self._before.get(pid, (0.0, 0))[1]
                              for pid, (_, b) in after.items())
        self.store_cpu_s = cpu - self._cpu0
        self.store_bytes = sum(moved[k] - self._moved0[k] for k in ("received", "sent"))
        self.requests = moved["requests"] - self._moved0["requests"]
        # bytes moved to and from the warehouse's storage: on S3 the bodies the store
        # received and sent; locally what the job's processes read and wrote
        self.bytes = self.store_bytes if self.remote else self.file_bytes

    def row(self) -> dict:
        return {"wall_s": round(self.wall_s, 3), "cpu_s": round(self.cpu_s, 3),
                "bytes": int(self.bytes), "file_bytes": int(self.file_bytes),
                "store_cpu_s": round(self.store_cpu_s, 3),
                "store_bytes": int(self.store_bytes), "requests": int(self.requests)}


# moto's server (as `python -m moto.server` runs it), its WSGI app wrapped to count the
# bytes of every request and response body: GET /_bench/bytes answers them
STORE = r"""
import json, os, sys, threading
from moto.server import DomainDispatcherApplication, MotoRequestHandler, create_backend_app
from werkzeug.serving import run_simple
os.environ["MOTO_PORT"] = sys.argv[2]
app = DomainDispatcherApplication(create_backend_app)
moved = {"received": 0, "sent": 0, "requests": 0}
lock = threading.Lock()

def counted(environ, start_response):
    if environ.get("PATH_INFO") == "/_bench/bytes":
        start_response("200 OK", [("Content-Type", "application/json")])
        with lock:
            return [json.dumps(moved).encode()]
    with lock:
        moved["requests"] += 1
    environ["wsgi.input"] = Counted(environ["wsgi.input"])
    return sent(app(environ, start_response))

class Counted:  # a request body as the app reads it (chunked uploads have no length)
    def __init__(self, raw):
        self.raw = raw
    def _n(self, data):
        with lock:
            moved["received"] += len(data)
        return data
    def read(self, *a):
        return self._n(self.raw.read(*a))
    def readline(self, *a):
        return self._n(self.raw.readline(*a))
    def __iter__(self):
        return (self._n(x) for x in self.raw)
    def __getattr__(self, name):
        return getattr(self.raw, name)

def sent(body):
    for chunk in body:
        with lock:
            moved["sent"] += len(chunk)
        yield chunk

run_simple(sys.argv[1], int(sys.argv[2]), counted, threaded=True,
           request_handler=MotoRequestHandler)
"""


def start_store() -> tuple[subprocess.Popen, str]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {k: v for k, v in os.environ.items() if not k.startswith("AWS_")}
    proc = subprocess.Popen([sys.executable, "-c", STORE, "127.0.0.1", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    endpoint = f"http://127.0.0.1:{port}"
    for _ in range(300):
        try:
            urllib.request.urlopen(endpoint + "/moto-api/", timeout=1).close()
            return proc, endpoint
        except OSError:
            time.sleep(0.1)
    proc.kill()
    raise SystemExit("moto's server did not start (pip install 'moto[server]')")


def store_bytes(endpoint: str | None) -> dict[str, int]:
    if endpoint is None:
        return {"received": 0, "sent": 0, "requests": 0}
    with urllib.request.urlopen(endpoint + "/_bench/bytes", timeout=10) as r:
        return json.loads(r.read())


def prepare(work: Path, ships: int, radars: int, seed: int, duration_s: float) -> Path:
    """The slice's archive (cached)."""
    from jobs.simulate import run_simulate
    from pipeline.families import load_config

    d = work / f"region-{ships}x{radars}-s{seed}-{START_NS // NS}-{int(duration_s)}s"
    if not (d / "done").exists():
        shutil.rmtree(d, ignore_errors=True)
        run_simulate("region", duration_s + 10.0, seed, d / "archive", load_config(),
                     start_ns=START_NS - 10 * NS, ships=ships, radars=radars)
        (d / "done").write_text("ok\n")
    return d / "archive"


def _fmt_bytes(n: float) -> str:
    return f"{n / 2**20:,.1f} MiB"


def main() -> None:
    ap = argparse.ArgumentParser(prog="bench/cluster.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/surveil-bench-cluster"))
    ap.add_argument("--ships", type=int, default=3000)
    ap.add_argument("--radars", type=int, default=6)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--slice", default="10m")
    ap.add_argument("--nodes", default="1,2,4")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()

    import ray
    from cpu_probe import probe
    from ray.cluster_utils import Cluster

    import jobs  # noqa: F401  (polars on one thread, as every surveil command)
    from jobs.common import parse_duration
    from pipeline.batch import run_batch
    from pipeline.families import load_config
    from pipeline.ingest.driver import run_ingest
    from pipeline.reports import list_reports, run_named_report
    from pipeline.warehouse.location import parse_location

    slice_s = parse_duration(a.slice)
    end_ns = START_NS + int(slice_s * NS)
    a.workdir.mkdir(parents=True, exist_ok=True)
    archive = prepare(a.workdir, a.ships, a.radars, a.seed, slice_s)
    cfg = load_config(archive / "region.toml")
    files = sorted(archive.glob("*.mcap"))
    store, endpoint = start_store()
    result: dict = {"machine": platform.machine(), "cpus": os.cpu_count(),
                    "ships": a.ships, "radars": a.radars, "slice": a.slice,
                    "cpu_probe_s": [round(probe()["cpu_s"], 3)], "ingest": {}, "batch": [],
                    "reports": {}}
    try:
        os.environ.update({"AWS_ACCESS_KEY_ID": KEY_ID, "AWS_SECRET_ACCESS_KEY": SECRET,
                           "AWS_REGION": REGION, "AWS_ENDPOINT_URL": endpoint,
                           "AWS_ALLOW_HTTP": "true"})  # the raylets and workers inherit them
        import boto3

        bucket = f"bench-{uuid.uuid4().hex[:8]}"
        boto3.client("s3", endpoint_url=endpoint, aws_access_key_id=KEY_ID,
                     aws_secret_access_key=SECRET, region_name=REGION).create_bucket(
            Bucket=bucket)
        server = (store.pid, endpoint)
        local = a.workdir / "wh-local"
        shutil.rmtree(local, ignore_errors=True)
        where = {"local": parse_location(local), "s3": parse_location(f"s3://{bucket}/wh")}
        for name, wh in where.items():
            with Meter(server, remote=name == "s3") as m:
                s = run_ingest(files, cfg, wh, executor="process")
            assert s.exit_code in (0, 1), s.render()
            result["ingest"][name] = m.row() | {"rows": sum(s.rows.values())}
            print(f"ingest {name}: {m.wall_s:.1f} s wall, {m.cpu_s:.1f} CPU s, "
                  f"{_fmt_bytes(m.bytes)} moved (store: {m.store_cpu_s:.1f} CPU s, "
                  f"{_fmt_bytes(m.store_bytes)})", flush=True)
        for nodes in [int(n) for n in a.nodes.split(",") if n]:
            for name, wh in where.items():
                cluster = Cluster(initialize_head=True, head_node_args={
                    "num_cpus": 1, "object_store_memory": 200 * 2**20,
                    "include_dashboard": False})
                for _ in range(nodes - 1):
                    cluster.add_node(num_cpus=1, object_store_memory=200 * 2**20)
                cluster.wait_for_nodes()
                ray.init(address=cluster.address, log_to_driver=False)
                try:
                    with Meter(server, remote=name == "s3") as m:
                        s = run_batch(cfg, wh, start_ns=START_NS, end_ns=end_ns,
                                      executor_kind="ray", families=("maritime",))
                finally:
                    ray.shutdown()
                    cluster.shutdown()
                assert s.exit_code == 0, s.render()
                row = {"nodes": nodes, "storage": name, "units": s.units_total,
                       "derived_rows": sum(s.rows.values())} | m.row()
                result["batch"].append(row)
                print(f"batch {nodes} node(s), {name}: {s.units_total} units, "
                      f"{m.wall_s:.1f} s wall, {m.cpu_s:.1f} CPU s, {_fmt_bytes(m.bytes)} "
                      f"moved (store: {m.store_cpu_s:.1f} CPU s, "
                      f"{_fmt_bytes(m.store_bytes)})", flush=True)
        result["cpu_probe_s"].append(round(probe()["cpu_s"], 3))
        for report in list_reports():
            per: dict = {}
            for name, wh in where.items():
                runs = []
                for _ in range(a.repeat):
                    with Meter(server, remote=name == "s3") as m:
                        t = run_named_report(wh, report, start_ns=START_NS, end_ns=end_ns,
                                             cfg=cfg)
                    runs.append(m.row() | {"rows": t.num_rows})
                per[name] = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
            per["wall_ratio"] = round(per["s3"]["wall_s"] / max(per["local"]["wall_s"], 1e-9), 2)
            per["cpu_ratio"] = round(per["s3"]["cpu_s"] / max(per["local"]["cpu_s"], 1e-9), 2)
            result["reports"][report] = per
            print(f"report {report:<28} local {per['local']['wall_s']:6.2f} s "
                  f"{per['local']['cpu_s']:6.2f} CPU s {_fmt_bytes(per['local']['bytes']):>12}"
                  f" | s3 {per['s3']['wall_s']:6.2f} s {per['s3']['cpu_s']:6.2f} CPU s "
                  f"{_fmt_bytes(per['s3']['bytes']):>12} (store {per['s3']['store_cpu_s']:.2f}"
                  f" CPU s) | x{per['wall_ratio']} wall, x{per['cpu_ratio']} CPU", flush=True)
        result["cpu_probe_s"].append(round(probe()["cpu_s"], 3))
    finally:
        store.terminate()
        store.wait(10)
    walls = [r["wall_ratio"] for r in result["reports"].values()]
    cpus = [r["cpu_ratio"] for r in result["reports"].values()]
    result["report_ratio_median"] = {"wall": statistics.median(walls),
                                     "cpu": statistics.median(cpus)}
    total = {k: sum(r[k]["wall_s"] for r in result["reports"].values()) for k in ("local", "s3")}
    result["reports_total_wall_s"] = total
    print(f"\nreports on S3 / on local disk: wall x{statistics.median(walls):.2f} median "
          f"(max x{max(walls):.2f}), CPU x{statistics.median(cpus):.2f} median "
          f"(max x{max(cpus):.2f}); all {len(walls)} reports: {total['local']:.1f} s local, "
          f"{total['s3']:.1f} s on S3 (x{total['s3'] / total['local']:.2f})")
    print(f"CPU probe: {', '.join(f'{p:.2f}' for p in result['cpu_probe_s'])} s")
    if a.json:
        a.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    if sys.argv[0] == "-c":
        main()
    else:  # Ray gives its workers the driver script's folder first on their path, where
        # bench/pipeline.py would shadow the package: run from `-c` (no script folder)
        code = (f"import sys; sys.path[:0] = [{str(REPO)!r}]; sys.path.append({str(_HERE)!r});"
                " import cluster; cluster.main()")
        env = {**os.environ, "PYTHONPATH": str(REPO)}  # the workers import this checkout
        os.execve(sys.executable, [sys.executable, "-c", code, *sys.argv[1:]], env)
