"""Every report in sql/ runs, binds its parameters and has the header it promises."""

from __future__ import annotations

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


def test_report_memory_defaults_to_half_the_machine(monkeypatch):
    """Exact percentiles hold their values: a day-long report needs more than a fixed
    2 GB, so the default follows the machine (and never goes below 2 GiB)."""
    import os

    from pipeline.reports import _half_the_memory

    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    assert _half_the_memory() == f"{max(2 * 1024**3, total // 2) // 1024**2}MiB"
    monkeypatch.setattr(os, "sysconf", lambda name: (_ for _ in ()).throw(ValueError(name)))
    assert _half_the_memory() == "2048MiB"
