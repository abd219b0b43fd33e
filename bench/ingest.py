"""Ingest benchmark: radar reports from MCAP into the warehouse, against a baseline and the
read+decompress floor (issue 3, "Speed").

    .venv/bin/python bench/ingest.py [--messages 1000000] [--workdir DIR]
        [--executors serial,process] [--variants json,protobuf,ros2] [--repeat 1]
        [--no-tracemalloc] [--in-process]

For N = ``--messages`` and N/4 (N first) it writes three MCAP files of the same N radar track
reports (zstd chunks of ~1 MiB, message indexes, summary; payloads built in bulk):

- ``json``: the simulator's JSON (``schemas/radar_track_report.schema.json``, same encoder
  as ``pipeline.io.mcap_write``), ~440 B per report;
- ``protobuf``: ``surveil.RadarTrackReport`` (``schemas/radar_track_report.proto``);
- ``ros2``: CDR ``surveil_msgs/msg/RadarTrackReport`` (``schemas/radar_track_report.msg``).

Then, each in its own subprocess (so that ``ru_maxrss`` is that measurement's own peak):

- ``floor``: read the file and decompress every chunk (summary -> chunk index -> zstd);
- ``baseline``: ``mcap`` ``iter_decoded_messages`` (json.loads / mcap_protobuf /
  mcap_ros2 decoder) -> one dict per message -> ``pa.Table.from_pylist`` -> Parquet (zstd);
- ``surveil``: ``pipeline.ingest.driver.run_ingest`` into a fresh warehouse (``serial`` and
  ``process`` executors), checked to have written N rows to ``radar_tracks``.

The table gives seconds (median of ``--repeat`` runs), messages/s, file MB/s, the speed-up
over the baseline, the time over the floor, the peak RSS of the measuring process (and its
children: the process pool) and, in a second run of the same command, the peak of the
Python heap seen by ``tracemalloc`` (allocations of numpy/polars/Arrow buffers that go
through Python's allocator count; Arrow's own pool does not; for the process executor only
the driver is traced). Each measurement imports its libraries before the clock starts;
``import s`` gives that time apart, with the table schemas' parse (once per process; the
surveil process executor's workers import and parse again, inside the measured time).
"""

from __future__ import annotations

import argparse
import importlib
import itertools
import json
import os
import platform
import resource
import shutil
import statistics
import struct
import subprocess
import sys
import tempfile
import time
import tracemalloc
import zlib
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
_HERE = Path(__file__).resolve().parent
# run as a script: bench/ is sys.path[0] and bench/pipeline.py would shadow the package
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(REPO))

T0_NS = 1_768_435_200 * 10**9  # 2026-01-15T00:00:00Z
CHUNK_BYTES = 1 << 20
_HEADER = np.dtype(
    [("op", "u1"), ("len", "<u8"), ("ch", "<u2"), ("seq", "<u4"), ("t", "<u8"), ("pub", "<u8")]
)
VARIANTS = {
    "json": ("json", "jsonschema", "surveil.RadarTrackReport"),
    "protobuf": ("protobuf", "protobuf", "surveil.RadarTrackReport"),
    "ros2": ("cdr", "ros2msg", "surveil_msgs/msg/RadarTrackReport"),
}


# -- the reports -------------------------------------------------------------------------


