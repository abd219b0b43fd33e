"""The `surveil` command: exit codes and clear errors, not tracebacks."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def surveil(*args: str, cwd: Path = REPO, env: dict[str, str] | None = None
            ) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "jobs.cli", *args], capture_output=True,
                          text=True, cwd=cwd, check=False,
                          env=None if env is None else {**os.environ, **env})


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


WINDOW = ("--from", "2026-01-15T00:50:00Z", "--to", "2026-01-15T01:10:00Z")


def test_csv_report_is_streamed_as_the_whole_table_formats_it(e2e, monkeypatch):
    """`report --format csv` writes DuckDB's record batches as they come: the same text
    as the whole table formatted (was: the table, its CSV bytes and their text held at
    once: 7.6 GB for map_tracks over a regional day), here in 1,000-row batches."""
    import io

    import pipeline.reports
    from pipeline.render import format_report
    from pipeline.reports import named_report_batches, run_named_report, write_csv

    whole = run_named_report(e2e.warehouse, "map_tracks")
    assert whole.num_rows > 3_000
    monkeypatch.setattr(pipeline.reports, "ROWS_PER_BATCH", 1_000)
    buf = io.BytesIO()
    with named_report_batches(e2e.warehouse, "map_tracks") as reader:
        assert write_csv(reader, buf) == whole.num_rows
    assert buf.getvalue().decode() == format_report(whole, "csv")
    res = surveil("--warehouse", str(e2e.warehouse), "report", "map_tracks", "--format", "csv")
    assert res.returncode == 0 and res.stdout == format_report(whole, "csv")


def test_a_report_out_of_duckdb_memory_says_what_to_do(e2e):
    res = surveil("--warehouse", str(e2e.warehouse), "report", "map_tracks", "--format", "csv",
                  env={"SURVEIL_REPORT_MEMORY": "1MB"})
    assert res.returncode == 1 and "SURVEIL_REPORT_MEMORY" in res.stderr
    assert "Traceback" not in res.stderr


def test_global_options_after_the_subcommand_and_unknown_sector(e2e):
    res = surveil("report", "accuracy_by_sector", "--warehouse", str(e2e.warehouse),
                  "--sector", "nowhere")
    assert res.returncode == 2 and "approach_sw" in res.stderr and "runway" in res.stderr
    res = surveil("report", "accuracy_by_sector", "--warehouse", str(e2e.warehouse), *WINDOW)
    assert res.returncode == 0 and "inner_channel" in res.stdout
    res = surveil("batch", *WINDOW, "--config", "/no/such.toml")
    assert res.returncode == 2 and "not found" in res.stderr


def test_empty_report_says_why(e2e):
    res = surveil("--warehouse", str(e2e.warehouse), "report", "surface_accuracy_by_area",
                  *WINDOW)
    assert res.returncode == 0
    assert "airfield_obs" in res.stderr and "surveil simulate --scenario airfield" in res.stderr


def test_sql_and_schema(e2e):
    res = surveil("--warehouse", str(e2e.warehouse), "sql",
                  "SELECT count(*) AS n FROM system_tracks", "--format", "json")
    assert res.returncode == 0 and '"n"' in res.stdout
    res = surveil("--warehouse", str(e2e.warehouse), "sql", "SELECT * FROM no_such_table")
    assert res.returncode == 2 and "no_such_table" in res.stderr
    res = subprocess.run([sys.executable, "-m", "jobs.cli", "--warehouse", str(e2e.warehouse),
                          "sql"], input="SELECT 40 + 2 AS answer;\n.quit\n", text=True,
                         capture_output=True, cwd=REPO, check=False)
    assert res.returncode == 0 and "42" in res.stdout
    # piped without a final ';' (was: nothing run, exit 0), and a query opening with a
    # comment (was: exit 2, click read "-- ..." as an option)
    res = subprocess.run([sys.executable, "-m", "jobs.cli", "--warehouse", str(e2e.warehouse),
                          "sql", "--format", "csv"], input="SELECT 1 AS a;\nSELECT 40 + 2 AS b",
                         text=True, capture_output=True, cwd=REPO, check=False)
    assert res.returncode == 0 and res.stdout.split() == ['"b"', "42"], res.stderr
    res = surveil("--warehouse", str(e2e.warehouse), "sql", "-- the answer\nSELECT 6 * 7 AS c",
                  "--format", "csv")
    assert res.returncode == 0 and res.stdout.split() == ['"c"', "42"], res.stderr
    res = surveil("schema", "radar_tracks", "--format", "csv")
    assert res.returncode == 0
    assert '"range_m","double","no","m","slant range from the site, m"' in res.stdout
    res = surveil("schema")
    assert res.returncode == 0 and "cross_track_by_leg" in res.stdout


def test_shell_completion_offers_report_names():
    import os

    env = {**os.environ, "_SURVEIL_COMPLETE": "bash_complete", "COMP_WORDS": "surveil report acc",
           "COMP_CWORD": "2"}
    code = "from jobs.cli import cli; cli(prog_name='surveil')"
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         cwd=REPO, check=False)
    assert "accuracy_by_sector" in res.stdout and "accuracy_over_time" in res.stdout


def test_scenario_choices_are_the_registered_scenarios():
    from jobs.cli import SCENARIO_NAMES, simulate
    from pipeline.simulate.scenarios import SCENARIOS

    choice = next(p for p in simulate.params if p.name == "scenario").type
    assert sorted(choice.choices) == sorted(SCENARIOS) == sorted(SCENARIO_NAMES)
