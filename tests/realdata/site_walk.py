"""A recording, as its own site, walked the way docs/site.md tells a new user to:
``import`` -> ``config init`` -> ``ingest`` -> ``batch`` -> every ``report`` ->
``audit``, each step a real ``surveil`` process (its exit code, stdout and stderr kept),
with no hand-written config. Used by tests/realdata/test_site_walk.py and runnable by
hand: ``python -m tests.realdata.site_walk RECORDING [--origin LAT,LON]``."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import polars as pl

REPO = Path(__file__).resolve().parents[2]
HOUR_NS = 3600 * 10**9


@dataclass
class Step:
    args: list[str]
    code: int
    out: str
    err: str

    @property
    def command(self) -> str:
        return "surveil " + " ".join(self.args)

    def traceback(self) -> bool:
        return "Traceback (most recent call last)" in self.err + self.out


@dataclass
class Walk:
    recording: Path
    root: Path
    site: str
    steps: list[Step] = field(default_factory=list)
    reports: dict[str, Step] = field(default_factory=dict)
    window: tuple[str, str] | None = None

    @property
    def config(self) -> Path:
        return self.root / f"{self.site}.toml"

    @property
    def warehouse(self) -> Path:
        return self.root / "warehouse"

    def step(self, name: str) -> Step:
        return next(s for s in self.steps if s.args[0] == name or
                    (s.args[:2] == ["config", name]))

    def empty_reports(self) -> dict[str, str]:
        """report -> the reason its stderr gives for no rows."""
        out = {}
        for name, s in self.reports.items():
            for line in s.err.splitlines():
                if line.startswith(f"{name}: no rows."):
                    out[name] = line.split("no rows.", 1)[1].strip()
        return out


def surveil(args: list[str], cwd: Path) -> Step:
    res = subprocess.run([sys.executable, "-m", "jobs.cli", *args], capture_output=True,
                         text=True, cwd=cwd, env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin",
                                                  "HOME": str(cwd)}, check=False)
    return Step(args, res.returncode, res.stdout, res.stderr)


def _window(warehouse: Path) -> tuple[str, str] | None:
    from pipeline.warehouse.delta import read_table

    led = pl.from_arrow(read_table(warehouse, "ingest_ledger",
                                   columns=["start_time_ns", "end_time_ns"]))
    if led.height == 0 or led["start_time_ns"].null_count() == led.height:
        return None
    lo = int(led["start_time_ns"].min()) // HOUR_NS * HOUR_NS
    hi = (int(led["end_time_ns"].max()) // HOUR_NS + 1) * HOUR_NS
    return str(lo), str(hi)


def walk(recording: Path, root: Path, site: str, *, origin: str | None = None,
         base_time: str | None = None, reports: tuple[str, ...] | None = None) -> Walk:
    """Walk ``recording`` (a file or a folder) as site ``site`` under ``root``."""
    root.mkdir(parents=True, exist_ok=True)
    w = Walk(recording, root, site)
    cfg, wh = str(w.config), str(w.warehouse)
    imp = ["import", str(recording), "--out", str(root / "archive"), "--site", site]
    if base_time:
        imp += ["--base-time", base_time]
    is_mcap = recording.suffix == ".mcap"
    archive = str(recording) if is_mcap else str(root / "archive")
    if not is_mcap:
        w.steps.append(surveil(imp, root))
    init = ["config", "init", archive, "--out", cfg, "--name", site]
    if origin:
        init += ["--origin", origin]
    w.steps.append(surveil(init, root))
    if w.steps[-1].code != 0:
        return w
    ingest = ["ingest", archive, "--config", cfg, "--warehouse", wh, "--executor", "serial"]
    if is_mcap:
        ingest += ["--site", site]
    w.steps.append(surveil(ingest, root))
    w.window = _window(w.warehouse)
    if w.window is None:
        return w
    frm, to = w.window
    common = ["--from", frm, "--to", to, "--config", cfg, "--warehouse", wh]
    w.steps.append(surveil(["batch", *common, "--executor", "serial"], root))
    names = reports
    if names is None:
        listed = surveil(["report", "--list", "--config", cfg], root)
        names = tuple(line.split()[0] for line in listed.out.splitlines() if line.strip())
    for name in names:
        w.reports[name] = surveil(["report", name, *common, "--site", site, "--format",
                                   "json"], root)
    w.steps.append(surveil(["audit", *common, "--site", site, "--out", str(root / "audit")],
                           root))
    return w


def main() -> None:  # pragma: no cover (by hand)
    import argparse
    import tempfile

    ap = argparse.ArgumentParser()
    ap.add_argument("recording", type=Path)
    ap.add_argument("--origin")
    ap.add_argument("--base-time")
    ap.add_argument("--site", default="mysite")
    ap.add_argument("--root", type=Path, default=None)
    a = ap.parse_args()
    root = a.root or Path(tempfile.mkdtemp(prefix="walk-"))
    w = walk(a.recording, root, a.site, origin=a.origin, base_time=a.base_time)
    for s in w.steps:
        print(f"$ {s.command}\n  -> exit {s.code}")
        print("  " + (s.out.strip() + "\n" + s.err.strip()).strip().replace("\n", "\n  ")[:3000])
    for name, why in w.empty_reports().items():
        print(f"  empty {name}: {why}")
    print(json.dumps({n: s.code for n, s in w.reports.items()}))
    print(root)


if __name__ == "__main__":  # pragma: no cover
    main()


def write_cat010_capture(out: Path, *, duration_s: float = 3600.0, seed: int = 11,
                         scenario_config: Path | None = None) -> Path:
    """An airfield capture as a real one arrives: the ``airfield`` scenario's CAT010 data
    blocks (SMR 0/10, MLAT 0/20; the demo's fault schedule unless ``scenario_config``)
    back to back in a raw ASTERIX file, without truth, VASN or MCAP metadata. Read with
    ``surveil import --base-time 2026-01-15`` (the records carry the time of day)."""
    import tempfile

    from mcap.reader import make_reader

    from jobs.simulate import run_simulate
    from pipeline.families import load_config

    with tempfile.TemporaryDirectory() as tmp:
        files = run_simulate("airfield", duration_s, seed, Path(tmp), load_config(),
                             scenario_config=scenario_config)
        blocks: list[tuple[int, bytes]] = []
        for f in files:
            with open(f, "rb") as fh:
                for _, ch, m in make_reader(fh).iter_messages():
                    if ch.message_encoding == "asterix":
                        blocks.append((m.log_time, m.data))
    blocks.sort(key=lambda b: b[0])
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(b"".join(d for _, d in blocks))
    return out
