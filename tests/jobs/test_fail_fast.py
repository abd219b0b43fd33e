"""Fail fast and clearly (issue 17, item 6): a command that reads a warehouse that does
not exist exits 2 naming it and creates nothing; no bad option gives a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from jobs.cli import main

REPO = Path(__file__).resolve().parents[2]
WINDOW = ("--from", "2026-01-15T00:00:00Z", "--to", "2026-01-15T01:00:00Z")

# every command that reads a warehouse (only ingest, run and demo create one)
READERS = {
    "batch": ("batch", *WINDOW, "--executor", "serial"),
    "reprocess": ("reprocess", *WINDOW, "--executor", "serial"),
    "report": ("report", "accuracy_by_sector"),
    "report-window": ("report", "siap_by_sector", *WINDOW, "--format", "csv"),
    "sql": ("sql", "SELECT 1"),
    "audit": ("audit", *WINDOW, "--out", "AUDIT"),
    "export": ("export", *WINDOW, "--out", "OUT.mcap"),
    "calibrate": ("calibrate", *WINDOW),
    "calibrate-radars": ("calibrate-radars", *WINDOW),
    "doctor": ("doctor",),
    "doctor-repair": ("doctor", "--repair"),
}


def surveil(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
            *args: str) -> tuple[int, str, str]:
    """The console entry point (``jobs.cli:main``) in-process: (exit code, out, err)."""
    monkeypatch.setattr(sys, "argv", ["surveil", *args])
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("name", list(READERS))
def test_reading_a_missing_warehouse_is_exit_2_naming_it(name, tmp_path, monkeypatch, capsys):
    missing = tmp_path / "no-such-warehouse"
    args = [a.replace("AUDIT", str(tmp_path / "audit")).replace("OUT", str(tmp_path / "x"))
            for a in READERS[name]]
    code, out, err = surveil(monkeypatch, capsys, "--warehouse", str(missing), *args)
    assert code == 2, (out, err)
    assert f"warehouse {missing} does not exist" in err
    assert "Traceback" not in err and "committed" not in out
    assert not missing.exists()  # nothing created
    # a folder that is not a warehouse (no tables/) is named too
    code, _, err = surveil(monkeypatch, capsys, "--warehouse", str(tmp_path), *args)
    assert code == 2 and f"warehouse {tmp_path} is not a warehouse" in err
    assert not (tmp_path / "tables").exists()


def test_missing_warehouse_as_a_real_process(tmp_path):
    """Was: `report` printed an empty table with exit 0, `batch` created a warehouse and
    said "committed"."""
    missing = tmp_path / "wh"
    for args in (("report", "siap_by_sector"), ("batch", *WINDOW)):
        res = subprocess.run([sys.executable, "-m", "jobs.cli", "--warehouse", str(missing),
                              *args], capture_output=True, text=True, cwd=REPO, check=False)
        assert res.returncode == 2, res.stderr
        assert str(missing) in res.stderr and "Traceback" not in res.stderr
        assert not missing.exists()


BAD_OPTIONS = [
    ("--log-level", "bogus", "report", "--list"),
    ("--log-json", "maybe", "report", "--list"),
    ("--config", "/no/such/file.toml", "report", "--list"),
    ("--config", str(REPO), "report", "--list"),  # a folder
    ("--warehouse", str(REPO / "README.md"), "report", "siap_by_sector"),  # a file
    ("--no-such-option",),
    ("no-such-command",),
    ("batch", "--from", "yesterday", "--to", "now"),
    ("batch", "--from", "2026-01-15T01:00:00Z", "--to", "2026-01-15T00:00:00Z"),
    ("batch", *WINDOW, "--executor", "bogus"),
    ("batch", "--from", "2026-01-15T00:00:00Z"),
    ("reprocess", "--from", "2026-13-45T00:00:00Z", "--to", "2026-01-15T00:00:00Z"),
    ("report", "no_such_report"),
    ("report", "siap_by_sector", "--format", "xml"),
    ("report", "siap_by_sector", "--sector", "atlantis"),
    ("report", "siap_by_sector", "--param", "novalue"),
    ("report", "siap_by_sector", "--from", "noon"),
    ("simulate", "--scenario", "moon", "--out", "X"),
    ("simulate", "--duration", "0", "--out", "X"),
    ("simulate", "--duration", "forever", "--out", "X"),
    ("simulate", "--seed", "abc", "--out", "X"),
    ("simulate", "--start", "tomorrow", "--out", "X"),
    ("ingest",),
    ("ingest", "/no/such/archive"),
    ("ingest", "X", "--from", "never"),
    ("demo", "--scenarios", "moon"),
    ("demo", "--duration", "-1h"),
    ("schema", "no_such_table"),
    ("sql", "SELECT * FROM no_such_table"),
    ("audit", *WINDOW),
    ("export", *WINDOW),
    ("calibrate", *WINDOW, "--max-order", "99"),
    ("experiment", "identification", "--sigma", "abc"),
    ("experiment", "ownship", "--runs", "0"),
    ("experiment", "ownship", "--duration", "0s"),
    ("gaps-montecarlo", "--particles", "5"),
    ("config", "check", "/no/such.toml"),
    ("import", "X", "--out", "Y", "--base-time", "whenever"),
]


@pytest.mark.parametrize("args", BAD_OPTIONS, ids=[" ".join(a)[:60] for a in BAD_OPTIONS])
def test_no_bad_option_gives_a_traceback(args, e2e, tmp_path, monkeypatch, capsys):
    """Exit 2 with a one-line reason, never a traceback (the warehouse exists, so the
    option itself is what fails)."""
    args = [a.replace("X", str(tmp_path / "x")).replace("Y", str(tmp_path / "y"))
            if len(a) == 1 else a for a in args]
    if "--warehouse" not in args:
        args = ["--warehouse", str(e2e.warehouse), *args]
    code, out, err = surveil(monkeypatch, capsys, *args)
    assert code == 2, (args, out, err)
    assert "Traceback" not in err + out
    assert err.strip(), "no reason given"