def reports(n: int, seed: int = 1) -> dict[str, np.ndarray | list[str]]:
    """N radar track reports as columns (schema field order): two sites, 400 tracks each,
    3 s scans, report times ~1 ms apart, values like the simulator's (full-precision)."""
    rng = np.random.default_rng(seed)
    i = np.arange(n)
    site = np.where(i % 2 == 0, "R1", "R2")
    track = (i // 2) % 400 + 1000
    rng_m = rng.uniform(500.0, 24000.0, n)
    az = rng.uniform(0.0, 2 * np.pi, n)
    status = np.array(["new", "confirmed", "coasting", "lost"])[(i % 97 == 0) * 2 + (i % 13 != 0)]
    return {
        "site_id": site,
        "track_id": track.astype(np.int64),
        "time_ns": T0_NS + i.astype(np.int64) * 1_000_000 + rng.integers(0, 999_999, n),
        "range_m": rng_m,
        "azimuth_rad": az,
        "x_m": rng_m * np.sin(az),
        "y_m": rng_m * np.cos(az),
        "course_rad": rng.uniform(0.0, 2 * np.pi, n),
        "speed_mps": rng.uniform(0.0, 12.0, n),
        "sigma_range_m": np.full(n, 15.0),
        "sigma_azimuth_rad": np.full(n, 0.007853981633974483),
        "sigma_course_rad": np.full(n, 0.03490658503988659),
        "sigma_speed_mps": np.full(n, 0.25),
        "scan_period_s": np.where(site == "R1", 3.0, 4.0),
        "scan_end_azimuth_rad": np.full(n, 6.283185307179586),
        "status": status,
    }


def payloads(variant: str, cols: dict) -> tuple[np.ndarray, np.ndarray, bytes]:
    """(payload bytes, offsets (n+1), schema data) of one encoding, built in bulk."""
    if variant == "json":
        import polars as pl
        import pyarrow as pa

        from pipeline.io.mcap_write import json_payloads as _json_payloads
        from pipeline.messages import RADAR_REPORT, message_layout

        layout = message_layout(RADAR_REPORT)
        df = pl.DataFrame(
            {k: list(v) if k in ("site_id", "status") else v for k, v in cols.items()}
        )
        arr = _json_payloads(df, layout.names).to_arrow().cast(pa.large_binary())
        offsets = np.frombuffer(arr.buffers()[1], np.int64)[arr.offset : arr.offset + len(arr) + 1]
        data = np.frombuffer(arr.buffers()[2], np.uint8)[offsets[0] : offsets[-1]]
        return data, offsets - offsets[0], layout.data
    from pipeline.decode import radar_binary as rb

    str_cols = {k: (list(v) if k in ("site_id", "status") else v) for k, v in cols.items()}
    if variant == "protobuf":
        schema = rb.radar_descriptor_set()
        data, offsets = rb.encode_protobuf(str_cols, rb.protobuf_fields(schema, rb.PROTO_SCHEMA))
    else:
        schema = rb.radar_ros2_text().encode()
        data, offsets = rb.encode_cdr(str_cols, rb.ros2_fields(schema.decode()))
    return data, offsets, schema


# -- a bulk MCAP writer ------------------------------------------------------------------


def _chunk_records(times: np.ndarray, data: np.ndarray, offsets: np.ndarray, seq0: int) -> bytes:
    """Message records of one chunk (channel 1), headers and payloads placed by numpy."""
    n = len(times)
    lengths = np.diff(offsets)
    head = np.zeros(n, _HEADER)
    head["op"], head["len"], head["ch"] = 5, 22 + lengths, 1
    head["seq"], head["t"], head["pub"] = np.arange(seq0, seq0 + n), times, times
    starts = np.concatenate([[0], np.cumsum(31 + lengths)[:-1]])
    out = np.empty(int(31 * n + lengths.sum()), np.uint8)
    out[(starts[:, None] + np.arange(31)).ravel()] = head.view(np.uint8)
    body = data[offsets[0] : offsets[-1]]
    out[np.arange(len(body)) + np.repeat(starts + 31 - (offsets[:-1] - offsets[0]), lengths)] = body
    return out.tobytes()


def write_mcap(path: Path, variant: str, times: np.ndarray, data, offsets, schema: bytes) -> None:
    """One channel of ``variant`` messages as a zstd-chunked MCAP file with message
    indexes, statistics and a chunk index (the layout ``mcap.writer.Writer`` produces)."""
    import zstandard
    from mcap.data_stream import RecordBuilder
    from mcap.opcode import Opcode
    from mcap.records import (
        Channel,
        Chunk,
        ChunkIndex,
        DataEnd,
        Footer,
        Header,
        Schema,
        Statistics,
    )

    enc, senc, sname = VARIANTS[variant]
    sch = Schema(id=1, name=sname, encoding=senc, data=schema)
    chn = Channel(id=1, topic="/radar/bench/tracks", message_encoding=enc, schema_id=1, metadata={})
    n = len(times)
    rec = np.cumsum(31 + np.diff(offsets))
    bounds = [0]
    while bounds[-1] < n:
        base = rec[bounds[-1] - 1] if bounds[-1] else 0
        bounds.append(max(int(np.searchsorted(rec, base + CHUNK_BYTES)), bounds[-1] + 1))
    bounds[-1] = min(bounds[-1], n)
    zc = zstandard.ZstdCompressor()
    magic = b"\x89MCAP0\r\n"

    def record(obj) -> bytes:
        rb = RecordBuilder()
        obj.write(rb)
        return rb.end()

    indexes = []
    with open(path, "wb") as f:
        f.write(magic + record(Header(profile="", library="surveil-bench")))
        for a, b in itertools.pairwise(bounds):
            pre = record(sch) + record(chn) if a == 0 else b""
            body = _chunk_records(times[a:b], data, offsets[a : b + 1], a)
            raw = pre + body
            comp = zc.compress(raw)
            t0, t1 = int(times[a:b].min()), int(times[a:b].max())
            ck = Chunk("zstd", comp, t1, t0, zlib.crc32(raw), len(raw))
            start = f.tell()
            cb = record(ck)
            f.write(cb)
            starts = np.concatenate([[0], np.cumsum(31 + np.diff(offsets[a : b + 1]))[:-1]])
            entries = np.empty((b - a, 2), "<u8")
            entries[:, 0], entries[:, 1] = times[a:b], starts + len(pre)
            mi = struct.pack(
                "<BQHI", int(Opcode.MESSAGE_INDEX), 6 + entries.nbytes, 1, entries.nbytes
            )
            mi_at = f.tell()
            f.write(mi + entries.tobytes())
            indexes.append(
                ChunkIndex(
                    message_start_time=t0, message_end_time=t1, chunk_start_offset=start,
                    chunk_length=len(cb), message_index_offsets={1: mi_at},
                    message_index_length=len(mi) + entries.nbytes, compression="zstd",
                    compressed_size=len(comp), uncompressed_size=len(raw),
                )
            )  # fmt: skip
        f.write(record(DataEnd(0)))
        summary_start = f.tell()
        stats = Statistics(
            message_count=n, schema_count=1, channel_count=1, attachment_count=0,
            metadata_count=0, chunk_count=len(indexes), message_start_time=int(times.min()),
            message_end_time=int(times.max()), channel_message_counts={1: n},
        )  # fmt: skip
        summary = record(sch) + record(chn) + record(stats) + b"".join(map(record, indexes))
        crc = zlib.crc32(
            struct.pack("<BQQQ", int(Opcode.FOOTER), 20, summary_start, 0), zlib.crc32(summary)
        )
        f.write(summary + record(Footer(summary_start, 0, crc)) + magic)


def make_files(workdir: Path, n: int, variants: list[str]) -> dict[str, Path]:
    cols = reports(n)
    times = np.sort(cols["time_ns"])  # log time: when the report reached the recorder
    out = {}
    for v in variants:
        path = workdir / f"radar_{v}_{n}.mcap"
        if not path.exists():
            data, offsets, schema = payloads(v, cols)
            write_mcap(path, v, times, data, offsets, schema)
        out[v] = path
    return out


# -- measurements (each run in its own process) ------------------------------------------


def measure_floor(path: Path) -> int:
    """Read the file, decompress every chunk; returns the uncompressed bytes."""
    import zstandard
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        dz = zstandard.ZstdDecompressor()
        total = 0
        for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            f.seek(ci.chunk_start_offset)
            rec = f.read(ci.chunk_length)
            (clen,) = struct.unpack_from("<I", rec, 9 + 28)
            data = memoryview(rec)[9 + 32 + clen + 8 :]
            total += len(dz.decompress(data, max_output_size=ci.uncompressed_size))
    return total


def measure_baseline(path: Path, out: Path) -> int:
    """mcap iter_decoded_messages -> dicts -> pa.Table.from_pylist -> Parquet."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from mcap.reader import make_reader

    class JsonFactory:  # mcap ships no JSON decoder factory
        def decoder_for(self, message_encoding, schema):
            return json.loads if message_encoding == "json" else None

    from mcap_protobuf.decoder import DecoderFactory as PbFactory
    from mcap_ros2.decoder import DecoderFactory as Ros2Factory

    fields = list(reports(1))
    rows = []
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[JsonFactory(), PbFactory(), Ros2Factory()])
        for _, _, msg, obj in reader.iter_decoded_messages():
            # protobuf / ROS 2 objects: one getattr per field
            row = obj if isinstance(obj, dict) else {k: getattr(obj, k) for k in fields}
            row["log_time_ns"] = msg.log_time
            rows.append(row)
    table = pa.Table.from_pylist(rows)
    pq.write_table(table, out, compression="zstd")
    return table.num_rows


def measure_surveil(path: Path, warehouse: Path, executor: str) -> int:
    from pipeline.families import load_config
    from pipeline.ingest.driver import run_ingest

    shutil.rmtree(warehouse, ignore_errors=True)
    summary = run_ingest([path], load_config(), warehouse, executor=executor)
    if summary.exit_code != 0:
        raise RuntimeError(summary.render())
    return summary.rows["radar_tracks"]


_IMPORTS = {
    "floor": ["zstandard", "mcap.reader"],
    "baseline": ["pyarrow", "pyarrow.parquet", "mcap.reader", "mcap_protobuf.decoder",
                 "mcap_ros2.decoder"],
    "surveil": ["pipeline.ingest.driver", "pipeline.config"],
}  # fmt: skip
# what a process does once before its first file, timed with the imports: the table
# schemas (schemas/*.toml; before the ingest context parsed them, the ingest driver did at
# import)
_PREPARE = {"surveil": ["pipeline.tables:table_specs"]}


def run_measurement(kind: str, path: Path, scratch: Path, executor: str, trace: bool) -> dict:
    """One measurement in this process: seconds, rows, peaks. The libraries are imported
    first and timed apart (``import_s``): a nightly job pays them once per process, not
    per file."""
    t_imp = time.perf_counter()
    for module in _IMPORTS[kind]:
        importlib.import_module(module)
    for target in _PREPARE.get(kind, []):
        module, _, name = target.partition(":")
        getattr(importlib.import_module(module), name)()
    import_s = time.perf_counter() - t_imp
    if trace:
        tracemalloc.start()
    t0 = time.perf_counter()
    if kind == "floor":
        rows = measure_floor(path)
    elif kind == "baseline":
        rows = measure_baseline(path, scratch / "baseline.parquet")
    else:
        rows = measure_surveil(path, scratch / "warehouse", executor)
    seconds = time.perf_counter() - t0
    peak_py = tracemalloc.get_traced_memory()[1] if trace else None
    if trace:
        tracemalloc.stop()
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # the process pool
    return {
        "seconds": seconds,
        "import_s": import_s,
        "rows": rows,
        "rss_kb": max(own_peak_kb(), kids),
        "py_peak": peak_py,
    }


def own_peak_kb() -> int:
    """Peak resident set of this process since it started: ``VmHWM`` (per address space;
    ``ru_maxrss`` would also count the parent's pages at fork time), else ``ru_maxrss``."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def generate_in_subprocess(workdir: Path, n: int, variants: list[str]) -> dict[str, Path]:
    cmd = [
        sys.executable, __file__, "--generate", str(n), "--workdir", str(workdir),
        "--variants", ",".join(variants),
    ]  # fmt: skip
    res = subprocess.run(cmd, capture_output=True, text=True, check=False, cwd=REPO)
    if res.returncode != 0:
        raise RuntimeError(f"generating {n} reports failed:\n{res.stderr[-3000:]}")
    return {v: Path(p) for v, p in json.loads(res.stdout.strip().splitlines()[-1]).items()}


def in_subprocess(kind: str, path: Path, scratch: Path, executor: str, trace: bool) -> dict:
    cmd = [
        sys.executable, __file__, "--measure", kind, "--file", str(path),
        "--scratch", str(scratch), "--executor", executor,
    ]  # fmt: skip
    if trace:
        cmd.append("--trace")
    res = subprocess.run(cmd, capture_output=True, text=True, check=False, cwd=REPO)
    if res.returncode != 0:
        raise RuntimeError(f"{kind} on {path.name} failed:\n{res.stderr[-3000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


# -- the run -----------------------------------------------------------------------------


def machine() -> str:
    model = "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),)
    from importlib.metadata import version  # no import of the libraries themselves here

    libs = ", ".join(
        f"{m} {version(m)}" for m in ("polars", "pyarrow", "numpy", "deltalake", "mcap")
    )
    return (
        f"machine: {os.cpu_count()} CPUs ({model}), load average {load[0]:.2f}; "
        f"Python {platform.python_version()}, {libs}"
    )


def plan(variants: list[str], executors: list[str]) -> list[tuple[str, str, str]]:
    """(variant, measurement, executor) in the order they run."""
    steps = []
    for v in variants:
        steps.append((v, "floor", "-"))
        steps += [(v, "surveil", e) for e in executors]
        steps.append((v, "baseline", "-"))
    return steps


def bench(args: argparse.Namespace) -> list[dict]:
    workdir = (
        Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="surveil-bench-"))
    )
    workdir.mkdir(parents=True, exist_ok=True)
    # N before N/4: the headline cells are measured in the first minute of the run (a
    # shared host's speed drifts within minutes; the floor and baseline of each size are
    # measured next to its surveil runs either way). The table lists sizes ascending.
    sizes = sorted({max(1, args.messages // 4), args.messages}, reverse=True)
    variants = args.variants.split(",")
    executors = args.executors.split(",")
    results = []
    for n in sizes:
        t0 = time.perf_counter()
        if args.in_process:
            files = make_files(workdir, n, variants)
        else:  # keep this process small: its children's peak RSS counts it from fork on
            files = generate_in_subprocess(workdir, n, variants)
        print(
            f"wrote {n:,} reports x {len(files)} variants in {time.perf_counter() - t0:.1f} s",
            flush=True,
        )
        for variant, kind, executor in plan(variants, executors):
            path = files[variant]
            scratch = workdir / f"scratch_{variant}_{n}_{kind}_{executor}"
            scratch.mkdir(exist_ok=True)
            run = run_measurement if args.in_process else in_subprocess
            timed = [run(kind, path, scratch, executor, False) for _ in range(args.repeat)]
            traced = run(kind, path, scratch, executor, True) if args.tracemalloc else None
            r = {
                "variant": variant, "messages": n, "what": kind, "executor": executor,
                "file_mb": path.stat().st_size / 1e6,
                "seconds": statistics.median(t["seconds"] for t in timed),
                "import_s": statistics.median(t["import_s"] for t in timed),
                "rows": timed[0]["rows"], "rss_mb": max(t["rss_kb"] for t in timed) / 1024,
                "py_peak_mb": traced["py_peak"] / 2**20 if traced else None,
            }  # fmt: skip
            if kind != "floor" and r["rows"] != n:
                raise RuntimeError(f"{variant} {kind}: {r['rows']} rows, expected {n}")
            results.append(r)
            print(f"  {variant:8s} {kind:8s} {executor:7s} {r['seconds']:7.2f} s", flush=True)
            shutil.rmtree(scratch, ignore_errors=True)
    if not args.workdir:
        shutil.rmtree(workdir, ignore_errors=True)
    return results


def table(results: list[dict]) -> str:
    ref = {
        (r["variant"], r["messages"], r["what"]): r["seconds"]
        for r in results
        if r["what"] != "surveil"
    }
    lines = [
        f"{'variant':8s} {'messages':>9s} {'what':8s} {'executor':8s} {'s':>7s} {'msg/s':>10s} "
        f"{'MB/s':>7s} {'x baseline':>10s} {'x floor':>8s} {'RSS MB':>7s} {'py peak MB':>10s} "
        f"{'import s':>8s}"
    ]
    for r in sorted(results, key=lambda r: r["messages"]):  # stable: run order within a size
        key = (r["variant"], r["messages"])
        base = ref.get((*key, "baseline"))
        floor = ref.get((*key, "floor"))
        rate = r["messages"] / r["seconds"]
        speedup = f"{base / r['seconds']:.1f}" if base else "-"
        over = f"{r['seconds'] / floor:.1f}" if floor else "-"
        peak = f"{r['py_peak_mb']:.0f}" if r["py_peak_mb"] is not None else "-"
        lines.append(
            f"{r['variant']:8s} {r['messages']:9,d} {r['what']:8s} {r['executor']:8s} "
            f"{r['seconds']:7.2f} {rate:10,.0f} {r['file_mb'] / r['seconds']:7.1f} "
            f"{speedup:>10s} {over:>8s} {r['rss_mb']:7.0f} {peak:>10s} {r['import_s']:8.2f}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--messages", type=int, default=1_000_000)
    p.add_argument("--workdir", default=None, help="keep the generated files here (reused)")
    p.add_argument("--executors", default="serial,process")
    p.add_argument("--variants", default="json,protobuf,ros2")
    p.add_argument("--repeat", type=int, default=1, help="timed runs per cell (median)")
    p.add_argument("--no-tracemalloc", dest="tracemalloc", action="store_false")
    p.add_argument("--in-process", action="store_true", help="no subprocess per measurement")
    p.add_argument("--json", dest="json_out", default=None, help="also write the results here")
    # internal: one measurement in a child process
    p.add_argument("--measure", help=argparse.SUPPRESS)
    p.add_argument("--file", help=argparse.SUPPRESS)
    p.add_argument("--scratch", help=argparse.SUPPRESS)
    p.add_argument("--executor", default="serial", help=argparse.SUPPRESS)
    p.add_argument("--trace", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--generate", type=int, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.generate:
        files = make_files(Path(args.workdir), args.generate, args.variants.split(","))
        print(json.dumps({v: str(p) for v, p in files.items()}))
        return 0
    if args.measure:
        r = run_measurement(
            args.measure, Path(args.file), Path(args.scratch), args.executor, args.trace
        )
        print(json.dumps(r))
        return 0
    print(machine(), flush=True)
    results = bench(args)
    print()
    print(table(results))
    if args.json_out:
        Path(args.json_out).write_text(
            json.dumps({"machine": machine(), "results": results}, indent=1)
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
