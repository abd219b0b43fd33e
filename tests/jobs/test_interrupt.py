"""Issue 18, item 5: SIGINT / SIGTERM stop a job cleanly (real subprocesses): exit 130 /
143, no traceback, no pool worker left behind, nothing incomplete committed (every file
in the ledger has all its rows), no staging left, and a re-run converges."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from mcap_fixtures import T0_NS, radar_messages, write_mcap

from pipeline.warehouse.delta import read_table

REPO = Path(__file__).resolve().parents[2]
N_FILES, N_MSGS = 24, 2000


def _archive(root: Path) -> Path:
    src = root / "archive"
    src.mkdir()
    for k in range(N_FILES):
        write_mcap(src / f"f{k:02d}.mcap",
                   radar_messages(N_MSGS, site=f"R{k % 3 + 1}", t0_ns=T0_NS + k * 3600 * 10**9),
                   chunk_size=1 << 16)  # fmt: skip
    return src


def _children(pid: int) -> set[int]:
    """Every descendant of ``pid`` now (from /proc)."""
    out: set[int] = set()
    todo = [pid]
    while todo:
        p = todo.pop()
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                kids = (task / "children").read_text().split()
            except OSError:
                continue
            for k in map(int, kids):
                if k not in out:
                    out.add(k)
                    todo.append(k)
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs Linux /proc")
@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupted_ingest_exits_cleanly(tmp_path, sig, code):
    src = _archive(tmp_path)
    wh = tmp_path / "wh"
    cmd = [sys.executable, "-m", "jobs.cli", "--warehouse", str(wh), "ingest", str(src),
           "--executor", "process"]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    ledger_log = wh / "tables" / "ingest_ledger" / "_delta_log"
    deadline = time.monotonic() + 120
    while not ledger_log.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)  # until the first file is committed: workers busy with the rest
    workers = _children(proc.pid)
    assert proc.poll() is None, "the ingest finished before it could be interrupted"
    assert workers, "no pool worker seen"
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == code, (out, err)
    assert "Traceback" not in err and "BrokenProcessPool" not in err, err
    time.sleep(0.5)
    assert not [p for p in workers if _alive(p)], "pool workers left behind"
    assert not list((wh / "_staging").glob("*")) if (wh / "_staging").exists() else True
    # whatever is in the ledger is whole
    ledger = read_table(wh, "ingest_ledger").to_pylist()
    assert ledger and len(ledger) < N_FILES
    radar = read_table(wh, "radar_tracks", columns=["source_file"]).to_pylist()
    per_file: dict[str, int] = {}
    for r in radar:
        per_file[r["source_file"]] = per_file.get(r["source_file"], 0) + 1
    assert {r["source_file"] for r in ledger} == set(per_file)
    assert all(n == N_MSGS for n in per_file.values())
    # a re-run converges
    again = subprocess.run([*cmd[:-2], "--executor", "serial"], cwd=REPO, env=env,
                           capture_output=True, text=True, check=False)  # fmt: skip
    assert again.returncode == 0, again.stdout + again.stderr
    assert read_table(wh, "radar_tracks").num_rows == N_FILES * N_MSGS
