"""Hostile-input bench (issue 18): generate each class of bad input, run the commands an
operator would (``surveil import`` / ``ingest`` / ``batch`` / ``report``) as real
subprocesses, and print one row per case: the exit codes, whether any command printed a
traceback, rows kept against rows expected (every good item), and the rejects rows.

    .venv/bin/python bench/hostile.py [--workdir DIR] [--cases a,b,...] [--no-batch]

Goal: no traceback in any row, nothing lost beyond the bad item (kept == expected), the
bad items counted as rejects, exit 1 whenever something was rejected, exit 2 for usage
errors. The inputs come from :mod:`pipeline.simulate.hostile` (deterministic).

The second table (issue 40, ``--trust``; ``--no-trust`` skips it) is the warehouse under
attack: a copy of the ``clean`` case's batched warehouse per case, damaged (a log entry
cut in half, a garbage next version, a raw or derived Parquet file deleted or rewritten)
or abused (analysts' SQL that writes files, reads outside the warehouse, attaches or
installs; report parameters that are no numbers; a site name that is terminal markup; a
FIFO in an archive folder; configs that make no physical sense), then the commands an
operator runs, each with the exit codes that tell the truth. Goal: every code as
expected, no traceback, no command hanging, nothing written outside the warehouse.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from pipeline.simulate import hostile as h  # noqa: E402
from pipeline.units import NS  # noqa: E402

HOUR_NS = 3600 * NS
N_RADAR = 2000  # good radar reports per MCAP case
N_AST = 9832  # ASTERIX records (as in the damaged .ast)
N_PCAP = 7576  # ASTERIX records in the pcap cases (as in the pcap)
N_GNSS = 252  # nmea_fixes(120): RMC + GGA each second, ZDA every 10 s: a nav_gnss row each
RADAR_T = "radar_tracks"
AST_T = "airfield_obs"


@dataclass
class Case:
    """One hostile input: files to write, the table whose rows count, how many rows a
    loss-free run keeps, how many rejects rows it should write, and the steps to run."""

    name: str
    what: str
    table: str
    expected: int
    bad_items: int
    make: Callable[[Path], None]
    imported: bool = False  # the input goes through `surveil import` first
    extra: list[list[str]] = field(default_factory=list)  # more commands (window abuse)
    window: tuple[int, int] = (h.T0_NS, h.T0_NS + HOUR_NS)
    warehouse: str = "wh"  # the warehouse folder's name (a hostile one in one case)


def _radar(n: int = N_RADAR) -> list[tuple[int, bytes]]:
    return [(h.T0_NS + i * NS, h.radar_report(i)) for i in range(n)]


def _with(bad: list[tuple[int, bytes]]) -> Callable[[Path], None]:
    def make(d: Path) -> None:
        msgs = sorted(_radar() + bad, key=lambda m: m[0] % 2**63)
        h.write_radar_mcap(d / "in" / "case.mcap", msgs)

    return make


DEEP = b'{"a":' * 1000 + b"1" + b"}" * 1000


AST_K = len(h.cat010_blocks(N_AST)) // 80  # the broken block: early, as in the issue


def _ast_bad_len(d: Path) -> None:
    blocks = h.cat010_blocks(N_AST)
    data = b"".join(blocks)
    k = AST_K
    off = sum(len(b) for b in blocks[:k])
    h.write(d / "in" / "damaged.ast", h.damage_length(data, off + 1, 60_000))


def _records_in(blocks: list[bytes], k: int) -> int:
    """CAT010 records in data block ``k`` (one, two or three: see cat010_blocks)."""
    return 1 + k % 3


def _pcap(d: Path, ng: bool) -> None:
    blocks = h.cat010_blocks(N_PCAP)
    t0 = h.T0_NS + 36_000 * NS
    frames = [(t0 + i * NS // 10, h.udp_frame(b)) for i, b in enumerate(blocks)]
    k = 33
    if ng:
        data, offs = h.pcapng_bytes(frames)
        data = data[: offs[k] + 4] + (123_457).to_bytes(4, "little") + data[offs[k] + 8 :]
        h.write(d / "in" / "damaged.pcapng", data)
    else:
        data, offs = h.pcap_bytes(frames)
        h.write(d / "in" / "damaged.pcap", h.damage_length(data, offs[k] + 8, 60_000))


def _nmea(lines: list[str], name: str = "gnss.log") -> Callable[[Path], None]:
    def make(d: Path) -> None:
        h.write(d / "in" / name, "\r\n".join(lines) + "\r\n")

    return make


def _zda_lines() -> list[str]:
    lines = h.nmea_fixes(120)
    bad = h.nmea_sentence("GPZDA,120130.00,15,01,26,00,00")  # two-digit year
    return [*lines[:50], bad, *lines[50:]]


def _vendor_lines() -> list[str]:
    lines = h.nmea_fixes(120)
    return ["# vendor header: ACME plotter v2", *lines[:30], "#PACME,status,ok", *lines[30:]]


def _concat(d: Path) -> None:
    a = h.write_radar_mcap(d / "a.mcap", _radar(1000))
    later = [(h.T0_NS + (1000 + i) * NS, h.radar_report(1000 + i, site="R1"))
             for i in range(1000)]  # fmt: skip
    b = h.write_radar_mcap(d / "b.mcap", later)
    h.write(d / "in" / "cat.mcap", a.read_bytes() + b.read_bytes())


def _duplicate(d: Path) -> None:
    p = h.write_radar_mcap(d / "in" / "first.mcap", _radar())
    shutil.copy(p, d / "in" / "same_content.mcap")


def _truncated(d: Path) -> None:
    p = h.write_radar_mcap(d / "whole.mcap", _radar())
    data = p.read_bytes()
    h.write(d / "in" / "cut.mcap", data[: len(data) // 2])


def _not_mcap(d: Path) -> None:
    h.write_radar_mcap(d / "in" / "good.mcap", _radar())
    h.write(d / "in" / "sheet.mcap", "this is a spreadsheet, not an MCAP file\n")


def _plain(d: Path) -> None:
    h.write_radar_mcap(d / "in" / "good.mcap", _radar())


def _t(k: int) -> int:
    return h.T0_NS + k * NS + 1


FAR = "9999-01-01T00:00:00Z"
CASES = [
    Case("clean", "2,000 good radar reports (reference row)", RADAR_T, N_RADAR, 0, _plain),
    Case("deep_json", "one radar payload nested 1,000 deep (2 KB)", RADAR_T, N_RADAR, 1,
         _with([(_t(5), DEEP)])),
    Case("log_time_2p63+5", "one message with log_time above int64 (legal MCAP)", RADAR_T,
         N_RADAR, 1, _with([(2**63 + 5, h.radar_report(3))])),
    Case("log_time_2p64-1", "one message with log_time = uint64 max", RADAR_T, N_RADAR, 1,
         _with([(2**64 - 1, h.radar_report(3))])),
    Case("x_site_1e308", "one report with x = 1e308 m", RADAR_T, N_RADAR, 1,
         _with([(_t(7), h.radar_report(7, x_m=1e308))])),
    Case("time_ns_0", "one report with time_ns = 0", RADAR_T, N_RADAR, 1,
         _with([(_t(7), h.radar_report(7, t_ns=0))])),
    Case("time_ns_int64_max", "one report with time_ns = 2^63-1", RADAR_T, N_RADAR, 1,
         _with([(_t(7), h.radar_report(7, t_ns=2**63 - 1))])),
    Case("site_id_5MB", "one report with a 5 MB site_id", RADAR_T, N_RADAR, 1,
         _with([(_t(7), h.radar_report(7, site="R" * (5 << 20)))])),
    Case("site_id_8KB", "one report with an 8 KB site_id", RADAR_T, N_RADAR, 1,
         _with([(_t(7), h.radar_report(7, site="R" * 8192))])),
    Case("not_json", "one payload that is not JSON", RADAR_T, N_RADAR, 1,
         _with([(_t(9), b'{"site_id": "R1", "track_id": ')])),
    Case("ast_bad_len", f"raw ASTERIX, {N_AST} records, one LEN octet broken", AST_T,
         N_AST - _records_in([], AST_K), 1, _ast_bad_len, imported=True),
    Case("pcap_bad_len", f"pcap, {N_PCAP} records, one record length broken", AST_T,
         N_PCAP - _records_in([], 33), 1, lambda d: _pcap(d, False), imported=True),
    Case("pcapng_bad_block", f"pcapng, {N_PCAP} records, one block length broken", AST_T,
         N_PCAP - _records_in([], 33), 1, lambda d: _pcap(d, True), imported=True),
    Case("gpzda_2digit_year", "NMEA log, one $GPZDA with a two-digit year", "nav_gnss",
         N_GNSS, 1, _nmea(_zda_lines()), imported=True),
    Case("vendor_#_lines", "NMEA log with '#' vendor lines (counted, not messages)",
         "nav_gnss", N_GNSS, 0, _nmea(_vendor_lines()), imported=True),
    Case("concatenated_mcap", "cat a.mcap b.mcap > c.mcap (1,000 + 1,000 reports)", RADAR_T,
         2000, 0, _concat),
    Case("duplicate_content", "the same file under two names", RADAR_T, N_RADAR, 0,
         _duplicate),
    Case("truncated_mcap", "an MCAP file cut in half (kept: what precedes the cut)",
         RADAR_T, -1, 1, _truncated),
    Case("not_mcap", "a text file named .mcap beside a good one", RADAR_T, N_RADAR, 1,
         _not_mcap),
    Case("window_far_future", "batch / reprocess / ingest --to 9999-01-01", RADAR_T, N_RADAR,
         0, _plain, extra=[["batch", "--from", "2026-01-01", "--to", FAR],
                           ["reprocess", "--from", "2026-01-01", "--to", FAR],
                           ["ingest", "{in}", "--from", "2026-01-01", "--to", FAR]]),
    Case("warehouse_path_^", "a warehouse path Delta cannot use ('^': a Rust panic before)",
         RADAR_T, 0, 0, _plain, warehouse="wh^1"),
    Case("window_year", "batch over a year holding one hour of data (clipped)", RADAR_T,
         N_RADAR, 0, _plain,
         window=(h.T0_NS - 180 * 24 * HOUR_NS, h.T0_NS + 185 * 24 * HOUR_NS)),
]  # fmt: skip


def _iso(t_ns: int) -> str:
    import datetime as dt

    return dt.datetime.fromtimestamp(t_ns // NS, dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _run(args: list[str], wh: Path, timeout_s: float | None = None) -> tuple[int, bool, str]:
    """``surveil --warehouse wh ARGS`` as a subprocess (no stdin): exit code, whether it
    printed a traceback (or a C++ abort), its output."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "jobs.cli", "--warehouse", str(wh), *args]
    res = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, check=False,
                         timeout=timeout_s, stdin=subprocess.DEVNULL)
    text = res.stdout + res.stderr
    return res.returncode, "Traceback" in text or "terminate called" in text, text


