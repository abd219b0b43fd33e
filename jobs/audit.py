"""`surveil audit`: the HTML audit of one window (and a PDF of it through headless
Chromium when asked)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from pipeline.audit.browser import BrowserError, find_chromium, print_pdf
from pipeline.audit.data import AuditData, collect
from pipeline.audit.page import render
from pipeline.config import Config
from pipeline.reports import open_warehouse
from pipeline.requirements import FAIL, OUTCOMES


@dataclass(frozen=True)
class AuditResult:
    html: Path
    pdf: Path | None
    data: AuditData
    pdf_skipped: str = ""

    def render(self) -> str:
        v = self.data.verdicts
        counts = ", ".join(f"{sum(x.outcome == s for x in v)} {s}" for s in OUTCOMES)
        lines = [f"audit: {self.html}", f"requirements: {counts}"]
        lines += [f"  FAIL {x.requirement} [{x.scope}]: {x.value} {x.unit}, required "
                  f"{x.comparison} {x.limit:g} {x.unit} ({x.samples} samples)"
                  for x in v if x.status == FAIL]
        lines += [f"WARNING: {w}" for w in self.data.provenance_warnings]
        why = sorted({x.status for x in v if x.not_applicable})
        lines += [f"  {w}" for w in why]
        if self.pdf:
            lines.append(f"pdf: {self.pdf}")
        if self.pdf_skipped:
            lines.append(f"pdf not written: {self.pdf_skipped}")
        return "\n".join(lines)


def audit_name(start_ns: int, end_ns: int, sector: str | None) -> str:
    """``audit_<from>_<to>[_<sector>].html``; in the sector's name every character but a
    letter, digit, ``.``, ``_`` or ``-`` is written ``_`` (a sector ``a/b`` is
    ``..._a_b.html``: a name from the config never makes a path)."""
    from jobs.common import iso

    stem = f"audit_{iso(start_ns)}_{iso(end_ns)}".replace(":", "").replace("-", "")
    return stem + (f"_{re.sub(r'[^A-Za-z0-9._-]', '_', sector)}" if sector else "") + ".html"


def run_audit(cfg: Config, warehouse: Path, out_dir: Path, *, start_ns: int, end_ns: int,
              sector: str | None = None, pdf: bool = False, site: str | None = None
              ) -> AuditResult:
    """Write ``<out_dir>/audit_<from>_<to>[_<sector>].html`` (and ``.pdf``) over ``site``
    (None: every site; each report row keeps its ``site``)."""
    from jobs.common import one_site

    site = one_site(warehouse, site, start_ns, end_ns)
    con = open_warehouse(warehouse)
    try:
        data = collect(con, cfg, warehouse, start_ns=start_ns, end_ns=end_ns, sector=sector,
                       site=site)
    finally:
        con.close()
    out_dir.mkdir(parents=True, exist_ok=True)
    html_path = out_dir / audit_name(start_ns, end_ns, sector)
    tmp = html_path.with_suffix(".html.tmp")
    tmp.write_text(render(data), encoding="utf-8")
    tmp.replace(html_path)
    pdf_path, skipped = None, ""
    if pdf:
        if find_chromium() is None:
            skipped = "no Chromium found (apt-get install chromium, or set SURVEIL_CHROMIUM)"
        else:
            try:
                pdf_path = html_path.with_suffix(".pdf")
                print_pdf(html_path, pdf_path)
            except BrowserError as exc:
                pdf_path, skipped = None, str(exc)
    return AuditResult(html_path, pdf_path, data, skipped)
