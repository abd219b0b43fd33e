"""`surveil audit` on a real warehouse, opened in a real headless Chromium: no script or
console error, every chart drawn, a screenshot kept (its path is printed), a PDF."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from jobs.audit import run_audit
from pipeline.audit.browser import dump_dom, find_chromium
from pipeline.audit.page import chart_count

ARTIFACTS = "audit-artifacts"


@pytest.fixture(scope="module")
def audit_page(e2e, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp(ARTIFACTS)
    result = run_audit(e2e.cfg, e2e.warehouse, out, start_ns=e2e.start_ns, end_ns=e2e.end_ns)
    return result.html


def test_page_is_self_contained(audit_page):
    page = audit_page.read_text()
    # nothing fetched from elsewhere: no external script, stylesheet, image or frame
    assert not re.search(r"""<(script|link|img|iframe)[^>]+(src|href)=["']?(https?:)?//""", page)
    assert "Plotly.newPlot" in page and "plotly.js" in page.lower()
    assert chart_count(page) >= 6  # map, accuracy, error over time, identification, SIAP, legs
    for anchor in ("verdicts", "map", "accuracy", "identification", "siap", "cross-track",
                   "faults", "heading", "gaps"):
        assert f"id='{anchor}'" in page
    # the maritime-only warehouse: the airfield sections say why they are empty
    assert "surveil simulate --scenario airfield" in page


def test_page_renders_in_chromium(audit_page):
    if find_chromium() is None:
        pytest.skip("no Chromium on PATH (apt-get install chromium; .ci/run installs it)")
    png = audit_page.with_name("audit.png")
    run = dump_dom(audit_page, png, width=1360, height=3000)
    dom = run.stdout
    errors = re.search(r'data-js-errors="([^"]*)"', dom)
    assert errors is None, errors.group(1)
    assert run.console_errors() == []
    drawn = re.search(r'data-charts-drawn="(\d+)"', dom)
    assert drawn is not None, "the page's scripts did not finish"
    assert int(drawn.group(1)) == chart_count(audit_page.read_text())
    assert dom.count('class="main-svg"') >= int(drawn.group(1))
    assert png.is_file() and png.stat().st_size > 50_000
    kept = Path(__file__).resolve().parents[2] / ".pytest-artifacts"
    kept.mkdir(exist_ok=True)
    shutil.copy(png, kept / "audit.png")
    print(f"\nscreenshot: {png} (copy: {kept / 'audit.png'})")


def test_pdf_of_the_same_page(e2e, tmp_path):
    if find_chromium() is None:
        pytest.skip("no Chromium on PATH (apt-get install chromium; .ci/run installs it)")
    result = run_audit(e2e.cfg, e2e.warehouse, tmp_path, start_ns=e2e.start_ns,
                       end_ns=e2e.end_ns, sector="inner_channel", pdf=True)
    assert result.pdf is not None, result.pdf_skipped
    assert result.pdf.read_bytes()[:5] == b"%PDF-" and result.pdf.stat().st_size > 100_000
    assert result.html.name.endswith("_inner_channel.html")