def run_case(case: Case, root: Path, batch: bool) -> dict:
    d = root / case.name
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    case.make(d)
    wh = d / case.warehouse
    codes: dict[str, int | str] = {}
    tb = False
    src = d / "in"
    if case.imported:
        codes["import"], t, _ = _run(["import", str(src), "--out", str(d / "mcap")], wh)
        tb |= t
        src = d / "mcap"
    codes["ingest"], t, _ = _run(["ingest", str(src), "--executor", "serial"], wh)
    tb |= t
    if batch:
        lo, hi = case.window
        codes["batch"], t, _ = _run(["batch", "--from", _iso(lo), "--to", _iso(hi),
                                     "--executor", "serial"], wh)  # fmt: skip
        tb |= t
        codes["report"], t, _ = _run(["report", "accuracy_by_sector", "--from", _iso(lo),
                                      "--to", _iso(hi)], wh)  # fmt: skip
        tb |= t
    for extra in case.extra:
        args = [a.replace("{in}", str(src)) for a in extra] + ["--executor", "serial"]
        codes[f"{extra[0]}(abuse)"], t, _ = _run(args, wh)
        tb |= t
    from pipeline.warehouse.delta import read_table

    if case.warehouse != "wh":  # refused: nothing may have been written there
        wh = d / "nothing_written"
    kept = read_table(wh, case.table, columns=["source_file"]).num_rows
    rejects = read_table(wh, "rejects", columns=["reason_code"]).column(0).to_pylist()
    by_code: dict[str, int] = {}
    for c in rejects:
        by_code[c] = by_code.get(c, 0) + 1
    return {"case": case.name, "codes": codes, "traceback": tb, "kept": kept,
            "expected": case.expected, "rejects": by_code, "bad": case.bad_items}  # fmt: skip


