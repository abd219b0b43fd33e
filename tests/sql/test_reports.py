"""Every report in sql/ runs, binds its parameters and has the header it promises."""

from __future__ import annotations

import re

import duckdb
import pytest

from jobs.demo import DEMO_REPORTS
from pipeline.render import format_report
from pipeline.reports import UnknownReportError, list_reports, load_report, run_named_report


@pytest.mark.parametrize("name", list_reports())
def test_report_header(name):
    r = load_report(name)
    assert r.header.get("name") == name
    assert "grain" in r.header and "params" in r.header
    assert "ORDER BY" in r.text.upper()
    # the same rows on every run: mode() breaks ties by thread timing unless ordered
    for m in re.finditer(r"\bmode\(([^()]*)\)", r.text, re.IGNORECASE):
        assert "ORDER BY" in m.group(1).upper(), f"{name}: {m.group(0)} (write mode(x ORDER BY x))"


def test_ordered_mode_breaks_ties_by_the_smallest_value():
    """What the reports rely on (sql/README.md): DuckDB's mode(x ORDER BY x) over many
    threads and row groups returns the smallest of the tied values."""
    con = duckdb.connect(config={"threads": 4})
    got = con.execute(
        "SELECT g, mode(x ORDER BY x) FROM (SELECT i % 1000 AS g, (i * 7919) % 3 AS x "
        "FROM range(3000000) t(i)) GROUP BY g ORDER BY g").fetchall()
    assert {x for _, x in got} == {0}  # each group holds 0, 1, 2 equally often


@pytest.mark.parametrize("name", list_reports())
def test_report_runs_on_the_warehouse(e2e, name):
    """Every report runs on the maritime warehouse; the spine's reports are non-empty
    there. Every report's rows and figures: tests/sql/test_report_values.py (a warehouse
    of every family)."""
    t = run_named_report(e2e.warehouse, name, start_ns=e2e.start_ns, end_ns=e2e.end_ns)
    if name in DEMO_REPORTS:
        assert t.num_rows > 0
    for fmt in ("table", "csv", "json"):
        assert format_report(t, fmt, title=name)


@pytest.mark.parametrize("name", list_reports())
def test_report_on_empty_window_is_empty(e2e, name):
    t = run_named_report(e2e.warehouse, name, start_ns=0, end_ns=1)
    assert t.num_rows == 0


@pytest.mark.parametrize("bad", ["nope", "../etc/passwd", "a;drop"])
def test_unknown_report(bad):
    with pytest.raises(UnknownReportError):
        load_report(bad)


def test_report_memory_defaults_to_half_the_machine():
    """Exact percentiles hold their values: a day-long report needs more than a fixed
    2 GB, so the default follows the machine (and never goes below 2 GiB)."""
    import os

    from pipeline.reports import REPORT_MEMORY, half_the_memory
    from pipeline.threads import machine_memory_bytes

    gib = 1024**3
    assert half_the_memory(24 * gib) == "12288MiB"
    assert half_the_memory(3 * gib) == half_the_memory(0) == "2048MiB"
    assert machine_memory_bytes() > 0  # Linux: sysconf or the cgroup
    if "SURVEIL_REPORT_MEMORY" not in os.environ:
        assert half_the_memory(machine_memory_bytes()) == REPORT_MEMORY
