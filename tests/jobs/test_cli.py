"""The `surveil` command: exit codes and clear errors, not tracebacks."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def surveil(*args: str, cwd: Path = REPO) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "jobs.cli", *args], capture_output=True,
                          text=True, cwd=cwd, check=False)


def test_help_ok():
    res = surveil("--help")
    assert res.returncode == 0
    for cmd in ("simulate", "ingest", "batch", "report", "reprocess", "demo"):
        assert cmd in res.stdout


def test_bad_config_is_usage_error(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[region\n")
    res = surveil("--config", str(bad), "batch", "--from", "2026-01-15T00:00:00Z",
                  "--to", "2026-01-15T01:00:00Z")
    assert res.returncode == 2 and "not valid TOML" in res.stderr
    assert "Traceback" not in res.stderr


def test_missing_path_and_empty_dir_are_usage_errors(tmp_path):
    (tmp_path / "empty").mkdir()
    for target in (tmp_path / "nothing-here", tmp_path / "empty"):
        res = surveil("--warehouse", str(tmp_path / "wh"), "ingest", str(target))
        assert res.returncode == 2, res.stderr
        assert "Traceback" not in res.stderr and "error" in res.stderr.lower()


def test_bad_time_and_inverted_window(tmp_path):
    res = surveil("--warehouse", str(tmp_path), "batch", "--from", "yesterday", "--to", "now")
    assert res.returncode == 2 and "not a time" in res.stderr
    res = surveil("--warehouse", str(tmp_path), "batch", "--from", "2026-01-15T01:00:00Z",
                  "--to", "2026-01-15T00:00:00Z")
    assert res.returncode == 2


def test_report_list_and_unknown(e2e):
    res = surveil("report", "--list")
    assert res.returncode == 0 and "accuracy_by_sector" in res.stdout
    res = surveil("--warehouse", str(e2e.warehouse), "report", "no_such_report")
    assert res.returncode == 2 and "available" in res.stderr


def test_report_formats(e2e):
    for fmt in ("csv", "json", "table"):
        res = surveil("--warehouse", str(e2e.warehouse), "report", "accuracy_by_sector",
                      "--sector", "inner_channel", "--format", fmt)
        assert res.returncode == 0, res.stderr
        assert "inner_channel" in res.stdout