def render(rows: list[dict]) -> str:
    head = (f"| {'case':<20} | {'exit codes':<70} | tb | {'kept / expected':<15} | "
            f"rejects rows (bad items) |")  # fmt: skip
    out = [head, "|" + "|".join("-" * (len(c)) for c in head.split("|")[1:-1]) + "|"]
    for r in rows:
        codes = " ".join(f"{k} {v}" for k, v in r["codes"].items())
        exp = "all" if r["expected"] < 0 else str(r["expected"])
        rej = ", ".join(f"{k} {v}" for k, v in sorted(r["rejects"].items())) or "none"
        out.append(f"| {r['case']:<20} | {codes:<70} | {'YES' if r['traceback'] else 'no':<2} "
                   f"| {r['kept']:>6} / {exp:<6} | {rej} ({r['bad']}) |")  # fmt: skip
    return "\n".join(out)


# --- the warehouse under attack (issue 40) --------------------------------------------------

DERIVED_T = "system_tracks"


@dataclass
class TrustCase:
    """One attack on a batched warehouse: ``attack(case_dir, warehouse)`` damages it or
    writes inputs, and returns the commands to run with the exit codes each may end in;
    ``outside``: a path no command may create."""

    name: str
    what: str
    attack: Callable[[Path, Path], list[tuple[list[str], set[int]]]]
    outside: str = ""


