"""Headless Chromium on an audit page: PDF, screenshot, and the DOM after the scripts ran.

Debian's ``chromium`` (or ``$SURVEIL_CHROMIUM``); every call runs one short-lived
browser with a throw-away profile, no network (every host resolves to nothing), and a
virtual-time budget so the page's scripts finish before the output is taken.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--no-first-run", "--disable-sync", "--disable-extensions",
    "--disable-default-apps", "--hide-scrollbars", "--mute-audio",
    "--host-resolver-rules=MAP * ~NOTFOUND",  # opens without a network, or fails visibly
    "--enable-logging=stderr", "--v=0",
)
TIMEOUT_S = 180
_JS_ERROR = re.compile(r"Uncaught|SyntaxError|ReferenceError|TypeError")


class BrowserError(RuntimeError):
    """Chromium is missing or failed."""


def find_chromium() -> str | None:
    """Path of a Chromium binary: ``$SURVEIL_CHROMIUM``, else the first on PATH."""
    env = os.environ.get("SURVEIL_CHROMIUM")
    if env:
        return env if Path(env).exists() else shutil.which(env)
    for name in CANDIDATES:
        found = shutil.which(name)
        if found:
            return found
    return None


@dataclass(frozen=True)
class BrowserRun:
    stdout: str
    stderr: str

    def console_errors(self) -> list[str]:
        """Console messages at error level and uncaught exceptions the browser logged."""
        out = []
        for line in self.stderr.splitlines():
            console_error = "CONSOLE" in line and ("ERROR" in line or "Uncaught" in line)
            if console_error or _JS_ERROR.search(line):
                out.append(line)
        return out


def _run(html_path: Path, *extra: str, budget_ms: int = 20_000) -> BrowserRun:
    exe = find_chromium()
    if exe is None:
        raise BrowserError("no Chromium found (apt-get install chromium, or set "
                           "SURVEIL_CHROMIUM)")
    with tempfile.TemporaryDirectory(prefix="surveil-chromium-") as profile:
        cmd = [exe, *FLAGS, f"--user-data-dir={profile}",
               f"--virtual-time-budget={budget_ms}", *extra, Path(html_path).resolve().as_uri()]
        try:
            res = subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT_S,
                                 check=False)
        except subprocess.TimeoutExpired as exc:
            raise BrowserError(f"chromium did not finish in {TIMEOUT_S} s") from exc
    if res.returncode != 0:
        raise BrowserError(f"chromium exited {res.returncode}: {res.stderr[-2000:]}")
    return BrowserRun(res.stdout, res.stderr)


def print_pdf(html_path: Path, pdf_path: Path) -> BrowserRun:
    """The page as a PDF (A4 by Chromium's default print settings, no header/footer)."""
    pdf_path = Path(pdf_path).resolve()
    run = _run(html_path, f"--print-to-pdf={pdf_path}", "--no-pdf-header-footer")
    if not pdf_path.is_file():
        raise BrowserError(f"chromium wrote no PDF: {run.stderr[-2000:]}")
    return run


def screenshot(html_path: Path, png_path: Path, width: int = 1360, height: int = 2400
               ) -> BrowserRun:
    """A PNG of the page's first ``width`` x ``height`` pixels."""
    png_path = Path(png_path).resolve()
    run = _run(html_path, f"--screenshot={png_path}", f"--window-size={width},{height}")
    if not png_path.is_file():
        raise BrowserError(f"chromium wrote no screenshot: {run.stderr[-2000:]}")
    return run


def dump_dom(html_path: Path, png_path: Path | None = None, width: int = 1360,
             height: int = 2400) -> BrowserRun:
    """The DOM after the page's scripts ran (``stdout``) and the browser's log; with
    ``png_path``, a screenshot of the same run too (one browser start, ~20 s here)."""
    extra = [f"--screenshot={Path(png_path).resolve()}"] if png_path is not None else []
    return _run(html_path, "--dump-dom", *extra, f"--window-size={width},{height}")