def _delta_file(wh: Path, table: str) -> Path:
    from urllib.parse import unquote

    from deltalake import DeltaTable

    root = wh / "tables" / table
    rel = DeltaTable(str(root)).get_add_actions(flatten=True).column("path")[0].as_py()
    return root / unquote(rel)


def _newest_log(wh: Path, table: str) -> Path:
    return max((wh / "tables" / table / "_delta_log").glob("*.json"), key=lambda p: int(p.stem))


def _window_args() -> list[str]:
    return ["--from", _iso(h.T0_NS), "--to", _iso(h.T0_NS + HOUR_NS)]


REPORT = ["report", "map_tracks", *_window_args()]
BATCH = ["batch", *_window_args(), "--executor", "serial"]
DOCTOR_THEN_OK = [(["doctor"], {1}), (["doctor", "--repair"], {0, 1}), (REPORT, {0})]


def _truncated_log(_d: Path, wh: Path) -> list[tuple[list[str], set[int]]]:
    entry = _newest_log(wh, DERIVED_T)
    entry.write_bytes(entry.read_bytes()[: entry.stat().st_size // 2])
    return [(REPORT, {2}), (BATCH, {2}), *DOCTOR_THEN_OK]


def _garbage_next(_d: Path, wh: Path) -> list[tuple[list[str], set[int]]]:
    entry = _newest_log(wh, DERIVED_T)
    (entry.parent / f"{int(entry.stem) + 1:020d}.json").write_text("garbage{\n")
    return [(REPORT, {2}), *DOCTOR_THEN_OK]


def _derived_deleted(_d: Path, wh: Path) -> list[tuple[list[str], set[int]]]:
    _delta_file(wh, DERIVED_T).unlink()
    return [(REPORT, {2}), *DOCTOR_THEN_OK]


def _derived_rewritten(_d: Path, wh: Path) -> list[tuple[list[str], set[int]]]:
    with open(_delta_file(wh, DERIVED_T), "ab") as f:
        f.write(b"tampered")
    return [(REPORT, {2}), (["sql", f"SELECT count(*) FROM {DERIVED_T}"], {2}),
            *DOCTOR_THEN_OK]


def _raw_deleted(d: Path, wh: Path) -> list[tuple[list[str], set[int]]]:
    _delta_file(wh, RADAR_T).unlink()
    base_in = d.parents[1] / "clean" / "in"  # the archive file its ledger names
    return [(BATCH, {2}), (["doctor", "--repair"], {1}),
            (["ingest", str(base_in), "--force", "--executor", "serial"], {0}),
            (BATCH, {0}), (["doctor"], {0})]


def _sql(query: str) -> Callable[[Path, Path], list[tuple[list[str], set[int]]]]:
    def attack(d: Path, wh: Path) -> list[tuple[list[str], set[int]]]:
        q = query.replace("{wh}", str(wh)).replace("{d}", str(d))
        return [(["sql", q], {2}), (REPORT, {0})]

    return attack


def _params(_d: Path, _wh: Path) -> list[tuple[list[str], set[int]]]:
    return [([*REPORT, "--param", f"step_s={v}"], {2}) for v in ("0", "inf", "nan", "-5")]


def _audit_sector(d: Path, _wh: Path) -> list[tuple[list[str], set[int]]]:
    return [(["audit", *_window_args(), "--sector", "a/b", "--out", str(d / "audit")], {2})]


def _markup_site(d: Path, _wh: Path) -> list[tuple[list[str], set[int]]]:
    h.write_radar_mcap(d / "odd" / "site.mcap", _radar(50), site="[/]")
    return [(["ingest", str(d / "odd"), "--executor", "serial"], {1}),
            (["sql", "SELECT * FROM rejects"], {0}), (REPORT, {0})]


def _fifo(d: Path, _wh: Path) -> list[tuple[list[str], set[int]]]:
    folder = d / "archive"
    h.write_radar_mcap(folder / "good.mcap", _radar(50))
    os.mkfifo(folder / "recorder.mcap")
    (folder / "gone.mcap").symlink_to(folder / "nowhere.mcap")
    return [(["ingest", str(folder), "--executor", "serial"], {0, 1}),
            (["run", str(folder), "--executor", "serial"], {0, 1})]


def _config(edit: Callable[[str], str]) -> Callable[[Path, Path], list[tuple[list[str], set[int]]]]:
    def attack(d: Path, _wh: Path) -> list[tuple[list[str], set[int]]]:
        cfg = d / "site.toml"
        cfg.write_text(edit((REPO / "config" / "surveil.toml").read_text()))
        return [(["config", "check", str(cfg)], {2}), (["--config", str(cfg), *BATCH], {2})]

    return attack


def _bow_tie(text: str) -> str:
    return text + ('\n[[sectors]]\nname = "bow_tie"\npolygon = [[46.30, 30.70], [46.40, 30.80], '
                   '[46.30, 30.80], [46.40, 30.70]]\n')


def _many_sectors(text: str) -> str:
    cells = "".join(f'\n[[sectors]]\nname = "s{i}"\npolygon = [[46.0, {30 + i * 1e-3:.3f}], '
                    f'[46.0, {30.0005 + i * 1e-3:.4f}], [46.1, {30.0005 + i * 1e-3:.4f}], '
                    f'[46.1, {30 + i * 1e-3:.3f}]]\n' for i in range(10_000))
    return text + cells


TRUST_CASES = [
    TrustCase("log_truncated", f"{DERIVED_T}'s newest log entry cut in half", _truncated_log),
    TrustCase("log_garbage_next", f"a garbage next version of {DERIVED_T}", _garbage_next),
    TrustCase("derived_deleted", f"a Parquet file of {DERIVED_T} deleted", _derived_deleted),
    TrustCase("derived_rewritten", f"a Parquet file of {DERIVED_T} rewritten (size)",
              _derived_rewritten),
    TrustCase("raw_deleted", f"a Parquet file of {RADAR_T} deleted", _raw_deleted),
    TrustCase("sql_copy_into_wh", "sql COPY ... TO a file in the warehouse",
              _sql(f"COPY (SELECT 1 AS x) TO '{{wh}}/tables/{DERIVED_T}/x.parquet'"),
              outside=f"wh/tables/{DERIVED_T}/x.parquet"),
    TrustCase("sql_copy_out", "sql COPY ... TO a file elsewhere",
              _sql("COPY (SELECT 1 AS x) TO '{d}/out.csv'"), outside="out.csv"),
    TrustCase("sql_read_passwd", "sql read_csv('/etc/passwd')",
              _sql("SELECT * FROM read_csv('/etc/passwd')")),
    TrustCase("sql_attach", "sql ATTACH another database",
              _sql("ATTACH '{d}/other.duckdb' AS other"), outside="other.duckdb"),
    TrustCase("sql_install", "sql INSTALL httpfs (the network)", _sql("INSTALL httpfs")),
    TrustCase("sql_set", "sql SET enable_external_access = true",
              _sql("SET enable_external_access = true")),
    TrustCase("param_not_a_number", "report --param step_s = 0 / inf / nan / -5", _params),
    TrustCase("audit_sector_a/b", "audit --sector 'a/b'", _audit_sector),
    TrustCase("site_markup", "an MCAP whose metadata site is '[/]'", _markup_site),
    TrustCase("archive_fifo", "a FIFO and a dangling link in an archive folder", _fifo),
    TrustCase("scan_period_1e-9", "a radar with scan_period_s = 1e-9",
              _config(lambda t: t.replace("scan_period_s = 3.0", "scan_period_s = 1e-9", 1))),
    TrustCase("sector_bow_tie", "a self-intersecting sector", _config(_bow_tie)),
    TrustCase("sectors_10000", "10,000 sectors", _config(_many_sectors)),
]


def _run_limited(args: list[str], wh: Path, timeout_s: float = 300.0
                 ) -> tuple[int | str, bool]:
    try:
        code, tb, _ = _run(args, wh, timeout_s)
    except subprocess.TimeoutExpired:
        return "hung", False
    return code, tb


def run_trust_case(case: TrustCase, base: Path, root: Path) -> dict:
    d = root / "trust" / case.name.replace("/", "_")
    shutil.rmtree(d, ignore_errors=True)
    shutil.copytree(base.parent, d, symlinks=True)
    wh = d / base.name
    steps = case.attack(d, wh)
    done, tb, as_expected = [], False, True
    for args, allowed in steps:
        code, t = _run_limited(args, wh)
        tb |= t
        ok = code in allowed
        as_expected &= ok
        name = next((a for a in args if not a.startswith("-") and "/" not in a), args[0])
        done.append(f"{name} {code}{'' if ok else '!'}")
    wrote = bool(case.outside) and (d / case.outside).exists()
    return {"case": case.name, "codes": done, "traceback": tb,
            "ok": as_expected and not wrote and not tb,
            "wrote": wrote}  # fmt: skip


def render_trust(rows: list[dict]) -> str:
    head = (f"| {'case':<20} | {'commands and exit codes (! = not the expected code)':<78} "
            f"| tb | wrote outside | as expected |")  # fmt: skip
    out = [head, "|" + "|".join("-" * (len(c)) for c in head.split("|")[1:-1]) + "|"]
    for r in rows:
        out.append(f"| {r['case']:<20} | {', '.join(r['codes']):<78} | "
                   f"{'YES' if r['traceback'] else 'no':<2} | {'YES' if r['wrote'] else 'no':<13} "
                   f"| {'yes' if r['ok'] else 'NO':<11} |")  # fmt: skip
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", type=Path, default=None)
    ap.add_argument("--cases", default="", help="comma-separated case names (default: all)")
    ap.add_argument("--no-batch", action="store_true", help="import/ingest only")
    ap.add_argument("--no-trust", action="store_true", help="skip the warehouse attacks")
    a = ap.parse_args()
    root = a.workdir or Path(tempfile.mkdtemp(prefix="surveil-hostile-"))
    wanted = {c for c in a.cases.split(",") if c}
    rows = []
    t0 = time.monotonic()
    for case in CASES:
        if wanted and case.name not in wanted:
            continue
        rows.append(run_case(case, root, not a.no_batch))
        print(render(rows[-1:]).splitlines()[-1], flush=True)
    if rows:
        print()
        print(render(rows))
    print(f"\n{len(rows)} cases in {time.monotonic() - t0:.0f} s; inputs under {root}")
    bad = [r["case"] for r in rows if r["traceback"]]
    lost = [r["case"] for r in rows if r["expected"] >= 0 and r["kept"] != r["expected"]]
    print(f"tracebacks: {', '.join(bad) or 'none'}; rows lost beyond the bad item: "
          f"{', '.join(lost) or 'none'}")
    if a.no_trust or a.no_batch:
        return
    base = root / "clean" / "wh"
    if not base.exists():
        run_case(CASES[0], root, True)
    trust = []
    for tcase in TRUST_CASES:
        if wanted and tcase.name not in wanted and "trust" not in wanted:
            continue
        trust.append(run_trust_case(tcase, base, root))
        print(render_trust(trust[-1:]).splitlines()[-1], flush=True)
    print()
    print(render_trust(trust))
    off = [r["case"] for r in trust if not r["ok"]]
    print(f"\nwarehouse attacks: {len(trust)} cases; not as expected: {', '.join(off) or 'none'}")


if __name__ == "__main__":
    main()
